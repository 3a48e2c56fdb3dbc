"""The batched rollout loop: an episode's bytes do not depend on how many run beside it, a run
killed mid-batch resumes with the episodes it had not finished, and an error names its episode."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import r2s_eval.rollout.candidate as candidate
import r2s_eval.rollout.loop as loop
from r2s_eval.horizon import Horizon
from r2s_eval.policies import PolicyError, RecedingHorizon
from r2s_eval.policies.interface import ChunkPolicy, PolicySpec
from r2s_eval.policies.lerobot_policy import load_lerobot_policy
from r2s_eval.rollout import run_episode, sample_inits, write_video
from r2s_eval.rollout.candidate import planned_episodes, run_candidate
from r2s_eval.sim import get_task
from r2s_eval.sim.build import make_env
from tests.helpers.worlds import bundled_world
from r2s_eval.utils.io import write_parquet
from r2s_eval.utils.numerics import deterministic_torch

from tests.helpers.policies import save_random_policy

TASKS = ["cup_on_plate", "stack_blocks"]
WORLD = {**bundled_world(), "image_height": 48, "image_width": 48, "cameras": ["head_left", "wrist_right"]}
ROLLOUT = {"horizon": {"chunk": 10, "execute": 5}, "inits_per_task": 3, "real_inits_per_task": None, "max_duration_s": 1.2,
           "device": "cpu", "model_batch": 4, "video_camera": "head_left", "video_size": [64, 64], "real_video_size": [64, 64],
           "video_fps": 10}
SEED = 3


@pytest.fixture(scope="module")
def inits(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("inits") / "inits.parquet"
    sample_inits([get_task(t, WORLD) for t in TASKS], ROLLOUT["inits_per_task"], SEED).to_parquet(path)
    return path


@pytest.fixture(scope="module")
def act(tmp_path_factory) -> Path:
    """The CPU line-up's ACT, randomly initialised, reading both cameras."""
    return save_random_policy(tmp_path_factory.mktemp("act"), WORLD["cameras"], (48, 48))


@pytest.fixture(scope="module")
def twin(tmp_path_factory) -> Path:
    """A real side with image noise, so the noise streams are part of what must match."""
    path = tmp_path_factory.mktemp("twin") / "twin_params.json"
    path.write_text(json.dumps({"params": {"image_noise_std": 4.0, "noise_seed": 7}}))
    return path


def _files(folder: Path) -> dict[str, bytes]:
    """Every file's bytes; the episode table as its rows (its metadata holds timings)."""
    files = {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
             if p.is_file() and p.name != "episodes.parquet"}
    files["episodes"] = pd.read_parquet(folder / "episodes.parquet").to_json().encode()
    return files


def _run(out: Path, inits: Path, act: Path, twin: Path | None, **batching) -> dict[str, bytes]:
    deterministic_torch(1)
    run_candidate(out, policy="act", arm="real" if twin else "sim", seed=SEED, rollout=ROLLOUT, world=WORLD,
                  policy_cfg={"type": "act"}, inits=str(inits), world_params=str(twin) if twin else None,
                  trained_dir=str(act), **batching)
    return _files(out)


def _one_at_a_time(tmp: Path, inits: Path, act: Path, twin: Path) -> dict[str, bytes]:
    """Each episode through `run_episode` and `RecedingHorizon.act` (one observation per call)."""
    from r2s_eval.sim import load_world_params

    deterministic_torch(1)
    policy = load_lerobot_policy(act, call_batch=ROLLOUT["model_batch"])
    files = {}
    for p in planned_episodes(pd.read_parquet(inits), "real", "act", SEED):
        env = make_env(p.task, WORLD, load_world_params(twin))
        runner = RecedingHorizon(policy, Horizon.from_config(ROLLOUT["horizon"]), slot=p.slot, seed=p.seed)
        result = run_episode(env, runner, p.object_poses, p.seed, 12, ROLLOUT["video_camera"],  # 1.2 s at 10 Hz
                             video_size=ROLLOUT["video_size"])
        env.close()
        write_video(tmp / f"{p.episode_id}.mp4", result.frames, ROLLOUT["video_fps"])
        write_parquet(tmp / f"{p.episode_id}.parquet", result.trajectory)
        files[f"videos/{p.episode_id}.mp4"] = (tmp / f"{p.episode_id}.mp4").read_bytes()
        files[f"trajectories/{p.episode_id}.parquet"] = (tmp / f"{p.episode_id}.parquet").read_bytes()
    return files


