"""Replacements for excluded comparisons: the seeded continuation of the sampled pair sequences
(``sample_reserve``), drawn only once the pairs are known to come from the same rollouts and seed."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from r2s_eval.compare.sampling import sample_pairs, sample_reserve
from r2s_eval.errors import DataError
from r2s_eval.utils.io import read_parquet_metadata


def reserve_for(pairs: pd.DataFrame, pairs_path: str | Path, episodes: pd.DataFrame, seed: int,
                n_reserve: int) -> pd.DataFrame:
    """The pairs' seeded continuation; checks first that the pairs came from these rollouts and seed."""
    meta = read_parquet_metadata(pairs_path)
    policies = meta.get("policies") or sorted(set(pairs["policy_i"]) | set(pairs["policy_j"]))
    checkpoints = meta.get("checkpoints") or [int(pairs["pair_index"].max()) + 1]
    again = sample_pairs(episodes, policies, checkpoints, seed)
    cols = ["policy_i", "policy_j", "pair_index", "episode_a", "episode_b"]
    if again[cols].astype(str).values.tolist() != pairs[cols].astype(str).values.tolist():
        raise DataError(f"{pairs_path} was not sampled from these rollouts with seed {seed}; rerun compare_pairs")
    return sample_reserve(episodes, policies, checkpoints, seed, n_reserve)
