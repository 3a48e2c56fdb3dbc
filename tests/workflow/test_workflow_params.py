"""Rule params match what stages read: each stage's READS/PROVIDED declaration against its code,
every rule's --cfg built from that declaration, and transport settings outside the rerun check
(dry runs only: seconds, no slow marker)."""

from __future__ import annotations

import ast
import re
import shlex
import subprocess
from pathlib import Path

import pytest

from r2s_eval.stages._reads import STAGES_DIR, declaration

from .conftest import REPO, SNAKEMAKE, overrides_arg, planned_job_blocks, snakemake

STAGES = sorted(p.stem for p in STAGES_DIR.glob("*.py") if not p.stem.startswith("_"))
RULES = sorted((REPO / "workflow" / "rules").glob("*.smk"))


def _is_cfg(node: ast.AST) -> bool:
    """`args.cfg` or `cfg`, the stage's own name for its --cfg slice."""
    return (isinstance(node, ast.Attribute) and node.attr == "cfg" and isinstance(node.value, ast.Name)
            and node.value.id == "args") or (isinstance(node, ast.Name) and node.id == "cfg")


def _config_keys_read(stage: str) -> set[str]:
    """Top-level keys the stage reads from its --cfg: `args.cfg[...]`, `cfg[...]`, `.get(...)` on
    either, where `cfg` is the stage's own name for it."""
    tree = ast.parse((STAGES_DIR / f"{stage}.py").read_text())
    keys = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):  # a callee reading the whole config would hide its reads
            whole = [a for a in [*node.args, *(k.value for k in node.keywords)] if _is_cfg(a)]
            assert not whole, f"stage {stage} line {node.lineno} passes its whole --cfg to a call: pass the slices"
        if isinstance(node, ast.Subscript) and _is_cfg(node.value) and isinstance(node.slice, ast.Constant):
            keys.add(node.slice.value)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get"
              and _is_cfg(node.func.value) and node.args and isinstance(node.args[0], ast.Constant)):
            keys.add(node.args[0].value)
    return keys


@pytest.mark.parametrize("stage", STAGES)
def test_each_stage_declares_exactly_what_it_reads(stage):
    decl = declaration(stage)
    declared = set(decl["READS"]) | set(decl["PROVIDED"])
    assert _config_keys_read(stage) == declared, f"stage {stage}: reads {_config_keys_read(stage)}, declares {declared}"


@pytest.mark.parametrize("stage", STAGES)
def test_each_stage_reads_a_setting_by_its_declared_path(stage):
    # `cfg["stats.n_boot"]`, never `cfg["stats"]["n_boot"]`: a stage declares the settings it
    # uses, so a change elsewhere in their group never reruns it (a group is declared only where
    # it is handed whole to a library call, or is the stage's own options, report.<name>).
    tree = ast.parse((STAGES_DIR / f"{stage}.py").read_text())
    nested = [node.lineno for node in ast.walk(tree)
              if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Subscript) and _is_cfg(node.value.value)]
    assert not nested, f"stages/{stage}.py lines {nested} index into a config group: declare the dotted path"


def test_every_rule_builds_its_cfg_from_the_stage_declaration():
    text = "\n".join(p.read_text() for p in RULES)
    assert "params_of(" not in text
    for block in re.split(r"\n(?=\s*rule \w+:)", text):
        stage = re.search(r"-m r2s_eval\.stages\.(\w+)", block)
        if not stage:
            continue
        stage = stage.group(1)
        decl = declaration(stage)
        if "--cfg" in block:
            assert decl["READS"] or decl["PROVIDED"], f"rule running {stage} passes --cfg, the stage declares none"
            helper = re.search(r"cfg=(\w+)", block).group(1)
            assert helper in ("stage_params", "policy_params", "rollout_params", "judge_params", "libero_rollout_params",
                              "cross_rollout_params", "ablation_rollout_params", "seed_rollout_params",
                              "twin_ablation_params", "sim_variant_params", "twin_alone_params",
                              "sim_variant_rollout_params"), block
            if helper == "stage_params":
                assert f'stage_params("{stage}"' in block, block  # with the values it PROVIDES, if any
        else:
            assert not decl["READS"] and not decl["PROVIDED"], f"stage {stage} declares config its rule never passes"


def _stage_cfg(workdir: Path, stage: str, target: str, overrides: list[str]) -> dict:
    """The --cfg a dry run would hand to `stage` (what Snakemake compares on rerun)."""
    import json

    out = snakemake(workdir, "-n", "-p", target, overrides=overrides).stdout
    for line in out.splitlines():
        if f"r2s_eval.stages.{stage} " in line:
            argv = shlex.split(line.strip())
            return json.loads(argv[argv.index("--cfg") + 1])
    raise AssertionError(f"no {stage} job in the plan:\n{out[-2000:]}")


