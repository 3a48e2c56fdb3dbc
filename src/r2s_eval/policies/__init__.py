"""Candidate manipulation policies, trained and run through LeRobot, or served elsewhere.

Public API:
    ChunkPolicy, PolicySpec        one interface: a batch of observations in, action chunks out
    RecedingHorizon(policy, chunk_size, n_action_steps).act(obs) -> np.ndarray (14,)
    load_lerobot_policy(checkpoint_dir, device="cpu") -> LeRobotPolicy (a ChunkPolicy)
    train_policy(dataset_root, repo_id, policy_cfg, out_dir, seed, device="cpu") -> summary dict
    load_policy(checkpoint_dir, device="cpu", chunk_size=None, n_action_steps=None, seed=0) -> RecedingHorizon
    candidate_configs(experiment), candidate_config(name, experiment)   # read from conf/policies
"""

from r2s_eval.policies.config import (
    PolicyConfigError,
    candidate_config,
    candidate_configs,
    make_lerobot_config,
    validate_policy_cfg,
)
from r2s_eval.policies.data import DatasetContractError
from r2s_eval.policies.interface import ActionMap, ChunkPolicy, PolicyError, PolicySpec, RecedingHorizon
from r2s_eval.policies.lerobot_policy import LeRobotPolicy, load_lerobot_policy
from r2s_eval.policies.runner import PolicyRunner, load_policy
from r2s_eval.policies.train import train_policy

__all__ = [
    "ActionMap",
    "ChunkPolicy",
    "LeRobotPolicy",
    "PolicyError",
    "PolicySpec",
    "RecedingHorizon",
    "load_lerobot_policy",
    "DatasetContractError",
    "PolicyConfigError",
    "PolicyRunner",
    "candidate_config",
    "candidate_configs",
    "load_policy",
    "make_lerobot_config",
    "train_policy",
    "validate_policy_cfg",
]
