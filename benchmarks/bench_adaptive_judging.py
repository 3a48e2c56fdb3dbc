"""Adaptive judging vs the fixed allocation: judge requests needed for the same decisions.

A simulated judge answers A/B questions about policy pairs. Its latent preferences follow a
Bradley-Terry model with ties (Davidson): strength ``s = success rate in percent + 1`` and, for a
pair (i, j), ``P(i better) = s_i / D``, ``P(tie) = nu * sqrt(s_i s_j) / D`` with
``D = s_i + s_j + nu * sqrt(s_i s_j)`` (``NU``). Every policy has one rollout per (task, init), so
a pair's *unit* (task, init) is one rollout pair; per simulated run each unit draws ONE latent
outcome (i better / tie / j better), whichever order it is asked in and however often. An answer
for one orientation: on a decisive unit the better side with probability ``1 - EPS``, on a tie
side A with probability ``0.5 + BETA`` (position bias). Answers are cached per (unit,
orientation): asking again costs nothing and returns the same answer; the other orientation is a
new request with its own draw. Both allocations below ask the same simulated judge in a run.

Worlds (``WORLDS``; one rollout per policy, task and init): *paper*, six VLAs at 53.6, 63.6, 7.1,
65.7, 4.3 and 2.1 % success, 7 tasks x 50 inits, fixed budget 2000 comparisons per pair; *demo*,
54.0, 9.5 and 0.0 %, 7 x 18, 400; *hard*, 40, 42, 20 and 5 %, 7 x 50, 2000; *null*, four
policies at 30 %, 7 x 18, 400 (any declared order is wrong there).

FIXED (``r2s_eval.compare.sample_pairs``, checkpoints ``[budget]``): every episode is described
up front, then each pair's sequence of ``budget`` comparisons is judged, round robin over pairs.
Requests = descriptions + distinct (episode_a, episode_b) questions. At the full budget a pair is
decided when the 95% percentile interval of policy_i's win rate under the unit bootstrap (the
pair's distinct units with their answers summed, resampled with replacement within each task,
``--n-boot`` replicates) excludes 1/2; the same bootstrap at ``alpha / n_pairs`` per pair gives
the fixed allocation's decisions at the adaptive rule's guarantee (``alpha`` over the ranking),
the comparison that is fair to both (a single look at the end against looks after every block).

ADAPTIVE (``r2s_eval.compare.sequential``): each pair's blocks from ``unit_order`` (two units of
every task, one per side); each round ``allocate(states, max(1, round(concurrency / block
size)))`` picks whole blocks, whose comparisons go to ``PairState.add`` (each pair at
``pair_alpha(alpha, n_pairs)``); it stops when every pair is decided or no open pair has blocks
left. Requests = one per unit judged + the distinct episodes touched so far (descriptions are
made when first needed).

The sequences of ``sample_pairs`` and the block orders of ``unit_order`` are made for
``--designs`` seeds per world (``10000 * seed + d``) and run ``r`` uses design ``r % designs``;
the judge's latent outcomes, its answers and the bootstrap draws are fresh in every run (seeded
by ``(seed, world, run)``), so the printed numbers depend on the arguments only, not on
``--workers``.

Reported per world (medians and shares over runs):

* fixed requests (descriptions + comparisons) at the full budget;
* adaptive requests at the end of the first round where its decided pairs, with their
  directions, include every pair the fixed allocation decided in that run (median, 90th
  percentile, over the runs that get there; a run where the fixed allocation decides nothing
  gets there after the first round) and the share of runs that get there at all; the median of
  fixed / adaptive over those runs; both for the fixed decisions at 95 % per pair and at alpha
  over the ranking;
* adaptive requests when it stops, and fixed / adaptive-at-stop;
* the share of runs with at least one pair declared in the wrong order (against the true
  strengths; between equal strengths any declaration is wrong), adaptive and fixed;
* the mean over pairs of the interval width: the adaptive confidence sequence's when it stops,
  the fixed allocation's unit-bootstrap interval at the longest prefix of its round-robin order
  whose requests do not exceed the adaptive total (a pair with no comparison yet counts 1).

``--figure PATH`` also draws the mean interval width against judge requests, one panel per world.

Run: ``python benchmarks/bench_adaptive_judging.py [--runs 1000] [--worlds paper,demo,hard,null]
[--seed 0] [--alpha 0.05] [--concurrency 16] [--n-boot 1000] [--designs 10] [--nu 1] [--eps 0.1]
[--beta 0.1] [--workers 2] [--figure widths.png]`` (the defaults; about 5 minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

from r2s_eval.compare.sampling import sample_pairs
from r2s_eval.compare.sequential import PairState, allocate, pair_alpha, unit_order

NU = 1.0  # Davidson tie parameter
EPS = 0.1  # chance that the judge prefers the worse rollout of a decisive unit
BETA = 0.1  # position bias: on a tie the judge picks side A with probability 0.5 + BETA
# The configured error rate and bootstrap (conf/compare, conf/stats), read rather than copied.
_CONF = Path(__file__).resolve().parents[1] / "conf"
ALPHA = float(OmegaConf.load(_CONF / "compare" / "default.yaml").alpha)
CONCURRENCY = 16
N_BOOT = int(OmegaConf.load(_CONF / "stats" / "default.yaml").n_boot)
RUNS = 1000
DESIGNS = 10
_SHIFT = 20  # a unit's answers packed as n + (wins << _SHIFT): one gather per bootstrap
_LOW_BITS = (1 << _SHIFT) - 1


@dataclass(frozen=True)
class World:
    """Policies' success rates (percent), the rollout grid and the fixed budget per pair."""

    success: tuple[float, ...]
    n_tasks: int
    n_inits: int
    budget: int


