"""The judges' resolution sweep: the variants it runs and the comparisons it asks for.

``resolution.sweeps[kind]`` holds a planted kind's execution change at its weakest
(``execution``, r2s_eval.policies.execution) and the dotted ``key`` of it that the ``levels``
set. Level i (from 1, the weakest) of a kind is the variant ``<policy>.<kind>.<i>`` of
``resolution.policy``. Each level's sim episode is paired with the clean run's from the same
(task, init): both start alike and share the episode's seeds, so what differs between them is
the planted change and what it caused. The clean run's side (A or B) is drawn per comparison
from the run's seed, so a judge that leans to one side cannot pass that off as resolution.
"""

from __future__ import annotations

import copy
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import pandas as pd

from r2s_eval.compare.sampling import PAIR_COLUMNS
from r2s_eval.errors import DataError

# Columns the sweep's comparisons carry beside the sampled pairs' (PAIR_COLUMNS).
SWEEP_COLUMNS = ("kind", "level", "magnitude", "clean_side")


@dataclass(frozen=True)
class SweepLevel:
    kind: str
    level: int  # 1 = the weakest
    key: str  # the execution key the level sets (dotted)
    magnitude: float
    policy: str  # the variant's name
    execution: dict  # its whole execution change

    def variant(self, base: str) -> dict:
        """The level as a line-up entry (``type: variant``)."""
        return {"type": "variant", "of": base, "execution": copy.deepcopy(self.execution)}


def with_key(execution: Mapping | None, key: str, value) -> dict:
    """A copy of `execution` with the dotted `key` set to `value`."""
    out = copy.deepcopy(dict(execution or {}))
    *parents, leaf = key.split(".")
    node = out
    for part in parents:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise DataError(f"execution key {key!r}: {part!r} holds {node!r}, not a mapping")
    node[leaf] = value
    return out


def sweep_levels(resolution: Mapping) -> list[SweepLevel]:
    """Every level of every kind `resolution` runs (none when its policy is null), kinds in the
    order of ``kinds``."""
    base = resolution.get("policy")
    if base is None:
        return []
    out = []
    for kind in resolution["kinds"]:
        sweep = resolution["sweeps"][kind]
        for level, value in enumerate(sweep["levels"], start=1):
            out.append(SweepLevel(kind, level, sweep["key"], float(value), f"{base}.{kind}.{level}",
                                  with_key(sweep.get("execution"), sweep["key"], value)))
    return out


def _clean_side(seed: int, variant: str, task: str, init_id) -> str:
    """A for the clean run or B, from a hash of the run's seed and the comparison: the same
    comparison always gets the same side, whatever else the sweep holds."""
    return "AB"[zlib.crc32(f"{seed}|{variant}|{task}|{init_id}".encode()) & 1]


def sweep_pairs(episodes: pd.DataFrame, clean: str, levels: Sequence[SweepLevel], seed: int) -> pd.DataFrame:
    """One comparison per level and (task, init) that the clean run and the level both ran:
    PAIR_COLUMNS (policy_i the clean run, policy_j the level) and SWEEP_COLUMNS."""
    lacking = [c for c in ("episode_id", "policy", "task", "init_id") if c not in episodes.columns]
    if lacking:
        raise DataError(f"the sweep's episode table lacks columns {lacking}")
    by_policy = {p: g.drop_duplicates(["task", "init_id"]).set_index(["task", "init_id"])["episode_id"]
                 for p, g in episodes.groupby("policy")}
    if clean not in by_policy:
        raise DataError(f"the sweep's episodes hold no run of the clean candidate {clean!r}")
    rows = []
    for lv in levels:
        if lv.policy not in by_policy:
            raise DataError(f"the sweep's episodes hold no run of level {lv.level} of {lv.kind} ({lv.policy})")
        changed = by_policy[lv.policy]
        for task, init_id in sorted(set(by_policy[clean].index) & set(changed.index), key=str):
            side = _clean_side(seed, lv.policy, task, init_id)
            ep_clean, ep_changed = by_policy[clean][(task, init_id)], changed[(task, init_id)]
            a, b = (ep_clean, ep_changed) if side == "A" else (ep_changed, ep_clean)
            pa, pb = (clean, lv.policy) if side == "A" else (lv.policy, clean)
            rows.append({"pair_index": len(rows), "policy_i": clean, "policy_j": lv.policy, "task": task,
                         "init_id": init_id, "episode_a": a, "episode_b": b, "policy_a": pa, "policy_b": pb,
                         "first_checkpoint": 1, "kind": lv.kind, "level": lv.level, "magnitude": lv.magnitude,
                         "clean_side": side})
    return pd.DataFrame(rows, columns=[*PAIR_COLUMNS, *SWEEP_COLUMNS])
