"""r2s-eval's worlds as a LeRobot environment: ``lerobot-eval --env.type=r2s_eval --env.task=<task>``.

LeRobot imports this distribution by its name (``lerobot_env_`` prefix) before it parses the
command line; importing it registers ``R2SEvalEnv`` under ``--env.type=r2s_eval``. The environment
is r2s-eval's Gymnasium environment (``r2s_eval.world.gym_env``), registered as
``r2s_eval/World-v0``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.processor import ObservationProcessorStep, PolicyProcessorPipeline
from lerobot.utils.constants import ACTION, OBS_IMAGES, OBS_STATE

from r2s_eval.errors import R2SError
from r2s_eval.sim.tasks import world_config
from r2s_eval.world import gym_env

ENV_TYPE = "r2s_eval"


@dataclass
class RolloutImageLayout(ObservationProcessorStep):
    """The camera images in the memory layout r2s-eval's rollout loop hands a policy: channel first
    as a view of the channel-last image (``permute``), not a channel-first copy. The values are the
    same; a convolution over the other layout takes other kernels and rounds differently (ACT's
    actions a few 1e-8 apart), and the rollout stage's episodes would not be reproduced exactly."""

    def observation(self, observation):
        return {key: value.permute(0, 2, 3, 1).contiguous().permute(0, 3, 1, 2) if key.startswith(f"{OBS_IMAGES}.")
                else value for key, value in observation.items()}

    def transform_features(self, features):
        return features


@EnvConfig.register_subclass(ENV_TYPE)
@dataclass
class R2SEvalEnv(EnvConfig):
    """One task of an r2s-eval world.

    ``world``: a world of r2s-eval's ``conf/world`` (``tabletop``, ``panda``, ``so101``) or a world
    file; ``task``: one of its tasks; ``world_params``: the calibrated sim's
    ``results/calib/world_params.json`` (or the twin's; None: nominal); ``inits`` and
    ``experiment_seed``: start episode ``--seed=k`` from the rollout stage's init ``k``
    (``results/rollout/inits.parquet``) with its episode seed; ``image_height``/``image_width``
    (0: the world's), ``cameras`` (empty: the world's); ``episode_length``: steps before truncation (None: the rollout stage's
    ``rollout.max_duration_s`` at the world's control rate, 150 steps at 10 Hz, 450 at 30 Hz).
    ``fps`` is the world's control rate.
    """

    world: str = "tabletop"
    task: str | None = "cup_on_plate"
    world_params: str | None = None
    inits: str | None = None
    experiment_seed: int = 0
    image_height: int = 0
    image_width: int = 0
    cameras: list[str] = field(default_factory=list)
    episode_length: int | None = None
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self):
        # LeRobot's command-line parser builds this config and buries any exception it raises
        # under its own "Couldn't instantiate class" traceback: a fault in what the user wrote is
        # kept and raised by create_envs, which LeRobot calls first, as one line.
        self._problem = None
        try:
            self._describe_world()
        except R2SError as err:
            self._problem = err

    def _describe_world(self) -> None:
        config = world_config(self.world)
        self.fps = int(round(float(config["robot"]["control_hz"])))
        if self.episode_length is None:  # an episode's length is a time: the same seconds at any rate
            self.episode_length = gym_env.episode_steps(config)
        recorded = self.recorded()
        for key, shape in recorded.items():
            if key == ACTION:
                self.features[ACTION], self.features_map[ACTION] = PolicyFeature(FeatureType.ACTION, shape), ACTION
            elif key == OBS_STATE:
                self.features["agent_pos"] = PolicyFeature(FeatureType.STATE, shape)
                self.features_map["agent_pos"] = OBS_STATE
            else:
                camera = key.removeprefix(f"{OBS_IMAGES}.")
                self.features[f"pixels/{camera}"] = PolicyFeature(FeatureType.VISUAL, shape)
                self.features_map[f"pixels/{camera}"] = key

    def recorded(self) -> dict[str, tuple]:
        """The world's features in the dataset's keys ({key: shape})."""
        size = (self.image_height, self.image_width) if self.image_height and self.image_width else None
        return gym_env.world_features(self.world, size, self.cameras or None)

    @property
    def package_name(self) -> str:
        return "r2s_eval.world.gym_env"

    @property
    def gym_id(self) -> str:
        return gym_env.ENV_ID

    @property
    def gym_kwargs(self) -> dict:
        size = (self.image_height, self.image_width) if self.image_height and self.image_width else None
        return {"world": self.world, "task": self.task, "world_params": self.world_params, "inits": self.inits,
                "experiment_seed": self.experiment_seed, "image_size": size, "cameras": self.cameras or None,
                "max_steps": self.episode_length, "max_episode_steps": self.episode_length}

    def check_policy(self, policy_dir: str | Path) -> None:
        """One line (r2s_eval's PolicyError) when the LeRobot policy saved in ``policy_dir`` reads
        or writes a feature this world does not record, or records at another width."""
        import json

        saved = json.loads((Path(policy_dir) / "config.json").read_text())
        features = {k: tuple(v["shape"]) for part in ("input_features", "output_features")
                    for k, v in (saved.get(part) or {}).items()}
        gym_env.check_policy_features(features, self.world, self.recorded(), f"policy {str(policy_dir)!r}")

    def get_env_processors(self):
        return PolicyProcessorPipeline(steps=[RolloutImageLayout()]), PolicyProcessorPipeline(steps=[])

    def create_envs(self, n_envs: int, use_async_envs: bool = False):
        """LeRobot's environments of this task; a fault in the world, task, world parameters,
        inits or policy ends the command with one line (SystemExit), not a traceback."""
        try:
            return self._create_envs(n_envs, use_async_envs)
        except R2SError as err:
            raise SystemExit(f"--env.type={ENV_TYPE}: {err}") from None

    def _create_envs(self, n_envs: int, use_async_envs: bool):
        from lerobot.configs import parser
        from lerobot.envs.utils import freeze_after_episode_end

        if self._problem is not None:
            raise self._problem
        policy_dir = parser.get_path_arg("policy")  # lerobot-eval's --policy.path, checked before any model loads
        if policy_dir and (Path(policy_dir) / "config.json").is_file():
            self.check_policy(policy_dir)
        # The environments' arguments are checked here, so a task or world parameters they cannot
        # take are reported before LeRobot's vector environment wraps the error.
        kwargs = self.gym_kwargs
        gym_env.checked_arguments(kwargs["world"], kwargs["task"], kwargs["world_params"], kwargs["inits"],
                                  kwargs["image_size"], kwargs["cameras"])
        # A finished episode is frozen (LeRobot's wrapper) rather than reset and stepped while
        # the other environments of the batch finish theirs.
        make_one = freeze_after_episode_end(
            lambda: gym.make(self.gym_id, disable_env_checker=self.disable_env_checker, **self.gym_kwargs))
        vector = gym.vector.AsyncVectorEnv if use_async_envs and n_envs > 1 else gym.vector.SyncVectorEnv
        extra = {"context": "forkserver"} if vector is gym.vector.AsyncVectorEnv else {}
        envs = vector([make_one for _ in range(n_envs)], autoreset_mode=gym.vector.AutoresetMode.SAME_STEP, **extra)
        return {self.type: {0: envs}}
