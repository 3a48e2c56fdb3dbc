"""Candidate manipulation policies, trained and run through LeRobot.

Public API:
    train_policy(dataset_root, repo_id, policy_cfg, out_dir, seed, device="cpu") -> summary dict
    load_policy(checkpoint_dir, device="cpu", chunk_size=None, n_action_steps=None, seed=0) -> PolicyRunner
    PolicyRunner.reset(seed=None); PolicyRunner.act(obs) -> np.ndarray (14,)
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
from r2s_eval.policies.runner import PolicyRunner, load_policy
from r2s_eval.policies.train import train_policy

__all__ = [
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
