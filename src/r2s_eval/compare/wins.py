"""Win counts per checkpoint from judged comparisons."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from r2s_eval.compare.sampling import _check_checkpoints
from r2s_eval.errors import ConfigError, DataError

_NEEDED = ("pair_index", "policy_i", "policy_j", "policy_a", "policy_b", "winner")


def checkpoint_positions(judged_pairs_df: pd.DataFrame) -> pd.Series:
    """Each comparison's position for the checkpoints: checkpoint ``n`` holds those below ``n``.

    The fixed allocation's is the comparison's place in its pair's sequence (``pair_index``); the
    adaptive allocation's (``checkpoint_position``) its place in the whole sequence judged,
    divided by the number of policy pairs (see ``r2s_eval.judge.adaptive``).
    """
    if "checkpoint_position" in judged_pairs_df.columns:
        return judged_pairs_df["checkpoint_position"]
    return judged_pairs_df["pair_index"]


def wins_at_checkpoints(
    judged_pairs_df: pd.DataFrame,
    policies: Sequence[str],
    checkpoints: Sequence[int],
) -> np.ndarray:
    """``wins[c, i, j]`` = how often policies[i] was preferred over policies[j] in the first
    ``checkpoints[c]`` comparisons of their pair (checkpoints in the order given).

    `judged_pairs_df` is ``judge_pairs`` output. Every policy pair must have been judged on at
    least ``max(checkpoints)`` comparisons (pair_index 0..n-1), otherwise the checkpoints would
    silently compare pairs on different numbers of comparisons.
    """
    lacking = [c for c in _NEEDED if c not in judged_pairs_df.columns]
    if lacking:
        raise DataError(f"judged pairs table lacks columns {lacking}")
    policies = [str(p) for p in policies]
    index = {p: k for k, p in enumerate(policies)}
    if len(index) != len(policies):
        raise ConfigError(f"duplicate policies in {policies}")
    _check_checkpoints(checkpoints)
    ck = [int(c) for c in checkpoints]
    df = judged_pairs_df[list(_NEEDED)].astype({c: str for c in _NEEDED[1:]})
    adaptive = "checkpoint_position" in judged_pairs_df.columns
    df["position"] = checkpoint_positions(judged_pairs_df).to_numpy()

    unknown = sorted((set(df["policy_i"]) | set(df["policy_j"])) - set(index))
    if unknown:
        raise DataError(f"judged pairs name policies {unknown} that are not in {policies}")
    bad = df[(df["winner"] != df["policy_a"]) & (df["winner"] != df["policy_b"])]
    if len(bad):
        r = bad.iloc[0]
        raise DataError(f"pair {r.policy_i} vs {r.policy_j}, pair_index {r.pair_index}: winner {r.winner!r} is neither side")

    wins = np.zeros((len(ck), len(policies), len(policies)), dtype=np.int64)
    n_max = max(ck)
    seen = set()
    for (pi, pj), g in df.groupby(["policy_i", "policy_j"], sort=False):
        seen.add(frozenset((pi, pj)))
        idx = np.sort(g["pair_index"].to_numpy())
        if not adaptive and (len(idx) < n_max or not np.array_equal(idx[:n_max], np.arange(n_max))):
            raise DataError(
                f"pair {pi} vs {pj}: checkpoints need judged comparisons with pair_index 0..{n_max - 1}, "
                f"found {len(idx)} comparisons"
            )
        pos = g["position"].to_numpy()
        win_i = (g["winner"] == pi).to_numpy()
        for c, n in enumerate(ck):
            first = pos < n
            wins[c, index[pi], index[pj]] = int(np.sum(first & win_i))
            wins[c, index[pj], index[pi]] = int(np.sum(first & ~win_i))
    missing = [(a, b) for k, a in enumerate(policies) for b in policies[k + 1:] if frozenset((a, b)) not in seen]
    if missing:
        raise DataError(f"judged pairs lack policy pairs {missing}")
    return wins
