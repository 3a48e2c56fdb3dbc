"""Adaptive judging: each policy pair's units in blocks, a confidence sequence per pair, and the
rule that picks which pair is judged next.

Units and blocks. A policy pair's *unit* is one (task, init_id) both policies have rollouts for;
it is compared once, in one orientation (the swap audit asks the other one apart). Each pair's
units are laid out in a seeded order of *blocks* (``unit_order``): a block holds two fresh units
of every task (each task's units drawn without replacement), one with policy_i as A and one with
it as B (a fair coin says which is which), in a shuffled order. A pair is judged a whole block at
a time, so it is task-stratified and exactly A/B-balanced per task after every block.

Evidence. Comparison ``k`` of a block scores ``x_k`` = 1 when policy_i was preferred, else 0.
The target is ``mu``, the task-averaged probability that the judge prefers policy_i on a new
initial configuration (each side half of the time). The inits of a task are independent draws
and every block takes fresh ones; taking them without replacement does not spoil this, as a
random ordering of independent draws is a sequence of independent draws.

Confidence sequence. ``BettingSequence`` is the hedged betting confidence sequence for a bounded
mean with predictable plug-in bets (Waudby-Smith & Ramdas, JRSS-B 2024), betting on every
comparison with one stake per block, fixed before the block is judged; the stake never falls
below the one tuned to the pair's last possible comparison (its number of units), which keeps
the interval tight where close pairs are decided, near the end of their units. That stake makes the
block's capital a fair bet even though tasks differ and the judge may prefer position A: for a
candidate mean ``m``, the two comparisons of a task in the block have expectations
``mu_t + b_t`` and ``mu_t - b_t`` (``b_t`` the task's position bias), so their factors multiply to
at most ``(1 + s (mu_t - m))**2``, and by the AM-GM inequality the product over the tasks is at
most ``(1 + s (mean_t mu_t - m))**(2T)`` = 1 at ``m = mu``. So the capital at the true mean is a
nonnegative supermartingale from block to block, and by Ville's inequality the interval covers
``mu`` at every block simultaneously with probability ``1 - alpha``: looking after every block,
and stopping when it suits, keeps the guarantee. Each pair runs at ``alpha / n_pairs``
(Bonferroni): with probability at least ``1 - alpha`` no pair of the whole ranking is ever
declared in the wrong order. A pair is *decided* once its interval excludes 1/2. The target is
the policies' preference on new initial configurations, not on the rollouts at hand: the
finite-population form would certify the realised answers of these rollouts, which decides a
51/49 pair by a coin.

Which pairs. Every policy pair has to be decided: the Bradley-Terry fit and the win-rate matrix
use all of them, and win rates need not be transitive.

Allocation (``allocate``). A round asks as many whole blocks as the judge's concurrency keeps
busy; they go one by one to the open pair (undecided, blocks left) expected to be decided
soonest: a pair without comparisons first, then the fewest further comparisons until a normal
approximation of its interval, ``sqrt(2 log(2 / alpha_p) var / n)``, would exclude 1/2 at its
current estimate (``var`` the plug-in variance of a comparison). Clear pairs are settled in a
block or two; pairs near a tie get what is left, until their units or the budget run out. Ties
go to the pair listed first.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np
import pandas as pd

from r2s_eval.compare.sampling import index_episodes, pair_rng, shared_inits
from r2s_eval.errors import ConfigError, DataError

# Columns of ``unit_order`` (the adaptive form of the pairs table): those of ``sample_pairs``
# plus the block each unit belongs to. ``pair_index`` is the unit's position in its pair's order,
# ``first_checkpoint`` is -1 (which checkpoint holds a unit depends on when it is judged).
UNIT_COLUMNS = (
    "pair_index", "policy_i", "policy_j", "task", "init_id",
    "episode_a", "episode_b", "policy_a", "policy_b", "first_checkpoint", "block",
)
_GRID = np.linspace(0.0, 1.0, 2001)[1:-1]  # candidate means; 0 and 1 are excluded by the bets' bounds
_BET_CAP = 0.75  # c in the paper (1/2 or 3/4): bets at most c / m (or c / (1 - m)), so capital never hits zero


def unit_order(episodes_df: pd.DataFrame, policies: Sequence[str], seed: int) -> pd.DataFrame:
    """Every policy pair's units in seeded blocks (see the module); one row per unit.

    `episodes_df` is one arm's episode table (episode_id, policy, task, init_id). A pair has as
    many blocks as half the shared inits of its task with the fewest (the others' extra units are
    left out); a pair sharing no init on some task is an error naming it. Where a policy has
    several episodes of one (task, init), one is drawn.
    """
    policies, tasks, episodes = index_episodes(episodes_df, policies)
    frames = []
    for pi, pj in combinations(policies, 2):
        rng = pair_rng(seed, pi, pj, salt="adaptive\x00")
        queues = {}
        for task in tasks:
            inits = shared_inits(episodes, pi, pj, task)
            queues[task] = [inits[k] for k in rng.permutation(len(inits))]
        n_blocks = min(len(q) for q in queues.values()) // 2
        if n_blocks == 0:
            short = min(queues, key=lambda t: len(queues[t]))
            raise DataError(f"policies {pi!r} and {pj!r} share one init for task {short!r}; adaptive judging "
                            "needs two per task (one for each side)")
        first, second = sorted((pi, pj))
        rows = []
        for b in range(n_blocks):
            slots = []
            for task in tasks:
                first_is_a = bool(rng.integers(2))  # which of the task's two units has `first` as A
                slots += [(task, queues[task][2 * b], first_is_a), (task, queues[task][2 * b + 1], not first_is_a)]
            for k in rng.permutation(len(slots)):
                task, init, first_is_a = slots[k]
                pa, pb = (first, second) if first_is_a else (second, first)
                ea_pool, eb_pool = episodes[(pa, task)][init], episodes[(pb, task)][init]
                ea = ea_pool[int(rng.integers(len(ea_pool)))]
                eb = eb_pool[int(rng.integers(len(eb_pool)))]
                rows.append((len(rows), pi, pj, task, init, ea, eb, pa, pb, -1, b))
        frames.append(pd.DataFrame(rows, columns=list(UNIT_COLUMNS)))
    out = pd.concat(frames, ignore_index=True)
    return out.astype({"pair_index": "int64", "init_id": "int64", "first_checkpoint": "int64", "block": "int64"})


class BettingSequence:
    """The hedged betting confidence sequence for a mean in [0, 1] (module docstring), fed one
    block of scores at a time, all bet on with the stake fixed before the block: ``interval`` is
    the running intersection at level ``1 - alpha`` after the blocks so far ((0, 1) before any),
    on a grid of step 1/2000.
    """

    def __init__(self, alpha: float, horizon: int | None = None):
        if not 0.0 < alpha < 1.0:
            raise ConfigError(f"alpha must lie in (0, 1), got {alpha}")
        self.alpha = float(alpha)
        self.horizon = horizon
        self.n, self.total, self.squares = 0, 0.0, 0.0
        self.log_up = np.zeros_like(_GRID)  # log capital of bets that the mean is above each m
        self.log_down = np.zeros_like(_GRID)
        self.excluded = np.zeros(_GRID.shape, dtype=bool)  # m once its hedged capital reached 1/alpha

    @property
    def mean(self) -> float:
        """The plug-in mean of a score (1/2 before any)."""
        return (0.5 + self.total) / (self.n + 1)

    @property
    def variance(self) -> float:
        """The plug-in variance of a score (1/4 before any)."""
        return (0.25 + self.squares) / (self.n + 1)

    def add(self, scores: Sequence[float]) -> None:
        y = np.asarray(scores, dtype=float).ravel()
        if y.size == 0 or not np.all(np.isfinite(y)) or np.any((y < 0) | (y > 1)):
            raise DataError(f"a block needs scores in [0, 1], got {y.tolist()}")
        t = self.n + 1
        # One predictable stake for the whole block, sized from the scores before it.
        stake = np.sqrt(2.0 * np.log(2.0 / self.alpha) / (self.variance * t * np.log1p(t)))
        if self.horizon:  # never below the stake tuned to the most scores there can be
            stake = max(stake, np.sqrt(2.0 * np.log(2.0 / self.alpha) / (self.variance * self.horizon)))
        up = np.minimum(stake, _BET_CAP / _GRID)[:, None]
        down = np.minimum(stake, _BET_CAP / (1.0 - _GRID))[:, None]
        gap = y[None, :] - _GRID[:, None]
        self.log_up += np.log1p(up * gap).sum(axis=1)
        self.log_down += np.log1p(-down * gap).sum(axis=1)
        self.excluded |= np.logaddexp(self.log_up, self.log_down) - np.log(2.0) >= np.log(1.0 / self.alpha)
        for value in y:  # the plug-in estimates, one score at a time
            self.n += 1
            self.total += value
            self.squares += (value - self.mean) ** 2

    @property
    def interval(self) -> tuple[float, float]:
        if self.n == 0:
            return 0.0, 1.0
        inside = _GRID[~self.excluded]
        if inside.size == 0:  # only possible when the grid is too coarse for the data; say so
            raise DataError(f"confidence sequence is empty after {self.n} scores (alpha {self.alpha})")
        return float(inside[0]), float(inside[-1])


def confidence_sequence(blocks: Sequence[Sequence[float]], alpha: float) -> tuple[float, float]:
    """``BettingSequence(alpha)`` fed `blocks` (each a sequence of scores), in order: its
    interval after the last."""
    seq = BettingSequence(alpha)
    for block in blocks:
        seq.add(block)
    return seq.interval


@dataclass
class PairState:
    """One policy pair's evidence: its blocks' comparisons (1 when policy_i was preferred) and
    what they decide, at level `alpha`."""

    policy_i: str
    policy_j: str
    blocks_left: int
    alpha: float
    blocks: int = 0
    horizon: int | None = None  # the most comparisons the pair can get (tunes the bets)

    def __post_init__(self):
        self.sequence = BettingSequence(self.alpha, self.horizon)
        self.low, self.high = 0.0, 1.0

    def add(self, outcomes: Sequence[float]) -> None:
        self.sequence.add(outcomes)
        self.blocks += 1
        self.low, self.high = self.sequence.interval

    @property
    def comparisons(self) -> int:
        return self.sequence.n

    @property
    def decided(self) -> bool:
        return self.low > 0.5 or self.high < 0.5

    @property
    def winner(self) -> str | None:
        """policy_i or policy_j once decided, else None."""
        if self.low > 0.5:
            return self.policy_i
        if self.high < 0.5:
            return self.policy_j
        return None

    def comparisons_to_decide(self) -> float:
        """Further comparisons until a normal approximation of the interval would exclude 1/2
        at the current estimate (0 before any comparison: such a pair goes first)."""
        n = self.sequence.n
        if n == 0:
            return 0.0
        gap = abs(self.sequence.mean - 0.5)
        if gap == 0:
            return np.inf
        needed = 2.0 * np.log(2.0 / self.alpha) * self.sequence.variance / gap**2
        return max(needed - n, 1.0)


def pair_alpha(alpha: float, n_pairs: int) -> float:
    """Each pair's level so that the whole ranking's error stays within `alpha` (Bonferroni)."""
    if not 0.0 < alpha < 1.0:
        raise ConfigError(f"compare.alpha must lie in (0, 1), got {alpha}")
    return float(alpha) / max(1, int(n_pairs))


def allocate(pairs: Sequence[PairState], n_blocks: int, block_sizes: Sequence[int] | None = None) -> list[int]:
    """Indices into `pairs` of the next `n_blocks` blocks (a pair may get several; fewer when the
    open pairs run out of blocks). See the module for the rule; `block_sizes` (comparisons per
    block of each pair; 1 when not given) counts the blocks given this round as comparisons
    already made."""
    sizes = list(block_sizes) if block_sizes is not None else [1] * len(pairs)
    given = [0] * len(pairs)

    def priority(k: int) -> tuple[int, float]:
        p = pairs[k]
        if p.comparisons == 0:  # no evidence yet: one block first, more only where nothing is nearer
            return (0, 0.0) if given[k] == 0 else (1, np.inf)
        left = p.comparisons_to_decide() - given[k] * sizes[k]
        if given[k] and left <= 0:
            return 2, given[k]  # expected to be settled by what it got this round: last
        return 1, left

    out = []
    for _ in range(int(n_blocks)):
        open_pairs = [k for k, p in enumerate(pairs) if not p.decided and given[k] < p.blocks_left]
        if not open_pairs:
            break
        best = min(open_pairs, key=priority)  # ties: the pair listed first
        given[best] += 1
        out.append(best)
    return out
