"""Stage: how stable each ranking is when the evaluation is repeated with fresh initial configurations.

Each task's real-side inits are split into ``stability.repetitions`` disjoint blocks; repetition
r ranks the candidates from block r alone, the checkpoints fixed: each judge by a Bradley-Terry
fit of the comparisons of block r's sim rollouts (and of its share of the sim-only inits beyond
``rollout.real_inits_per_task``), and a real evaluation by the success of block r's
first ``stability.real_trials_per_task`` real trials per task and policy (and, for the figure,
of its first m for each m of ``trials_curve``). The truth of repetition r: planted pairs by
construction, every other pair by the twin's success over the real trials of the other blocks
where it is clear (``r2s_eval.stats.stability``). With the judged sim rollouts, the ranking by
their success and each judge against the sim's own truth split a judge's errors into the sim's
and its own. With the same checkpoints rolled out in the twin (``stability.networks_in_twin``:
pi^S on the real side), the sim's and each judge's ranking against the twin's truth of the
networks they rank, which splits the sim and the judges from what training on other data
changes. Writes the summary JSON, the table and the figure of agreement with the truth against
real trials spent. Each evaluation's share of the pairs ordered as the truth comes with its
interval over the repetitions, and each one's difference from the real evaluation at
``real_trials_per_task``, paired per repetition, with its own (``stats.ci_level``).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from r2s_eval.report.figures import save_figure, stability_figure
from r2s_eval.report.tables import stability_table
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.stages import _cli
from r2s_eval.stats.stability import stability_summary
from r2s_eval.utils.io import write_json, write_text

READS = ("stability", "rollout.inits_per_task", "rollout.real_inits_per_task", "report.stability", "stats.ci_level")  # config paths the --cfg slice holds
PROVIDED = ("planted_variants",)  # {variant: the candidate whose weights it runs}, from the line-up


def main(args) -> None:
    cfg = args.cfg
    opts = cfg["stability"]
    real = load_episodes(args.real_rollouts)
    verdicts = {Path(path).parent.name: pd.read_parquet(path) for path in args.verdicts}  # <judge>/verdicts.parquet
    sim = load_episodes(args.sim_rollouts) if args.sim_rollouts else None
    networks = load_episodes(args.networks_in_twin) if args.networks_in_twin else None
    summary = stability_summary(
        real, verdicts, inits_per_task=int(cfg["rollout.inits_per_task"]), repetitions=int(opts["repetitions"]),
        real_trials_per_task=int(opts["real_trials_per_task"]), trials_curve=[int(m) for m in opts["trials_curve"]],
        truth_z=float(opts["truth_z"]), variants=dict(cfg.get("planted_variants") or {}), sim=sim,
        networks_in_twin=networks, level=float(cfg["stats.ci_level"]),
        real_inits_per_task=cfg["rollout.real_inits_per_task"])
    write_json(args.out, summary, provenance=True)
    report = cfg["report.stability"]
    write_text(args.table, stability_table(summary, decimals=int(report["decimals"])), comment="%")
    save_figure(stability_figure(summary, report), args.pdf, args.png, dpi=report["dpi"])
    for name, card in summary["evaluations"].items():
        print(f"{name:>12}: equal to the truth {card['equal_share']}, Kendall distance {card['kendall_distance']}, "
              f"flip rates {[round(p['flip_rate'], 2) for p in card['pairs'].values()]}, "
              f"errors in most repetitions {card['repeated_errors']}")
    beside = summary.get("beside_real") or {"differences": {}}
    for name, diff in beside["differences"].items():
        print(f"{name:>12} minus {beside['reference']}: {diff['difference']:+.3f}, interval {diff['interval']}")
    for view, label in (("against_sim_truth", "the sim's own truth"),
                        ("against_networks_in_twin", "the twin's truth of the networks ranked")):
        for name, card in (summary.get(view) or {}).items():
            print(f"{name:>12} against {label}: {card['agreement']}, errors in most repetitions "
                  f"{card['repeated_errors']}")


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--real-rollouts", nargs="+", required=True, help="real-side rollout folders, one per policy")
    p.add_argument("--verdicts", nargs="+", required=True, help="verdicts per judge (results/judge/<judge>/verdicts.parquet)")
    p.add_argument("--sim-rollouts", nargs="*", default=[], help="the judged sim rollout folders, one per policy")
    p.add_argument("--networks-in-twin", nargs="*", default=[],
                   help="the judged checkpoints' rollouts in the twin (results/cross/real/<policy>), one per policy")
    p.add_argument("--out", required=True)
    p.add_argument("--table", required=True)
    p.add_argument("--pdf", required=True)
    p.add_argument("--png", required=True)
    _cli.run(main, p)