WORLDS = {
    "paper": World((53.6, 63.6, 7.1, 65.7, 4.3, 2.1), 7, 50, 2000),
    "demo": World((54.0, 9.5, 0.0), 7, 18, 400),
    "hard": World((40.0, 42.0, 20.0, 5.0), 7, 50, 2000),
    "null": World((30.0, 30.0, 30.0, 30.0), 7, 18, 400),
}


@dataclass(frozen=True)
class Design:
    """One seed's fixed sequences and adaptive block orders, as indices into a run's answers.

    A run's answers are a flat boolean array over (pair, task, init, orientation), orientation 0
    with policy_i as A; ``True`` means policy_i was preferred. Episodes are numbered
    (policy, task, init) the same way.
    """

    n_pairs: int
    describes: int  # every episode of every policy
    # Fixed: the comparisons in round-robin order (pair_index * n_pairs + pair).
    row_q: np.ndarray  # answer index of each comparison
    row_unit: np.ndarray  # compact unit of each comparison
    cum_questions: np.ndarray  # distinct questions among the first G comparisons, G = 0..rows
    # Compact units sorted by (pair, task, first appearance).
    unit_pair: np.ndarray
    unit_stratum: np.ndarray
    unit_rank: np.ndarray
    stratum_start: np.ndarray
    # Adaptive: per pair, (blocks, tasks) answer indices and (blocks, 2 * tasks) episode indices.
    block_q: tuple[np.ndarray, ...]
    block_ep: tuple[np.ndarray, ...]

    def fixed_requests(self, prefix: int) -> int:
        return self.describes + int(self.cum_questions[prefix])

    def prefix_within(self, requests: float) -> int:
        """The longest prefix of the round-robin order whose requests do not exceed `requests`."""
        if requests < self.describes:
            return 0
        return int(np.searchsorted(self.cum_questions, requests - self.describes, side="right")) - 1


def policy_names(world: World) -> list[str]:
    return [f"policy{k}" for k in range(len(world.success))]


