"""The adaptive judging driver: whole blocks of comparisons, round after round, to the policy pairs
whose order is still open, until every pair is decided, runs out of units, or the budget is spent.

The rule that picks the pairs, the blocks and the confidence sequences are
``r2s_eval.compare.sequential``'s; this module asks the judge. Everything it chooses is a
function of the seeded unit order and the answers, and every answer comes from the content-keyed
cache when it is there, so a rerun, or a run killed mid-round and resumed, makes the same choices
and sends no request twice.

* Lazy describing (two-step judges): a rollout is described when a chosen comparison first needs
  it; the rollouts of pairs decided early are never described. Describe and compare requests are
  counted apart.
* Invalid answers: the comparison is excluded and its slot takes the next unused unit of the same
  task of that pair, with the same sides; when the task has none left, the block is incomplete,
  does not count as evidence, and the pair has no blocks left.
* The order-swap audit asks the share of judged comparisons ``swap_audited`` picks once more with
  the sides swapped, after the last round, as in the fixed allocation.
* Checkpoints: comparison ``k`` of the whole sequence (in the order judged) belongs to position
  ``k // n_pairs``, so checkpoint ``c`` holds what the judge was asked within the fixed
  allocation's budget for ``c`` comparisons per pair (``checkpoint_position``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from r2s_eval.compare.sequential import PairState, allocate, pair_alpha
from r2s_eval.errors import ConfigError, DataError
from r2s_eval.judge.base import Judge
from r2s_eval.judge.cache import AnswerCache
from r2s_eval.judge.drivers import _comparisons, _verdict_table, describe_rollouts
from r2s_eval.judge.questions import description_questions
from r2s_eval.judge.replacement import exclusion_record, pair_label
from r2s_eval.judge.cached_runner import Asker, StageStats, finish, require_columns, sum_stats
from r2s_eval.judge.scratch import clear_leftovers
from r2s_eval.judge.swap_audit import ask_swapped, swap_columns, swap_stats
from r2s_eval.utils.io import write_json

log = logging.getLogger(__name__)

# Added to the verdict columns by the adaptive driver.
ADAPTIVE_COLUMNS = ("round", "block", "sequence_index", "checkpoint_position")


class _Pair:
    """One policy pair's units: a queue per task in the seeded order, and its blocks' slot layouts."""

    def __init__(self, rows: pd.DataFrame, alpha: float):
        first = rows.iloc[0]
        self.state = PairState(str(first["policy_i"]), str(first["policy_j"]), blocks_left=0, alpha=alpha,
                               horizon=len(rows))
        self.queues: dict[str, list[dict[str, Any]]] = {}
        self.layouts: list[list[tuple[str, str]]] = []  # per block: (task, policy on side A)
        for b, g in rows.sort_values("pair_index", kind="stable").groupby("block", sort=True):
            self.layouts.append([(str(r["task"]), str(r["policy_a"])) for r in g.to_dict("records")])
            for r in g.to_dict("records"):
                self.queues.setdefault(str(r["task"]), []).append(r)
        self.next_block = 0
        self.judged = 0
        self.update_left()

    def update_left(self) -> None:
        """Blocks that can still be filled: a block takes two units of every task."""
        self.state.blocks_left = (min(len(q) for q in self.queues.values()) // 2
                                  if self.next_block < len(self.layouts) else 0)

    def take(self, task: str, side_a: str) -> dict[str, Any] | None:
        """The next unused unit of `task`, oriented so that `side_a` is A; None when none is left."""
        queue = self.queues[task]
        if not queue:
            return None
        unit = dict(queue.pop(0))
        if unit["policy_a"] != side_a:
            unit["episode_a"], unit["episode_b"] = unit["episode_b"], unit["episode_a"]
            unit["policy_a"], unit["policy_b"] = unit["policy_b"], unit["policy_a"]
        unit["source_index"] = int(unit["pair_index"])
        unit["replaced"] = 0
        return unit

    def open_block(self) -> tuple[int, list[dict[str, Any]]]:
        b = self.next_block
        units = [self.take(task, side) for task, side in self.layouts[b]]
        self.next_block += 1
        self.update_left()
        return b, units  # every slot is filled: blocks_left counted a unit of every task


def judge_adaptively(units_df: pd.DataFrame, judge: Judge, cache_dir: str | Path, *, alpha: float,
                     budget_per_pair: int, checkpoints: Sequence[int], episodes_df: pd.DataFrame,
                     episodes_dir: str | Path, descriptions_df: pd.DataFrame | None = None,
                     workers: int | None = None, stats_path: str | Path | None = None,
                     describe_stats_path: str | Path | None = None,
                     swap_share: float | None = None) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """Judge the unit order `units_df` (``compare.sequential.unit_order`` output) adaptively.

    Returns (verdicts, descriptions). verdicts: the judged units, in the order judged, with the
    columns of ``unit_order``, ``VERDICT_COLUMNS`` and ``ADAPTIVE_COLUMNS``; its stats
    (``attrs["stats"]``) add ``allocation``, ``stop`` (all_decided / units_exhausted /
    budget_spent), ``rounds``, ``pairs`` (per policy pair: blocks, comparisons, interval, decided,
    winner), ``undecided`` (the pairs left open) and the swap-audit and exclusion counts.
    descriptions: for two-step judges, the rollouts described on the way (in episode-table order),
    with the describe stats in ``attrs["stats"]`` (also written to `describe_stats_path`); None
    for one-step judges. `descriptions_df`, when given, is used instead of describing.
    """
    t0 = time.perf_counter()
    require_columns(units_df, ("pair_index", "policy_i", "policy_j", "task", "init_id", "episode_a", "episode_b",
                               "policy_a", "policy_b", "block"), "unit order")
    mode = judge.stage_cfg["mode"]
    share = float(judge.stage_cfg["swap_share"] if swap_share is None else swap_share)
    workers = int(workers or judge.stage_cfg["concurrency"])
    groups = [g for _, g in units_df.groupby(["policy_i", "policy_j"], sort=False)]
    level = pair_alpha(alpha, len(groups))
    pairs = [_Pair(g, level) for g in groups]
    block_size = 2 * units_df["task"].nunique()  # two units of every task
    total_budget = int(budget_per_pair) * len(pairs)
    blocks_per_round = max(1, round(workers / block_size))
    if total_budget < block_size:
        raise ConfigError(f"compare.budget {budget_per_pair} per policy pair leaves no room for one block of "
                          f"{block_size} comparisons over {len(pairs)} pairs")

    clear_leftovers(Path(cache_dir), ("compare", "compare_videos", "requests"))
    judge.attach_cache(cache_dir)
    stats = StageStats(stage="compare", judge=judge.name)
    lazy = mode == "two_step" and descriptions_df is None
    describer = _LazyDescriber(judge, cache_dir, episodes_df, episodes_dir, workers) if lazy else None
    if lazy:
        question, cache = describer.question([]), AnswerCache(cache_dir, "compare")
    else:
        question, cache = _comparisons(mode, judge, cache_dir, descriptions_df, episodes_df, episodes_dir)
    ask = Asker(question, cache, stats, workers)

    rows: list[dict[str, Any]] = []
    keys: list[str] = []
    exclusions: list[dict[str, Any]] = []
    stop, n_round = "all_decided", 0
    while True:
        room = (total_budget - len(rows)) // block_size
        chosen = allocate([p.state for p in pairs], min(blocks_per_round, room), [block_size] * len(pairs))
        if not chosen:
            if any(not p.state.decided and p.state.blocks_left > 0 for p in pairs):
                stop = "budget_spent"
            elif any(not p.state.decided for p in pairs):
                stop = "units_exhausted"
            break
        blocks = []
        for k in chosen:
            b, units = pairs[k].open_block()
            for u in units:
                u.update({"round": n_round, "block": b})
            blocks.append((k, units))
        round_rows = [u for _, units in blocks for u in units]
        first = len(rows)
        labels = [pair_label(first + n, r) for n, r in enumerate(round_rows)]
        if lazy:
            ask.question = describer.question(round_rows)
        round_keys = ask([(labels[n], r["episode_a"], r["episode_b"]) for n, r in enumerate(round_rows)])
        exclusions += _replace_invalid(round_rows, labels, round_keys, ask, blocks, pairs, describer)
        rows += round_rows
        keys += round_keys
        for k, units in blocks:
            complete = [u for u in units if not u.get("incomplete")]
            if len(complete) == len(units):
                wins = [u["policy_a"] if ask.letter(key) == "A" else u["policy_b"]
                        for u, key in zip(units, round_keys[_span(round_rows, units)])]
                pairs[k].state.add([float(w == pairs[k].state.policy_i) for w in wins])
            pairs[k].judged += len(units)
            pairs[k].update_left()
        n_round += 1

    # Incomplete blocks' answered units stay (they are judged comparisons); their empty slots go.
    kept = [n for n, r in enumerate(rows) if not r.get("empty")]
    rows, keys = [rows[n] for n in kept], [keys[n] for n in kept]
    for n, r in enumerate(rows):
        r["sequence_index"] = n
        r["checkpoint_position"] = n // len(pairs)
        r["first_checkpoint"] = next(int(c) for c in sorted(checkpoints) if c > r["checkpoint_position"])
        r.pop("incomplete", None)
    labels = [pair_label(n, r) for n, r in enumerate(rows)]
    if lazy:
        ask.question = describer.question(rows)
    audited, swap_key_of = ask_swapped(rows, labels, share, ask)
    columns = [c for c in units_df.columns if c != "block"]
    out = _verdict_table(units_df.iloc[:0][columns], rows, keys, ask, judge.name, swap_columns(audited, swap_key_of, ask))
    for c in ADAPTIVE_COLUMNS:
        out[c] = pd.Series([r[c] for r in rows], dtype="int64")
    stats.items = len(out)
    decisions = [_decision(p) for p in pairs]
    stats.extra.update({
        "mode": mode, "allocation": "adaptive", "alpha": float(alpha), "pair_alpha": level,
        "budget_per_pair": int(budget_per_pair), "blocks_per_round": blocks_per_round, "rounds": n_round,
        "stop": stop, "pairs": decisions,
        "undecided": [f"{d['policy_i']} vs {d['policy_j']}" for d in decisions if not d["decided"]],
        "excluded": len(exclusions), "replacements": int(out["replaced"].sum()),
        "reasked_answers": int(out["reasks"].sum()), "swap_share": share, **swap_stats(out),
        "exclusions": exclusions,
    })
    descriptions = describer.result(describe_stats_path) if lazy else None
    if descriptions is not None:  # the describe side of the cost, beside the compare side
        made = descriptions.attrs["stats"]
        stats.extra.update({"describe_calls": int(made.get("calls", 0)), "describe_requests": int(made.get("requests", 0)),
                            "described": len(descriptions)})
    return finish(stats, t0, out, stats_path), descriptions


def _span(round_rows: list[dict[str, Any]], units: list[dict[str, Any]]) -> slice:
    start = next(n for n, r in enumerate(round_rows) if r is units[0])
    return slice(start, start + len(units))


def _decision(p: _Pair) -> dict[str, Any]:
    s = p.state
    return {"policy_i": s.policy_i, "policy_j": s.policy_j, "blocks": s.blocks, "comparisons": p.judged,
            "win_rate_low": s.low, "win_rate_high": s.high, "decided": s.decided, "winner": s.winner}


def _replace_invalid(round_rows, labels, keys, ask: Asker, blocks, pairs,
                     describer: _LazyDescriber | None) -> list[dict[str, Any]]:
    """Replace each unit whose answer stayed invalid by its pair's next unused unit of the same
    task (same sides), until all are valid or the task has none left (the slot is then empty and
    its block incomplete). Returns one record per excluded comparison."""
    block_of = {id(u): (k, units) for k, units in blocks for u in units}
    exclusions = []
    pending = [n for n, key in enumerate(keys) if ask.letter(key) is None]
    while pending:
        again = []
        for n in pending:
            row = round_rows[n]
            exclusions.append(exclusion_record(row, ask.answers[keys[n]]))
            log.warning("%s: invalid answer after a re-ask; excluded and replaced", labels[n])
            k, units = block_of[id(row)]
            unit = pairs[k].take(str(row["task"]), str(row["policy_a"]))
            if unit is None:
                log.warning("%s: its pair has no unused unit of task %r left; the block is incomplete",
                            labels[n], row["task"])
                row["empty"] = True
                for other in units:
                    other["incomplete"] = True
                continue
            for name in ("init_id", "episode_a", "episode_b", "source_index"):
                row[name] = unit[name]
            row["replaced"] += 1
            labels[n] = pair_label(n, row)
            again.append(n)
        if describer is not None and again:
            ask.question = describer.question([round_rows[n] for n in again])
        for n, key in zip(again, ask([(labels[n], round_rows[n]["episode_a"], round_rows[n]["episode_b"]) for n in again])):
            keys[n] = key
        pending = [n for n in again if ask.letter(keys[n]) is None]
    return exclusions


class _LazyDescriber:
    """Describes rollouts when comparisons first need them (through the describe cache), and keeps
    what it described and what that cost."""

    def __init__(self, judge: Judge, cache_dir: str | Path, episodes_df: pd.DataFrame, episodes_dir: str | Path,
                 workers: int):
        self.judge, self.cache_dir, self.episodes_dir, self.workers = judge, cache_dir, episodes_dir, workers
        self.episodes = episodes_df.assign(episode_id=episodes_df["episode_id"].astype(str)).set_index(
            "episode_id", drop=False)
        self.parts: list[pd.DataFrame] = []
        self.stats: list[dict[str, Any]] = []
        self.described: set[str] = set()

    def question(self, rows: list[dict[str, Any]]):
        """The comparison question over every rollout described so far, after describing those
        `rows` need that are not yet."""
        needed = []
        for r in rows:
            for e in (str(r["episode_a"]), str(r["episode_b"])):
                if e not in self.described and e not in needed:
                    needed.append(e)
        if needed:
            unknown = [e for e in needed if e not in self.episodes.index]
            if unknown:
                raise DataError(f"episodes {unknown[:5]} are not in the rollouts' episode table")
            part = describe_rollouts(self.episodes.loc[needed].reset_index(drop=True), self.episodes_dir, self.judge,
                                     self.cache_dir, workers=self.workers)
            self.parts.append(part)
            self.stats.append(part.attrs["stats"])
            self.described.update(needed)
        return description_questions(self.table(), self.judge, self.judge.compare_identity())

    def table(self) -> pd.DataFrame:
        """The descriptions so far, in episode-table order."""
        if not self.parts:
            return pd.DataFrame(columns=["episode_id", "instruction", "description", "description_sha"])
        table = pd.concat(self.parts, ignore_index=True)
        order = {e: n for n, e in enumerate(self.episodes.index)}
        return table.sort_values("episode_id", key=lambda s: s.map(order), kind="stable").reset_index(drop=True)

    def result(self, stats_path: str | Path | None) -> pd.DataFrame:
        table = self.table()
        stats = sum_stats(self.stats) if self.stats else {"stage": "describe", "judge": self.judge.name}
        stats.update({"items": len(table), "lazy": True})
        table.attrs["stats"] = stats
        if stats_path is not None:
            write_json(stats_path, stats, provenance=True)
        return table
