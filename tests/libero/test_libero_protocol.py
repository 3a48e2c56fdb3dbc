"""The LIBERO setting's own side, without LIBERO: task selection and its errors, the episodes
every policy runs, the spec check before any episode, and a LIBERO record turned into our
rollout files (what the judges and reports read)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from r2s_eval.errors import ConfigError
from r2s_eval.horizon import Horizon
from r2s_eval.judge.trajectory import load_trajectory
from r2s_eval.libero import SUITES, selected_tasks, suite_of
from r2s_eval.libero.rollout import failure_text, keep_episode, planned_episodes, policy_cameras, shards, world_job
from r2s_eval.policies.interface import PolicyError, PolicySpec
from r2s_eval.rollout.episode_store import collect_episodes, episode_store
from r2s_eval.rollout.mp4 import read_video

CAMERAS = {"image": "agentview", "wrist_image": "robot0_eye_in_hand"}


def test_all_tasks_of_a_suite_with_its_step_limit():
    tasks = selected_tasks(["libero_goal", "libero_10_3", "libero_10_1"], {"libero_goal": 300})
    assert [t.name for t in tasks] == [f"libero_goal_{i}" for i in range(10)] + ["libero_10_3", "libero_10_1"]
    assert {t.max_steps for t in tasks if t.suite == "libero_goal"} == {300}
    assert {t.max_steps for t in tasks if t.suite == "libero_10"} == {SUITES["libero_10"][1]}  # LIBERO's own limit
    assert suite_of("libero_10_3") == "libero_10" and suite_of("libero_spatial_0") == "libero_spatial"


def test_unknown_suite_or_task_is_an_error_listing_the_valid_ones():
    with pytest.raises(ConfigError, match=r"no suite or task 'libero_space'.*libero_10.*libero_goal.*libero_spatial"):
        selected_tasks(["libero_space"])
    with pytest.raises(ConfigError, match=r"'libero_object_10' does not exist; libero_object has tasks libero_object_0..libero_object_9"):
        selected_tasks(["libero_object_2", "libero_object_10"])
    with pytest.raises(ConfigError, match=r"\['libero_goal_1'\] selected more than once"):
        selected_tasks(["libero_goal", "libero_goal_1"])
    with pytest.raises(ConfigError, match="not a LIBERO task name"):
        suite_of("cup_on_plate")


def test_config_validation_names_libero_mistakes():
    from r2s_eval.config import compose_config

    conf = Path(__file__).resolve().parents[2] / "conf"
    cfg = compose_config(conf, experiment="libero_smoke")
    assert cfg["libero"]["episodes_per_task"] == 3 and sorted(cfg["policies"]) == ["tiny_a", "tiny_b"]
    with pytest.raises(ConfigError, match="libero.tasks.*libero_11"):
        compose_config(conf, experiment="libero_smoke", overrides=["libero.tasks=[libero_11]"])
    with pytest.raises(ConfigError, match="libero.max_steps.*libero_11"):
        compose_config(conf, experiment="libero_smoke", overrides=["+libero.max_steps.libero_11=10"])
    with pytest.raises(ConfigError, match="policies.act.type.*checkpoint"):
        compose_config(conf, experiment="libero_smoke", overrides=["+policies.act={type:act}"])
    with pytest.raises(ConfigError, match="libero.video.fps"):
        compose_config(conf, experiment="libero_smoke", overrides=["libero.video.fps=3"])
    # A setting the LIBERO run would ignore is an error, not a silent no-op.
    with pytest.raises(ConfigError, match=r"rollout.max_duration_s \(set by the command-line override.*not read in the LIBERO setting"):
        compose_config(conf, experiment="libero_smoke", overrides=["rollout.max_duration_s=5"])
    with pytest.raises(ConfigError, match="teleop.keep_failed.*not read in the LIBERO setting"):
        compose_config(conf, experiment="libero_smoke", overrides=["teleop.keep_failed=true"])
    assert compose_config(conf, experiment="libero_smoke",
                          overrides=["rollout.horizon.execute=4"])["rollout"]["horizon"]["execute"] == 4


def test_every_policy_runs_the_same_episodes():
    tasks = selected_tasks(["libero_spatial_0", "libero_spatial_1"])
    a, b = planned_episodes(tasks, 3, seed=7, policy="pi0"), planned_episodes(tasks, 3, seed=7, policy="smolvla")
    assert [(p.task, p.init_id, p.seed) for p in a] == [(p.task, p.init_id, p.seed) for p in b]
    assert [p.init_id for p in a] == [0, 1, 2, 0, 1, 2]  # the official initial states, in order
    assert not {p.episode_id for p in a} & {p.episode_id for p in b}  # ids say nothing shared
    with pytest.raises(PolicyError, match="1..50"):
        planned_episodes(tasks, 51, seed=7, policy="pi0")


def test_shards_keep_tasks_whole():
    tasks = selected_tasks(["libero_spatial_0", "libero_spatial_1", "libero_spatial_2"])
    parts = shards(planned_episodes(tasks, 2, seed=0, policy="p"), workers=2)
    assert len(parts) == 2 and sorted(len(s) for s in parts) == [2, 4]
    assert all(len({p.task for p in s}) == len(s) // 2 for s in parts)


def test_a_policy_libero_cannot_feed_fails_before_any_episode():
    spec = PolicySpec(cameras=("observation.images.image", "observation.images.wrist_image"), action_dim=7,
                      max_chunk=25, state_dim=8)
    keys = {f"observation.images.{k}": v for k, v in CAMERAS.items()}
    assert policy_cameras(spec, CAMERAS, "ok") == keys
    keys = CAMERAS
    with pytest.raises(PolicyError, match=r"'wide'.*14-D actions.*LIBERO takes 7-D"):
        policy_cameras(PolicySpec(("observation.images.image",), 14, 25), keys, "wide")
    with pytest.raises(PolicyError, match=r"reads cameras \['observation.images.front'\]"):
        policy_cameras(PolicySpec(("observation.images.front",), 7, 25), keys, "front")
    with pytest.raises(PolicyError, match="expects a 14-D state"):
        policy_cameras(PolicySpec(("observation.images.image",), 7, 25, state_dim=14), keys, "state")


def _record(n_steps: int, frames: int, success: bool) -> dict:
    rng = np.random.default_rng(0)
    return {
        "frames": rng.integers(0, 255, (frames, 64, 64, 3), dtype=np.uint8),
        "state": rng.normal(size=(n_steps, 8)).astype(np.float32),
        "action": rng.normal(size=(n_steps, 7)).astype(np.float32),
        "eef_pos": rng.normal(size=(n_steps, 3)).astype(np.float32),
        "contact_force_n": np.abs(rng.normal(size=n_steps)),
        "success": np.arange(n_steps) == n_steps - 1 if success else np.zeros(n_steps, bool),
        "final_success": np.asarray(success), "instruction": np.asarray("put the bowl on the plate"),
        "init_state_sha256": np.asarray("ab" * 32), "model_calls": np.asarray(3), "inference_s": np.asarray(0.5),
    }


def test_a_libero_record_becomes_our_rollout_files(tmp_path):
    planned = planned_episodes(selected_tasks(["libero_goal_4"]), 2, seed=0, policy="pi0")
    out = tmp_path / "rollout" / "pi0"
    store = episode_store(out, "identity")
    for p, success in zip(planned, (True, False)):
        np.savez(tmp_path / f"{p.episode_id}.npz", **_record(12, 4, success))
        keep_episode(tmp_path / f"{p.episode_id}.npz", p, store, "pi0", fps=5)
        assert not (tmp_path / f"{p.episode_id}.npz").exists()
    episodes = collect_episodes(out, store, planned)
    assert episodes["success"].tolist() == [True, False] and episodes["task"].tolist() == ["libero_goal_4"] * 2
    assert episodes["instruction"].tolist() == ["put the bowl on the plate"] * 2
    row = episodes.iloc[0]
    assert read_video(out / row["video_path"]).shape == (4, 64, 64, 3)
    trajectory = load_trajectory(out / row["trajectory_path"])  # what the kinematic judge reads
    assert trajectory.n_steps == 12 and trajectory.state.shape == (12, 8) and trajectory.progress[-1] == 1.0
    assert pd.read_parquet(out / row["trajectory_path"])["success"].tolist()[-1]


def test_the_world_job_carries_the_protocol(tmp_path):
    tasks = selected_tasks(["libero_object_2"], {"libero_object": 40})
    planned = planned_episodes(tasks, 2, seed=0, policy="p")
    libero = {"observation": {"image_size": [224, 224], "rotate_180": True}, "settle_steps": 10, "render": "on_demand",
              "video": {"camera": "agentview", "size": [256, 256], "fps": 5}}
    job = world_job(libero, Horizon(25, 5), {"observation.images.image": "agentview"}, planned,
                    {t.name: t for t in tasks}, 1234, tmp_path)
    assert job["execute"] == 5  # the LIBERO side runs what the job says, it checks no rule
    assert job["video"]["every"] == 4 and job["server"] == {"host": "127.0.0.1", "port": 1234}
    assert [(e["suite"], e["task_index"], e["init_index"], e["max_steps"]) for e in job["episodes"]] == [
        ("libero_object", 2, 0, 40), ("libero_object", 2, 1, 40)]
    json.dumps(job)  # it goes to the LIBERO process as JSON


def test_a_failed_libero_process_is_named_by_task_init_and_policy(tmp_path):
    (tmp_path / "current.json").write_text(json.dumps({"suite": "libero_10", "task_index": 3, "init_index": 7}))
    assert failure_text(tmp_path, -9, "pi0") == (
        "LIBERO process failed on libero_10 task 3 init 7 (policy 'pi0'): the process ended with status -9")
    (tmp_path / "failed.json").write_text(json.dumps({"suite": "libero_10", "task_index": 3, "init_index": 8,
                                                      "error": "ValueError: bad chunk"}))
    assert failure_text(tmp_path, 1, "pi0") == "LIBERO process failed on libero_10 task 3 init 8 (policy 'pi0'): ValueError: bad chunk"
