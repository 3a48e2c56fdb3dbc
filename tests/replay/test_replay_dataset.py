"""Replaying a whole teleop dataset: one row per episode in the index's order, the successes
recorded, each episode's retries seeded by (seed, episode)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

from r2s_eval.config import compose_config  # noqa: E402
from r2s_eval.data import ACTION_KEY, episode_frames, open_metadata  # noqa: E402
from r2s_eval.errors import DataError  # noqa: E402
from r2s_eval.replay import replay_episode  # noqa: E402
from r2s_eval.replay.dataset_replay import replay_dataset  # noqa: E402
from r2s_eval.sim import WorldParams  # noqa: E402
from r2s_eval.sim.build import make_env  # noqa: E402
from r2s_eval.twin.record import record_teleop  # noqa: E402

CONF = Path(__file__).resolve().parents[2] / "conf"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    root = tmp_path_factory.mktemp("teleop")
    cfg = compose_config(CONF, "smoke")
    world = dict(cfg["world"], cameras=["head_left"])
    truth, _ = record_teleop(str(root / "data"), WorldParams(), teleop=dict(cfg["teleop"], episodes_per_task=2),
                             world=world, tasks=["cup_on_plate"], suite=cfg["suite"], seed=0)
    index = truth[["episode_index", "task"]].drop_duplicates().iloc[::-1].reset_index(drop=True)  # not sorted
    index["instruction"] = "put the cup on the plate"
    estimates = truth.assign(calibration=truth["episode_index"] == 0)
    estimates.loc[estimates["episode_index"] == 1, "x_m"] += 0.2  # far off: every retry fails
    return root, world, cfg["replay"], index, estimates


def test_replay_dataset_rows_follow_the_index_and_record_only_successes(recorded, tmp_path):
    root, world, replay, index, estimates = recorded
    table = replay_dataset(root / "data", index, estimates, WorldParams(), tmp_path / "sim", world=world,
                           video=replay["video"], max_attempts=2, perturb_xy_m=0.01, perturb_yaw_rad=0.1, seed=3)
    assert table["episode_index"].tolist() == [1, 0]
    assert table["success"].tolist() == [False, True] and table["attempts"].tolist() == [2, 1]
    assert table["sim_episode_index"].tolist() == [-1, 0] and table["calibration"].tolist() == [False, True]
    assert {"cup.x_m", "plate.yaw_rad", "wall_s"} <= set(table.columns)
    assert open_metadata(tmp_path / "sim").total_episodes == 1

    # Episode 1's retries are the draw of default_rng([seed, 1]), whatever ran before it.
    meta = open_metadata(root / "data")
    actions = np.stack(episode_frames(root / "data", meta, 1)[ACTION_KEY].to_numpy())
    est = estimates[estimates["episode_index"] == 1]
    alone = replay_episode(make_env("cup_on_plate", world, WorldParams()), actions,
                           {r.object: (r.x_m, r.y_m, r.yaw_rad) for r in est.itertuples()},
                           np.random.default_rng([3, 1]), max_attempts=2, perturb_xy_m=0.01, perturb_yaw_rad=0.1,
                           seed=1, yaw_symmetry={r.object: int(r.yaw_symmetry) for r in est.itertuples()})
    assert table.loc[0, "cup.x_m"] == alone.poses["cup"][0]


def test_replay_dataset_names_an_episode_without_an_estimate(recorded, tmp_path):
    root, world, replay, index, estimates = recorded
    with pytest.raises(DataError, match="episode 0: no initial-pose estimate"):
        replay_dataset(root / "data", index, estimates[estimates["episode_index"] != 0], WorldParams(),
                       tmp_path / "sim", world=world, video=replay["video"], max_attempts=1, perturb_xy_m=0.01,
                       perturb_yaw_rad=0.1, seed=0)
