"""Shared pieces of the serving tests: a tiny ACT checkpoint, `r2s_eval.serve` subprocesses."""

from __future__ import annotations

import os
import queue
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.helpers import policy_server
from tests.helpers.datasets import build_dataset

REPO_ID = "test/serving_synthetic"
HEAD = "observation.images.head_left"
API_KEY_ENV = "R2S_SERVING_TEST_KEY"
START_TIMEOUT_S = 120


@pytest.fixture(scope="session")
def helpers():
    """tests/helpers/policy_server.py (free ports, observations, fake policy, fault server)."""
    return policy_server


@pytest.fixture(scope="session")
def act_checkpoint(tmp_path_factory) -> Path:
    """A 3-step ACT checkpoint on a 2-episode synthetic dataset (a few seconds)."""
    from r2s_eval.config import candidate_config
    from r2s_eval.policies import train_policy

    base = tmp_path_factory.mktemp("serving")
    root = build_dataset(base / "data", REPO_ID, n_episodes=2, n_steps=20,
                         image_hw=(32, 32), cameras=(HEAD,))
    cfg = candidate_config("act", "smoke", steps=3, batch_size=4, image_keys=[HEAD], image_size=[24, 24])
    out = base / "act"
    train_policy(root, REPO_ID, cfg, out, seed=0)
    return out


@dataclass
class Served:
    proc: subprocess.Popen
    port: int
    line: str
    stderr_path: Path
    key: str | None = None

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")


def _launch(ckpt: Path, log_dir: Path, name: str, key: str | None) -> tuple[subprocess.Popen, int, Path, queue.Queue]:
    port = policy_server.free_port()
    cmd = [sys.executable, "-m", "r2s_eval.serve", str(ckpt), "--port", str(port), "--name", name]
    env = dict(os.environ, MUJOCO_GL="egl")
    env.pop(API_KEY_ENV, None)
    if key is not None:
        cmd += ["--api-key-env", API_KEY_ENV]
        env[API_KEY_ENV] = key
    stderr_path = log_dir / f"{name}.stderr"
    with stderr_path.open("w") as stderr:  # the child keeps its own handle
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=stderr, text=True, env=env)
    lines: queue.Queue = queue.Queue()

    def pump():  # a reader thread: waiting on the pipe must not block the test past its timeout
        for line in proc.stdout:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=pump, daemon=True).start()
    return proc, port, stderr_path, lines


def _wait_serving(proc, lines: queue.Queue, stderr_path: Path) -> str:
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.5)
        except queue.Empty:
            continue
        if line is None:
            break
        if line.startswith("serving "):
            return line.strip()
    proc.kill()
    raise AssertionError(f"server did not start (rc={proc.poll()}):\n{stderr_path.read_text()[-4000:]}")


def _terminate(procs: list[subprocess.Popen]) -> None:
    for proc in procs:  # all at once: each takes a moment to shut down
        if proc.poll() is None:
            proc.terminate()
    for proc in procs:
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="session")
def served(act_checkpoint, tmp_path_factory) -> dict[str, Served]:
    """Two `python -m r2s_eval.serve` subprocesses, started side by side: open and key-protected."""
    log_dir = tmp_path_factory.mktemp("serve_logs")
    key = "test-key-" + os.urandom(6).hex()
    launched = {
        "open": (_launch(act_checkpoint, log_dir, "act_open", None), None),
        "keyed": (_launch(act_checkpoint, log_dir, "act_keyed", key), key),
    }
    out = {}
    try:
        for kind, ((proc, port, stderr_path, lines), k) in launched.items():
            line = _wait_serving(proc, lines, stderr_path)
            out[kind] = Served(proc, port, line, stderr_path, k)
        yield out
    finally:
        _terminate([proc for (proc, *_), _k in launched.values()])
