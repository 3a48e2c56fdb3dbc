"""Stage: the fidelity report (``r2s_eval.report.fidelity_report``) and its table and figure.

Reads the real side's reference (pi^R on the robot; its episodes too where it was counted from
rollouts, for intervals paired over the shared inits), pi^S's sim rollouts, the cross-evaluation
rollouts (pi^R in the calibrated sim; pi^S on the twin), optionally the ablation rollouts
(``FAMILY=FOLDER``: pi^S in the twin without that family) and further training seeds' rollouts
(``WORLD:SEED=FOLDER``), the calibrated sim's world parameters and, with the twin, its truth;
the checkpoints in further sims (``SIM:TRAINED_ON=FOLDER``, ``fidelity.sims``) and pi^S in the
twin with each reality effect alone (``EFFECT=FOLDER``, ``none`` among them).
"""

from __future__ import annotations

import pandas as pd

from r2s_eval.report import save_figure
from r2s_eval.report.fidelity_report import (ablation_figure, ablation_table, alone_table, build_report, fidelity_table,
                                             format_report, sim_rates, sims_table)
from r2s_eval.stages import _cli
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.twin.reality import load_reality_effects
from r2s_eval.utils.io import read_json, write_json, write_text

READS = ("stats.n_boot", "stats.ci_level", "seed", "report.fidelity",
         "world.robot.control_hz")  # config paths the --cfg slice holds


def main(args) -> None:
    cfg, opts = args.cfg, args.cfg["report.fidelity"]
    seeds = {(key.partition(":")[0], int(key.partition(":")[2])): episodes
             for key, episodes in _cli.keyed(args.seed_rollouts, load_episodes, "seed-rollouts").items()}
    twin = read_json(args.twin)["params"] if args.twin else None
    # The twin's true latency (seconds, its reality effects) in control steps, as the estimate counts.
    reality = load_reality_effects(args.twin) if args.twin else None
    latency_truth = None if reality is None else reality.latency_s * float(cfg["world.robot.control_hz"])
    report = build_report(
        pd.read_parquet(args.reference), load_episodes(args.sim), load_episodes(args.cross_sim),
        load_episodes(args.cross_real) if args.cross_real else None,
        _cli.keyed(args.ablation, load_episodes, "ablation"), seeds,
        read_json(args.world_params), twin["joint_offset_rad"] if twin is not None else None,
        float(cfg["stats.ci_level"]), int(cfg["stats.n_boot"]), int(cfg["seed"]),
        latency_truth=latency_truth,
        sims=_cli.keyed(args.sims, load_episodes, "sims"), alone=_cli.keyed(args.alone, load_episodes, "alone"),
        real=load_episodes(args.real) if args.real else None)
    print(format_report(report))
    write_json(args.out, report, provenance=True)
    decimals = int(opts["decimals"])
    write_text(args.table, fidelity_table(report, decimals=decimals), comment="%")
    if args.sims_table:
        write_text(args.sims_table, sims_table(report, decimals), comment="%")
    if args.alone_table:
        write_text(args.alone_table, alone_table(report["alone"], decimals), comment="%")
    if args.ablation_table:
        write_text(args.ablation_table, ablation_table(report["ablation"], decimals), comment="%")
        save_figure(ablation_figure(report["ablation"], sim_rates(report), opts), args.pdf, args.png, dpi=opts["dpi"])


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--reference", required=True, help="reference success table (pi^R on the real side)")
    p.add_argument("--sim", nargs="+", required=True, help="pi^S sim rollout folders")
    p.add_argument("--cross-sim", nargs="+", required=True, help="pi^R rollout folders in the calibrated sim")
    p.add_argument("--real", nargs="*", default=[], help="pi^R's rollout folders on the real side, the reference's "
                                                          "episodes (paired intervals)")
    p.add_argument("--cross-real", nargs="*", default=[], help="pi^S rollout folders on the twin")
    p.add_argument("--ablation", nargs="*", default=[], help="FAMILY=FOLDER: pi^S in the twin without FAMILY")
    p.add_argument("--seed-rollouts", nargs="*", default=[], help="WORLD:SEED=FOLDER: a further seed's rollouts")
    p.add_argument("--sims", nargs="*", default=[], help="SIM:TRAINED_ON=FOLDER: a checkpoint in a further sim")
    p.add_argument("--alone", nargs="*", default=[], help="EFFECT=FOLDER: pi^S in the twin with that effect alone")
    p.add_argument("--world-params", required=True, help="the calibrated sim's world parameters (calib_joints)")
    p.add_argument("--twin", help="the twin's world parameters and reality effects (its true joint offsets and "
                                  "commands' latency)")
    p.add_argument("--out", required=True)
    p.add_argument("--table", required=True)
    p.add_argument("--ablation-table", help="the ablation's table (with --ablation; its figure: --pdf, --png)")
    p.add_argument("--sims-table", help="the crossing in every sim (with --sims)")
    p.add_argument("--alone-table", help="what each reality effect costs on its own (with --alone)")
    p.add_argument("--pdf")
    p.add_argument("--png")
    _cli.run(main, p)
