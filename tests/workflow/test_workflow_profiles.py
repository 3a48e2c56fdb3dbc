"""What each job asks for: workflow/profiles/default under every run, the slurm profile on top,
GPUs from the config (dry runs only: seconds, no slow marker)."""

from __future__ import annotations

import importlib.util
import re
import subprocess
from collections import Counter

import pytest
import yaml

from .conftest import REPO, SNAKEMAKE, planned_job_blocks, planned_jobs, shown_pages, snakemake

DEFAULT = yaml.safe_load((REPO / "workflow" / "profiles" / "default" / "config.yaml").read_text())
SLURM = yaml.safe_load((REPO / "workflow" / "profiles" / "slurm" / "config.yaml").read_text())
needs_plugin = pytest.mark.skipif(importlib.util.find_spec("snakemake_executor_plugin_slurm") is None,
                                  reason="snakemake-executor-plugin-slurm is not installed")


def job_requests(output: str) -> list[tuple[str, dict, dict]]:
    """(rule, wildcards, {resource: value, 'threads': n}) of every job a dry run plans."""
    jobs = []
    for rule, wildcards, block in planned_job_blocks(output):
        res = re.search(r"resources: (.*)", block)
        threads = re.search(r"threads: (\d+)", block)
        requests = dict(kv.split("=", 1) for kv in res.group(1).split(", ")) if res else {}
        requests["threads"] = threads.group(1) if threads else "1"
        jobs.append((rule, wildcards, requests))
    return jobs


def by_rule(jobs) -> dict[str, dict]:
    return {rule: requests for rule, _, requests in jobs}


def test_default_profile_takes_effect_without_being_named(tmp_path):
    # Snakemake finds a workflow profile beside the Snakefile only; the workflow applies ours.
    # (Cores enough for every job's threads: Snakemake lowers a job's threads to the run's cores.)
    rules = by_rule(job_requests(snakemake(tmp_path, "-n", "-c", "4").stdout))
    for rule, requests in rules.items():
        expected = {**DEFAULT["default-resources"], **DEFAULT["set-resources"].get(rule, {})}
        assert {k: int(requests[k]) for k in expected} == expected, rule
        assert int(requests["threads"]) == DEFAULT["set-threads"].get(rule, 1), rule


def test_command_line_changes_one_value_and_keeps_the_rest(tmp_path):
    out = snakemake(tmp_path, "-n", "-c", "2", "--set-threads", "train=2", "--set-resources", "train:mem_mb=1234",
                    "--default-resources", "runtime=45").stdout
    rules = by_rule(job_requests(out))
    assert rules["train"]["threads"] == "2" and rules["train"]["mem_mb"] == "1234"
    assert int(rules["train"]["runtime"]) == DEFAULT["set-resources"]["train"]["runtime"]
    assert rules["twin"]["runtime"] == "45" and int(rules["twin"]["mem_mb"]) == DEFAULT["default-resources"]["mem_mb"]
    assert rules["rollout"]["threads"] == str(DEFAULT["set-threads"]["rollout"])


def test_gpus_follow_the_config(tmp_path):
    # A CPU experiment asks for no GPU; a policy fine-tuned on cuda asks for one in its training
    # job only, and a transformers judge on cuda in its two judge jobs only.
    assert not any("gpu" in r for _, _, r in job_requests(snakemake(tmp_path / "cpu", "-n").stdout))
    overrides = ["+policies.act.device=cuda",
                 "+judges.local_vlm={backend:transformers,family:qwen3_vl,model:some/vlm,device:cuda}"]
    jobs = job_requests(snakemake(tmp_path / "gpu", "-n", overrides=overrides).stdout)
    on_gpu = {(rule, tuple(wc.values())) for rule, wc, r in jobs if r.get("gpu") == "1"}
    policies = {wc["policy"] for rule, wc, _ in jobs if rule == "describe"}
    assert len(policies) >= 2 and on_gpu == {
        ("train", ("real", "act")), ("train", ("sim", "act")), ("judge_pairs", ("local_vlm",)),
        *(("describe", ("local_vlm", p)) for p in policies),  # one describe job per policy
    }
    assert all(r.get("gpu", "0") == "0" for rule, wc, r in jobs if (rule, tuple(wc.values())) not in on_gpu)


