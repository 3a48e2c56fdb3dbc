"""Shared pieces of the annotation and browser tests (their fixtures `run` and `annotation_set`
are in tests/conftest.py): Debian's chromium driven by Playwright, the annotation
server as a process of its own (so it can be killed like a crashed machine), a small run
directory with real videos, and annotators who answer with the keyboard."""

from __future__ import annotations

import contextlib
import json
import os
import runpy
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from r2s_eval.config import select, to_json
from r2s_eval.judge.base import CriterionNote, Description
from r2s_eval.rollout.mp4 import write_video
from r2s_eval.stages._reads import declaration
from r2s_eval.utils.io import write_json, write_parquet

CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run", "--disable-quic"]
POLICIES = ("alpha", "beta", "gamma")
TASKS = {"cup_on_plate": "Pick the Cup and Place it on the Plate",
         "block_in_bin": "Put the red block into the bin"}
INITS = 4
# Which rollouts succeed: alpha always, gamma never, beta on even inits -> all three categories.
SUCCESS = {"alpha": lambda init: True, "beta": lambda init: init % 2 == 0, "gamma": lambda init: False}


def chromium() -> str:
    """Debian's chromium, looked up at run time; the test is skipped without it or Playwright."""
    pytest.importorskip("playwright.sync_api", reason="Playwright for Python is not installed")
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        pytest.skip("chromium is not installed (Debian: apt-get install chromium)")
    return path


@contextlib.contextmanager
def browser() -> Iterator:
    from playwright.sync_api import sync_playwright

    executable = chromium()
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=executable, headless=True, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class AnnotationServer:
    """``python -m r2s_eval.annotate serve`` in a process group of its own."""

    def __init__(self, set_dir: Path, db: Path, port: int | None = None):
        self.set_dir, self.db, self.port = Path(set_dir), Path(db), port or free_port()
        self.proc: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> AnnotationServer:
        self.log = open(self.db.with_suffix(f".{self.port}.log"), "a")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "r2s_eval.annotate", "serve", "--set", str(self.set_dir), "--db", str(self.db),
             "--port", str(self.port)], stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            assert self.proc.poll() is None, self.db.with_suffix(f".{self.port}.log").read_text()
            try:
                with urllib.request.urlopen(f"{self.url}/api/info", timeout=2) as r:
                    if r.status == 200:
                        return self
            except OSError:
                time.sleep(0.2)
        raise AssertionError("the annotation server did not start")

    def kill(self) -> None:
        """SIGKILL, like a crash: no handler runs, nothing is flushed on the way out."""
        os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()
        self.log.close()

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.kill()
        if not self.log.closed:
            self.log.close()

    def __enter__(self) -> AnnotationServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


# ------------------------------------------------------------------------ a small run


