"""Stage: how far one judge can be trusted beyond the ranking metrics.

Position bias (share of A answers, overall and on same-outcome pairs), order-swap
consistency where the verdicts carry swapped answers, and agreement with human annotators
where an annotations CSV is configured (majority vote, unanimous share, Fleiss' kappa, and
the judge's agreement with the majority, by outcome category); the report card: agreement with the sim outcomes on
mixed-outcome pairs, with a planted policy order on pairs that both succeeded, planted quality (each
variant against the candidate whose weights it runs, on pairs that both succeeded; with the judge's
BT fit and the reference's success intervals where given), and the shuffled-label control of
the BT fit. Quantities without data are null.
"""

from __future__ import annotations

import logging

import pandas as pd

from r2s_eval.report import judge_audit
from r2s_eval.report.summaries import reference_interval
from r2s_eval.stages import _cli
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.utils.io import read_json, write_json

# The share intervals use the statistics' bootstrap settings and the run's seed.
READS = ("report.judge_audit", "stats.n_boot", "stats.ci_level", "seed")  # config paths the --cfg slice holds
PROVIDED = ("planted_variants",)  # {variant: the candidate whose weights it runs}, from the line-up

log = logging.getLogger("r2s_eval.judge_audit")


def main(args) -> None:
    opts = args.cfg["report.judge_audit"]
    verdicts = pd.read_parquet(args.verdicts)
    annotations = pd.read_csv(args.annotations) if args.annotations else None
    audit = judge_audit(
        verdicts, load_episodes(args.rollouts), annotations=annotations, annotations_source=str(args.annotations),
        swapped_letter_columns=opts["swapped_letter_columns"], swapped_winner_columns=opts["swapped_winner_columns"],
        planted_order=opts["planted_order"], planted_variants=args.cfg.get("planted_variants") or {},
        fit=pd.read_parquet(args.fit) if args.fit else None,
        reference_ci=reference_interval({args.judge: read_json(args.validation)}) if args.validation else None,
        n_boot=int(args.cfg["stats.n_boot"]),
        ci_level=float(args.cfg["stats.ci_level"]), seed=int(args.cfg["seed"]),
        shuffled_permutations=int(opts["shuffled_permutations"]),
    )
    if audit["swap_consistency"] is None:
        log.info("%s: no swapped answers (looked for %s)", args.verdicts,
                 opts["swapped_letter_columns"] + opts["swapped_winner_columns"])
    write_json(args.out, {"judge": args.judge, "verdicts": str(args.verdicts), **audit}, provenance=True)
    log.info("%s", {k: v for k, v in audit.items() if k not in ("shuffled_label_control", "human")})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--judge", required=True)
    p.add_argument("--verdicts", required=True)
    p.add_argument("--rollouts", nargs="+", required=True, help="sim rollout folders, one per policy")
    p.add_argument("--annotations", help="CSV of human annotations (episode_a, episode_b, choice[, annotator])")
    p.add_argument("--fit", help="the judge's BT fit (planted quality: do the scores' intervals separate)")
    p.add_argument("--validation", help="the judge's validation JSON (planted quality: the reference's success intervals)")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