@needs_plugin
def test_slurm_profile_plans_the_paper_in_tens_of_jobs(tmp_path):
    # The paper's experiment through the slurm profile, as documented: one Slurm job per
    # Snakemake job, rollouts batched per arm and policy, VLA jobs on the GPU partition.
    cmd = [*SNAKEMAKE, "-s", str(REPO / "Snakefile"), "-d", str(tmp_path), "-n",
           "--profile", "workflow/profiles/slurm", "--config", "experiment=paper"]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    jobs = job_requests(proc.stdout)
    assert len(jobs) == len(planned_jobs(proc.stdout)) < 200
    # The docs (Running on a cluster) document this count (the dry run's total counts `all` too).
    readme = "\n".join(shown_pages().values())
    assert f"| `paper` | {len(jobs)} |" in readme
    assert f"fresh directory: total {len(jobs) + 1}, {len(jobs)} Slurm jobs" in readme
    policies = {wc["policy"] for rule, wc, _ in jobs if rule == "train"}
    assert len([1 for rule, _, _ in jobs if rule == "rollout"]) == 2 * len(policies) >= 8
    # ... and the jobs that ask for a GPU, rule by rule.
    on_gpu = Counter(rule for rule, _, requests in jobs if requests.get("gpu") == "1")
    said = re.search(r"in `paper` (\d+) jobs do: (.*?) \(", " ".join(readme.split()))
    assert said, "docs/cluster.md says how many of the paper's jobs ask for a GPU"
    assert int(said.group(1)) == sum(on_gpu.values())
    assert {rule: int(n) for n, rule in re.findall(r"(\d+) `(\w+)`", said.group(2))} == on_gpu
    for rule, _, requests in jobs:
        gpu_stage = rule in {"train", "rollout", "cross_rollout"}  # VLAs on cuda; the vLLM judges are a service
        assert requests.get("gpu", "0") == ("1" if gpu_stage else "0"), rule
        assert requests["slurm_partition"] == ("gpu" if gpu_stage else "cpu"), rule
        assert requests["slurm_account"] == "my_lab"


SIZE = re.compile(r"(\d+) / ([\d.]+) GB / (\d+) (h|min)( × attempt)?")


def _documented(size: str) -> tuple[int, float, int, bool]:
    """(threads, GB, minutes, grows with the attempt) of a cell of docs/cluster.md's size table."""
    threads, gb, runtime, unit, attempt = SIZE.match(size).groups()
    return int(threads), float(gb), int(runtime) * (60 if unit == "h" else 1), attempt is not None


def _profile_size(threads: int, resources: dict) -> tuple[int, float, int, bool]:
    runtime = str(resources["runtime"])
    base = re.fullmatch(r"(\d+)(?: \* attempt)?", runtime)
    assert base, f"a run time the docs' table cannot show: {runtime!r}"
    return threads, resources["mem_mb"] / 1000, int(base.group(1)), "attempt" in runtime


def test_the_cluster_page_shows_what_each_stage_asks_for():
    # docs/cluster.md's table, row by row, against the two profiles as the workflow merges them:
    # the default profile under every run, the slurm profile's values over it rule by rule.
    rows = re.findall(r"^\| (.+?) \| (.+?) \| (.+?) \|$", (REPO / "docs" / "cluster.md").read_text(), re.M)
    shown = {}
    for names, default, slurm in rows:
        if SIZE.match(default) and SIZE.match(slurm):
            for rule in re.findall(r"`(\w+)`", names) or [None]:  # None: "every other rule"
                shown[rule] = (_documented(default), _documented(slurm))
    sized = {*DEFAULT["set-threads"], *DEFAULT["set-resources"], *SLURM["set-threads"], *SLURM["set-resources"]}
    assert sized <= set(shown), f"the table leaves out {sorted(sized - set(shown))}"
    for rule, (default, slurm) in shown.items():
        threads = DEFAULT["set-threads"].get(rule, 1)
        resources = {**DEFAULT["default-resources"], **DEFAULT["set-resources"].get(rule, {})}
        assert default == _profile_size(threads, resources), rule
        resources = {**DEFAULT["default-resources"], **SLURM["default-resources"],
                     **DEFAULT["set-resources"].get(rule, {}), **SLURM["set-resources"].get(rule, {})}
        assert slurm == _profile_size(SLURM["set-threads"].get(rule, threads), resources), rule