def test_an_episode_is_the_same_bytes_whatever_runs_beside_it(tmp_path, inits, act, twin):
    alone = _run(tmp_path / "n1", inits, act, twin, batch_episodes=1)
    side_by_side = _run(tmp_path / "n4", inits, act, twin, batch_episodes=4, threads=2)
    assert len(alone) == 2 * 6 + 1
    assert alone.keys() == side_by_side.keys()
    for name in alone:
        assert alone[name] == side_by_side[name], name
    # The same bytes as the one-at-a-time loop (run_episode, one observation per model call).
    (tmp_path / "old").mkdir()
    for name, data in _one_at_a_time(tmp_path / "old", inits, act, twin).items():
        assert alone[name] == data, name
    # The policy really acted: it moved the arms, differently from episode to episode.
    trajectories = [pd.read_parquet(tmp_path / "n1" / n) for n in alone if n.startswith("trajectories/")]
    actions = [np.stack(t["action"]) for t in trajectories]
    assert all(np.abs(np.diff(a, axis=0)).max() > 1e-3 for a in actions)
    assert not np.array_equal(actions[0], actions[1])


class ImagePolicy(ChunkPolicy):
    """A fast deterministic policy whose actions follow its slot's seed and what it sees;
    `fail(slot, query)` says when to raise or return NaN."""

    name = "image"

    def __init__(self, fail=None):
        self.spec = PolicySpec(cameras=("observation.images.head_left",), action_dim=14, max_chunk=10)
        self.seeds, self.queries, self.fail = {}, {}, fail or (lambda slot, query: None)

    def reset(self, slot, seed):
        self.seeds[slot], self.queries[slot] = seed, 0

    def predict_chunks(self, slots, observations):
        chunks = []
        for slot, obs in zip(slots, observations):
            self.queries[slot] += 1
            what = self.fail(slot, self.queries[slot])
            if what == "raise":
                exc = PolicyError(f"policy {self.name!r} at 127.0.0.1:9: connection closed")
                exc.slot = slot
                raise exc
            brightness = float(obs["observation.images.head_left"].mean()) / 255.0
            state = np.asarray(obs["observation.state"], dtype=np.float32)
            t = np.arange(10, dtype=np.float32)[:, None]
            chunk = state + 0.02 * np.sin(0.3 * t + self.seeds[slot] % 7 + brightness)
            chunks.append(np.full_like(chunk, np.nan) if what == "nan" else chunk)
        return np.stack(chunks).astype(np.float32)


def _run_image_policy(monkeypatch, out: Path, inits: Path, policy: ImagePolicy, arm: str = "sim",
                      rollout: dict = ROLLOUT, twin: Path | None = None, **batching) -> pd.DataFrame:
    monkeypatch.setattr(candidate, "open_policy", lambda *args, **kwargs: policy)
    return run_candidate(out, policy="image", arm=arm, seed=SEED, rollout=rollout, world=WORLD,
                         policy_cfg={"type": "server"}, inits=str(inits), world_params=str(twin) if twin else None,
                         **batching)


def test_real_side_videos_are_the_policy_image_unless_sized(tmp_path, monkeypatch, inits, twin):
    """No judge sees the real side's videos: by default they are the policy's own (noisy) image of
    the video camera; real_video_size renders them like the judges' videos. Sim videos keep
    video_size either way."""
    from r2s_eval.rollout.mp4 import read_video

    rollout = {**ROLLOUT, "real_video_size": None}
    sizes = {}
    for arm, cfg in (("real", rollout), ("sim", rollout), ("real_sized", ROLLOUT)):
        out = tmp_path / arm
        episodes = _run_image_policy(monkeypatch, out, inits, ImagePolicy(), arm=arm.split("_")[0], rollout=cfg,
                                     twin=twin if arm.startswith("real") else None, batch_episodes=3)
        sizes[arm] = {read_video(out / v).shape[1:3] for v in episodes["video_path"]}
    assert sizes == {"real": {(48, 48)}, "sim": {(64, 64)}, "real_sized": {(64, 64)}}


