"""Compose the Hydra configuration once and hand out plain, key-sorted slices.

Snakemake compares rule params by `repr()`, so every slice given to a rule must be a plain
container (no DictConfig) with a stable key order; otherwise a rerun is missed or forced.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf


def compose_config(
    config_dir: str | Path,
    experiment: str = "demo",
    overrides: Sequence[str] = (),
    config_name: str = "config",
) -> dict[str, Any]:
    """Compose `config_name` with the experiment and user overrides into a plain dict."""
    config_dir = Path(config_dir).resolve()
    if not (config_dir / f"{config_name}.yaml").exists():
        raise FileNotFoundError(f"no Hydra config {config_name}.yaml in {config_dir}")
    all_overrides = [f"experiment={experiment}", *overrides]
    with initialize_config_dir(config_dir=str(config_dir), version_base="1.3"):
        cfg = compose(config_name=config_name, overrides=all_overrides)
    return sort_keys(OmegaConf.to_container(cfg, resolve=True))


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
