"""A world's task as a Gymnasium environment: ``gymnasium.make("r2s_eval/World-v0", world=..., task=...)``.

The environment is the simulation r2s-eval's rollout stage runs (``r2s_eval.twin.reality.make_world_env``)
driven through the same episode (``r2s_eval.rollout.loop.Episode``: reset, observation, step,
success, video frame), so an episode stepped here with the same actions is the rollout stage's.

Arguments (``gymnasium.make`` keywords):

- ``world``: a world of the ``world`` config group (``tabletop``, ``panda``, ``so101``, ...) or a
  world file (``.yaml``, a lab's setup); ``task``: one of its tasks.
- ``world_params``: a world-parameter JSON (the calibrated sim's ``results/calib/world_params.json``,
  the twin's ``results/real/twin_params.json``, whose reality effects then act around the
  simulation as on the rollout stage's real arm); None: the nominal world.
- ``inits``: the rollout stage's initial configurations (``results/rollout/inits.parquet``) and
  ``experiment_seed`` (the experiment's ``seed``): ``reset(seed=k)`` then starts from init ``k``
  of the task with the episode seed the rollout stage gives it. Without ``inits``, ``reset(seed=k)``
  samples the task's start regions with ``k``.
- ``image_size`` (H, W; default: the world's), ``cameras`` (default: the world's), the video's
  ``video_camera`` and ``video_size`` (default: the first camera, as the policy sees it), and
  ``success_hold_steps`` (the rollout stage's 3).

Observations follow LeRobot's Gymnasium layout, which ``lerobot-eval`` maps onto the dataset's:
``agent_pos`` is ``observation.state`` (the dataset's features, in its units) and
``pixels/<camera>`` is ``observation.images.<camera>`` (uint8 H x W x 3). Actions are the dataset's
``action`` (its units). ``terminated`` is the task's success (held ``success_hold_steps`` steps),
also ``info["is_success"]``. An episode is cut (``truncated``) after ``max_steps`` control steps;
left out, after the rollout stage's ``rollout.max_duration_s`` at the world's control rate
(``episode_steps``: 150 steps at 10 Hz, 450 at 30 Hz). ``gymnasium.make``'s ``max_episode_steps``
adds Gymnasium's own time limit around that (a shorter one cuts first).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
import yaml
from gymnasium import spaces

from r2s_eval.errors import ConfigError, DataError, PolicyError
from r2s_eval.paths import CONF_DIR
from r2s_eval.rollout.inits import episode_seed, poses_of
from r2s_eval.rollout.loop import Episode
from r2s_eval.sim import load_world_params
from r2s_eval.sim.build import check_world_params, feature_ranges
from r2s_eval.sim.robot import world_robot
from r2s_eval.sim.tasks import world_config, world_tasks
from r2s_eval.twin.reality import load_reality_effects, make_world_env

ENV_ID = "r2s_eval/World-v0"
# The rollout stage's episode length in seconds, read from its config group's default (one owner).
DEFAULT_EPISODE_S = float(yaml.safe_load((CONF_DIR / "rollout" / "default.yaml").read_text())["max_duration_s"])


def episode_steps(world: str | Path | dict) -> int:
    """The default episode length of ``world`` in its control steps (``DEFAULT_EPISODE_S`` at its rate)."""
    return world_robot(world if isinstance(world, dict) else world_config(world)).steps_in(DEFAULT_EPISODE_S)


def world_features(world: str | Path, image_size: tuple[int, int] | None = None,
                   cameras: list[str] | None = None) -> dict[str, tuple]:
    """What the world records, in the dataset's keys: {key: shape} for ``observation.state``,
    ``action`` and each camera's ``observation.images.<camera>`` (H, W, 3)."""
    config = world_config(world)
    robot = world_robot(config)
    h, w = image_size or (int(config["image_height"]), int(config["image_width"]))
    features = {"observation.state": (robot.action_dim,), "action": (robot.action_dim,)}
    for camera in cameras or config["cameras"]:
        features[f"observation.images.{camera}"] = (int(h), int(w), 3)
    return features


def check_policy_features(policy_features: dict[str, tuple], world: str | Path, recorded: dict[str, tuple],
                          policy: str = "the policy") -> None:
    """Raise PolicyError (one line) unless every feature ``policy`` reads or writes (its
    ``{key: shape}``, images channel first as LeRobot stores them) is one ``world`` records
    (``world_features``) with the same width."""
    for key, shape in policy_features.items():
        if key not in recorded:
            offered = sorted(k for k in recorded if k != "action")
            raise PolicyError(f"{policy} reads {key}, which world {str(world)!r} does not record (it records {offered})")
        if not key.startswith("observation.images.") and tuple(shape) != tuple(recorded[key]):
            raise PolicyError(f"{policy}'s {key} has shape {tuple(shape)}, world {str(world)!r} records {tuple(recorded[key])}")


