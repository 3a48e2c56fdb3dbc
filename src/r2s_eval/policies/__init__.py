"""Candidate manipulation policies, trained and run through LeRobot, or served elsewhere.

Public API:
    ChunkPolicy, PolicySpec        one interface: a batch of observations in, action chunks out
    RecedingHorizon(policy, Horizon(chunk, execute)).act(obs) -> np.ndarray (14,)
    load_lerobot_policy(checkpoint_dir, device="cpu") -> LeRobotPolicy (a ChunkPolicy)
    train_policy(dataset_root, repo_id, policy_cfg, out_dir, seed, episodes=None, replicate=0) -> summary dict
    load_policy(checkpoint_dir, horizon=Horizon(...), device="cpu", seed=0) -> RecedingHorizon
    validate_policy_cfg(cfg), make_lerobot_config(cfg)   # policy_type(name): r2s_eval.policies.types

Candidate line-ups read from conf/: r2s_eval.config.candidate_configs / candidate_config. Where a
candidate comes from (trained here, a checkpoint, a server): r2s_eval.policy_sources.

Names are imported on first use: validating a config (the workflow does it at every start) needs
`trained_config` and `types` only, not torch, lerobot and transformers.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

_WHERE = {
    "PolicyConfigError": "trained_config",
    "SUPPORTED_TYPES": "types",
    "make_lerobot_config": "trained_config",
    "policy_type": "types",
    "validate_policy_cfg": "trained_config",
    "DatasetContractError": "data",
    "ActionMap": "interface",
    "ChunkPolicy": "interface",
    "PolicyError": "interface",
    "PolicySpec": "interface",
    "RecedingHorizon": "interface",
    "LeRobotPolicy": "lerobot_policy",
    "load_lerobot_policy": "lerobot_policy",
    "PolicyRunner": "closed_loop",
    "load_policy": "closed_loop",
    "train_policy": "train",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_WHERE})


if TYPE_CHECKING:
    from r2s_eval.policies.trained_config import PolicyConfigError, make_lerobot_config, validate_policy_cfg
    from r2s_eval.policies.types import SUPPORTED_TYPES, policy_type
    from r2s_eval.policies.data import DatasetContractError
    from r2s_eval.policies.interface import ActionMap, ChunkPolicy, PolicyError, PolicySpec, RecedingHorizon
    from r2s_eval.policies.lerobot_policy import LeRobotPolicy, load_lerobot_policy
    from r2s_eval.policies.closed_loop import PolicyRunner, load_policy
    from r2s_eval.policies.train import train_policy