def episode_table(world: World) -> pd.DataFrame:
    rows = [
        (f"{p}/task{t}/{n}", p, f"task{t}", n)
        for p in policy_names(world) for t in range(world.n_tasks) for n in range(world.n_inits)
    ]
    return pd.DataFrame(rows, columns=["episode_id", "policy", "task", "init_id"])


def _indices(world: World, df: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(pair, task, init, orientation, answer index) of each row of a pairs table."""
    names = policy_names(world)
    pair_of = {(names[a], names[b]): k for k, (a, b) in enumerate(combinations(range(len(names)), 2))}
    pair = np.array([pair_of[(i, j)] for i, j in zip(df["policy_i"], df["policy_j"])], dtype=np.int64)
    task = df["task"].str.removeprefix("task").astype(int).to_numpy()
    init = df["init_id"].to_numpy(dtype=np.int64)
    orient = (df["policy_a"] != df["policy_i"]).to_numpy().astype(np.int64)
    q = ((pair * world.n_tasks + task) * world.n_inits + init) * 2 + orient
    return pair, task, init, orient, q


@lru_cache(maxsize=None)
def design(world_name: str, seed: int) -> Design:
    world = WORLDS[world_name]
    names = policy_names(world)
    episodes = episode_table(world)
    T, N = world.n_tasks, world.n_inits
    n_pairs = len(names) * (len(names) - 1) // 2

    fixed = sample_pairs(episodes, names, [world.budget], seed)
    pair, task, init, _, q = _indices(world, fixed)
    order = np.argsort(fixed["pair_index"].to_numpy() * n_pairs + pair, kind="stable")
    pair, task, init, q = pair[order], task[order], init[order], q[order]
    g = np.arange(len(q))
    first_q = np.full(n_pairs * T * N * 2, len(q))
    np.minimum.at(first_q, q, g)
    cum_questions = np.searchsorted(np.sort(first_q[first_q < len(q)]), np.arange(len(q) + 1), side="left")
    unit = (pair * T + task) * N + init
    first_u = np.full(n_pairs * T * N, len(q))
    np.minimum.at(first_u, unit, g)
    seen = np.flatnonzero(first_u < len(q))
    stratum = seen // N
    seen = seen[np.lexsort((first_u[seen], stratum))]
    compact = np.full(n_pairs * T * N, -1)
    compact[seen] = np.arange(len(seen))
    unit_stratum_label = seen // N
    new = np.r_[True, unit_stratum_label[1:] != unit_stratum_label[:-1]]
    unit_stratum = np.cumsum(new) - 1
    stratum_start = np.flatnonzero(new)
    unit_rank = np.arange(len(seen)) - stratum_start[unit_stratum]

    blocks = unit_order(episodes, names, seed)
    b_pair, b_task, b_init, b_orient, b_q = _indices(world, blocks)
    pol = {p: k for k, p in enumerate(names)}
    ep_a = (blocks["policy_a"].map(pol).to_numpy() * T + b_task) * N + b_init
    ep_b = (blocks["policy_b"].map(pol).to_numpy() * T + b_task) * N + b_init
    block = blocks["block"].to_numpy()
    block_q, block_ep = [], []
    for k in range(n_pairs):
        rows = np.flatnonzero(b_pair == k)
        rows = rows[np.argsort(block[rows], kind="stable")]
        n_blocks = int(block[rows].max()) + 1
        block_q.append(b_q[rows].reshape(n_blocks, -1))  # two units of every task per block
        block_ep.append(np.stack([ep_a[rows], ep_b[rows]], axis=1).reshape(n_blocks, -1))

    return Design(
        n_pairs=n_pairs,
        describes=len(names) * T * N,
        row_q=q,
        row_unit=compact[unit],
        cum_questions=cum_questions,
        unit_pair=seen // (T * N),
        unit_stratum=unit_stratum,
        unit_rank=unit_rank,
        stratum_start=stratum_start,
        block_q=tuple(block_q),
        block_ep=tuple(block_ep),
    )


def judge_answers(world: World, rng: np.random.Generator, nu: float, eps: float, beta: float) -> np.ndarray:
    """One run's cached answers, flat over (pair, task, init, orientation): policy_i preferred."""
    s = np.asarray(world.success, dtype=float) + 1.0
    I, J = np.triu_indices(len(s), 1)
    tie = nu * np.sqrt(s[I] * s[J])
    denom = s[I] + s[J] + tie
    p_i, p_tie = (s[I] / denom)[:, None, None], (tie / denom)[:, None, None]
    u = rng.random((len(I), world.n_tasks, world.n_inits))
    latent = np.where(u < p_i, 1, np.where(u < p_i + p_tie, 0, -1))[..., None]
    v = rng.random((len(I), world.n_tasks, world.n_inits, 2))
    decisive = (latent == 1) ^ (v < eps)
    a_preferred = v < 0.5 + beta
    on_tie = np.stack([a_preferred[..., 0], ~a_preferred[..., 1]], axis=-1)
    return np.where(latent == 0, on_tie, decisive).ravel()


def fixed_intervals(d: Design, answers: np.ndarray, prefixes: Sequence[int], V: np.ndarray,
                    tail: float = 0.025) -> np.ndarray:
    """Unit-bootstrap percentile intervals (``tail`` cut on each side: 95% by default) of
    policy_i's win rate after each prefix of the round-robin order: (len(prefixes), n_pairs, 2);
    a pair with no comparison gets (0, 1).

    Replicates share the uniforms `V` (units, n_boot) across prefixes: slot ``r`` of a task
    stratum picks one of the stratum's units seen so far if ``r`` is below their number.
    """
    row_answer = answers[d.row_q].astype(np.int64)
    U = len(d.unit_pair)
    out = np.empty((len(prefixes), d.n_pairs, 2))
    out[..., 0], out[..., 1] = 0.0, 1.0
    for c, G in enumerate(prefixes):
        if G <= 0:
            continue
        n = np.bincount(d.row_unit[:G], minlength=U)
        wins = np.bincount(d.row_unit[:G], weights=row_answer[:G], minlength=U).astype(np.int64)
        size = np.add.reduceat((n > 0).astype(np.int64), d.stratum_start)[d.unit_stratum]
        cols = np.flatnonzero(d.unit_rank < size)
        size = size[cols].astype(np.int32)[:, None]
        picks = ((V if cols.size == U else V[cols]) * size.astype(np.float32)).astype(np.int32)
        np.minimum(picks, size - 1, out=picks)  # float32 rounding may reach size itself
        picks += d.stratum_start[d.unit_stratum[cols]].astype(np.int32)[:, None]
        packed = n + (wins << _SHIFT)
        pairs = d.unit_pair[cols]
        seg = np.r_[0, np.flatnonzero(np.diff(pairs)) + 1]
        total = np.add.reduceat(packed[picks], seg, axis=0)  # (pairs present, n_boot)
        rate = (total >> _SHIFT) / (total & _LOW_BITS)
        out[c, pairs[seg]] = np.quantile(rate, [tail, 1.0 - tail], axis=1).T
    return out


def _verdicts(intervals: np.ndarray) -> np.ndarray:
    """+1 where policy_i is declared better, -1 where policy_j is, 0 undecided."""
    return np.where(intervals[..., 0] > 0.5, 1, np.where(intervals[..., 1] < 0.5, -1, 0))


def truth(world: World) -> np.ndarray:
    s = np.asarray(world.success)
    I, J = np.triu_indices(len(s), 1)
    return np.sign(s[I] - s[J]).astype(int)


def _any_wrong(verdicts: np.ndarray, true: np.ndarray) -> bool:
    return bool(np.any((verdicts != 0) & (verdicts != true)))


def _at_levels(requests: np.ndarray, values: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """The value of a step curve (last point with requests <= level) at each level."""
    return values[np.searchsorted(requests, levels, side="right") - 1]


@dataclass(frozen=True)
class Settings:
    seed: int
    alpha: float
    concurrency: int
    n_boot: int
    designs: int
    nu: float
    eps: float
    beta: float


def simulate_run(world_name: str, run: int, cfg: Settings, levels: np.ndarray | None) -> dict:
    """One run of both allocations on one simulated judge."""
    world = WORLDS[world_name]
    d = design(world_name, 10_000 * cfg.seed + run % cfg.designs)
    rng = np.random.default_rng([cfg.seed, list(WORLDS).index(world_name), run])
    answers = judge_answers(world, rng, cfg.nu, cfg.eps, cfg.beta)
    true = truth(world)
    names = policy_names(world)
    V = rng.random((len(d.unit_pair), cfg.n_boot), dtype=np.float32)

    full = len(d.row_q)
    fixed_verdict = _verdicts(fixed_intervals(d, answers, [full], V)[0])
    # The same bootstrap at the adaptive rule's guarantee: every pair at alpha / n_pairs.
    family_verdict = _verdicts(fixed_intervals(d, answers, [full], V, tail=cfg.alpha / (2 * d.n_pairs))[0])
    fixed_total = d.fixed_requests(full)

    level_pair = pair_alpha(cfg.alpha, d.n_pairs)
    states = [PairState(names[i], names[j], blocks_left=len(d.block_q[k]), alpha=level_pair,
                        horizon=d.block_q[k].size)
              for k, (i, j) in enumerate(combinations(range(len(names)), 2))]
    block_size = d.block_q[0].shape[1]
    per_round = max(1, round(cfg.concurrency / block_size))
    touched = np.zeros(len(names) * world.n_tasks * world.n_inits, dtype=bool)
    judged = [0] * d.n_pairs
    compares = 0
    history_requests, history_width = [0], [1.0]
    match = match_family = None
    wanted = np.flatnonzero(fixed_verdict != 0)
    wanted_family = np.flatnonzero(family_verdict != 0)
    while True:
        picks = allocate(states, per_round, [block_size] * len(states))
        if not picks:
            break
        for k in picks:
            b = judged[k]
            judged[k] += 1
            states[k].add(answers[d.block_q[k][b]].astype(float))
            states[k].blocks_left -= 1
            compares += d.block_q[k].shape[1]
            touched[d.block_ep[k][b]] = True
        requests = compares + int(touched.sum())
        history_requests.append(requests)
        history_width.append(float(np.mean([s.high - s.low for s in states])))
        verdict = np.array([1 if s.low > 0.5 else -1 if s.high < 0.5 else 0 for s in states])
        if match is None and np.array_equal(verdict[wanted], fixed_verdict[wanted]):
            match = requests
        if match_family is None and np.array_equal(verdict[wanted_family], family_verdict[wanted_family]):
            match_family = requests
    adaptive_verdict = np.array([1 if s.low > 0.5 else -1 if s.high < 0.5 else 0 for s in states])
    stop = history_requests[-1]
    shared = int(np.count_nonzero(adaptive_verdict[wanted] == fixed_verdict[wanted]))

    prefixes = [d.prefix_within(stop)]
    if levels is not None:
        prefixes += [d.prefix_within(r) for r in levels]
    widths = np.diff(fixed_intervals(d, answers, prefixes, V), axis=-1)[..., 0].mean(axis=1)
    out = {
        "fixed_requests": fixed_total,
        "fixed_describes": d.describes,
        "fixed_decided": int(np.count_nonzero(fixed_verdict)),
        "fixed_wrong": _any_wrong(fixed_verdict, true),
        "family_decided": int(np.count_nonzero(family_verdict)),
        "family_wrong": _any_wrong(family_verdict, true),
        "adaptive_match_family": np.nan if match_family is None else float(match_family),
        "fixed_width_equal": float(widths[0]),
        "adaptive_match": np.nan if match is None else float(match),
        "adaptive_stop": float(stop),
        "adaptive_decided": int(np.count_nonzero(adaptive_verdict)),
        "adaptive_shared": shared,
        "adaptive_describes": int(touched.sum()),
        "adaptive_wrong": _any_wrong(adaptive_verdict, true),
        "adaptive_width_stop": history_width[-1],
    }
    if levels is not None:
        out["curve_fixed"] = widths[1:]
        out["curve_adaptive"] = _at_levels(np.asarray(history_requests), np.asarray(history_width), levels)
    return out


def _chunk(job: tuple[str, range, Settings, np.ndarray | None]) -> list[dict]:
    world_name, runs, cfg, levels = job
    return [simulate_run(world_name, r, cfg, levels) for r in runs]


def figure_levels(world_name: str, cfg: Settings, n: int = 10) -> np.ndarray:
    """Request levels for the figure: geometric up to the fixed allocation's full total."""
    d = design(world_name, 10_000 * cfg.seed)
    total = d.fixed_requests(len(d.row_q))
    return np.unique(np.round(np.geomspace(total / 40, total, n)))


def summarise(results: list[dict], alpha: float) -> dict:
    def col(key):
        return np.array([r[key] for r in results], dtype=float)

    match = col("adaptive_match")
    reached = np.isfinite(match)
    fixed = col("fixed_requests")
    stop = col("adaptive_stop")
    match_family = col("adaptive_match_family")
    reached_family = np.isfinite(match_family)
    out = {
        "family_decided": float(col("family_decided").mean()),
        "family_wrong": float(col("family_wrong").mean()),
        "reached_family": float(reached_family.mean()),
        "adaptive_match_family_median": float(np.median(match_family[reached_family])) if reached_family.any() else np.nan,
        "ratio_match_family": (float(np.median(fixed[reached_family] / match_family[reached_family]))
                               if reached_family.any() else np.nan),
        "runs": len(results),
        "fixed_requests": float(np.median(fixed)),
        "fixed_describes": float(np.median(col("fixed_describes"))),
        "fixed_decided": float(col("fixed_decided").mean()),
        "reached": float(reached.mean()),
        "adaptive_match_median": float(np.median(match[reached])) if reached.any() else np.nan,
        "adaptive_match_p90": float(np.percentile(match[reached], 90)) if reached.any() else np.nan,
        "ratio_match": float(np.median(fixed[reached] / match[reached])) if reached.any() else np.nan,
        "adaptive_stop_median": float(np.median(stop)),
        "adaptive_stop_p90": float(np.percentile(stop, 90)),
        "ratio_stop": float(np.median(fixed / stop)),
        "adaptive_decided": float(col("adaptive_decided").mean()),
        "adaptive_shared": float(col("adaptive_shared").mean()),
        "adaptive_describes": float(np.median(col("adaptive_describes"))),
        "adaptive_wrong": float(col("adaptive_wrong").mean()),
        "fixed_wrong": float(col("fixed_wrong").mean()),
        "adaptive_width_stop": float(col("adaptive_width_stop").mean()),
        "fixed_width_equal": float(col("fixed_width_equal").mean()),
        "alpha": alpha,
    }
    if "curve_fixed" in results[0]:
        out["curve_fixed"] = np.mean([r["curve_fixed"] for r in results], axis=0)
        out["curve_adaptive"] = np.mean([r["curve_adaptive"] for r in results], axis=0)
    return out


ROWS = (
    ("runs", "runs", "{:.0f}"),
    ("fixed requests (median; describe+compare)", None, None),
    ("fixed, 95% per pair: pairs decided (mean)", "fixed_decided", "{:.2f}"),
    ("fixed, alpha over the ranking: pairs decided (mean)", "family_decided", "{:.2f}"),
    ("adaptive requests at the latter's decisions, median", "adaptive_match_family_median", "{:.0f}"),
    ("  share of runs that match them", "reached_family", "{:.3f}"),
    ("fixed / adaptive at that match (median)", "ratio_match_family", "{:.2f}x"),
    ("adaptive requests at the 95%-per-pair decisions, median", "adaptive_match_median", "{:.0f}"),
    ("  90th percentile", "adaptive_match_p90", "{:.0f}"),
    ("  share of runs that match them", "reached", "{:.3f}"),
    ("fixed / adaptive at the match (median)", "ratio_match", "{:.2f}x"),
    ("adaptive requests at its stop, median", "adaptive_stop_median", "{:.0f}"),
    ("  90th percentile", "adaptive_stop_p90", "{:.0f}"),
    ("  descriptions among them, median", "adaptive_describes", "{:.0f}"),
    ("fixed / adaptive at its stop (median)", "ratio_stop", "{:.2f}x"),
    ("adaptive: pairs decided (mean)", "adaptive_decided", "{:.2f}"),
    ("  of them decided by fixed too, same direction (mean)", "adaptive_shared", "{:.2f}"),
    ("runs with a pair in the wrong order, adaptive", "adaptive_wrong", "{:.3f}"),
    ("runs with a pair in the wrong order, fixed 95% per pair", "fixed_wrong", "{:.3f}"),
    ("runs with a pair in the wrong order, fixed alpha over the ranking", "family_wrong", "{:.3f}"),
    ("mean interval width, adaptive at its stop", "adaptive_width_stop", "{:.3f}"),
    ("mean interval width, fixed at equal requests", "fixed_width_equal", "{:.3f}"),
)


def print_table(summary: dict[str, dict]) -> None:
    worlds = list(summary)
    label_w = max(len(r[0]) for r in ROWS) + 2
    cells = {}
    for w, s in summary.items():
        describes = int(s["fixed_describes"])
        cells[w] = [
            f"{s['fixed_requests']:.0f} ({describes}+{s['fixed_requests'] - describes:.0f})" if key is None
            else fmt.format(s[key]) if np.isfinite(s[key]) else "-"
            for _, key, fmt in ROWS
        ]
    col_w = max(12, *(len(c) for w in worlds for c in cells[w]), *(len(w) for w in worlds)) + 2
    print("".ljust(label_w) + "".join(w.rjust(col_w) for w in worlds))
    for k, (label, _, _) in enumerate(ROWS):
        print(label.ljust(label_w) + "".join(cells[w][k].rjust(col_w) for w in worlds))


def verdict(world_name: str, s: dict) -> str:
    parts = []
    if world_name in ("paper", "demo"):
        for label, ratio, reached in (("at alpha over the ranking", "ratio_match_family", "reached_family"),
                                      ("95% per pair", "ratio_match", "reached")):
            if np.isfinite(s[ratio]):
                ok = s[ratio] >= 3.0 and s[reached] >= 0.5
                parts.append(f"the fixed allocation's decisions {label}: {s[ratio]:.2f}x fewer requests, matched in "
                             f"{s[reached]:.1%} of runs (goal >= 3x in most runs: {'met' if ok else 'NOT met'})")
            else:
                parts.append(f"the fixed allocation's decisions {label}: never matched")
    parts.append(f"{s['ratio_stop']:.2f}x fewer requests at the adaptive stop")
    ok = s["adaptive_wrong"] <= s["alpha"]
    parts.append(f"wrong orders {s['adaptive_wrong']:.3f} {'<=' if ok else '>'} alpha {s['alpha']} "
                 f"({'met' if ok else 'NOT met'})")
    return f"{world_name}: " + "; ".join(parts)


def draw_figure(path: str, summary: dict[str, dict], levels: dict[str, np.ndarray]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    fig, axes = plt.subplots(1, len(summary), figsize=(4.2 * len(summary), 3.6), squeeze=False)
    for ax, (w, s) in zip(axes[0], summary.items()):
        ax.plot(levels[w], s["curve_fixed"], "o-", label="fixed (sample_pairs)")
        ax.plot(levels[w], s["curve_adaptive"], "s-", label="adaptive (sequential)")
        ax.axvline(s["fixed_requests"], color="grey", lw=0.8, ls=":")
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())  # minor labels overlap on short log ranges
        ax.set_ylim(0, 1.02)
        ax.set_title(f"{w} ({s['runs']} runs)")
        ax.set_xlabel("judge requests (describe + compare)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("mean interval width over pairs")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> dict[str, dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=RUNS, help="simulated runs per world")
    parser.add_argument("--worlds", default=",".join(WORLDS), help=f"comma-separated, of {list(WORLDS)}")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--alpha", type=float, default=ALPHA, help="error level of the whole ranking (adaptive)")
    parser.add_argument("--concurrency", type=int, default=CONCURRENCY, help="judge requests in flight")
    parser.add_argument("--n-boot", type=int, default=N_BOOT, help="unit-bootstrap replicates (fixed)")
    parser.add_argument("--designs", type=int, default=DESIGNS, help="seeds of sample_pairs / unit_order per world")
    parser.add_argument("--nu", type=float, default=NU, help="Davidson tie parameter")
    parser.add_argument("--eps", type=float, default=EPS, help="judge error on a decisive unit")
    parser.add_argument("--beta", type=float, default=BETA, help="position bias on a tie")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), help="processes over runs")
    parser.add_argument("--figure", help="PNG/PDF path: mean interval width against requests")
    args = parser.parse_args(argv)
    worlds = [w.strip() for w in args.worlds.split(",") if w.strip()]
    unknown = sorted(set(worlds) - set(WORLDS))
    if unknown or not worlds:
        parser.error(f"unknown worlds {unknown}; choose from {list(WORLDS)}")
    if args.runs < 1 or args.designs < 1 or args.n_boot < 2:
        parser.error("--runs and --designs must be >= 1, --n-boot >= 2")
    cfg = Settings(args.seed, args.alpha, args.concurrency, args.n_boot, args.designs, args.nu, args.eps, args.beta)

    start = time.perf_counter()
    print(
        f"{args.runs} runs per world, alpha {args.alpha}, concurrency {args.concurrency} "
        f"(blocks per round = max(1, round(concurrency / block size))), judge nu {args.nu} eps {args.eps} "
        f"beta {args.beta}, {args.n_boot} bootstrap replicates, {args.designs} designs per world, "
        f"{args.workers} workers; load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs"
    )
    for w in worlds:  # built before the workers start, so forked workers inherit them
        for k in range(min(args.designs, args.runs)):
            design(w, 10_000 * args.seed + k)
    levels = {w: figure_levels(w, cfg) for w in worlds} if args.figure else {}
    step = max(1, min(50, args.runs // (4 * max(1, args.workers))))
    jobs = [(w, range(r, min(r + step, args.runs)), cfg, levels.get(w)) for w in worlds
            for r in range(0, args.runs, step)]
    if args.workers > 1:
        methods = multiprocessing.get_all_start_methods()
        ctx = multiprocessing.get_context("fork" if "fork" in methods else None)
        with ctx.Pool(args.workers) as pool:
            chunks = pool.map(_chunk, jobs, chunksize=1)
    else:
        chunks = [_chunk(job) for job in jobs]
    results: dict[str, list[dict]] = {w: [] for w in worlds}
    for job, chunk in zip(jobs, chunks):
        results[job[0]].extend(chunk)
    summary = {w: summarise(results[w], args.alpha) for w in worlds}

    print_table(summary)
    for w in worlds:
        print(verdict(w, summary[w]))
    if args.figure:
        draw_figure(args.figure, summary, levels)
        print(f"figure: {args.figure}")
    print(f"wall time {time.perf_counter() - start:.1f} s")
    return summary


if __name__ == "__main__":
    main()
