"""Closed-loop inference of a trained checkpoint with an explicit receding horizon.

`load_policy` wraps a local LeRobot checkpoint (`LeRobotPolicy`, one model call per chunk) in
the evaluation's `RecedingHorizon`: every `n_action_steps` actions it asks for a fresh chunk of
`chunk_size` actions and executes its first `n_action_steps`. Re-planning frequency is a setting
of the evaluation (`rollout.n_action_steps` in the workflow), never of the checkpoint, so the
caller always states it.
"""

from __future__ import annotations

from pathlib import Path

from r2s_eval.policies.interface import RecedingHorizon
from r2s_eval.policies.lerobot_policy import load_lerobot_policy

# The name the rest of the package has used for a policy driven closed loop.
PolicyRunner = RecedingHorizon


def load_policy(
    checkpoint_dir: str | Path,
    *,
    n_action_steps: int,
    chunk_size: int | None = None,
    device: str = "cpu",
    seed: int = 0,
) -> RecedingHorizon:
    """A checkpoint as a closed-loop runner executing `n_action_steps` of every chunk;
    `chunk_size` (actions used per query) defaults to the chunk the model predicts."""
    policy = load_lerobot_policy(checkpoint_dir, device=device)
    return RecedingHorizon(policy, chunk_size=chunk_size or policy.spec.max_chunk,
                           n_action_steps=n_action_steps, seed=seed)
