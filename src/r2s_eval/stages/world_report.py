"""Stage and script: the calibrated world's fidelity per task, from the artefacts.

In a run's working directory, prints the report the workflow wrote (``results/world/report.json``,
or ``--report PATH``)::

    python -m r2s_eval.stages.world_report

As the workflow's stage, builds it from the artefacts, writes it as JSON (its layout:
``r2s_eval.report.calibration_report``) and prints the table (to its log)::

    python -m r2s_eval.stages.world_report --cfg '{...}' --truth results/real/init_truth.parquet \\
        --errors results/init/error.parquet --replay results/replay/log.parquet \\
        --estimates results/init/estimates.parquet --reference results/reference/success.parquet \\
        --rollouts results/rollout/sim/* --out results/world/report.json
"""

from __future__ import annotations

import argparse
import json

import pandas as pd

from r2s_eval.errors import DataError
from r2s_eval.report.calibration_report import DEFAULT_REPORT, build_report, format_table, saved_table
from r2s_eval.stages import _cli
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.utils.io import read_json, read_parquet_metadata, write_json

READS = ("stats.n_boot", "stats.ci_level", "seed")  # config paths the --cfg slice holds (see _reads.py)
BUILD_INPUTS = ("cfg", "truth", "errors", "replay")  # what building the report needs


def main(args: argparse.Namespace) -> None:
    given = [name for name in BUILD_INPUTS if getattr(args, name) is not None]
    if not given:
        print(saved_table(args.report))
        return
    if len(given) < len(BUILD_INPUTS):
        missing = [f"--{name}" for name in BUILD_INPUTS if name not in given]
        raise DataError(f"building the world report needs {', '.join(missing)} too (or none of them, to print "
                        f"{args.report})")
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
                          seed=int(args.cfg["seed"]), fidelity=read_json(args.fidelity) if args.fidelity else None,
                          calibration=read_json(args.calibration) if args.calibration else None)
    print(format_table(report))
    if args.out:
        write_json(args.out, report, provenance=True)


def parser() -> argparse.ArgumentParser:
    p = _cli.parser(__doc__.split("\n")[0], cfg=False)
    p.add_argument("--report", default=DEFAULT_REPORT, help="the report to print when nothing is to be built")
    p.add_argument("--cfg", type=json.loads, help="the stage's config slice as JSON (building the report)")
    p.add_argument("--truth", help="teleop truth parquet (its metadata holds the attempt log)")
    p.add_argument("--errors", help="init_error's per-object error table")
    p.add_argument("--replay", help="replay log parquet")
    p.add_argument("--estimates", help="init estimates (for the per-episode estimation cost)")
    p.add_argument("--reference", help="reference success table (the real side), for the real-sim gap")
    p.add_argument("--rollouts", nargs="*", default=[], help="sim rollout folders, one per policy, for the gap")
    p.add_argument("--fidelity", help="the fidelity report: the gap's calibration and training parts, joint offsets")
    p.add_argument("--calibration", help="calib_error's scores: the cameras against the twin, the appearance fit")
    p.add_argument("--out", help="write the report as JSON here")
    return p


if __name__ == "__main__":
    _cli.run(main, parser())
