"""Task-stratified, init-matched, side-balanced sampling of A/B comparisons.

For every unordered policy pair one sequence of ``max(checkpoints)`` comparisons is drawn:

* tasks come in shuffled blocks holding every task once, so in EVERY prefix the per-task counts
  differ by at most one;
* both sides of a comparison start from the same initial configuration (``init_id``), drawn from
  the inits both policies have for that task in shuffled rounds: every shared init once before
  any init a second time. A comparison of the same rollout pair again is no new evidence, so a
  checkpoint as large as the pair's shared inits compares each of them exactly once;
* sides come in shuffled blocks of two (policy i as A once, as B once), so in every prefix
  policy i is A half of the time, +-1/2;
* when a policy has several episodes for one (task, init), one is drawn at random.

Checkpoint n is the first n comparisons of every pair: smaller checkpoints are prefixes of larger
ones and no comparison is judged twice; sampling with a larger ``max(checkpoints)`` and the same
seed extends the sequences without changing their beginnings. The random stream of a pair depends only on the seed and
the two policy names, so adding a policy leaves the other pairs' sequences unchanged.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from itertools import combinations

import numpy as np
import pandas as pd

from r2s_eval.errors import ConfigError, DataError

PAIR_COLUMNS = (
    "pair_index", "policy_i", "policy_j", "task", "init_id",
    "episode_a", "episode_b", "policy_a", "policy_b", "first_checkpoint",
)
_NEEDED = ("episode_id", "policy", "task", "init_id")


def pair_rng(seed: int, a: str, b: str, salt: str = "") -> np.random.Generator:
    """The random stream of one unordered policy pair: adding a policy leaves the others' unchanged.
    `salt` gives another use its own streams."""
    lo, hi = sorted((a, b))
    digest = hashlib.sha256(f"{salt}{lo}\x00{hi}".encode()).digest()
    return np.random.default_rng([int(seed), int.from_bytes(digest[:8], "little")])


def index_episodes(episodes_df: pd.DataFrame, policies: Sequence[str]
                   ) -> tuple[list[str], list[str], dict[tuple[str, str], dict[int, list[str]]]]:
    """The policies (checked), the tasks any of them has, and (policy, task) -> {init_id: sorted
    episode ids} (sorted, so results do not depend on the table's row order)."""
    lacking = [c for c in _NEEDED if c not in episodes_df.columns]
    if lacking:
        raise DataError(f"episode table lacks columns {lacking}")
    if "arm" in episodes_df.columns and episodes_df["arm"].nunique() > 1:
        raise DataError(f"episode table mixes arms {sorted(episodes_df['arm'].unique())}; sample one arm at a time")
    policies = [str(p) for p in policies]
    if len(policies) < 2 or len(set(policies)) != len(policies):
        raise ConfigError(f"need at least two distinct policies, got {policies}")
    df = episodes_df[list(_NEEDED)].astype({"episode_id": str, "policy": str, "task": str})
    absent = sorted(set(policies) - set(df["policy"]))
    if absent:
        raise DataError(f"policies {absent} have no episodes in the episode table")
    df = df[df["policy"].isin(policies)]
    episodes: dict[tuple[str, str], dict[int, list[str]]] = {}
    for (pol, task, init), ids in df.groupby(["policy", "task", "init_id"])["episode_id"]:
        episodes.setdefault((pol, task), {})[int(init)] = sorted(ids)
    return policies, sorted(df["task"].unique()), episodes


def shared_inits(episodes: dict[tuple[str, str], dict[int, list[str]]], pi: str, pj: str, task: str) -> list[int]:
    """The inits both policies have for `task`, sorted; an error naming them when there is none."""
    inits = sorted(set(episodes.get((pi, task), {})) & set(episodes.get((pj, task), {})))
    if not inits:
        raise DataError(f"policies {pi!r} and {pj!r} share no initial configuration (init_id) for task {task!r}")
    return inits


def checkpoint_sizes(spec: dict) -> list[int]:
    """Comparisons per policy pair at each checkpoint, from ``{start, stop, step}`` (stop included)."""
    return list(range(int(spec["start"]), int(spec["stop"]) + 1, int(spec["step"])))


def _check_checkpoints(checkpoints: Sequence[int]) -> list[int]:
    ck = [int(c) for c in checkpoints]
    if not ck or any(c <= 0 for c in ck) or any(c != x for c, x in zip(ck, checkpoints)):
        raise ConfigError(f"checkpoints must be a non-empty list of positive integers, got {list(checkpoints)}")
    return sorted(set(ck))


def sample_pairs(
    episodes_df: pd.DataFrame,
    policies: Sequence[str],
    checkpoints: Sequence[int],
    seed: int,
) -> pd.DataFrame:
    """Draw the nested comparison sequences of every policy pair.

    `episodes_df` is the episode table of ONE arm (needs episode_id, policy, task, init_id); every
    task that any of `policies` has is compared, so each pair must share an init on each of them.
    Pairs are (policies[i], policies[j]) with i < j, in list order.

    Returns one row per comparison, sorted by pair then ``pair_index``, columns ``PAIR_COLUMNS``:
    pair_index (0-based position in the pair's sequence), policy_i, policy_j, task, init_id,
    episode_a, episode_b, policy_a, policy_b, first_checkpoint (the smallest checkpoint that
    includes the comparison).
    """
    policies, tasks, episodes = index_episodes(episodes_df, policies)
    ck = _check_checkpoints(checkpoints)
    n = ck[-1]
    first_ck = np.searchsorted(np.asarray(ck), np.arange(n) + 1)  # index of the first checkpoint >= k+1
    frames = []
    for pi, pj in combinations(policies, 2):
        common = {task: shared_inits(episodes, pi, pj, task) for task in tasks}
        rng = pair_rng(seed, pi, pj)
        first, second = sorted((pi, pj))

        # Draws happen in sequence order, so a longer sequence extends a shorter one with the
        # same seed (checkpoints can be added later without re-judging anything).
        rows, task_block, side_block = [], [], np.zeros(0, dtype=bool)
        init_rounds: dict[str, list[int]] = {}  # per task, the inits left in its current round
        for k in range(n):
            if k % len(tasks) == 0:  # task-balanced: a new shuffled block holding every task once
                task_block = [tasks[t] for t in rng.permutation(len(tasks))]
            if k % 2 == 0:  # side-balanced: a new shuffled block (first-named policy as A, as B)
                side_block = rng.permutation([True, False])
            task, fa = task_block[k % len(tasks)], bool(side_block[k % 2])
            if not init_rounds.get(task):  # a new shuffled round of the task's shared inits
                init_rounds[task] = [common[task][i] for i in rng.permutation(len(common[task]))]
            init = init_rounds[task].pop()
            pa, pb = (first, second) if fa else (second, first)
            ea_pool, eb_pool = episodes[(pa, task)][init], episodes[(pb, task)][init]
            ea = ea_pool[int(rng.integers(len(ea_pool)))]
            eb = eb_pool[int(rng.integers(len(eb_pool)))]
            rows.append((k, pi, pj, task, init, ea, eb, pa, pb, ck[first_ck[k]]))
        frames.append(pd.DataFrame(rows, columns=list(PAIR_COLUMNS)))
    out = pd.concat(frames, ignore_index=True)
    return out.astype({"pair_index": "int64", "init_id": "int64", "first_checkpoint": "int64"})


def sample_reserve(
    episodes_df: pd.DataFrame,
    policies: Sequence[str],
    checkpoints: Sequence[int],
    seed: int,
    n_reserve: int,
) -> pd.DataFrame:
    """Replacement comparisons: positions n .. n + n_reserve - 1 of every pair's sequence.

    n = max(checkpoints). These continue the seeded streams of ``sample_pairs`` (same arguments),
    so they never coincide with a planned comparison's draw and do not change any of them; a judge
    stage takes from them, in order and for the same task, when a planned comparison has to be
    excluded. Columns as ``sample_pairs``, with first_checkpoint -1 (no checkpoint plans them).
    """
    n = _check_checkpoints(checkpoints)[-1]
    if int(n_reserve) < 0:
        raise ConfigError(f"n_reserve must be >= 0, got {n_reserve}")
    if int(n_reserve) == 0:
        return pd.DataFrame(columns=list(PAIR_COLUMNS))
    extended = sample_pairs(episodes_df, policies, [n + int(n_reserve)], seed)
    reserve = extended[extended["pair_index"] >= n].copy()
    reserve["first_checkpoint"] = -1
    return reserve.reset_index(drop=True)
