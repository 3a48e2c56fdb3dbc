"""Compose the Hydra configuration once, validate it, and hand out plain, key-sorted slices.

Snakemake compares rule params by `repr()`, so every slice given to a rule must be a plain
container (no DictConfig) with a stable key order; otherwise a rerun is missed or forced.

The composed config is checked against the typed schema (`r2s_eval.schema`) before it is
returned: an unknown, misplaced or mistyped key is a ConfigError naming the key and the file or
command-line override that set it.
"""

from __future__ import annotations

import copy
import json
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

from hydra import compose, initialize_config_dir
from hydra.errors import HydraException
import yaml
from omegaconf import OmegaConf, open_dict
from omegaconf.errors import OmegaConfBaseException

from r2s_eval.errors import ConfigError, R2SError
from r2s_eval.paths import CONF_DIR
from r2s_eval.schema import (
    WITHOUT_TRAINING,
    Source,
    composition_sources,
    config_problems,
    foreign_cameras,
    problems_error,
    unknown_override_problem,
    where,
)


def compose_config(
    config_dir: str | Path,
    experiment: str = "demo",
    overrides: Sequence[str] = (),
    config_name: str = "config",
) -> dict[str, Any]:
    """Compose `config_name` with the experiment and user overrides into a plain, validated dict."""
    return compose_with_layers(config_dir, experiment, overrides, config_name)[0]


def compose_with_layers(
    config_dir: str | Path,
    experiment: str = "demo",
    overrides: Sequence[str] = (),
    config_name: str = "config",
) -> tuple[dict[str, Any], list[Source], set[str]]:
    """``compose_config``'s dict, the layers it was composed from (highest precedence first) and
    the paths filled in from the world (``derive_camera_settings``)."""
    config_dir = Path(config_dir).resolve()
    if not (config_dir / f"{config_name}.yaml").exists():
        raise FileNotFoundError(f"no Hydra config {config_name}.yaml in {config_dir}")
    overrides = list(overrides)
    # Hydra stops at the first override of a key it does not have: each such override is set
    # aside and the rest composed again, so that every problem is reported at once.
    refused: list[str] = []
    while True:
        try:
            with initialize_config_dir(config_dir=str(config_dir), version_base="1.3"):
                cfg = compose(config_name=config_name, overrides=[f"experiment={experiment}", *overrides],
                              return_hydra_config=True)
            break
        except (HydraException, OmegaConfBaseException) as exc:
            line = _refused_override(exc, overrides)
            if line is None:
                raise _composition_error(exc, experiment, overrides, refused) from exc
            refused.append(unknown_override_problem(_override_key(line), line))
            overrides = [o for o in overrides if o is not line]
    choices = OmegaConf.to_container(cfg.hydra.runtime.choices)
    with open_dict(cfg):
        del cfg["hydra"]
    plain = sort_keys(OmegaConf.to_container(cfg, resolve=True))
    sources = composition_sources(config_dir, config_name, choices, overrides)
    as_written = dict(leaves(plain))
    unset = derive_camera_settings(plain)
    plain = sort_keys(plain)  # a derived key keeps its sorted place
    derived = {path for path, value in leaves(plain) if as_written.get(path, value) != value}
    problems = refused + config_problems(plain, sources)
    if unset:  # one line for the settings the world could not fill (not one more per setting)
        problems = [p for p in problems if not p.startswith(tuple(f"{key} (" for key in unset))]
    if foreign_cameras(plain.get("world")):
        # Cameras of another world leave none fixed: that is the cause, not the derived settings.
        cause = [p for p in problems if p.startswith("world.cameras (")]
        problems = cause + [p for p in problems if p not in cause]
    elif unset:
        problems.insert(len(refused), f"{unset[0]} ({where(unset[0], sources)}) is null (the world's first recorded "
                                      f"fixed camera), but world.cameras {plain['world'].get('cameras')} records "
                                      f"none (a camera on no arm); set {', '.join(unset)}")
    if problems:
        raise problems_error(problems)
    return plain, sources, derived


