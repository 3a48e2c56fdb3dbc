"""One closed-loop episode: the policy acts, the world steps, everything is recorded."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import pandas as pd

from r2s_eval.sim import TabletopEnv


class Policy(Protocol):
    def reset(self) -> None: ...
    def act(self, obs: dict) -> np.ndarray: ...


@dataclass
class EpisodeResult:
    success: bool
    length: int
    frames: list[np.ndarray] = field(repr=False)
    trajectory: pd.DataFrame = field(repr=False)


def episode_id(*parts) -> str:
    """Opaque id: judges must not learn the policy or arm from a file name."""
    return hashlib.sha256("/".join(map(str, parts)).encode()).hexdigest()[:16]


def _record(env: TabletopEnv, step: int, obs: dict, action: np.ndarray) -> dict:
    ee = env.ee_positions()
    row = {
        "step": step,
        "time_s": step * env.control_dt_s,
        "state": np.asarray(obs["observation.state"], dtype=float).tolist(),
        "action": np.asarray(action, dtype=float).tolist(),
        "ee_pos_left": ee["left"].tolist(),
        "ee_pos_right": ee["right"].tolist(),
        "contact_force_n": float(env.contact_force_n()),
        "progress": float(env.task_progress()),
        "success": bool(env.is_success()),
    }
    for name, pose in env.object_poses().items():
        row[f"obj_pos.{name}"] = pose["pos_world_m"].tolist()
        row[f"obj_quat.{name}"] = pose["quat_wxyz"].tolist()
    return row


def run_episode(
    env: TabletopEnv,
    policy: Policy,
    object_poses: dict[str, tuple[float, float, float]],
    seed: int,
    max_steps: int,
    video_camera: str,
    video_size: tuple[int, int] | None = None,
    success_hold_steps: int = 3,
) -> EpisodeResult:
    """Run until the success check has held for `success_hold_steps` steps, or `max_steps`.

    The caller resets the policy (with the episode's seed) before calling.

    Holding success for a few steps keeps a cup that is let go mid-air from counting.

    Video: one frame per control step from `video_camera`. With `video_size` (H, W) the frame is
    rendered at that size for the judges, whatever the policy consumes; with None it is the
    policy's own image of that camera when the policy watches it (else a render at the env's
    image size). A rendered frame carries the world's image noise from its own generator
    (seeded by the episode), so recording it never changes what the policy observes.
    """
    video_key = f"observation.images.{video_camera}"
    size = None if video_size is None else (int(video_size[0]), int(video_size[1]))
    video_rng = np.random.default_rng([seed, 0x71DE0])  # the judge video's own noise stream

    def frame(obs: dict) -> np.ndarray:
        if video_key in obs and size is None:
            return obs[video_key]
        rgb = env.render(video_camera, size=size)  # clean: the observations' noise stream stays theirs
        std = float(env.params.image_noise_std)
        if std > 0:
            rgb = np.clip(rgb + video_rng.normal(0.0, std, rgb.shape), 0, 255).astype(np.uint8)
        return rgb

    obs = env.reset(object_poses, seed=seed)
    frames = [frame(obs)]
    rows, held = [], 0
    instruction = env.task.instruction  # language-conditioned policies read it
    for step in range(max_steps):
        action = policy.act({**obs, "task": instruction})
        obs = env.step(action)
        rows.append(_record(env, step, obs, action))
        frames.append(frame(obs))
        held = held + 1 if rows[-1]["success"] else 0
        if held >= success_hold_steps:
            break
    return EpisodeResult(success=held >= success_hold_steps, length=len(rows), frames=frames, trajectory=pd.DataFrame(rows))
