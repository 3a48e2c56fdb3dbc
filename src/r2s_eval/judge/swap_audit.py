"""The order-swap audit: a fixed share of comparisons is asked a second time with the sides swapped.

A judge without a position bias names the same rollout in both orders, i.e. answers the other
letter. Which comparisons are audited depends only on their position (``swap_audited``), so the
audited set is the same in every rerun and at every checkpoint.
"""

from __future__ import annotations

import hashlib
from typing import Any

import pandas as pd

from r2s_eval.judge.cached_runner import Asker


def swap_audited(policy_i: str, policy_j: str, pair_index: int, share: float) -> bool:
    """Whether comparison `pair_index` of a policy pair is also asked with the sides swapped.

    A hash of the position, not a random draw: the audited set only grows with `share` and is the
    same in every rerun and at every checkpoint.
    """
    if share <= 0:
        return False
    h = hashlib.sha256(f"{policy_i}\x00{policy_j}\x00{int(pair_index)}".encode()).digest()
    return int.from_bytes(h[:8], "big") / 2.0**64 < share


def ask_swapped(rows: list[dict[str, Any]], labels: list[str], share: float,
                ask: Asker) -> tuple[list[bool], dict[int, str]]:
    """Ask the audited rows with A and B swapped: whether each row is audited, and row -> swapped key."""
    audited = [
        share > 0 and swap_audited(str(r.get("policy_i")), str(r.get("policy_j")), int(r.get("pair_index", n)), share)
        for n, r in enumerate(rows)
    ]
    swapped = [n for n, a in enumerate(audited) if a]
    swap_keys = ask([(labels[n] + " swapped", rows[n]["episode_b"], rows[n]["episode_a"]) for n in swapped])
    return audited, dict(zip(swapped, swap_keys))


def swap_columns(audited: list[bool], swap_key_of: dict[int, str], ask: Asker) -> dict[str, list[Any]]:
    """The table's swap_audited, verdict_swapped ("" when not audited or invalid) and swap_cache_key."""
    rows = range(len(audited))
    return {
        "swap_audited": audited,
        "verdict_swapped": [str(ask.letter(swap_key_of[n]) or "") if n in swap_key_of else "" for n in rows],
        "swap_cache_key": [swap_key_of.get(n, "") for n in rows],
    }


def swap_stats(out: pd.DataFrame) -> dict[str, Any]:
    """How many rows were audited, how many swapped answers were invalid, and the consistency."""
    both = out[out["swap_audited"] & (out["verdict_swapped"] != "")]
    return {
        "swap_audited": int(out["swap_audited"].sum()),
        "swap_invalid": int((out["swap_audited"] & (out["verdict_swapped"] == "")).sum()),
        # Consistent: the same rollout wins in both orders, i.e. the letters differ.
        "swap_consistency": float((both["verdict"] != both["verdict_swapped"]).mean()) if len(both) else None,
    }
