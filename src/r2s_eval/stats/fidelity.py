"""How close the calibrated simulation is to its reality, split into what causes the gap.

The method's real-sim gap compares pi^S in the simulation with pi^R on the robot: two different
checkpoints, each in its own world. Rolling the same checkpoint out in the other world from the
same initial configurations splits it exactly, per policy-task cell::

    S_sim - R_real  =  (S_sim - R_sim)  +  (R_sim - R_real)
       total            training part       calibration part

``R_real``: pi^R on the real side (the reference); ``R_sim``: pi^R in the calibrated simulation;
``S_sim``: pi^S in the simulation; ``S_real``: pi^S on the real side (only where the real side
can run it: the twin). The calibration part compares the same weights in two worlds; the
training part two trainings in one world. Every part is a set of per-cell differences of two
rates, summarised as ``r2s_eval.stats.proportions.gap_summary`` does (mean absolute and signed
gap, largest, with bootstrap intervals). Every world starts a cell's trials from the same seeded
inits, so where both worlds' episodes are at hand the interval is paired over those inits (the
part's ``paired``); a world known only by its counts (a lab's hardware trials) is drawn
binomially, independent of the other.

Same-policy agreement: Pearson r and MMRV of the per-policy success (the mean of its per-task
rates, as the reference defines it: ``reference_rates``) of R_sim against R_real, as SimplerEnv scores its simulator with the same policy in both worlds.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from r2s_eval.stats.metrics import mmrv, pearson
from r2s_eval.stats.proportions import count_gap_cells, gap_summary, paired_outcomes, wilson_interval
from r2s_eval.stats.reference import reference_rates

# name -> (what the gap compares: minuend, subtrahend)
PARTS = {
    "calibration": ("R_sim", "R_real"),
    "training": ("S_sim", "R_sim"),
    "total": ("S_sim", "R_real"),
    "calibration_reverse": ("S_real", "S_sim"),
    "training_real": ("S_real", "R_real"),
}


def cross_evaluation(worlds: dict[str, pd.DataFrame], level: float, n_boot: int, seed,
                     episodes: dict[str, pd.DataFrame | None] | None = None) -> dict:
    """The split (module docstring) from success tables per world: ``worlds`` maps R_real,
    R_sim, S_sim and optionally S_real to tables (policy, task, trials, successes);
    ``episodes`` the worlds whose episodes (policy, task, init_id, success) are at hand to theirs.

    Returns per cell the four rates with Wilson intervals and trials, per part the cells' gaps
    with Newcombe intervals and their summary, and the same-policy agreement."""
    worlds = {name: table for name, table in worlds.items() if table is not None and len(table)}
    episodes = {name: e for name, e in (episodes or {}).items() if e is not None and name in worlds}
    cells: dict[tuple[str, str], dict] = {}
    for name, table in worlds.items():
        for c in table.itertuples():
            ci = wilson_interval(int(c.successes), int(c.trials), level)
            cells.setdefault((c.policy, c.task), {"policy": c.policy, "task": c.task})[name] = {
                "rate": float(c.successes / c.trials), "ci": list(ci), "successes": int(c.successes),
                "trials": int(c.trials)}
    parts = {}
    for part, (plus, minus) in PARTS.items():
        if plus not in worlds or minus not in worlds:
            continue
        gap_cells = count_gap_cells(worlds[minus], worlds[plus], level)
        paired = (paired_outcomes(episodes[minus], episodes[plus]) if minus in episodes and plus in episodes
                  else None)
        summary = gap_summary(gap_cells, level, n_boot, seed, paired=paired)
        summary["compares"] = f"{plus} - {minus}"
        summary["cells_gap_pp"] = [
            {"policy": g.policy, "task": g.task, "gap_pp": 100 * g.gap,
             "ci_pp": [100 * g.gap_ci_low, 100 * g.gap_ci_high]} for g in gap_cells.itertuples()]
        parts[part] = summary
    return {"cells": sorted(cells.values(), key=lambda c: (c["task"], c["policy"])), "parts": parts,
            "agreement": same_policy_agreement(worlds), "ci_level": float(level)}


def same_policy_agreement(worlds: dict[str, pd.DataFrame]) -> dict:
    """Pearson r and MMRV (pp) of each simulated world's per-policy success against R_real."""
    if "R_real" not in worlds:
        return {}
    real = reference_rates(worlds["R_real"])
    out = {}
    for name in ("R_sim", "S_sim"):
        if name not in worlds:
            continue
        sim = reference_rates(worlds[name])
        policies = sorted(set(sim.index) & set(real.index))
        if len(policies) < 2:
            continue
        x, y = sim[policies].to_numpy(), real[policies].to_numpy()
        r = pearson(x, y)
        out[name] = {"policies": policies, "pearson": None if np.isnan(r) else r, "mmrv_pp": 100 * mmrv(x, y)}
    return out


def seed_spread(tables: dict[str, dict[int, pd.DataFrame]]) -> list[dict]:
    """Per world (R_real, S_sim, ...) and policy-task cell, the success rate of every training
    seed and their spread (max - min, sample standard deviation), in percent."""
    rows = []
    for world, per_seed in tables.items():
        rates: dict[tuple[str, str], dict[int, float]] = {}
        for seed, table in sorted(per_seed.items()):
            for c in table.itertuples():
                rates.setdefault((c.policy, c.task), {})[seed] = 100 * c.successes / c.trials
        for (policy, task), by_seed in sorted(rates.items()):
            values = np.array(list(by_seed.values()))
            rows.append({"world": world, "policy": policy, "task": task, "seeds": sorted(by_seed),
                         "rates_pct": [by_seed[s] for s in sorted(by_seed)],
                         "range_pp": float(values.max() - values.min()),
                         "std_pp": float(values.std(ddof=1)) if len(values) > 1 else None})
    return rows
