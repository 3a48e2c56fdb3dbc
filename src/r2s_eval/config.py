"""Compose the Hydra configuration once, validate it, and hand out plain, key-sorted slices.

Snakemake compares rule params by `repr()`, so every slice given to a rule must be a plain
container (no DictConfig) with a stable key order; otherwise a rerun is missed or forced.

The composed config is checked against the typed schema (`r2s_eval.schema`) before it is
returned: an unknown, misplaced or mistyped key is a ConfigError naming the key and the file or
command-line override that set it.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra import compose, initialize_config_dir
from hydra.errors import HydraException
from omegaconf import OmegaConf, open_dict
from omegaconf.errors import OmegaConfBaseException

from r2s_eval.errors import ConfigError
from r2s_eval.schema import composition_sources, unknown_override_error, validate_config


def compose_config(
    config_dir: str | Path,
    experiment: str = "demo",
    overrides: Sequence[str] = (),
    config_name: str = "config",
) -> dict[str, Any]:
    """Compose `config_name` with the experiment and user overrides into a plain, validated dict."""
    config_dir = Path(config_dir).resolve()
    if not (config_dir / f"{config_name}.yaml").exists():
        raise FileNotFoundError(f"no Hydra config {config_name}.yaml in {config_dir}")
    overrides = list(overrides)
    all_overrides = [f"experiment={experiment}", *overrides]
    try:
        with initialize_config_dir(config_dir=str(config_dir), version_base="1.3"):
            cfg = compose(config_name=config_name, overrides=all_overrides, return_hydra_config=True)
    except (HydraException, OmegaConfBaseException) as exc:
        raise _composition_error(exc, experiment, overrides) from exc
    choices = OmegaConf.to_container(cfg.hydra.runtime.choices)
    with open_dict(cfg):
        del cfg["hydra"]
    plain = sort_keys(OmegaConf.to_container(cfg, resolve=True))
    validate_config(plain, composition_sources(config_dir, config_name, choices, overrides))
    return plain


def _composition_error(exc: Exception, experiment: str, overrides: list[str]) -> ConfigError:
    """Hydra's refusal as a ConfigError; an override of a key that does not exist names it."""
    m = re.search(r"Could not override '([^']+)'", str(exc))
    if m:
        line = next((o for o in overrides if o.lstrip("~+").split("=", 1)[0] == m.group(1)), m.group(1))
        return unknown_override_error(m.group(1), line)
    return ConfigError(f"cannot compose experiment {experiment!r} with overrides {overrides}: "
                       f"{str(exc).split('Config search path')[0].strip() or type(exc).__name__}")


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
                raise KeyError(f"config has no field {path!r}")
            node = node[key]
        out[path] = node
    return sort_keys(out)


def to_json(value: Any) -> str:
    return json.dumps(sort_keys(value), sort_keys=True, separators=(",", ":"))
