"""Win counts per checkpoint."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from r2s_eval.compare import wins_at_checkpoints


def judged(rows: dict[tuple[str, str], str]) -> pd.DataFrame:
    """rows: (policy_i, policy_j) -> winners as a string of 'i'/'j' per pair_index; sides alternate."""
    out = []
    for (pi, pj), seq in rows.items():
        for k, w in enumerate(seq):
            pa, pb = (pi, pj) if k % 2 == 0 else (pj, pi)
            winner = pi if w == "i" else pj
            out.append({"pair_index": k, "policy_i": pi, "policy_j": pj, "task": "lift", "init_id": 0,
                        "episode_a": f"e{k}a", "episode_b": f"e{k}b", "policy_a": pa, "policy_b": pb,
                        "verdict": "A" if winner == pa else "B", "winner": winner})
    return pd.DataFrame(out)


def test_compare_wins_counts_prefixes():
    df = judged({("x", "y"): "iijij", ("x", "z"): "jjjjj", ("y", "z"): "ijiji"})
    wins = wins_at_checkpoints(df.sample(frac=1.0, random_state=0), ["x", "y", "z"], [1, 3, 5])
    assert wins.shape == (3, 3, 3) and wins.dtype == np.int64
    np.testing.assert_array_equal(wins[0], [[0, 1, 0], [0, 0, 1], [1, 0, 0]])
    np.testing.assert_array_equal(wins[1], [[0, 2, 0], [1, 0, 2], [3, 1, 0]])
    np.testing.assert_array_equal(wins[2], [[0, 3, 0], [2, 0, 3], [5, 2, 0]])
    # Every comparison counts once: wins + losses = checkpoint size for every pair.
    for c, n in enumerate([1, 3, 5]):
        total = wins[c] + wins[c].T
        assert (total[~np.eye(3, dtype=bool)] == n).all()


def test_compare_wins_follow_policy_order():
    df = judged({("x", "y"): "iij"})
    a = wins_at_checkpoints(df, ["x", "y"], [3])
    b = wins_at_checkpoints(df, ["y", "x"], [3])
    np.testing.assert_array_equal(a[0], b[0].T)


def test_compare_wins_errors():
    df = judged({("x", "y"): "iij", ("x", "z"): "ij", ("y", "z"): "iii"})
    with pytest.raises(ValueError, match="pair x vs z: .*0..2"):
        wins_at_checkpoints(df, ["x", "y", "z"], [3])
    with pytest.raises(ValueError, match=r"lack policy pairs \[\('y', 'z'\)\]"):
        wins_at_checkpoints(judged({("x", "y"): "ii", ("x", "z"): "ij"}), ["x", "y", "z"], [2])
    with pytest.raises(ValueError, match=r"\['z'\] that are not in"):
        wins_at_checkpoints(df, ["x", "y"], [2])
    bad = judged({("x", "y"): "ii"})
    bad.loc[0, "winner"] = "q"
    with pytest.raises(ValueError, match="winner 'q' is neither side"):
        wins_at_checkpoints(bad, ["x", "y"], [2])
