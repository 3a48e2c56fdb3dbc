"""The annotation set: which compared rollout pairs people are asked about, and how they see them.

Pairs come from the judged comparisons (``compare_pairs``), so every annotated pair has the same
task and init on both sides and every judge has an answer for it. A pair is one unordered pair
of rollout videos; repeated comparisons of the same two videos are one pair.

* Outcome balance: the count is split as evenly as possible over the three outcome categories
  (both succeeded, both failed, one of each; sim outcomes).
* Task spread: within a category, tasks take turns (in a seeded order), so per-task counts
  differ by at most one while every task still has pairs; within a task, the policy pairs take
  turns the same way.
* Where a category has fewer pairs than its share, all of them are taken and the shortfall is
  recorded: the set is never topped up from another category, which would undo the balance.
* Blinding: which video is shown as A is a fresh seeded coin per pair (independent of the order
  the judge saw), items are shuffled so their ids carry no category, and each video is served
  under a token drawn from a hash of the seed and the episode id.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence

import numpy as np
import pandas as pd

from r2s_eval.errors import DataError
from r2s_eval.stats.annotators import OUTCOME_CATEGORIES as CATEGORIES
from r2s_eval.stats.annotators import outcome_category
from r2s_eval.stats.units import tagged_seed

SET_KEY = 0x616E6E6F  # spawn-key tag of the annotation set's draws ("anno")

SET_COLUMNS = (
    "item_id", "task", "init_id", "instruction", "category",
    "episode_a", "episode_b", "policy_a", "policy_b", "success_a", "success_b", "video_a", "video_b",
)
_PAIR_NEEDED = ("task", "init_id", "episode_a", "episode_b", "policy_a", "policy_b")
_EPISODE_NEEDED = ("episode_id", "policy", "task", "init_id", "instruction", "success", "video_path")


def category_targets(n_pairs: int) -> dict[str, int]:
    """``n_pairs`` split over the categories, the first ones taking the remainder."""
    base, extra = divmod(int(n_pairs), len(CATEGORIES))
    return {c: base + (k < extra) for k, c in enumerate(CATEGORIES)}


def video_token(episode_id: str, seed: int) -> str:
    """The opaque name a video is served under: it reveals neither policy nor outcome."""
    return hashlib.sha256(f"r2s-annotate\x00{int(seed)}\x00{episode_id}".encode()).hexdigest()[:20] + ".mp4"


def _require(df: pd.DataFrame, cols: Sequence[str], what: str) -> None:
    lacking = [c for c in cols if c not in df.columns]
    if lacking:
        raise DataError(f"{what} lacks columns {lacking} (has {list(df.columns)})")


def candidate_pairs(pairs: pd.DataFrame, episodes: pd.DataFrame) -> pd.DataFrame:
    """The distinct unordered video pairs among the comparisons, with their outcome category.

    Columns: task, init_id, episode_1, episode_2 (sorted ids), policy_1, policy_2, success_1,
    success_2, category, n_comparisons. Raises ``DataError`` naming the pair when a compared
    episode has no sim rollout or the two sides differ in task or init.
    """
    _require(pairs, _PAIR_NEEDED, "compared pairs")
    _require(episodes, _EPISODE_NEEDED, "sim rollout episodes")
    ep = episodes.assign(episode_id=episodes["episode_id"].astype(str)).set_index("episode_id")
    if ep.index.duplicated().any():
        raise DataError(f"sim rollout episodes repeat episode ids {sorted(ep.index[ep.index.duplicated()])[:5]}")
    rows: dict[tuple[str, str], dict] = {}
    for r in pairs.itertuples(index=False):
        ea, eb = str(r.episode_a), str(r.episode_b)
        for e in (ea, eb):
            if e not in ep.index:
                raise DataError(f"compared pair {ea} / {eb} (task {r.task}, init {r.init_id}): episode {e} has no sim rollout")
        for e in (ea, eb):
            if str(ep.at[e, "task"]) != str(r.task) or int(ep.at[e, "init_id"]) != int(r.init_id):
                raise DataError(f"compared pair {ea} / {eb}: episode {e} is task {ep.at[e, 'task']}, init "
                                f"{ep.at[e, 'init_id']}, but the pair says task {r.task}, init {r.init_id}")
        if ea == eb:
            raise DataError(f"compared pair {ea} / {eb} compares a rollout with itself")
        key = tuple(sorted((ea, eb)))
        if key in rows:
            rows[key]["n_comparisons"] += 1
            continue
        e1, e2 = key
        s1, s2 = bool(ep.at[e1, "success"]), bool(ep.at[e2, "success"])
        rows[key] = {"task": str(r.task), "init_id": int(r.init_id), "episode_1": e1, "episode_2": e2,
                     "policy_1": str(ep.at[e1, "policy"]), "policy_2": str(ep.at[e2, "policy"]),
                     "success_1": s1, "success_2": s2, "category": outcome_category(s1, s2), "n_comparisons": 1}
    columns = ["task", "init_id", "episode_1", "episode_2", "policy_1", "policy_2", "success_1", "success_2",
               "category", "n_comparisons"]
    out = pd.DataFrame(list(rows.values()), columns=columns)
    return out.sort_values(["task", "init_id", "episode_1", "episode_2"], ignore_index=True)


def _take_turns(groups: list[list[int]], rng: np.random.Generator) -> list[int]:
    """Interleave groups (each already in its own order): one from each group per round, the
    groups visited in a seeded order, until all are empty."""
    order = [groups[k] for k in rng.permutation(len(groups))]
    out, depth = [], 0
    while any(depth < len(g) for g in order):
        out += [g[depth] for g in order if depth < len(g)]
        depth += 1
    return out


def draw_annotation_set(pairs: pd.DataFrame, episodes: pd.DataFrame, n_pairs: int, seed: int) -> tuple[pd.DataFrame, dict]:
    """Draw ``n_pairs`` annotation items (fewer where a category runs short; see the module).

    ``pairs``: the compared pairs; ``episodes``: the sim rollout episodes (episode_id, policy,
    task, init_id, instruction, success, video_path). Returns the items (``SET_COLUMNS``: the
    key of the set, policies and outcomes included, which the annotation app never serves) and
    a summary: per category the target, what the pool holds, what was drawn and the shortfall,
    and the count per task.
    """
    if int(n_pairs) <= 0:
        raise DataError(f"the annotation set needs a positive number of pairs, got {n_pairs}")
    pool = candidate_pairs(pairs, episodes)
    instruction = episodes.assign(task=episodes["task"].astype(str)).groupby("task")["instruction"].first()
    targets = category_targets(n_pairs)
    chosen: list[int] = []
    summary: dict = {"n_target": int(n_pairs), "categories": {}}
    for k, category in enumerate(CATEGORIES):
        rng = np.random.default_rng(tagged_seed(seed, SET_KEY, 0, k))
        in_cat = pool[pool["category"] == category]
        per_task = []
        for _, task_rows in in_cat.groupby("task", sort=True):
            by_pair = [list(rng.permutation(g.index.to_numpy()))
                       for _, g in task_rows.groupby(["policy_1", "policy_2"], sort=True)]
            per_task.append(_take_turns(by_pair, rng))
        drawn = _take_turns(per_task, rng)[: targets[category]]
        chosen += drawn
        summary["categories"][category] = {"target": targets[category], "available": len(in_cat),
                                           "drawn": len(drawn), "shortfall": targets[category] - len(drawn)}
    rng = np.random.default_rng(tagged_seed(seed, SET_KEY, 1))
    picked = pool.loc[chosen].reset_index(drop=True)
    picked = picked.iloc[rng.permutation(len(picked))].reset_index(drop=True)  # ids carry no category
    flip = rng.random(len(picked)) < 0.5  # one fresh coin per item: which video is shown as A
    side = {"a": np.where(flip, 2, 1), "b": np.where(flip, 1, 2)}
    items = pd.DataFrame({"item_id": [f"{n:04d}" for n in range(len(picked))], "task": picked["task"],
                          "init_id": picked["init_id"].astype("int64"),
                          "instruction": [str(instruction[t]) for t in picked["task"]],
                          "category": picked["category"]})
    for s in ("a", "b"):
        cols = {f"{c}_{s}": [picked.at[n, f"{c}_{side[s][n]}"] for n in range(len(picked))]
                for c in ("episode", "policy", "success")}
        items = items.assign(**cols)
    items["video_a"] = [video_token(e, seed) for e in items["episode_a"]]
    items["video_b"] = [video_token(e, seed) for e in items["episode_b"]]
    items = items[list(SET_COLUMNS)].astype({"success_a": bool, "success_b": bool})
    summary["n_items"] = len(items)
    summary["n_shortfall"] = int(sum(c["shortfall"] for c in summary["categories"].values()))
    summary["per_task"] = {str(t): int(n) for t, n in items.groupby("task").size().items()}
    return items, summary
