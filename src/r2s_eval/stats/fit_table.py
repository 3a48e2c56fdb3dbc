"""Bradley-Terry strengths and bootstrap CIs of one judge's verdicts at every nested checkpoint.

Two bootstraps run on the same comparisons: ``binomial`` (the method's: each pair's wins
redrawn binomially, every comparison independent) and ``unit`` (the distinct rollout pairs,
one per policy pair, task and init_id, resampled within each task). Both intervals are
stored (``ci_low_<interval>``, ``ci_high_<interval>``); ``ci_low``/``ci_high`` repeat the one
``stats.interval`` names, which the ``interval`` column records. The replicates themselves
go to a second table, for the metric intervals of :func:`~r2s_eval.stats.validate`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from r2s_eval.compare import wins_at_checkpoints
from r2s_eval.compare.wins import checkpoint_positions
from r2s_eval.errors import DataError
from r2s_eval.stats.bradley_terry import bt_scores, fit_bradley_terry
from r2s_eval.stats.checkpoints import INTERVALS, bootstrap_checkpoints, check_interval
from r2s_eval.stats.units import ComparisonUnits, comparison_units

UNIT_COLUMNS = ("task", "init_id")
_KEYS = ["policy_i", "policy_j", "pair_index"]


def with_units(verdicts: pd.DataFrame, pairs: pd.DataFrame | None = None) -> pd.DataFrame:
    """The verdicts with the columns that identify each comparison's unit (task, init_id).

    The judge stage keeps them (with the init of any replacement comparison); verdicts that
    lack them take them from the sampled pairs, matched on (policy_i, policy_j, pair_index).
    Where both are given, each comparison's task must agree (replacements keep the task).
    """
    out = verdicts
    lacking = [c for c in UNIT_COLUMNS if c not in verdicts.columns]
    if lacking:
        if pairs is None:
            raise DataError(f"verdicts lack {lacking} and no pairs table was given to take them from")
        out = verdicts.merge(pairs[_KEYS + lacking], on=_KEYS, how="left", validate="many_to_one")
        if out[lacking].isna().any().any():
            raise DataError(f"verdicts have comparisons that the pairs table lacks ({lacking} unknown)")
    elif pairs is not None and "task" in pairs.columns:
        both = verdicts[_KEYS + ["task"]].merge(pairs[_KEYS + ["task"]], on=_KEYS, how="inner", suffixes=("", "_pairs"))
        differ = both[both["task"].astype(str) != both["task_pairs"].astype(str)]
        if len(differ):
            r = differ.iloc[0]
            raise DataError(
                f"verdicts and pairs disagree on the task of {r.policy_i} vs {r.policy_j}, pair_index "
                f"{r.pair_index} ({r.task!r} vs {r.task_pairs!r}); were they sampled together?"
            )
    return out


def units_of(verdicts: pd.DataFrame, policies: list[str], checkpoints: list[int]) -> ComparisonUnits:
    """Each comparison's unit: its policy pair, task (the stratum) and init_id."""
    index = {p: k for k, p in enumerate(policies)}
    pi = verdicts["policy_i"].astype(str)
    return comparison_units(
        pi.map(index).to_numpy(), verdicts["policy_j"].astype(str).map(index).to_numpy(),
        (verdicts["winner"].astype(str) == pi).to_numpy(), verdicts["init_id"].tolist(),
        n_policies=len(policies), stratum=verdicts["task"].astype(str).tolist(),
        position=checkpoint_positions(verdicts).to_numpy(), checkpoints=checkpoints,
    )


def fit_checkpoints(verdicts: pd.DataFrame, checkpoints: list[int], n_boot: int, level: float, seed: int,
                    interval: str = "unit", pairs: pd.DataFrame | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The fit table (one row per checkpoint and policy) and the bootstrap replicates (long:
    interval, checkpoint, replicate, policy, strength)."""
    interval = check_interval(interval)
    verdicts = with_units(verdicts, pairs)
    policies = sorted(set(verdicts["policy_i"].astype(str)) | set(verdicts["policy_j"].astype(str)))
    wins = wins_at_checkpoints(verdicts, policies, checkpoints)  # also checks the comparisons are complete
    units = units_of(verdicts, policies, checkpoints)
    if not np.array_equal(units.wins(), wins):
        raise AssertionError("unit win counts do not add up to the checkpoint win counts")
    # All checkpoints in one batched pass per bootstrap: (checkpoint, replicate, policy).
    boots, cis = bootstrap_checkpoints(wins, units, n_boot, seed, policies, level)
    units_per_pair = units.units_per_pair()  # (C, K)
    I, J = np.triu_indices(len(policies), 1)
    rows = []
    for k, n in enumerate(checkpoints):
        strengths = fit_bradley_terry(wins[k], names=policies)
        scores = bt_scores(strengths)
        for p, name in enumerate(policies):
            row = {
                "checkpoint": n, "policy": name, "strength": strengths[p], "score": scores[p],
                "ci_low": cis[interval][0][k, p], "ci_high": cis[interval][1][k, p],
                "interval": interval, "ci_level": level,
            }
            for other in INTERVALS:
                row[f"ci_low_{other}"] = cis[other][0][k, p]
                row[f"ci_high_{other}"] = cis[other][1][k, p]
            row.update({
                "wins": int(wins[k][p].sum()), "comparisons": int(wins[k][p].sum() + wins[k][:, p].sum()),
                # Distinct rollout pairs behind this policy's comparisons (summed over its pairs).
                "units": int(units_per_pair[k][(I == p) | (J == p)].sum()),
            })
            rows.append(row)
    C, B, P = boots["unit"].shape
    replicates = pd.concat([
        pd.DataFrame({
            "interval": name,
            "checkpoint": np.repeat(np.asarray(checkpoints), B * P),
            "replicate": np.tile(np.repeat(np.arange(B), P), C),
            "policy": np.tile(policies, C * B),
            "strength": boot.reshape(-1),
        })
        for name, boot in boots.items()
    ], ignore_index=True)
    return pd.DataFrame(rows), replicates
