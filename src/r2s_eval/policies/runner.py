"""Closed-loop inference of a trained checkpoint with an explicit receding horizon.

`load_policy` wraps a local LeRobot checkpoint (`LeRobotPolicy`, one model call per chunk) in
the evaluation's `RecedingHorizon`: every `n_action_steps` actions it asks for a fresh chunk of
`chunk_size` actions and executes its first `n_action_steps`. Re-planning frequency is a setting
of the evaluation, not of the checkpoint.
"""

from __future__ import annotations

import json
from pathlib import Path

from r2s_eval.policies.interface import RecedingHorizon
from r2s_eval.policies.lerobot_policy import RUNNER_CONFIG, load_lerobot_policy, resolve_checkpoint

# The name the rest of the package has used for a policy driven closed loop.
PolicyRunner = RecedingHorizon


def load_policy(
    checkpoint_dir: str | Path,
    device: str = "cpu",
    chunk_size: int | None = None,
    n_action_steps: int | None = None,
    seed: int = 0,
) -> RecedingHorizon:
    """A checkpoint as a closed-loop runner; `chunk_size` / `n_action_steps` default to the
    values the policy was trained with."""
    policy = load_lerobot_policy(checkpoint_dir, device=device)
    ckpt = resolve_checkpoint(checkpoint_dir)
    trained = json.loads((ckpt / RUNNER_CONFIG).read_text()) if (ckpt / RUNNER_CONFIG).is_file() else {}
    return RecedingHorizon(
        policy,
        chunk_size=chunk_size or trained.get("chunk_size", 25),
        n_action_steps=n_action_steps or trained.get("n_action_steps", 5),
        seed=seed,
    )