def _frames(policy: str, init: int, n: int = 40, size: int = 128) -> list[np.ndarray]:
    """A coloured square crossing the frame: each policy its colour, each init its row."""
    colour = {"alpha": (220, 60, 40), "beta": (40, 160, 70), "gamma": (50, 80, 220)}[policy]
    frames = []
    for k in range(n):
        image = np.full((size, size, 3), 235, dtype=np.uint8)
        x, y = 4 + k * (size - 28) // n, 10 + 25 * init % (size - 30)
        image[y:y + 20, x:x + 20] = colour
        image[-6:, : 3 + k * (size - 3) // n] = 90  # a progress strip at the bottom
        frames.append(image)
    return frames


def build_run(root: Path) -> dict:
    """Sim rollouts (real mp4 videos), compared pairs, one judge's verdicts and descriptions,
    a fit, a validation and two figures, laid out like a finished run under ``root``."""
    rows = []
    for policy in POLICIES:
        folder = root / "results" / "rollout" / "sim" / policy
        episodes = []
        for task, instruction in TASKS.items():
            for init in range(INITS):
                episode = f"ep{len(rows):03d}z"  # opaque and unique; 'z' keeps it out of hex tokens
                write_video(folder / "videos" / f"{episode}.mp4", _frames(policy, init), fps=10)
                row = {"episode_id": episode, "policy": policy, "task": task, "init_id": init,
                       "instruction": instruction, "success": SUCCESS[policy](init), "length": 40, "seed": init,
                       "arm": "sim", "video_path": f"videos/{episode}.mp4",
                       "trajectory_path": f"trajectories/{episode}.parquet"}
                episodes.append(row)
                rows.append({**row, "video_path": str(folder / row["video_path"])})
        write_parquet(folder / "episodes.parquet", pd.DataFrame(episodes))
    sim = pd.DataFrame(rows)
    by = {(r.policy, r.task, r.init_id): r.episode_id for r in sim.itertuples()}
    pairs, verdicts, k = [], [], 0
    for i, pi in enumerate(POLICIES):
        for pj in POLICIES[i + 1:]:
            n = 0
            for task in TASKS:
                for init in range(INITS):
                    a_first = (n % 2 == 0)
                    pa, pb = (pi, pj) if a_first else (pj, pi)
                    ea, eb = by[(pa, task, init)], by[(pb, task, init)]
                    pairs.append({"pair_index": n, "policy_i": pi, "policy_j": pj, "task": task, "init_id": init,
                                  "episode_a": ea, "episode_b": eb, "policy_a": pa, "policy_b": pb,
                                  "first_checkpoint": 8 if n < 8 else 16})
                    # The judge prefers the successful rollout, else the earlier policy of the line-up.
                    sa, sb = SUCCESS[pa](init), SUCCESS[pb](init)
                    letter = "A" if (sa, -POLICIES.index(pa)) > (sb, -POLICIES.index(pb)) else "B"
                    verdicts.append({**pairs[-1], "verdict": letter, "winner": pa if letter == "A" else pb,
                                     "rationale": "", "verdict_swapped": ("B" if letter == "A" else "A") if n % 4 == 0 else ""})
                    n, k = n + 1, k + 1
    write_parquet(root / "results" / "compare" / "pairs.parquet", pd.DataFrame(pairs))
    write_parquet(root / "results" / "judge" / "kin" / "verdicts.parquet", pd.DataFrame(verdicts))
    descriptions = []
    for r in sim.itertuples():
        label = "successful" if r.success else "failed"
        d = Description(criteria={
            "motion_smoothness": CriterionNote(f"{r.policy} moves smoothly"),
            "action_continuity": CriterionNote("continuous"),
            "task_progress": CriterionNote(f"Task {label}", label=label),
            "force_control": CriterionNote("gentle contact")}, summary=f"{r.policy}: {label}.", judge="kin")
        descriptions.append({"episode_id": r.episode_id, "judge": "kin", "instruction": r.instruction,
                             "description": d.to_json()})
    write_parquet(root / "results" / "judge" / "kin" / "descriptions.parquet", pd.DataFrame(descriptions))
    fit = [{"checkpoint": 16, "policy": p, "score": s, "ci_low": s - 5, "ci_high": s + 5, "strength": s / 100,
            "interval": "unit", "ci_level": 0.95} for p, s in zip(POLICIES, (60.0, 30.0, 10.0))]
    write_parquet(root / "results" / "fit" / "kin.parquet", pd.DataFrame(fit))
    metrics = {"spearman": 1.0, "pearson": 0.97, "mmrv": 0.0, "ci_width": 10.0}
    rate = {"alpha": 1.0, "beta": 0.5, "gamma": 0.0}
    write_json(root / "results" / "validate" / "kin.json", {
        "average": metrics, "last": metrics, "interval": "unit", "ci_level": 0.95,
        "reference": {"success_rate": rate, "ci_low": rate, "ci_high": rate, "definition": "mean over tasks"}})
    write_parquet(root / "results" / "reference" / "success.parquet", pd.DataFrame(
        {"policy": list(POLICIES), "task": "cup_on_plate", "trials": 4, "successes": [4, 2, 0]}))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for name in ("bt_convergence", "win_rate_matrix_kin"):
        fig, ax = plt.subplots(figsize=(4, 3))
        ax.plot([8, 16], [50, 60], marker="o")
        ax.set_title(name)
        (root / "reports").mkdir(exist_ok=True)
        fig.savefig(root / "reports" / f"{name}.png", dpi=80)
        plt.close(fig)
    return {"sim": sim, "rollouts": [str(root / "results" / "rollout" / "sim" / p) for p in POLICIES]}


def run_stage(stage: str, cfg: dict, *args: str, **provided) -> None:
    """A stage's entry point in this process, with the --cfg its declaration selects."""
    argv = [stage, "--cfg", to_json({**select(cfg, *declaration(stage)["READS"]), **provided}), *args]
    old = sys.argv
    sys.argv = argv
    try:
        runpy.run_module(f"r2s_eval.stages.{stage}", run_name="__main__")
    except SystemExit as exit_:
        assert not exit_.code, f"stage {stage} failed"
    finally:
        sys.argv = old


# ---------------------------------------------------------------------- annotators

def open_annotator(b, url: str, name: str):
    """A fresh browser context (its own storage) with the annotator's page, ready to answer."""
    context = b.new_context(viewport={"width": 1280, "height": 900})
    page = context.new_page()
    page.goto(f"{url}/?annotator={name}")
    page.wait_for_selector("body[data-state='ready'], body[data-state='done']")
    return page


def wait_until(page, expression: str, timeout_s: float = 20.0) -> None:
    """Poll a JS expression until it is truthy. (Playwright's wait_for_function evaluates its
    predicate with eval, which the page's Content-Security-Policy rightly forbids.)"""
    deadline = time.monotonic() + timeout_s
    while not page.evaluate(expression):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {expression}")
        time.sleep(0.05)


def answered(page) -> int:
    return int(page.get_attribute("body", "data-answered") or 0)


def answer_with_keyboard(page, letter: str) -> None:
    """Press A or B and wait until the server has acknowledged it (the count moves on)."""
    before = answered(page)
    page.keyboard.press(letter)
    wait_until(page, f"Number(document.body.dataset.answered) > {before} && "
                     "['ready', 'done'].includes(document.body.dataset.state)")


def videos_state(page, wait_ms: int = 800) -> dict:
    """Both videos: ready state, whether playing, how far their clocks moved in ``wait_ms``
    and how far apart they are."""
    return page.evaluate("""async (wait) => {
        const vs = [...document.querySelectorAll('video')].slice(0, 2);
        const t0 = vs.map(v => v.currentTime);
        await new Promise(r => setTimeout(r, wait));
        const t1 = vs.map(v => v.currentTime);
        return {ready: vs.map(v => v.readyState), paused: vs.map(v => v.paused),
                advanced: t1.map((t, k) => t - t0[k]), gap: Math.abs(t1[0] - t1[1]),
                width: vs.map(v => v.videoWidth), error: vs.map(v => v.error && v.error.message)};
    }""", wait_ms)


def screenshot_dir(tmp_path_factory) -> Path:
    """Where the browser tests leave their screenshots: <pytest's base temp>/screenshots."""
    folder = tmp_path_factory.getbasetemp() / "screenshots"
    folder.mkdir(exist_ok=True)
    return folder


def export_csv(set_dir: Path, db: Path, out: Path) -> pd.DataFrame:
    subprocess.run([sys.executable, "-m", "r2s_eval.annotate", "export", "--set", str(set_dir), "--db", str(db),
                    "--out", str(out)], check=True, capture_output=True)
    return pd.read_csv(out)


def fetch_json(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=10) as r:
        return json.loads(r.read())
