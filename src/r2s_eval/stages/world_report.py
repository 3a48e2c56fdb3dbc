"""Stage and script: the calibrated world's fidelity per task, from the artefacts.

Prints a table and writes the report as JSON (its layout: ``r2s_eval.report.world``)::

    python -m r2s_eval.stages.world_report --truth results/real/init_truth.parquet \\
        --errors results/init/error.parquet --replay results/replay/log.parquet \\
        --estimates results/init/estimates.parquet --reference results/reference/success.parquet \\
        --rollouts results/rollout/sim/* --out results/world/report.json
"""

from __future__ import annotations

import argparse

import pandas as pd

from r2s_eval.errors import DataError
from r2s_eval.report.world import build_report, format_table
from r2s_eval.stages import _cli
from r2s_eval.stages._rollouts import load_episodes
from r2s_eval.utils.io import read_parquet_metadata, write_json

READS = ("stats.n_boot", "stats.ci_level", "seed")  # config paths the --cfg slice holds (see _reads.py)


def main(args: argparse.Namespace) -> None:
    attempts = read_parquet_metadata(args.truth).get("attempts")
    if not attempts:
        raise DataError(f"{args.truth}: no teleop attempt log in its metadata (written by the teleop stage)")
    errors = pd.read_parquet(args.errors)
    replay_log = pd.read_parquet(args.replay)
    init_s = None
    if args.estimates:
        init_s = read_parquet_metadata(args.estimates).get("s_per_episode")
    reference = pd.read_parquet(args.reference) if args.reference else None
    sim_episodes = load_episodes(args.rollouts) if args.rollouts else None
    report = build_report(attempts, errors, replay_log, init_s, reference=reference, sim_episodes=sim_episodes,
                          level=float(args.cfg["stats.ci_level"]), n_boot=int(args.cfg["stats.n_boot"]),
                          seed=int(args.cfg["seed"]))
    print(format_table(report))
    if args.out:
        write_json(args.out, report, provenance=True)


def parser() -> argparse.ArgumentParser:
    p = _cli.parser(__doc__.split("\n")[0])
    p.add_argument("--truth", required=True, help="teleop truth parquet (its metadata holds the attempt log)")
    p.add_argument("--errors", required=True, help="init_error's per-object error table")
    p.add_argument("--replay", required=True, help="replay log parquet")
    p.add_argument("--estimates", help="init estimates (for the per-episode estimation cost)")
    p.add_argument("--reference", help="reference success table (the real side), for the real-sim gap")
    p.add_argument("--rollouts", nargs="*", default=[], help="sim rollout folders, one per policy, for the gap")
    p.add_argument("--out", help="write the report as JSON here")
    return p


if __name__ == "__main__":
    _cli.run(main, parser())
