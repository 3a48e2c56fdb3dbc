"""Candidate manipulation policies, trained and run through LeRobot.

Public API:
    train_policy(dataset_root, repo_id, policy_cfg, out_dir, seed, device="cpu") -> summary dict
    load_policy(checkpoint_dir, device="cpu", chunk_size=None, n_action_steps=None, seed=0) -> PolicyRunner
    PolicyRunner.reset(seed=None); PolicyRunner.act(obs) -> np.ndarray (14,)
    CANDIDATES, PROFILES, candidate_config(name, profile)   # "act", "diffusion", "act_weak"
"""

from r2s_eval.policies.config import (
    CANDIDATES,
    PROFILES,
    PolicyConfigError,
    candidate_config,
    make_lerobot_config,
    validate_policy_cfg,
)
from r2s_eval.policies.data import DatasetContractError
from r2s_eval.policies.runner import PolicyRunner, load_policy
from r2s_eval.policies.train import train_policy

__all__ = [
    "CANDIDATES",
    "PROFILES",
    "DatasetContractError",
    "PolicyConfigError",
    "PolicyRunner",
    "candidate_config",
    "load_policy",
    "make_lerobot_config",
    "train_policy",
    "validate_policy_cfg",
]
