"""Success rates with intervals, and the real-sim success gap over policy-task cells.

A rate from a handful of trials needs an interval that stays inside [0, 1] and does not
collapse at 0 or n successes: Wilson's score interval. A difference of two independent
rates (sim minus real in one policy-task cell) gets Newcombe's hybrid score interval, built
from the two Wilson intervals. Both come from statsmodels.

Over cells, the method reports the mean absolute gap (and the largest). Its interval comes
from a parametric bootstrap that redraws every cell's two sides binomially from their own
rates, as the reference bootstrap does. The mean *absolute* gap is biased upwards when the
true gaps are near zero (|noise| is positive), so the signed mean is reported beside it.

Where both sides ran every trial of a cell from the same seeded initial configuration (the same
weights in two worlds, or two weights in one: ``paired_outcomes``), the two outcomes of an init
are not independent: an init hard in one world tends to be hard in the other. Drawing the sides
independently then overstates the spread of their difference. The paired bootstrap redraws each
task's inits instead, both outcomes of an init together and every cell of the task on the same
draw, so the interval keeps the sides' correlation and the cells' (two policies on one init).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from statsmodels.stats.proportion import confint_proportions_2indep, proportion_confint

from r2s_eval.errors import DataError
from r2s_eval.stats.bradley_terry import _check_n_boot
from r2s_eval.stats.units import tagged_seed

GAP_KEY = 0x67617073  # spawn-key tag of the gap bootstrap's stream ("gaps")


def wilson_interval(successes: int, trials: int, level: float) -> tuple[float, float] | None:
    """Wilson score interval of ``successes / trials``; None without trials."""
    if trials <= 0:
        return None
    low, high = proportion_confint(int(successes), int(trials), alpha=1 - level, method="wilson")
    return float(low), float(high)


def newcombe_difference(successes_a: int, trials_a: int, successes_b: int, trials_b: int,
                        level: float) -> tuple[float, float] | None:
    """Newcombe's hybrid score interval of ``a - b`` (two independent rates); None where a side
    has no trials."""
    if trials_a <= 0 or trials_b <= 0:
        return None
    low, high = confint_proportions_2indep(int(successes_a), int(trials_a), int(successes_b), int(trials_b),
                                           method="newcomb", compare="diff", alpha=1 - level)
    return float(low), float(high)


def success_counts(episodes: pd.DataFrame) -> pd.DataFrame:
    """Episodes (policy, task, success) -> a success table (policy, task, successes, trials)."""
    return (episodes.assign(success=episodes["success"].astype(bool))
            .groupby(["policy", "task"], as_index=False)["success"].agg(successes="sum", trials="size"))


def success_gap_cells(reference: pd.DataFrame, sim_episodes: pd.DataFrame, level: float) -> pd.DataFrame:
    """One row per (policy, task) that both sides have: real and sim successes and trials, the
    rates with Wilson intervals, and ``gap = sim - real`` with Newcombe's interval (fractions).

    ``reference``: the reference success table (policy, task, trials, successes); ``sim_episodes``:
    sim rollout episodes (policy, task, success)."""
    lacking = [c for c in ["policy", "task", "success"] if c not in sim_episodes.columns]
    if lacking:
        raise DataError(f"sim rollout episodes lack columns {lacking}")
    return count_gap_cells(reference, success_counts(sim_episodes), level)


def count_gap_cells(real: pd.DataFrame, sim: pd.DataFrame, level: float) -> pd.DataFrame:
    """`success_gap_cells` of two success tables (policy, task, trials, successes): ``real`` is
    subtracted from ``sim`` (whichever worlds they come from)."""
    for name, table in (("reference success table", real), ("success table", sim)):
        lacking = [c for c in ["policy", "task", "trials", "successes"] if c not in table.columns]
        if lacking:
            raise DataError(f"{name} lacks columns {lacking}")
    cells = (real.groupby(["policy", "task"])[["successes", "trials"]].sum()
             .join(sim.groupby(["policy", "task"])[["successes", "trials"]].sum(),
                   lsuffix="_real", rsuffix="_sim", how="inner"))
    rows = []
    for (policy, task), c in cells.iterrows():
        s_real, n_real, s_sim, n_sim = (int(c[k]) for k in ("successes_real", "trials_real", "successes_sim", "trials_sim"))
        if n_real == 0 or n_sim == 0:
            continue
        real_ci, sim_ci = wilson_interval(s_real, n_real, level), wilson_interval(s_sim, n_sim, level)
        gap_ci = newcombe_difference(s_sim, n_sim, s_real, n_real, level)
        rows.append({"policy": policy, "task": task, "real_successes": s_real, "real_trials": n_real,
                     "sim_successes": s_sim, "sim_trials": n_sim, "real": s_real / n_real, "sim": s_sim / n_sim,
                     "real_ci_low": real_ci[0], "real_ci_high": real_ci[1],
                     "sim_ci_low": sim_ci[0], "sim_ci_high": sim_ci[1],
                     "gap": s_sim / n_sim - s_real / n_real, "gap_ci_low": gap_ci[0], "gap_ci_high": gap_ci[1]})
    return pd.DataFrame(rows)


def paired_outcomes(real: pd.DataFrame, sim: pd.DataFrame) -> pd.DataFrame | None:
    """The two sides' episodes (policy, task, init_id, success) joined per trial: one row per
    (policy, task, init_id) with the outcomes ``real`` and ``sim`` (booleans), for the cells both
    sides have. None where the sides cannot be paired: an episode without ``init_id``, an init
    run more than once in a cell, or a cell whose two sides ran different inits."""
    keys = ["policy", "task", "init_id"]
    if any(k not in side.columns for side in (real, sim) for k in [*keys, "success"]):
        return None
    real, sim = (side[[*keys, "success"]].assign(success=side["success"].astype(bool)) for side in (real, sim))
    if real.duplicated(keys).any() or sim.duplicated(keys).any():
        return None
    shared = (real[["policy", "task"]].drop_duplicates()
              .merge(sim[["policy", "task"]].drop_duplicates(), on=["policy", "task"]))
    real, sim = (side.merge(shared, on=["policy", "task"]) for side in (real, sim))
    joined = real.merge(sim, on=keys, how="outer", suffixes=("_real", "_sim"), indicator=True)
    if (joined["_merge"] != "both").any():
        return None
    return (joined.rename(columns={"success_real": "real", "success_sim": "sim"})[[*keys, "real", "sim"]]
            .astype({"real": bool, "sim": bool}).sort_values(keys).reset_index(drop=True))


def _paired_replicates(cells: pd.DataFrame, paired: pd.DataFrame, n_boot: int, rng) -> np.ndarray:
    """``(n_boot, cells)`` gap replicates (fractions): per task, its inits redrawn with
    replacement, one draw for all of the task's cells, both outcomes of an init together."""
    out = np.empty((n_boot, len(cells)))
    by_cell = {key: g for key, g in paired.groupby(["policy", "task"])}
    for task, rows in cells.groupby("task", sort=True):
        inits = np.array(sorted(paired.loc[paired["task"] == task, "init_id"].unique()))
        draws = rng.integers(0, len(inits), size=(n_boot, len(inits)))
        for i, policy in zip(rows.index, rows["policy"]):
            trials = by_cell[(policy, task)]
            # per init of the task: sim - real where this cell ran it, else nothing (NaN)
            difference = np.full(len(inits), np.nan)
            difference[np.searchsorted(inits, trials["init_id"].to_numpy())] = (
                trials["sim"].to_numpy(float) - trials["real"].to_numpy(float))
            drawn = difference[draws]
            counted = (~np.isnan(drawn)).sum(axis=1)
            # a draw that misses all of this cell's inits (possible only when the cell ran few of
            # the task's inits) keeps the cell's point gap
            out[:, i] = np.where(counted > 0, np.nansum(drawn, axis=1) / np.maximum(counted, 1), cells.at[i, "gap"])
    return out


