"""Closed-loop inference of a trained checkpoint with an explicit receding horizon.

`load_policy` wraps a local LeRobot checkpoint (`LeRobotPolicy`, one model call per chunk) in
the evaluation's `RecedingHorizon`: every `horizon.execute` actions it asks for a fresh chunk,
uses its first `horizon.chunk` actions and executes the first `horizon.execute`. Re-planning is
a setting of the evaluation (``rollout.horizon`` in the workflow), never of the checkpoint, so
the caller always states it.
"""

from __future__ import annotations

from pathlib import Path

from r2s_eval.horizon import Horizon
from r2s_eval.policies.interface import RecedingHorizon
from r2s_eval.policies.lerobot_policy import load_lerobot_policy

# The name the rest of the package has used for a policy driven closed loop.
PolicyRunner = RecedingHorizon


def load_policy(
    checkpoint_dir: str | Path,
    *,
    horizon: Horizon,
    device: str = "cpu",
    seed: int = 0,
) -> RecedingHorizon:
    """A checkpoint as a closed-loop runner of `horizon` (checked against the chunk the model
    predicts)."""
    policy = load_lerobot_policy(checkpoint_dir, device=device)
    return RecedingHorizon(policy, horizon, seed=seed)
