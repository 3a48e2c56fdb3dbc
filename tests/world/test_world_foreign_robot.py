"""A world the code never saw: the Franka Panda that gym-hil ships (used from the installed package,
never copied), two tasks, a camera placed by the world with a lab's intrinsics. The twin records
it, the calibration finds its objects from that camera's first frames and its joint offsets from
the recordings, and the replay reproduces the recordings in the simulation so calibrated."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

pytest.importorskip("gym_hil", reason="the Panda world's robot comes from gym-hil (pip install --no-deps gym-hil)")

from r2s_eval.calib.episodes import estimate_episodes  # noqa: E402
from r2s_eval.calib.joints import estimate_joint_offsets, recorded_episodes  # noqa: E402
from r2s_eval.calib.offsets import calibration_subset, fit_offsets  # noqa: E402
from r2s_eval.config import compose_config  # noqa: E402
from r2s_eval.data import IngestSpec, ingest_dataset  # noqa: E402
from r2s_eval.data.dataset import ACTION_KEY, episode_frames, open_metadata  # noqa: E402
from r2s_eval.replay import replay_episode  # noqa: E402
from r2s_eval.sim import WorldParams, world_robot  # noqa: E402
from r2s_eval.sim.build import make_env  # noqa: E402
from r2s_eval.twin import twin_world  # noqa: E402
from r2s_eval.twin.operator import success_rate  # noqa: E402
from r2s_eval.twin.record import record_teleop  # noqa: E402

CONF = Path(__file__).resolve().parents[2] / "conf"
PANDA = ["world=panda", "suite=world", "tasks=[block_on_plate]", "world.cameras=[head_left,front,wrist]",
         "calib.camera=front", "rollout.video_camera=front"]
EPISODES = 4
CALIBRATION = 2  # episodes per task whose measured poses fit the per-task offsets


@pytest.fixture(scope="module")
def panda(tmp_path_factory):
    cfg = compose_config(CONF, "smoke", PANDA)
    world = cfg["world"]
    robot = world_robot(world)
    twin = twin_world(cfg["real"]["twin"], world["objects"], robot)
    root = tmp_path_factory.mktemp("panda") / "teleop"
    teleop = {**cfg["teleop"], "episodes_per_task": EPISODES}
    truth, attempts = record_teleop(str(root), WorldParams(**twin["params"]), teleop=teleop, world=world,
                                    tasks=cfg["tasks"], suite=cfg["suite"], seed=cfg["seed"])
    return cfg, robot, root, truth, attempts


def test_the_world_reads_its_robot_from_the_installed_package(panda):
    cfg, robot, *_ = panda
    arm = robot.arms["panda"]
    assert "site-packages" in str(arm.model) or "dist-packages" in str(arm.model)
    assert robot.action_dim == 8 and robot.feature_names[-1] == "gripper.pos"
    assert not (CONF.parent / "assets" / "panda.xml").exists()


def test_the_twin_records_the_panda_in_its_own_layout(panda):
    cfg, robot, root, truth, attempts = panda
    meta = open_metadata(root)
    assert meta.info.robot_type == "franka_panda" and meta.info.fps == 10
    for key in ("observation.state", "action"):
        assert meta.features[key]["names"] == robot.feature_names
    assert meta.info.total_episodes == EPISODES and sum(a["success"] for a in attempts) == EPISODES
    assert {f"observation.images.{c}" for c in ("head_left", "front", "wrist")} <= set(meta.features)
    actions = np.stack(episode_frames(root, meta, 0)[ACTION_KEY].to_numpy())
    assert actions.shape[1] == 8 and actions[:, 7].max() > 30  # the gripper closes, recorded 0..100


def test_calibration_finds_the_objects_and_replay_reproduces_the_recordings(panda, tmp_path):
    cfg, robot, root, truth, _ = panda
    world = cfg["world"]
    spec = IngestSpec(cameras=list(world["cameras"]), feature_names=robot.feature_names, fps=10,
                      tasks={world["tasks"]["block_on_plate"]["instruction"]: "block_on_plate"},
                      first_frame_camera="front")
    index, _ = ingest_dataset(root, "local/panda", spec, tmp_path / "frames")
    # As the pipeline does: offsets fitted on the calibration episodes' measured poses (the twin's
    # truth), then every episode estimated with them; the other episodes score the estimate.
    subset = calibration_subset(index, CALIBRATION)
    offsets = fit_offsets(estimate_episodes(subset, tmp_path / "frames", cfg["calib"], world), truth)
    estimates = estimate_episodes(index, tmp_path / "frames", cfg["calib"], world, offsets)
    scored = estimates[~estimates["episode_index"].isin(subset["episode_index"])]
    merged = scored.merge(truth, on=["episode_index", "object"], suffixes=("", "_true"))
    error_m = np.hypot(merged["x_m"] - merged["x_m_true"], merged["y_m"] - merged["y_m_true"])
    assert len(merged) == 2 * (EPISODES - CALIBRATION) and error_m.max() < 0.01, merged

    # As the pipeline does: replay in the simulation calibrated with the joint offsets the
    # recordings show (their replay residuals); they are the twin's.
    fit = estimate_joint_offsets(robot, recorded_episodes(root, index, estimates),
                                 lambda task, params: make_env(task, world, params, cameras=()), iterations=2)
    twin = twin_world(cfg["real"]["twin"], world["objects"], robot)["params"]
    np.testing.assert_allclose(fit.offsets_rad["panda"], twin["joint_offset_rad"]["panda"], atol=np.deg2rad(0.2))
    meta = open_metadata(root)
    env = make_env("block_on_plate", world, WorldParams(joint_offset_rad=fit.offsets_rad), cameras=())
    replayed = 0
    for ep in index.itertuples():
        mine = estimates[estimates["episode_index"] == ep.episode_index]
        poses = {r.object: (r.x_m, r.y_m, r.yaw_rad) for r in mine.itertuples()}
        actions = np.stack(episode_frames(root, meta, ep.episode_index)[ACTION_KEY].to_numpy())
        result = replay_episode(env, actions, poses, np.random.default_rng(int(ep.episode_index)), max_attempts=8,
                                perturb_xy_m=0.01, perturb_yaw_rad=0.1, seed=int(ep.episode_index),
                                yaw_symmetry={r.object: int(r.yaw_symmetry) for r in mine.itertuples()})
        replayed += result.success
    env.close()
    assert replayed == EPISODES


def test_the_operator_puts_the_ball_in_the_cup(panda):
    """The second task, with the operator's default (human-like) settings in perturbed twins."""
    cfg, *_ = panda
    assert success_rate("ball_in_cup", episodes=4, twin=True, world=cfg["world"]) == 1.0
