"""Describe-stage throughput of the openai judge backend: concurrency 1 vs 8.

A local chat-completions server (the one the judge tests use, on 127.0.0.1) answers every
request after a fixed latency, standing in for a GPU server that batches requests. The describe
stage runs over the same rollout videos twice, with a fresh cache each time: once with one
request in flight, once with eight. Printed: videos per second for each and their ratio (target:
at least 6x at concurrency 8). Everything else in the stage (decoding, frame sampling, JPEG
encoding, caching) is measured too, so the ratio falls short of 8 by exactly that overhead.

Run: ``python benchmarks/bench_judge_throughput.py [--videos 48] [--latency-s 0.25] [--workers 8]``
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the tests' helper package: tests.helpers

from tests.helpers.chat_server import ChatServer  # noqa: E402
from tests.helpers.videos import make_rollouts  # noqa: E402

from r2s_eval.judge import describe_rollouts, make_judge  # noqa: E402
from r2s_eval.rollout.episode_store import load_episodes  # noqa: E402


def run(episodes, url: str, workers: int, cache: Path) -> float:
    judge = make_judge({"backend": "openai", "base_url": url, "model": "bench-vlm", "max_frames": 16,
                        "concurrency": workers})
    t0 = time.perf_counter()
    out = describe_rollouts(episodes, ".", judge, cache)
    wall = time.perf_counter() - t0
    assert out.attrs["stats"]["calls"] == len(episodes), out.attrs["stats"]
    return wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--videos", type=int, default=48)
    ap.add_argument("--latency-s", type=float, default=0.25)
    ap.add_argument("--workers", type=int, default=8)
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        half = args.videos // 2
        levels = {(p, "lift", i): lvl + 0.001 * i for p, lvl in (("good", 0.8), ("bad", 0.2)) for i in range(half)}
        episodes = load_episodes(make_rollouts(tmp / "rollouts", levels))
        with ChatServer(latency_s=args.latency_s) as server:
            # Warm-up (imports, first connection) outside the timings: it would favour the second run.
            run(episodes.head(2), server.url, 1, tmp / "warmup")
            serial = run(episodes, server.url, 1, tmp / "cache1")
            parallel = run(episodes, server.url, args.workers, tmp / "cache8")
    n = len(episodes)
    print(f"describe stage, {n} videos, {args.latency_s * 1000:.0f} ms per request")
    print(f"  concurrency 1: {serial:6.2f} s  {n / serial:6.2f} videos/s")
    print(f"  concurrency {args.workers}: {parallel:6.2f} s  {n / parallel:6.2f} videos/s")
    ratio = serial / parallel
    print(f"  speed-up: {ratio:.2f}x (target >= 6x at concurrency 8) -> {'met' if ratio >= 6 else 'NOT met'}")


if __name__ == "__main__":
    main()