def test_a_run_killed_mid_batch_resumes_with_the_episodes_it_had_not_finished(tmp_path, monkeypatch, inits):
    reference = tmp_path / "reference"
    _run_image_policy(monkeypatch, reference, inits, ImagePolicy(), batch_episodes=1)

    out = tmp_path / "out"
    started: list[int] = []
    recorder = loop.EpisodeRecorder

    class Recorder(recorder):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            started.append(1)

        def step(self, action):
            # The power goes at the third step of the second batch: 3 episodes done, 3 in flight.
            if len(started) > 3 and len(self.rows) == 2 and kill:
                raise KeyboardInterrupt("power cut")
            super().step(action)

    monkeypatch.setattr(candidate, "EpisodeRecorder", Recorder)
    monkeypatch.setattr("r2s_eval.rollout.batch.EpisodeRecorder", Recorder)
    kill = True
    with pytest.raises(KeyboardInterrupt):
        _run_image_policy(monkeypatch, out, inits, ImagePolicy(), batch_episodes=3)
    store = tmp_path / ".out.episodes"
    assert not out.exists()
    kept = sorted(p.name for p in store.iterdir() if p.is_dir())
    assert len(kept) == 3 and all((store / ep / "row.json").is_file() for ep in kept)
    assert not [p for p in store.rglob("*") if p.name.endswith(".tmp")]  # nothing half-written is left

    kill, started[:] = False, []
    episodes = _run_image_policy(monkeypatch, out, inits, ImagePolicy(), batch_episodes=3)
    assert len(started) == 3  # only the episodes that had not finished
    assert len(episodes) == 6 and not store.exists()
    assert _files(out) == _files(reference)


def test_a_policy_error_names_the_episode_of_its_slot(tmp_path, monkeypatch, inits):
    planned = planned_episodes(pd.read_parquet(inits), "sim", "image", SEED)
    culprit = planned[4]  # an episode of the second task, in the second batch of 3
    for what in ("nan", "raise"):
        policy = ImagePolicy(fail=lambda slot, query: what if slot == culprit.slot and query == 2 else None)
        with pytest.raises(PolicyError) as err:
            _run_image_policy(monkeypatch, tmp_path / what, inits, policy, batch_episodes=3)
        message = str(err.value)
        assert f"[sim rollout, task {culprit.task}, init {culprit.init_id}]" in message, message
        assert ("non-finite" if what == "nan" else "127.0.0.1:9") in message
        assert message.count("init ") == 1  # only that episode is named
        store = tmp_path / f".{what}.episodes"
        assert len([p for p in store.iterdir() if p.is_dir()]) == 3  # the first batch is kept


def test_a_policy_server_drives_the_batched_loop(tmp_path, inits, act):
    """A server answers one observation per request; the lanes' requests are sequential, one
    connection per episode, and the episodes are the same whatever runs beside them."""
    from r2s_eval.serving.policy_server import PolicyServer

    server = PolicyServer(load_lerobot_policy(act), port=0)
    port = server.start()
    try:
        tables = {}
        for n in (1, 3):
            out = tmp_path / f"server{n}"
            run_candidate(out, policy="remote", arm="sim", seed=SEED, rollout=ROLLOUT, world=WORLD,
                          policy_cfg={"type": "server", "spec": None, "action_map": None, "connect_timeout_s": 10.0,
                                      "reply_timeout_s": 60.0, "connect_retries": 1},
                          transport={"host": "127.0.0.1", "port": port}, inits=str(inits), batch_episodes=n)
            tables[n] = _files(out)
        assert tables[1] == tables[3]
    finally:
        server.stop()


def test_the_real_arm_runs_in_the_twins_environment_where_its_world_file_holds_reality(tmp_path, monkeypatch, inits):
    """A world file with a reality record (the twin's, a twin ablation's) builds the twin's
    environment around the simulation: one control step of latency in seconds steps what the
    calibrated sim's answer of one step steps, and not what the same parameters without it step;
    the calibrated sim's file builds a plain environment."""
    from r2s_eval.sim import TabletopEnv
    from r2s_eval.twin.reality import RealityEnv

    files = {"twin": {"params": {"noise_seed": 7}, "reality": {"latency_s": 0.1}},
             "answer": {"params": {"noise_seed": 7, "command_latency_steps": 1}},
             "plain": {"params": {"noise_seed": 7}}}
    built: dict[str, set] = {}
    make_world_env = candidate.make_world_env
    trajectories = {}
    for name, record in files.items():
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(record))

        def spy(*args, name=name, **kwargs):
            env = make_world_env(*args, **kwargs)
            built.setdefault(name, set()).add(type(env))
            return env

        monkeypatch.setattr(candidate, "make_world_env", spy)
        episodes = _run_image_policy(monkeypatch, tmp_path / name, inits, ImagePolicy(), arm="real", twin=path,
                                     batch_episodes=3)
        trajectories[name] = [pd.read_parquet(tmp_path / name / p) for p in episodes["trajectory_path"]]
    assert built == {"twin": {RealityEnv}, "answer": {TabletopEnv}, "plain": {TabletopEnv}}
    for late, answer, plain in zip(trajectories["twin"], trajectories["answer"], trajectories["plain"]):
        states = {k: np.stack(t["state"]) for k, t in (("late", late), ("answer", answer), ("plain", plain))}
        assert np.array_equal(states["late"], states["answer"])
        assert not np.array_equal(states["late"], states["plain"])