def checked_arguments(world: str | Path, task: str, world_params: str | None = None, inits: str | None = None,
                      image_size: tuple[int, int] | None = None, cameras: list[str] | None = None):
    """``WorldEnv``'s arguments checked without building the simulation: (world name, world config
    with ``image_size`` and ``cameras`` applied, world parameters or None, the task's inits or None).
    Raises one line naming the world, task, camera, file or init table at fault."""
    name, config = Path(world).stem, world_config(world)
    if image_size is not None:
        config = {**config, "image_height": int(image_size[0]), "image_width": int(image_size[1])}
    if cameras is not None:
        config = {**config, "cameras": list(cameras)}
    tasks = world_tasks(config)
    if task not in tasks:
        raise ConfigError(f"unknown task {task!r} of world {name!r}; its tasks are {sorted(tasks)}")
    robot = world_robot(config)
    unknown = [c for c in config["cameras"] if c not in robot.rig]
    if unknown:
        raise ConfigError(f"world {name!r} has no camera {unknown[0]!r}; its cameras are {sorted(robot.rig)}")
    params = None
    if world_params is not None:
        params = load_world_params(world_params)
        check_world_params(params, config, str(world_params), f"world {name!r}")
    task_inits = None
    if inits is not None:
        table = pd.read_parquet(inits)
        task_inits = table[table["task"] == task]
        if task_inits.empty:
            raise DataError(f"{inits}: no initial configurations of task {task!r} (it has {sorted(set(table['task']))})")
    return name, config, params, task_inits


class WorldEnv(gym.Env):
    """One task of a world; see the module docstring for the arguments."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, world: str = "tabletop", task: str = "cup_on_plate", world_params: str | None = None,
                 inits: str | None = None, experiment_seed: int = 0, image_size: tuple[int, int] | None = None,
                 cameras: list[str] | None = None, video_camera: str | None = None,
                 video_size: tuple[int, int] | None = None, success_hold_steps: int = 3,
                 max_steps: int | None = None, render_mode: str | None = "rgb_array"):
        name, config, params, self.inits = checked_arguments(world, task, world_params, inits, image_size, cameras)
        robot = world_robot(config)
        self._inits_file = inits
        self.experiment_seed = int(experiment_seed)
        self.world_name, self.task = name, task
        self.sim = make_world_env(task, config, params, load_reality_effects(world_params) if world_params else None)
        self.cameras = list(self.sim.cameras)
        self.task_description = self.sim.task.instruction  # what lerobot-eval hands a policy as its task
        self.video_camera = video_camera or self.cameras[0]
        self.video_size = None if video_size is None else (int(video_size[0]), int(video_size[1]))
        self.success_hold_steps = int(success_hold_steps)
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": int(round(robot.control_hz))}  # video writers take whole rates
        ranges = feature_ranges(robot)  # the dataset's range of each feature, where it has one
        low, high = np.array([ranges.get(f, (-np.inf, np.inf)) for f in robot.feature_names]).T
        self.action_space = spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
        h, w = self.sim.image_size
        self.observation_space = spaces.Dict({
            "agent_pos": spaces.Box(-np.inf, np.inf, (robot.action_dim,), dtype=np.float32),
            "pixels": spaces.Dict({c: spaces.Box(0, 255, (h, w, 3), dtype=np.uint8) for c in self.cameras}),
        })
        self.episode: Episode | None = None
        self.init_id: int | None = None  # the init the episode started from (with ``inits``)
        # lerobot-eval reads _max_episode_steps (Gymnasium's TimeLimit names it so).
        self._max_episode_steps = int(max_steps) if max_steps else robot.steps_in(DEFAULT_EPISODE_S)

    def _start(self, seed: int | None) -> tuple[dict | None, int]:
        """The object poses and episode seed of the episode seeded ``seed``; without a seed (a
        vector environment's automatic reset), the next init, or a seed drawn from ``np_random``."""
        if self.inits is None:
            seed = int(self.np_random.integers(2**31)) if seed is None else int(seed)
            return None, seed  # the task's sampler, seeded by the episode seed (TabletopEnv.reset)
        ids = sorted(set(self.inits["init_id"]))
        if seed is None:
            seed = ids[(ids.index(self.init_id) + 1) % len(ids)] if self.init_id in ids else ids[0]
        if seed not in ids:
            raise DataError(f"{self._inits_file}: no init {seed} of task {self.task!r} (its inits are "
                            f"{ids[0]}..{ids[-1]}; seed the episodes from {ids[0]}, e.g. lerobot-eval --seed={ids[0]})")
        self.init_id = int(seed)
        return poses_of(self.inits, self.task, seed), episode_seed(self.experiment_seed, seed)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        poses, seed_of_episode = self._start(seed)
        self.episode = Episode(self.sim, poses, seed_of_episode, self._max_episode_steps, self.video_camera,
                               self.video_size, self.success_hold_steps)
        return self._observation(), {"is_success": False}

    def step(self, action):
        action = np.asarray(action, dtype=np.float32)
        if action.shape != self.action_space.shape:
            raise PolicyError(f"world {self.world_name!r} takes {self.action_space.shape[0]}-D actions, got shape {action.shape}")
        self.episode.step(action)
        success = self.episode.success
        info = {"is_success": success, "task_progress": self.sim.task_progress()}
        return self._observation(), float(success), success, self.episode.done and not success, info

    def _observation(self) -> dict:
        obs = self.episode.policy_obs
        return {"agent_pos": obs["observation.state"],
                "pixels": {c: obs[f"observation.images.{c}"] for c in self.cameras}}

    def render(self):
        """The episode's video frame now (``Episode.frame``)."""
        return None if self.episode is None else self.episode.frame()

    def close(self) -> None:
        self.sim.close()


def register() -> None:
    """Register ``ENV_ID`` with Gymnasium (once)."""
    if ENV_ID not in gym.registry:
        # No registered time limit: a world's default length depends on its control rate
        # (WorldEnv's max_steps); gymnasium.make(..., max_episode_steps=N) still adds one.
        gym.register(id=ENV_ID, entry_point="r2s_eval.world.gym_env:WorldEnv")


register()