def leaves(cfg: dict[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """(dotted path, value) of every setting of ``cfg``; a list or an empty map is one setting."""
    out = []
    for key, value in cfg.items():
        path = f"{prefix}.{key}" if prefix else str(key)
        out += leaves(value, path) if isinstance(value, dict) and value else [(path, value)]
    return out


def layer_lines(cfg: dict[str, Any], sources: Sequence[Source], derived: set[str] = frozenset()) -> list[str]:
    """One line per setting: its path, its value and the layer that set it (a file of conf/, a
    command-line override, or the world, for a camera setting filled in from it)."""
    lines = []
    for path, value in leaves(cfg):
        shown = yaml.safe_dump(value, default_flow_style=True, width=10**9).strip().removesuffix("\n...").strip()
        layer = "from the world's cameras" if path in derived else where(path, sources).removeprefix("set in ").removeprefix("set by ")
        lines.append(f"{path}: {shown}  # {layer}")
    return lines


def fixed_cameras(world: dict) -> list[str]:
    """The recorded cameras of ``world`` (in ``world.cameras`` order) that stay put: rig cameras on
    no arm (neither an arm's model camera nor one placed on a body of an arm)."""
    rig = world.get("rig") or {}
    arms = list(((world.get("robot") or {}).get("arms") or {}))
    on_arm = lambda entry: "arm" in entry or any(str(entry.get("body", "")).startswith(f"{a}_") for a in arms)  # noqa: E731
    return [c for c in world.get("cameras") or () if isinstance(rig.get(c), dict) and not on_arm(rig[c])]


def derive_camera_settings(cfg: dict[str, Any]) -> list[str]:
    """Fill in the camera settings left null from the world: ``calib.camera`` (the initial-pose
    estimate's) and ``rollout.video_camera`` (the judges' videos) become its first recorded fixed
    camera, and a trained candidate of a type without cameras of its own that names no
    ``image_keys`` sees that camera. Returns the keys it could not fill (the world records no
    fixed camera)."""
    world = cfg.get("world") or {}
    fixed = fixed_cameras(world) if isinstance(world, dict) else []
    unset = [key for key, group in (("calib.camera", "calib"), ("rollout.video_camera", "rollout"))
             if isinstance(cfg.get(group), dict) and cfg[group].get(key.split(".")[1], "") is None]
    if cfg.get("libero") is None:
        unset += _derive_image_keys(cfg.get("policies") or {}, fixed)
    if not fixed:
        return unset
    for key in unset:
        group, name = key.split(".")
        cfg[group][name] = fixed[0]
    return []


def _derive_image_keys(policies: dict, fixed: list[str]) -> list[str]:
    """Give each trained candidate that names no cameras (``image_keys`` left out or null; a type
    without cameras of its own) the first fixed camera; the keys it could not fill (no fixed camera)."""
    from r2s_eval.policies.types import policy_type
    from r2s_eval.policies.types.registry import TOP_LEVEL_DEFAULTS

    unset = []
    for name, entry in policies.items():
        if not isinstance(entry, dict) or entry.get("image_keys") is not None or entry.get("type") in WITHOUT_TRAINING:
            continue
        try:
            own = policy_type(entry.get("type")).all_defaults()["image_keys"] != TOP_LEVEL_DEFAULTS["image_keys"]
        except R2SError:
            continue  # an unknown type: the schema names it
        if own:  # the type's own cameras (a null the group file wrote leaves them to it)
            entry.pop("image_keys", None)
            continue
        if fixed:
            entry["image_keys"] = [f"observation.images.{fixed[0]}"]
        else:
            unset.append(f"policies.{name}.image_keys")
    return unset


def _override_key(line: str) -> str:
    return line.lstrip("~+").split("=", 1)[0]


def _refused_override(exc: Exception, overrides: list[str]) -> str | None:
    """The override line Hydra refused because its key does not exist, if that is the refusal."""
    m = re.search(r"Could not override '([^']+)'", str(exc))
    if not m:
        return None
    return next((o for o in overrides if _override_key(o) == m.group(1)), None)


def _composition_error(exc: Exception, experiment: str, overrides: list[str], refused: list[str]) -> ConfigError:
    """Hydra's refusal as a ConfigError, after the overrides of unknown keys found before it."""
    reason = str(exc).split("Config search path")[0].strip() or type(exc).__name__
    return problems_error([*refused, f"cannot compose experiment {experiment!r} with overrides {overrides}: {reason}"])


def missing_inputs(cfg: dict[str, Any]) -> None:
    """Raise a ConfigError naming each setting whose file or folder is not there: a lab's teleop
    dataset and its trials CSV (relative paths: from the working directory). Checked when a run
    is planned, so a wrong path never lets earlier results stand in for the lab's."""
    real = cfg.get("real") or {}
    if cfg.get("libero") is not None or real.get("source") != "dataset":
        return
    wanted = {"dataset_root": (Path.is_dir, "a LeRobotDataset v3 folder"),
              "reference_csv": (Path.is_file, "a CSV of hardware trials: policy, task, trials, successes")}
    lines = [f"real.{key} = {real[key]}: no such {'folder' if test is Path.is_dir else 'file'} ({what})"
             for key, (test, what) in wanted.items() if not test(Path(real[key]))]
    if lines:
        raise problems_error(lines)


def stop_before_running(err: R2SError) -> NoReturn:
    """A fault of the user's found before anything runs (a config problem, a missing input): its
    message alone on stderr, one line per problem, no traceback, exit status 1. The workflow's
    planning and the world check (``python -m r2s_eval.world``) both stop through here, so a
    wrong entry reads the same in either."""
    sys.exit(str(err).strip())


def sort_keys(value: Any) -> Any:
    """Recursively sort dict keys so that repr() and JSON are stable."""
    if isinstance(value, dict):
        return {k: sort_keys(value[k]) for k in sorted(value)}
    if isinstance(value, list | tuple):
        return [sort_keys(v) for v in value]
    return value


def select(cfg: dict[str, Any], *paths: str) -> dict[str, Any]:
    """Return the sub-config made of the given dotted paths, e.g. select(cfg, "stats", "seed")."""
    out: dict[str, Any] = {}
    for path in paths:
        node: Any = cfg
        for key in path.split("."):
            if not isinstance(node, dict) or key not in node:
                raise ConfigError(f"config has no field {path!r}")
            node = node[key]
        out[path] = node
    return sort_keys(out)


def to_json(value: Any) -> str:
    return json.dumps(sort_keys(value), sort_keys=True, separators=(",", ":"))


# The candidate line-ups and their budgets live in the Hydra config (conf/policies/*.yaml,
# scaled by conf/experiment/*.yaml): one source of truth for the pipeline, tests and benchmarks.


def candidate_configs(experiment: str = "demo") -> dict[str, dict]:
    """The validated config of every candidate policy of `experiment`."""
    from r2s_eval.policy_sources import validate_candidate_cfg

    policies = compose_config(CONF_DIR, experiment)["policies"]
    return {name: validate_candidate_cfg(dict(cfg, name=name), name) for name, cfg in policies.items()}


def candidate_config(name: str, experiment: str = "demo", **changes: Any) -> dict:
    """The training config of candidate `name` (trained here) under `experiment`, with optional
    top-level changes."""
    from r2s_eval.policies.trained_config import validate_policy_cfg

    candidates = candidate_configs(experiment)
    if name not in candidates:
        raise ConfigError(f"unknown candidate policy {name!r} of experiment {experiment!r}; known: {sorted(candidates)}")
    if candidates[name]["type"] in WITHOUT_TRAINING:
        raise ConfigError(f"candidate policy {name!r} of experiment {experiment!r} is a {candidates[name]['type']}: "
                          f"it has no training config of its own")
    cfg = copy.deepcopy(candidates[name])
    cfg.update(copy.deepcopy(changes))
    return validate_policy_cfg(cfg)


def main(argv: Sequence[str] | None = None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m r2s_eval.config",
                                description="Print an experiment's composed configuration (what a run would use).")
    p.add_argument("experiment", nargs="?", default="demo", help="a file of conf/experiment/, without .yaml")
    p.add_argument("overrides", nargs="*", help="overrides as the workflow takes them, e.g. rollout.inits_per_task=4")
    p.add_argument("--where", action="store_true", help="one line per setting, with the file or override that set it")
    p.add_argument("--conf", type=Path, default=None,
                   help="the config folder (default: ./conf where the command runs in a checkout, as Snakemake "
                        "reads it beside the Snakefile; else the installed project's)")
    args = p.parse_args(argv)
    conf = args.conf or (Path("conf") if (Path("conf") / "config.yaml").is_file() else CONF_DIR)
    try:
        cfg, sources, derived = compose_with_layers(conf, args.experiment, args.overrides)
    except R2SError as err:
        print(err, file=sys.stderr)
        return 1
    print("\n".join(layer_lines(cfg, sources, derived)) if args.where else yaml.safe_dump(cfg, sort_keys=False), end="\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
