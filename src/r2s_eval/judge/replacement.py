"""Invalid comparisons: excluded, and replaced in place from a seeded reserve.

A comparison whose answer stays invalid after one re-ask (or whose server kept sending malformed
replies) is excluded and replaced in place by the next unused comparison of the same policy pair
and task from the reserve (``r2s_eval.compare.sample_reserve``), oriented so that the same policy
is A, and never by one already excluded. So every checkpoint still holds its planned number of
comparisons and smaller checkpoints remain prefixes of larger ones.
"""

from __future__ import annotations

import logging
from typing import Any

import pandas as pd

from r2s_eval.errors import JudgeError
from r2s_eval.judge.cached_runner import Asker, require_columns

log = logging.getLogger(__name__)

RESERVE_COLUMNS = (
    "pair_index", "policy_i", "policy_j", "task", "init_id", "episode_a", "episode_b", "policy_a", "policy_b",
)


def pair_label(n: int, row: dict[str, Any]) -> str:
    """How errors and warnings name table row `n` and the comparison it holds now."""
    replaced = f", replacement {row['replaced']}" if row.get("replaced") else ""
    return (f"pair row {n} ({row['policy_a']} vs {row['policy_b']}, episodes {row['episode_a']} / "
            f"{row['episode_b']}{replaced})")


def _group(row: dict[str, Any]) -> tuple[str, str, str]:
    return str(row.get("policy_i")), str(row.get("policy_j")), str(row.get("task"))


def _episodes(row: dict[str, Any]) -> frozenset[str]:
    """The comparison's two episodes, whichever side each is on."""
    return frozenset((str(row["episode_a"]), str(row["episode_b"])))


class Reserve:
    """Unused reserve comparisons per (policy_i, policy_j, task), in sequence order.

    Each reserve row is handed out once, and never when its episode pair (either order) is one
    already excluded in its group: that comparison's answer is known to be invalid, and a row
    replaced by the very comparison it held would be excluded, and counted, twice.
    """

    def __init__(self, reserve_df: pd.DataFrame | None):
        self.queues: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
        self.excluded: dict[tuple[str, str, str], set[frozenset[str]]] = {}
        if reserve_df is None:
            return
        require_columns(reserve_df, RESERVE_COLUMNS, "reserve table")
        for r in reserve_df.sort_values("pair_index", kind="stable").to_dict("records"):
            self.queues.setdefault(_group(r), []).append(r)

    def exclude(self, row: dict[str, Any]) -> None:
        self.excluded.setdefault(_group(row), set()).add(_episodes(row))

    def take(self, row: dict[str, Any], label: str) -> dict[str, Any]:
        """The fields of `row` that its replacement changes: episodes, init_id, source_index."""
        group = _group(row)
        queue = self.queues.get(group, [])
        excluded = self.excluded.get(group, set())
        while queue and _episodes(queue[0]) in excluded:
            queue.pop(0)  # exclusions only grow: this row can never serve
        if not queue:
            raise JudgeError(
                f"{label}: the judge's answer stayed invalid and no reserve comparison is left for policies "
                f"{group[0]} vs {group[1]} on task {group[2]!r} (none unused that was not excluded); raise the "
                "judge's 'reserve' option"
            )
        r = queue.pop(0)
        ea, eb = r["episode_a"], r["episode_b"]
        if r["policy_a"] != row["policy_a"]:  # keep the excluded comparison's sides
            ea, eb = eb, ea
        return {"episode_a": ea, "episode_b": eb, "init_id": r["init_id"], "source_index": int(r["pair_index"])}


def exclusion_record(row: dict[str, Any], answer: dict[str, Any]) -> dict[str, Any]:
    """The record of one excluded comparison, with the judge's replies."""
    return {
        "policy_i": row.get("policy_i"), "policy_j": row.get("policy_j"), "pair_index": row.get("pair_index"),
        "source_index": row["source_index"], "task": row.get("task"), "episode_a": row["episode_a"],
        "episode_b": row["episode_b"], "replies": answer.get("replies", []),
    }


def replace_invalid(rows: list[dict[str, Any]], labels: list[str], keys: list[str], ask: Asker,
                    reserve_df: pd.DataFrame | None) -> list[dict[str, Any]]:
    """Replace, in place in `rows`, `labels` and `keys`, every comparison whose answer is invalid,
    until all are valid; return one record per excluded comparison."""
    reserve = Reserve(reserve_df)
    exclusions: list[dict[str, Any]] = []
    pending = [n for n, k in enumerate(keys) if ask.letter(k) is None]
    while pending:
        # Every comparison excluded in this round is marked first, so that no replacement drawn
        # in it is one of them.
        for n in pending:
            exclusions.append(exclusion_record(rows[n], ask.answers[keys[n]]))
            reserve.exclude(rows[n])
            log.warning("%s: invalid answer after a re-ask; excluded and replaced", labels[n])
        for n in pending:
            rows[n].update(reserve.take(rows[n], labels[n]))
            rows[n]["replaced"] += 1
            labels[n] = pair_label(n, rows[n])
        for n, k in zip(pending, ask([(labels[n], rows[n]["episode_a"], rows[n]["episode_b"]) for n in pending])):
            keys[n] = k
        pending = [n for n in pending if ask.letter(keys[n]) is None]
    return exclusions
