"""The demo's CPU cost, stage by stage: this checkout against an earlier commit, in the same run.

Each side is a git worktree of its commit (the working tree's uncommitted changes are not
measured: commit first) running the README's first command, `snakemake -j 2
reports/realsim_table.tex`, from a fresh directory with this environment's Python, its own
`src/` first on the path. By default both run at once, side by side, so that they share the
machine alike; `--one-after-the-other` runs the baseline first.

What is counted: the CPU time (user + system) of the whole process tree of each run, Snakemake
included (`os.wait4`), and per stage the CPU-seconds each job logs when it ends
(`r2s_eval.stages._cli`; commits before that line was logged cannot be a side here). The table
sums the jobs of each stage; "Snakemake and start-up" is the rest of the tree's time. The new
side's ranking is printed after the table, to check that the planted order still holds.

Run: ``python benchmarks/bench_demo_cost.py --baseline 58fc49f [--new HEAD] [--keep DIR]``
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DONE = re.compile(r"stage done in ([\d.]+) s wall, ([\d.]+) CPU-s")


def processor() -> str:
    """The processor's model and its widest vector extension, as /proc/cpuinfo names them."""
    model, flags = platform.processor() or "unknown processor", set()
    try:
        text = Path("/proc/cpuinfo").read_text()
        model = re.search(r"^model name\s*:\s*(.+)$", text, re.M).group(1)
        flags = set(re.search(r"^flags\s*:\s*(.+)$", text, re.M).group(1).split())
    except (OSError, AttributeError):
        pass
    vectors = [v for v in ("avx512f", "avx2", "avx") if v in flags][:1]
    return f"{model} ({os.cpu_count()} CPUs, {vectors[0].upper() if vectors else 'no AVX'})"


def worktree(rev: str, dest: Path) -> Path:
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-f", str(dest), rev],
                   check=True, capture_output=True)
    return dest


def start(tree: Path, target: str, jobs: int) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(tree / "src"), MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    log = open(tree / "bench_snakemake.log", "w")
    return subprocess.Popen([sys.executable, "-m", "snakemake", "-j", str(jobs), target], cwd=tree, env=env,
                            stdout=log, stderr=subprocess.STDOUT)


def wait(running: dict[str, tuple[subprocess.Popen, float]]) -> dict[str, tuple[int, float, float]]:
    """Per run, as each ends: (exit status, CPU-seconds of its process tree, wall seconds)."""
    ended = {}
    by_pid = {proc.pid: (name, proc, t0) for name, (proc, t0) in running.items()}
    while by_pid:
        pid, status, usage = os.wait4(-1, 0)
        if pid not in by_pid:
            continue
        name, proc, t0 = by_pid.pop(pid)
        proc.returncode = os.waitstatus_to_exitcode(status)
        ended[name] = (proc.returncode, usage.ru_utime + usage.ru_stime, time.monotonic() - t0)
    return ended


def stage_cpu(tree: Path) -> dict[str, tuple[int, float]]:
    """Per stage (the first folder under logs/, or the log's name): jobs and their CPU-seconds."""
    found: dict[str, list[float]] = defaultdict(list)
    for log in sorted((tree / "logs").rglob("*.log")):
        match = DONE.search(log.read_text(errors="replace"))
        if match:
            rel = log.relative_to(tree / "logs")
            found[rel.parts[0] if len(rel.parts) > 1 else rel.stem].append(float(match.group(2)))
    return {stage: (len(cpu), sum(cpu)) for stage, cpu in found.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--baseline", required=True, help="the commit to compare against (logs its stages' CPU-seconds)")
    p.add_argument("--new", default="HEAD", help="the commit measured (default: HEAD)")
    p.add_argument("--target", default="reports/realsim_table.tex")
    p.add_argument("--jobs", type=int, default=2, help="snakemake -j of each side")
    p.add_argument("--one-after-the-other", action="store_true", help="run the baseline first, then the new side")
    p.add_argument("--keep", type=Path, default=None, help="leave both runs in this folder (default: removed)")
    args = p.parse_args()

    root = Path(tempfile.mkdtemp(prefix="bench_demo_")) if args.keep is None else args.keep
    root.mkdir(parents=True, exist_ok=True)
    sides = {"baseline": worktree(args.baseline, root / "baseline"), "new": worktree(args.new, root / "new")}
    results = {}
    try:
        started = time.monotonic()
        running = {}
        for name, tree in sides.items():
            running[name] = (start(tree, args.target, args.jobs), time.monotonic())
            if args.one_after_the_other:
                results.update(wait(running))
                running = {}
        results.update(wait(running))
        for name, (status, _, _) in results.items():
            if status != 0:
                raise SystemExit(f"the {name} run failed (exit {status}): {sides[name] / 'bench_snakemake.log'}")
        stages = {name: stage_cpu(tree) for name, tree in sides.items()}
        print(f"The demo ({args.target}, -j {args.jobs}, {'one after the other' if args.one_after_the_other else 'side by side'}) "
              f"on {processor()}, {time.monotonic() - started:.0f} s in all")
        print(f"baseline {args.baseline}, new {args.new}; CPU-seconds (user + system)")
        print(f"{'stage':22s} {'jobs':>9s} {'baseline':>9s} {'new':>9s} {'ratio':>7s}")
        names = sorted(set(stages["baseline"]) | set(stages["new"]),
                       key=lambda s: -stages["baseline"].get(s, (0, 0.0))[1])
        for stage in names:
            (jb, old), (jn, new) = stages["baseline"].get(stage, (0, 0.0)), stages["new"].get(stage, (0, 0.0))
            ratio = f"{old / new:6.2f}x" if new > 0 else "    -"
            print(f"{stage:22s} {jb:>4d}/{jn:<4d} {old:9.1f} {new:9.1f} {ratio}")
        rest = {name: results[name][1] - sum(cpu for _, cpu in stages[name].values()) for name in sides}
        print(f"{'Snakemake and start-up':22s} {'':9s} {rest['baseline']:9.1f} {rest['new']:9.1f} "
              f"{rest['baseline'] / max(rest['new'], 1e-9):6.2f}x")
        old_total, new_total = results["baseline"][1], results["new"][1]
        print(f"{'total':22s} {'':9s} {old_total:9.1f} {new_total:9.1f} {old_total / new_total:6.2f}x "
              f"(new = {100 * new_total / old_total:.0f} % of baseline)")
        print(f"wall: baseline {results['baseline'][2]:.0f} s, new {results['new'][2]:.0f} s")
        print("\nThe new side's ranking:\n" + (sides["new"] / "reports" / "ranking.txt").read_text())
    finally:
        if args.keep is None:
            for tree in sides.values():
                subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)], capture_output=True)
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