def gap_summary(cells: pd.DataFrame, level: float, n_boot: int, seed=0, paired: pd.DataFrame | None = None) -> dict:
    """Mean absolute, mean signed and largest absolute gap over the cells, in percentage
    points, with percentile intervals from the bootstrap (module docstring: paired over the
    shared inits when ``paired``, ``paired_outcomes`` of the cells' episodes, is given; else
    parametric), and what they rest on (cells, trials per side)."""
    if cells.empty:
        return {"cells": 0}
    n_boot = _check_n_boot(n_boot)
    rng = np.random.default_rng(tagged_seed(seed, GAP_KEY))
    n_real, n_sim = cells["real_trials"].to_numpy(np.int64), cells["sim_trials"].to_numpy(np.int64)
    cells = cells.reset_index(drop=True)
    if paired is not None:
        _check_pairs_match(cells, paired)
        boot_gap = 100 * _paired_replicates(cells, paired, n_boot, rng)
        interval_kind = ("percentile bootstrap over the shared initial configurations: each task's inits redrawn, "
                         "an init's two outcomes together, the task's cells on one draw")
    else:
        real = rng.binomial(n_real, cells["real"].to_numpy(float), size=(n_boot, len(cells))) / n_real
        sim = rng.binomial(n_sim, cells["sim"].to_numpy(float), size=(n_boot, len(cells))) / n_sim
        boot_gap = 100 * (sim - real)
        interval_kind = "percentile bootstrap, both sides of every cell redrawn binomially from their rates"
    gap = 100 * cells["gap"].to_numpy(float)
    tail = 100 * (1 - level) / 2

    def interval(replicates: np.ndarray) -> list[float]:
        return [float(np.percentile(replicates, tail)), float(np.percentile(replicates, 100 - tail))]

    return {
        "cells": int(len(cells)),
        "mean_abs_gap_pp": float(np.abs(gap).mean()),
        "mean_abs_gap_ci_pp": interval(np.abs(boot_gap).mean(axis=1)),
        "mean_gap_pp": float(gap.mean()),
        "mean_gap_ci_pp": interval(boot_gap.mean(axis=1)),
        "max_abs_gap_pp": float(np.abs(gap).max()),
        "real_trials_per_cell": sorted({int(n) for n in n_real}),
        "sim_trials_per_cell": sorted({int(n) for n in n_sim}),
        "ci_level": float(level),
        "n_boot": int(n_boot),
        "interval": interval_kind,
        "paired": paired is not None,
    }


def _check_pairs_match(cells: pd.DataFrame, paired: pd.DataFrame) -> None:
    """The paired trials are the cells' trials: the same cells, counts and successes per side."""
    counts = paired.groupby(["policy", "task"]).agg(trials=("init_id", "size"), real=("real", "sum"),
                                                    sim=("sim", "sum"))
    for c in cells.itertuples():
        if (c.policy, c.task) not in counts.index:
            raise DataError(f"policy {c.policy}, task {c.task}: no paired trials for this cell")
        n, s_real, s_sim = counts.loc[(c.policy, c.task)]
        if (n, s_real, s_sim) != (c.real_trials, c.real_successes, c.sim_successes) or n != c.sim_trials:
            raise DataError(f"policy {c.policy}, task {c.task}: the episodes ({n} trials, {s_real} and {s_sim} "
                            f"successes) are not the success table's ({c.real_trials} and {c.sim_trials} trials, "
                            f"{c.real_successes} and {c.sim_successes} successes)")
