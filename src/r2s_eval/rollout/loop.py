"""One closed-loop episode: the policy acts, the world steps, everything is recorded.

`Episode` is one episode (reset, observation, step, success, video frame), shared with the
Gymnasium environment (`r2s_eval.world.gym_env`); `EpisodeRecorder` is what an episode records,
one control step at a time: the judge video's frames and the trajectory rows. `run_episode`
drives one episode with a policy's `act`; the batched loop (`r2s_eval.rollout.batch`) drives
many recorders side by side. Both record through the same recorder, so an episode's bytes do
not depend on which loop ran it.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import pandas as pd

from r2s_eval.sim import TabletopEnv
from r2s_eval.errors import ConfigError


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
        **{f"ee_pos_{arm}": pos.tolist() for arm, pos in ee.items()},  # one column per arm of the robot
        "contact_force_n": float(env.contact_force_n()),
        "progress": float(env.task_progress()),
        "success": bool(env.is_success()),
    }
    for name in env.task.object_names:
        pose = env.object_state(name)  # the body pose; no planar pose is recorded
        row[f"obj_pos.{name}"] = pose["pos_world_m"].tolist()
        row[f"obj_quat.{name}"] = pose["quat_wxyz"].tolist()
    return row


class Episode:
    """One episode in `env`: reset from `object_poses` (None: the task's sampler, seeded by
    `seed`) and `seed`, then `step(action)` until `done`. The one definition of an episode that
    r2s-eval's rollout loops and the Gymnasium environment (`r2s_eval.world.gym_env`) share.

    Success: the task's success check has held for `success_hold_steps` steps (holding it for a
    few steps keeps a cup that is let go mid-air from counting). `done`: success, or `max_steps`
    steps (None: no limit).

    `frame()` is the episode's video frame now, from `video_camera`: with `video_size` (H, W) it
    is rendered at that size, whatever the policy consumes; with None it is the policy's own
    image of that camera when the policy watches it (else a render at the env's image size). A
    rendered frame is what the world's camera records (``env.render(add_noise=True)``: blur, lens,
    exposure and white balance as the policy's images of that camera have them), its pixel noise
    from its own generator (seeded by the episode, drawn once per frame), so recording it never
    changes what the policy observes.
    """

    def __init__(self, env: TabletopEnv, object_poses: dict[str, tuple[float, float, float]] | None, seed: int,
                 max_steps: int | None, video_camera: str, video_size: tuple[int, int] | None = None,
                 success_hold_steps: int = 3):
        self.env = env
        self.seed = int(seed)
        self.max_steps = None if max_steps is None else int(max_steps)
        self.success_hold_steps = int(success_hold_steps)
        self.video_camera = video_camera
        self._video_key = f"observation.images.{video_camera}"
        self._size = None if video_size is None else (int(video_size[0]), int(video_size[1]))
        self._video_rng = np.random.default_rng([self.seed, 0x71DE0])  # the judge video's own noise stream
        self.steps = 0
        self.held = 0
        self.instruction = env.task.instruction  # language-conditioned policies read it
        self.obs = env.reset(object_poses, seed=self.seed)
        self._has_images = True

    def render_observation(self) -> None:
        """Render this step's camera images now (from the thread that owns the renderers)."""
        self._images()

    def _images(self) -> dict:
        """The observation with the cameras' images of this step, rendered on first use."""
        if not self._has_images:
            self.obs.update(self.env.images())
            self._has_images = True
        return self.obs

    def frame(self) -> np.ndarray:
        """The video frame of this step (draws the next noise of the video's stream)."""
        if self._size is None and self.video_camera in self.env.cameras:
            return self._images()[self._video_key]
        # The video's own noise stream: the observations' stays theirs.
        return self.env.render(self.video_camera, size=self._size, add_noise=True, noise_rng=self._video_rng)

    @property
    def policy_obs(self) -> dict:
        """What the policy observes now: the world's streams and the instruction. The cameras
        are rendered when this is first asked for in a step (a policy that reads only at its
        query steps costs no render in between; the pixels do not depend on it)."""
        return {**self._images(), "task": self.instruction}

    @property
    def success(self) -> bool:
        return self.held >= self.success_hold_steps

    @property
    def done(self) -> bool:
        return self.success or (self.max_steps is not None and self.steps >= self.max_steps)

    def step(self, action: np.ndarray) -> None:
        self.obs = self.env.step(action, images=False)
        self._has_images = False
        self.steps += 1
        self.held = self.held + 1 if self.env.is_success() else 0


class EpisodeRecorder(Episode):
    """An `Episode` recorded one control step at a time: the trajectory rows, and the video.

    Video: one frame every `frame_every` control steps (step 0 included), handed to `on_frame`
    (default: kept in `frames`); `video_frame_every` turns a video frame rate into that stride.
    """

    def __init__(self, env: TabletopEnv, object_poses: dict[str, tuple[float, float, float]], seed: int,
                 max_steps: int, video_camera: str, video_size: tuple[int, int] | None = None,
                 success_hold_steps: int = 3, on_frame: Callable[[np.ndarray], None] | None = None,
                 frame_every: int = 1):
        super().__init__(env, object_poses, seed, max_steps, video_camera, video_size, success_hold_steps)
        self.frame_every = int(frame_every)
        self.frames: list[np.ndarray] = []
        self._on_frame = on_frame or self.frames.append
        self.rows: list[dict] = []
        self._on_frame(self.frame())

    def step(self, action: np.ndarray) -> None:
        super().step(action)
        self.rows.append(_record(self.env, len(self.rows), self.obs, action))
        if len(self.rows) % self.frame_every == 0:
            self._on_frame(self.frame())

    def result(self) -> EpisodeResult:
        return EpisodeResult(success=self.success, length=len(self.rows), frames=self.frames,
                             trajectory=pd.DataFrame(self.rows))


def video_frame_every(video_fps: float, control_dt_s: float) -> int:
    """Control steps between two judge-video frames at `video_fps`; the rate must divide the
    control rate, so the video's clock is the simulation's."""
    ratio = 1.0 / (float(video_fps) * float(control_dt_s))
    if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-9:
        raise ConfigError(f"video_fps {video_fps} must divide the control rate ({1 / control_dt_s:g} Hz)")
    return int(round(ratio))


def run_episode(
    env: TabletopEnv,
    policy: Policy,
    object_poses: dict[str, tuple[float, float, float]],
    seed: int,
    max_steps: int,
    video_camera: str,
    video_size: tuple[int, int] | None = None,
    success_hold_steps: int = 3,
    frame_every: int = 1,
) -> EpisodeResult:
    """One episode, the policy called at every control step (see `EpisodeRecorder`).

    The caller resets the policy (with the episode's seed) before calling.
    """
    episode = EpisodeRecorder(env, object_poses, seed, max_steps, video_camera, video_size, success_hold_steps,
                              frame_every=frame_every)
    while not episode.done:
        episode.step(policy.act(episode.policy_obs))
    return episode.result()
