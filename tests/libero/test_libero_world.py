"""LIBERO itself, in its own environment, driven by tiny VLA checkpoints through our policy
server: the same initial state for every policy, our recorded success equal to LIBERO's own
check at the last step, and a LIBERO process killed mid-run losing nothing finished."""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import pandas as pd
import pytest

import r2s_eval.libero.rollout as libero_rollout
from r2s_eval.libero.environment import LIBERO_SIDE_SCRIPT
from r2s_eval.libero.rollout import run_libero_candidate
from r2s_eval.policies.interface import PolicyError

pytestmark = pytest.mark.libero
REPLAY_CHECK = Path(__file__).resolve().parents[1] / "helpers" / "libero_replay_check.py"

LIBERO = {
    "tasks": ["libero_spatial_0"],
    "max_steps": {"libero_spatial": 15},
    "episodes_per_task": 2,
    "settle_steps": 5,
    "observation": {"cameras": {"image": "agentview", "wrist_image": "robot0_eye_in_hand"}, "image_size": [64, 64],
                    "rotate_180": True},
    "video": {"camera": "agentview", "size": [64, 64], "fps": 5},
    "render": "on_demand",
}
ROLLOUT = {"horizon": {"chunk": 25, "execute": 5}, "device": "cpu"}


def _run(out, name, ckpt, python, **kw):
    return run_libero_candidate(out / name, policy=name, seed=0, libero=LIBERO, rollout=ROLLOUT,
                                policy_cfg={"type": "checkpoint", "path": str(ckpt)}, python=python, **kw)


def test_same_initial_state_for_every_policy_and_success_as_libero_checks_it(libero_python, tiny_checkpoints, tmp_path):
    runs = {name: _run(tmp_path, name, ckpt, libero_python) for name, ckpt in tiny_checkpoints.items()}
    a, b = (runs[n].set_index(["task", "init_id"]).sort_index() for n in ("tiny_a", "tiny_b"))
    assert a.index.tolist() == [("libero_spatial_0", 0), ("libero_spatial_0", 1)] == b.index.tolist()
    assert (a["init_state_sha256"] == b["init_state_sha256"]).all()  # the same start, policy by policy
    assert a["init_state_sha256"].nunique() == 2  # and a different one per official init
    assert (a["seed"] == b["seed"]).all()
    assert not (a["episode_id"] == b["episode_id"]).any()

    # Replaying an episode's recorded actions from its initial state in a fresh LIBERO
    # environment reaches the recorded end, where LIBERO's own check agrees with our table.
    for name, episodes in runs.items():
        for row in episodes.itertuples():
            trajectory = pd.read_parquet(tmp_path / name / row.trajectory_path)
            assert len(trajectory) == row.length == LIBERO["max_steps"]["libero_spatial"] or row.success
            episode = {"suite": "libero_spatial", "task_index": 0, "init_index": row.init_id, "seed": row.seed,
                       "settle_steps": LIBERO["settle_steps"], "actions": trajectory["action"].map(list).tolist()}
            (tmp_path / "episode.json").write_text(json.dumps(episode))
            proc = subprocess.run([str(libero_python), str(REPLAY_CHECK), str(tmp_path / "episode.json"), str(LIBERO_SIDE_SCRIPT)],
                                  capture_output=True, text=True, env={"MUJOCO_GL": "egl", "PATH": "/usr/bin:/bin"})
            assert proc.returncode == 0, proc.stderr[-3000:]
            replayed = json.loads(proc.stdout.strip().splitlines()[-1])
            assert replayed["success"] == bool(row.success) == bool(trajectory["success"].iloc[-1])
            assert replayed["eef_pos"] == pytest.approx(list(trajectory["ee_pos_left"].iloc[-1]), abs=1e-6)


def test_a_killed_libero_process_keeps_finished_episodes(libero_python, tiny_checkpoints, tmp_path, monkeypatch):
    started, kept = [], []
    popen, keep = subprocess.Popen, libero_rollout.keep_episode

    def recording_popen(*args, **kwargs):
        started.append(popen(*args, **kwargs))
        return started[-1]

    def keep_then_kill(npz, planned, *args):
        keep(npz, planned, *args)
        kept.append(planned.init_id)
        if len(kept) == 1:
            started[-1].send_signal(signal.SIGKILL)  # a lost machine, mid-run

    monkeypatch.setattr(libero_rollout.subprocess, "Popen", recording_popen)
    monkeypatch.setattr(libero_rollout, "keep_episode", keep_then_kill)
    with pytest.raises(PolicyError, match=r"libero_spatial task 0 init 1 \(policy 'tiny_a'\).*1 of 2 episodes are kept"):
        _run(tmp_path, "tiny_a", tiny_checkpoints["tiny_a"], libero_python)
    assert kept == [0]

    episodes = _run(tmp_path, "tiny_a", tiny_checkpoints["tiny_a"], libero_python)
    assert kept == [0, 1]  # the rerun ran the unfinished episode only
    assert episodes["init_id"].tolist() == [0, 1] and len(started) == 2


def test_a_policy_server_candidate_acts_as_its_checkpoint(libero_python, tiny_checkpoints, tmp_path):
    # The same checkpoint served by `python -m r2s_eval.serve` (a lab's GPU box, here on
    # loopback) and entered as `type: server`: the same episodes, the same actions.
    import socket
    import sys
    import time

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    log = tmp_path / "server.log"
    server = subprocess.Popen([sys.executable, "-m", "r2s_eval.serve", str(tiny_checkpoints["tiny_b"]), "--port", str(port)],
                              stdout=open(log, "w"), stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 120
        while "serving" not in log.read_text():
            assert server.poll() is None and time.monotonic() < deadline, log.read_text()[-2000:]
            time.sleep(0.2)
        served = run_libero_candidate(tmp_path / "served", policy="tiny_b", seed=0, libero=LIBERO, rollout=ROLLOUT,
                                      policy_cfg={"type": "server", "port": port, "host": "127.0.0.1",
                                                  "connect_timeout_s": 10.0, "reply_timeout_s": 60.0,
                                                  "connect_retries": 3},
                                      python=libero_python)
    finally:
        server.kill()
        server.wait()
    local = _run(tmp_path, "tiny_b", tiny_checkpoints["tiny_b"], libero_python)
    for a, b in zip(served.itertuples(), local.itertuples()):
        assert a.init_state_sha256 == b.init_state_sha256
        actions_a = pd.read_parquet(tmp_path / "served" / a.trajectory_path)["action"]
        actions_b = pd.read_parquet(tmp_path / "tiny_b" / b.trajectory_path)["action"]
        assert len(actions_a) == len(actions_b)
        for x, y in zip(actions_a, actions_b):
            assert list(x) == pytest.approx(list(y), abs=1e-5)