def test_moving_a_judge_server_changes_nothing_snakemake_compares(tmp_path):
    judge = "+judges.vlm={{backend:openai,model:tiny-vlm,base_url:'{url}',concurrency:{n},timeout_s:{t}}}"
    a = _stage_cfg(tmp_path / "a", "describe", "results/judge/vlm/descriptions.parquet",
                   [judge.format(url="http://127.0.0.1:8000/v1", n=1, t=120)])
    b = _stage_cfg(tmp_path / "b", "describe", "results/judge/vlm/descriptions.parquet",
                   [judge.format(url="http://gpu-box:9000/v1", n=8, t=30)])
    assert a == b and a["judge"]["model"] == "tiny-vlm" and "base_url" not in a["judge"]
    c = _stage_cfg(tmp_path / "c", "describe", "results/judge/vlm/descriptions.parquet",
                   ["+judges.vlm={backend:openai,model:other-vlm,base_url:'http://127.0.0.1:8000/v1'}"])
    assert c != a  # the model is what answers: changing it reruns judging


def test_batching_rollouts_differently_changes_nothing_snakemake_compares(tmp_path):
    target = "results/rollout/sim/act"
    a = _stage_cfg(tmp_path / "a", "rollout", target, ["rollout.batch_episodes=1"])
    b = _stage_cfg(tmp_path / "b", "rollout", target, ["rollout.batch_episodes=5"])
    assert a == b and "batch_episodes" not in a["rollout"]
    c = _stage_cfg(tmp_path / "c", "rollout", target, ["rollout.model_batch=4"])
    assert c != a and c["rollout"]["model_batch"] == 4  # the call shape decides rounding: it reruns


@pytest.mark.parametrize("stage", STAGES)
def test_stage_entry_points_stay_thin(stage):
    # Parse, one library call, write: domain logic lives in its package.
    lines = len((STAGES_DIR / f"{stage}.py").read_text().splitlines())
    assert lines <= 80, f"stages/{stage}.py has {lines} lines; move its logic into the library"
    source = (STAGES_DIR / f"{stage}.py").read_text()
    others = re.findall(r"from r2s_eval\.stages\.(?!_cli|_reads)(\w+) import", source)
    assert not others, f"stages/{stage}.py imports other entry points {others}"


def test_the_joint_fit_s_settings_never_rerun_the_pose_estimate(tmp_path):
    target = "results/init/estimates.parquet"
    a = _stage_cfg(tmp_path / "a", "init_estimate", target, [])
    b = _stage_cfg(tmp_path / "b", "init_estimate", target, ["calib.joints.iterations=3"])
    assert a == b and "calib.joints" not in a and a["calib.camera"] == "head_left"
    c = _stage_cfg(tmp_path / "c", "init_estimate", target, ["calib.refine.max_iterations=4"])
    assert c != a


def _demo(workdir: Path, *args: str, overrides: list[str] = ()) -> str:
    cmd = [*SNAKEMAKE, "-s", str(REPO / "Snakefile"), "-d", str(workdir), *args, "--config", "experiment=demo"]
    proc = subprocess.run(cmd + ([overrides_arg(list(overrides))] if overrides else []), capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc.stdout


def _commands(out: str) -> dict[tuple, list[str]]:
    """{(rule, wildcards): the shell lines that hand it its --cfg} of a dry run's jobs."""
    return {(rule, tuple(sorted(wc.items()))): [line for line in block.splitlines() if "--cfg" in line]
            for rule, wc, block in planned_job_blocks(out)}


def _descendants(rulegraph: str, rules: set[str]) -> set[str]:
    labels = dict(re.findall(r'(\d+)\[label = "(\w+)"', rulegraph))
    children: dict[str, set[str]] = {}
    for a, b in re.findall(r"(\d+) -> (\d+)", rulegraph):
        children.setdefault(labels[a], set()).add(labels[b])
    seen, todo = set(rules), list(rules)
    while todo:
        for child in children.get(todo.pop(), ()):
            if child not in seen:
                seen.add(child)
                todo.append(child)
    return seen - {"all"}


def test_the_configuration_page_says_which_jobs_a_statistics_field_reruns(tmp_path):
    # docs/configuration.md lists, per statistics field, the jobs whose --cfg changes (Snakemake's
    # params trigger) and then the jobs downstream of them (their inputs get newer).
    page = " ".join((REPO / "docs" / "configuration.md").read_text().split())
    plain = _commands(_demo(tmp_path / "plain", "-n", "-p"))
    graph = _demo(tmp_path / "graph", "--rulegraph")
    for override, shown in [("stats.n_boot=500", "`stats.n_boot` or `stats.ci_level`:"),
                            ("stats.ci_level=0.9", "`stats.n_boot` or `stats.ci_level`:"),
                            ("stats.interval=binomial", "`stats.interval`:")]:
        changed = _commands(_demo(tmp_path / override, "-n", "-p", overrides=[override]))
        assert changed.keys() == plain.keys()
        direct = {rule for (rule, wc), lines in changed.items() if lines != plain[rule, wc]}
        said = page[page.index(f"- {shown}") + len(shown) + 2:].split(" - ")[0].split(".")[0]
        first, then = said.split("; then ")
        assert set(re.findall(r"`(\w+)`", first)) == direct, override
        assert set(re.findall(r"`(\w+)`", then)) == _descendants(graph, direct) - direct, override
