"""A judge's resolution per planted kind: what it sees at each magnitude, and where it starts to.

Per level of a kind (r2s_eval.compare.resolution), from the judge's verdicts on the clean run
against the changed one from the same (task, init):

* ``both_succeeded``: the pairs whose two runs both met the task's success check in the sim:
  the share on which the judge preferred the clean run, with a bootstrap interval over the pairs
  (each pair its own two rollouts, so each is new evidence). Only those: the built-in judges
  weigh how a run moved between two successes and compare two failures by how far each got
  (docs/judges.md, "Success before style"); ``both_failed`` counts the pairs left out;
* ``different_outcome``: the pairs where one run succeeded: the share on which the judge
  preferred the successful one (success before style);
* ``success``: the clean run's and the level's success in the sim and in the real world (the
  twin, or a lab's trials), each with its Wilson interval, and ``success_kept``: the level's rate
  inside the clean run's interval in both worlds, so the change is still quality, not failure.

Per kind: the smallest level that ``detects`` (share >= ``detect_share`` with its interval above
one half), the smallest that does so with success kept, and the best share seen.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from r2s_eval.compare.resolution import SweepLevel
from r2s_eval.errors import DataError
from r2s_eval.stats.audit import unit_share
from r2s_eval.stats.proportions import wilson_interval


def _rate(episodes: pd.DataFrame, policy: str, level: float) -> dict:
    runs = episodes[episodes["policy"] == policy]["success"].astype(bool)
    k, n = int(runs.sum()), int(runs.size)
    ci = wilson_interval(k, n, level)
    return {"successes": k, "trials": n, "rate": k / n if n else None,
            "ci_low": ci[0] if ci else None, "ci_high": ci[1] if ci else None}


def _inside(rate: dict, of: dict) -> bool | None:
    if rate["rate"] is None or of["ci_low"] is None:
        return None
    return bool(of["ci_low"] <= rate["rate"] <= of["ci_high"])


def level_rows(verdicts: pd.DataFrame, sim: pd.DataFrame, real: pd.DataFrame | None, clean: str,
               levels: Sequence[SweepLevel], *, detect_share: float, n_boot: int, ci_level: float,
               seed: int) -> list[dict]:
    """One row per level (see the module docstring). `verdicts`: the judge's answers on
    ``sweep_pairs`` (with ``winner``); `sim` / `real`: episode tables (policy, episode_id, success)."""
    success = sim.set_index("episode_id")["success"].astype(bool)
    missing = sorted(set(verdicts["episode_a"]).union(verdicts["episode_b"]) - set(success.index))
    if missing:
        raise DataError(f"the sweep's verdicts name sim episodes without a success record: {missing[:5]}")
    clean_sim = _rate(sim, clean, ci_level)
    clean_real = _rate(real, clean, ci_level) if real is not None else None
    rows = []
    for lv in levels:
        v = verdicts[(verdicts["kind"] == lv.kind) & (verdicts["level"] == lv.level)]
        clean_is_a = (v["clean_side"] == "A").to_numpy()
        ok_a, ok_b = success.loc[v["episode_a"]].to_numpy(), success.loc[v["episode_b"]].to_numpy()
        ok_clean, ok_changed = np.where(clean_is_a, ok_a, ok_b), np.where(clean_is_a, ok_b, ok_a)
        clean_won = (v["winner"] == clean).to_numpy()
        units = list(zip(v["task"], v["init_id"]))
        same = ok_clean == ok_changed
        both = same & ok_clean
        stats = {"n_boot": n_boot, "level": ci_level, "seed": seed}
        preferred = unit_share(clean_won[both], [u for u, b in zip(units, both) if b], **stats)
        # On different outcomes the judge is right when it prefers whichever run succeeded.
        succeeded_won = clean_won[~same] == ok_clean[~same]
        success_first = unit_share(succeeded_won, [u for u, s in zip(units, same) if not s], **stats)
        sim_rate = _rate(sim, lv.policy, ci_level)
        real_rate = _rate(real, lv.policy, ci_level) if real is not None else None
        kept = [_inside(sim_rate, clean_sim)] + ([_inside(real_rate, clean_real)] if real is not None else [])
        share, low = preferred["share"], preferred["ci_low"]
        rows.append({
            "kind": lv.kind, "level": lv.level, "key": lv.key, "magnitude": lv.magnitude, "policy": lv.policy,
            "both_succeeded": preferred, "both_failed": int((same & ~ok_clean).sum()),
            "different_outcome": success_first,
            "detects": bool(share is not None and share >= detect_share and low > 0.5),
            "success": {"sim": {"clean": clean_sim, "changed": sim_rate},
                        "real": None if real is None else {"clean": clean_real, "changed": real_rate}},
            "success_kept": None if None in kept else all(kept),
        })
    return rows


def kind_summaries(rows: Sequence[Mapping]) -> dict[str, dict]:
    """Per kind: the smallest level that detects it, the smallest that does with success kept in
    both worlds, and the level of the best clean-preferred share (each None where there is none)."""
    out = {}
    for kind in dict.fromkeys(r["kind"] for r in rows):
        mine = sorted((r for r in rows if r["kind"] == kind), key=lambda r: r["level"])
        detected = [r for r in mine if r["detects"]]
        kept = [r for r in detected if r["success_kept"]]
        scored = [r for r in mine if r["both_succeeded"]["share"] is not None]
        best = max(scored, key=lambda r: r["both_succeeded"]["share"]) if scored else None
        out[kind] = {
            "key": mine[0]["key"],
            "smallest_detected": detected[0]["level"] if detected else None,
            "smallest_detected_success_kept": kept[0]["level"] if kept else None,
            "best_level": best["level"] if best else None,
        }
    return out
