"""Stage: Bradley-Terry strengths and bootstrap CIs for one judge at every nested checkpoint."""

from __future__ import annotations

import numpy as np
import pandas as pd

from r2s_eval.compare import wins_at_checkpoints
from r2s_eval.stages import _cli
from r2s_eval.stages.compare_pairs import checkpoints as checkpoint_list
from r2s_eval.stats import bootstrap_bradley_terry, bt_confidence_intervals, bt_scores, fit_bradley_terry
from r2s_eval.utils.io import write_parquet


def fit_checkpoints(verdicts: pd.DataFrame, checkpoints: list[int], n_boot: int, level: float, seed: int) -> pd.DataFrame:
    policies = sorted(set(verdicts["policy_i"]) | set(verdicts["policy_j"]))
    wins = wins_at_checkpoints(verdicts, policies, checkpoints)
    # All checkpoints in one batched bootstrap: (checkpoint, replicate, policy).
    boots = bootstrap_bradley_terry(wins, n_boot=n_boot, seed=seed, names=policies)
    rows = []
    for k, n in enumerate(checkpoints):
        strengths = fit_bradley_terry(wins[k], names=policies)
        low, high = bt_confidence_intervals(boots[k], level=level)
        for p, name in enumerate(policies):
            rows.append({
                "checkpoint": n, "policy": name, "strength": strengths[p], "score": bt_scores(strengths)[p],
                "ci_low": low[p], "ci_high": high[p], "wins": int(wins[k][p].sum()),
                "comparisons": int(wins[k][p].sum() + wins[k][:, p].sum()),
            })
    return pd.DataFrame(rows)


def main(args) -> None:
    cfg = args.cfg
    verdicts = pd.read_parquet(args.verdicts)
    table = fit_checkpoints(verdicts, checkpoint_list(cfg), int(cfg["stats"]["n_boot"]), float(cfg["stats"]["ci_level"]), int(cfg["seed"]))
    a_share = float(np.mean(verdicts["verdict"] == "A"))
    write_parquet(args.out, table, metadata={"stage": "fit", "share_of_A_answers": a_share})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--verdicts", required=True)
    p.add_argument("--out", required=True)
    _cli.run(main, p)
