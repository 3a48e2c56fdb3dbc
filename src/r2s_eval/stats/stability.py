"""How stable a ranking is when the evaluation is repeated, against a truth the twin knows.

The evaluation is repeated k times with the checkpoints fixed and fresh initial configurations:
each task's inits are split into k disjoint blocks, and repetition r uses block r only (its sim
rollouts, the judges' comparisons of them, and for a real evaluation its first m real trials per
task). Nothing is shared between repetitions, so their spread is what a lab would see rerunning
the evaluation.

The truth is a set of pairwise orders (`Order`: +1, the first policy of the pair is better; -1,
the second; 0, the truth cannot tell). A planted pair (a variant and the candidate whose weights
it runs) is ordered by construction, the clean one first. Every other pair is ordered by the
twin's success over many trials where the difference is beyond `z` standard errors; closer pairs
are undecided and count neither way. The twin's trials behind the truth of repetition r are the
other repetitions' (kept apart from the real evaluation it judges).

How far a share of pairs ordered as the truth can be trusted: the repetitions are the experiment's
independent replicates (disjoint inits, each ranking made from its own block alone), so each
evaluation's mean share gets a Student-t interval over the repetitions' shares, and each one's
difference from the real evaluation at ``real_trials_per_task`` the same interval over the
paired per-repetition differences (`repetition_interval`). Resampling the inits within a
repetition instead would rank from fewer distinct inits than the repetition has, and so order
fewer pairs as the truth on every resample: an interval biased low, the more so for a noisier
ranking.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from itertools import combinations

import numpy as np
import pandas as pd
from scipy.stats import t as student_t

from r2s_eval.errors import DataError, StatsError
from r2s_eval.stats.bradley_terry import bt_scores, fit_bradley_terry

Pair = tuple[str, str]  # (a, b), a before b in the line-up's sorted order
Order = dict[Pair, int]  # +1: a above b, -1: b above a, 0: tied / undecided


def pairs_of(policies: Sequence[str]) -> list[Pair]:
    return list(combinations(sorted(policies), 2))


def order_of(scores: Mapping[str, float], tol: float = 1e-9) -> Order:
    """Every pair's order under ``scores`` (higher is better; equal scores tie)."""
    return {(a, b): int(np.sign(scores[a] - scores[b])) if abs(scores[a] - scores[b]) > tol else 0
            for a, b in pairs_of(list(scores))}


def success_rates(trials: pd.DataFrame) -> tuple[pd.Series, pd.Series]:
    """Per policy, the mean over tasks of the per-task success rate, and its standard error
    (binomial within each task). ``trials``: rows with policy, task, success."""
    per_task = trials.groupby(["policy", "task"])["success"].agg(["mean", "count"])
    var = per_task["mean"] * (1 - per_task["mean"]) / per_task["count"]
    rate = per_task["mean"].groupby(level="policy").mean()
    tasks = per_task["mean"].groupby(level="policy").size()
    se = np.sqrt(var.groupby(level="policy").sum()) / tasks
    return rate, se


def truth_order(trials: pd.DataFrame, variants: Mapping[str, str], policies: Sequence[str], z: float) -> Order:
    """The truth over ``policies``: planted pairs by construction (``variants``: {variant: clean}),
    the others by the twin's success in ``trials`` where it differs by more than ``z`` standard
    errors (else 0, undecided)."""
    rate, se = success_rates(trials)
    missing = sorted(set(policies) - set(rate.index))
    if missing:
        raise StatsError(f"no real trials of {missing} behind the truth")
    out = {}
    for a, b in pairs_of(policies):
        if variants.get(a) == b or variants.get(b) == a:
            out[(a, b)] = 1 if variants.get(b) == a else -1
            continue
        gap = float(rate[a] - rate[b])
        out[(a, b)] = int(np.sign(gap)) if abs(gap) > z * float(np.hypot(se[a], se[b])) else 0
    return out


def bt_order(verdicts: pd.DataFrame, policies: Sequence[str]) -> tuple[Order, dict[str, float]]:
    """The order of the Bradley-Terry scores fitted to ``verdicts`` (policy_i, policy_j, winner)."""
    names = sorted(policies)
    index = {p: k for k, p in enumerate(names)}
    wins = np.zeros((len(names), len(names)))
    for pi, pj, winner in zip(verdicts["policy_i"].astype(str), verdicts["policy_j"].astype(str),
                              verdicts["winner"].astype(str)):
        loser = pj if winner == pi else pi
        wins[index[winner], index[loser]] += 1
    scores = dict(zip(names, (float(s) for s in bt_scores(fit_bradley_terry(wins, names=names)))))
    return order_of(scores), scores


def error_weight(sign: int, truth: int) -> float:
    """How far an order's ``sign`` for a pair the truth decides goes against the truth's: 1 the
    other way, 0.5 a tie, 0 the same way."""
    return 1.0 if sign == -truth else 0.5 if sign == 0 else 0.0


def pair_label(pair: Pair) -> str:
    return f"{pair[0]} vs {pair[1]}"


def agreement(order: Order, truth: Order) -> dict:
    """How ``order`` stands against ``truth`` on the pairs the truth decides: the share ordered
    as the truth (a tie counts half), the Kendall distance (pairs against it, a tie a half) and
    whether the two agree on every decided pair."""
    decided = [pair for pair, sign in truth.items() if sign]
    if not decided:
        return {"decided_pairs": 0, "share": None, "kendall_distance": None, "equal": None}
    against = sum(error_weight(order[p], truth[p]) for p in decided)
    return {"decided_pairs": len(decided), "share": 1 - against / len(decided), "kendall_distance": against,
            "equal": against == 0}


def adjacent_pairs(rate: Mapping[str, float], variants: Mapping[str, str]) -> list[Pair]:
    """Neighbours in the truth's order: candidates by success, each variant right below the
    candidate whose weights it runs (where its success would place it above)."""
    ranked = [p for p in sorted(rate, key=lambda p: (-rate[p], p)) if p not in variants]
    for variant in sorted(variants, key=lambda v: (-rate[v], v)):
        clean = variants[variant]
        below = ranked[ranked.index(clean) + 1:]
        at = ranked.index(clean) + 1 + next((k for k, p in enumerate(below) if rate[p] < rate[variant]), len(below))
        ranked.insert(at, variant)
    return [tuple(sorted(pair)) for pair in zip(ranked, ranked[1:])]


def repeated(orders: Sequence[Order], truths: Sequence[Order], pairs: Sequence[Pair]) -> dict:
    """Over k repetitions (``orders[r]`` judged against ``truths[r]``): how often the ranking
    equals the truth, the mean Kendall distance and agreement share, and per pair of ``pairs``
    its flip rate (the share of repetitions on the minority side of that pair's order, a tie
    counting half to each: 0 = always the same order, 0.5 = a coin) and the share of
    repetitions ordering it against the truth (where the truth decides it; a tie counts half);
    ``errors``: every decided pair's errors over the repetitions, ``repeated_errors`` those
    against the truth in more than half of them."""
    if len(orders) != len(truths) or not orders:
        raise StatsError("one truth per repetition, at least one repetition")
    cards = [agreement(o, t) for o, t in zip(orders, truths)]
    judged = [c for c in cards if c["share"] is not None]
    out = {"repetitions": len(orders),
           "equal_share": float(np.mean([c["equal"] for c in judged])) if judged else None,
           "kendall_distance": float(np.mean([c["kendall_distance"] for c in judged])) if judged else None,
           "agreement": float(np.mean([c["share"] for c in judged])) if judged else None,
           "per_repetition": cards, "errors": errors_by_pair(orders, truths), "pairs": {}}
    out["repeated_errors"] = {pair: n for pair, n in out["errors"].items() if n > len(orders) / 2}
    for pair in pairs:
        signs = np.array([o[pair] for o in orders], dtype=float)
        above = float(np.sum(signs > 0) + 0.5 * np.sum(signs == 0))
        decided = [(o[pair], t[pair]) for o, t in zip(orders, truths) if t[pair]]
        wrong = float(np.mean([error_weight(s, t) for s, t in decided])) if decided else None
        out["pairs"][pair_label(pair)] = {
            "flip_rate": min(above, len(orders) - above) / len(orders), "against_truth": wrong,
            "truth_decided": len(decided), "first_above": above}
    return out


def errors_by_pair(orders: Sequence[Order], truths: Sequence[Order]) -> dict[str, float]:
    """Per pair the truth decides in some repetition: in how many repetitions the ranking orders it
    against the truth (a tie counts half), pairs never against it left out. An error that comes
    back in most repetitions is a bias of the evaluation, not noise: more repetitions repeat it."""
    counts: dict[str, float] = {}
    for order, truth in zip(orders, truths):
        for pair, sign in truth.items():
            if sign and order[pair] != sign:
                counts[pair_label(pair)] = counts.get(pair_label(pair), 0.0) + error_weight(order[pair], sign)
    return dict(sorted(counts.items(), key=lambda item: (-item[1], item[0])))


def repetition_interval(values: Sequence[float | None], level: float,
                        bounds: tuple[float, float] = (0.0, 1.0)) -> list[float] | None:
    """The Student-t ``level`` interval of the mean of ``values``, one per independent repetition
    (None ones left out), clipped to ``bounds``; None with fewer than two values."""
    x = np.asarray([v for v in values if v is not None], dtype=float)
    if len(x) < 2:
        return None
    half = float(student_t.ppf(0.5 + level / 2, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x)))
    return [max(bounds[0], float(x.mean()) - half), min(bounds[1], float(x.mean()) + half)]


def beside(card: Mapping, reference: Mapping, level: float) -> dict | None:
    """An evaluation's mean share minus the ``reference``'s, over the repetitions whose truth decides
    a pair, with the interval of the paired per-repetition differences; None where they share none."""
    pairs = [(c["share"], r["share"]) for c, r in zip(card["per_repetition"], reference["per_repetition"])
             if c["share"] is not None and r["share"] is not None]
    if not pairs:
        return None
    differences = [c - r for c, r in pairs]
    return {"difference": float(np.mean(differences)), "repetitions": len(differences),
            "interval": repetition_interval(differences, level, bounds=(-1.0, 1.0))}


def blocks(inits_per_task: int, repetitions: int, start: int = 0) -> list[range]:
    """Each repetition's init ids: k disjoint blocks of inits_per_task // k from ``start`` (the
    rest unused)."""
    size = inits_per_task // repetitions
    return [range(start + r * size, start + (r + 1) * size) for r in range(repetitions)]


def real_side_inits(inits_per_task: int, real_inits_per_task: int | None) -> int:
    """How many of each task's inits the real side rolls out (``rollout.real_inits_per_task``, a
    prefix of the sim's; None: all of them)."""
    return inits_per_task if real_inits_per_task is None else min(int(real_inits_per_task), inits_per_task)


def sim_blocks(parts: Sequence[range], inits_per_task: int, real_inits_per_task: int) -> list[list[int]]:
    """Each repetition's sim inits: its real block and its share of the inits that only the sim
    rolls out (``real_inits_per_task`` up to ``inits_per_task``), so a judge ranks from as many
    sim rollouts as the experiment runs while the real side keeps its trials."""
    extra = blocks(inits_per_task - real_inits_per_task, len(parts), start=real_inits_per_task)
    return [[*part, *more] for part, more in zip(parts, extra)]


def _spans(ids: Sequence[int]) -> str:
    """Init ids as runs: [0..19, 180..219] -> '0-19, 180-219'."""
    runs, start = [], None
    for k, i in enumerate(ids):
        if start is None:
            start = i
        if k + 1 == len(ids) or ids[k + 1] != i + 1:
            runs.append(f"{start}-{i}")
            start = None
    return ", ".join(runs)


def stability_summary(real: pd.DataFrame, verdicts: dict[str, pd.DataFrame], *, inits_per_task: int,
                      repetitions: int, real_trials_per_task: int, trials_curve, truth_z: float,
                      variants: dict[str, str], sim: pd.DataFrame | None = None,
                      networks_in_twin: pd.DataFrame | None = None, level: float | None = None,
                      real_inits_per_task: int | None = None) -> dict:
    """``real``: every real trial (policy, task, init_id, success); ``verdicts``: per judge its
    verdicts (policy_i, policy_j, winner, task, init_id).

    ``real_inits_per_task`` (None: ``inits_per_task``): the inits the real side rolls out, the
    first of the sim's. The real blocks split those; each repetition's sim block is its real block
    plus its share of the sim-only inits beyond them (`sim_blocks`), as a lab runs many more sim
    rollouts than real trials (the paper: 200 against 20 per task). The sim-only inits have no
    real trials, so no truth rests on the inits a repetition's sim ranks from.

    With ``sim`` (the judged sim rollouts: policy, task, init_id, success) two more views split a
    judge's errors into the sim's and its own: ``sim success``, the ranking by the success of each
    repetition's own sim rollouts (what a judge that only read outcomes would give), against the
    real truth; and ``against_sim_truth``, each judge against the truth the sim itself holds (the
    planted pairs, the others by the sim's success over the other repetitions' rollouts).

    With ``networks_in_twin`` (the same checkpoints the sim ranks, pi^S, rolled out in the twin
    from the same inits: policy, task, init_id, success) ``against_networks_in_twin`` holds the
    sim's success ranking and each judge against the twin's truth of those networks (the planted
    pairs, the others by their twin success over the other repetitions' inits; a candidate without
    rollouts there, one whose weights come from elsewhere, leaves its pairs undecided in that
    view). The real truth is pi^R's, another checkpoint per candidate trained on other data;
    where the two truths part, the candidates' order is the training's, which no sim or judge of
    pi^S can see.

    With ``level``, each evaluation's card gets ``agreement_interval`` (`repetition_interval` of
    its per-repetition shares) and ``beside_real`` holds each one's mean share minus that of the
    real evaluation at ``real_trials_per_task``, with the interval of the paired differences."""
    policies = sorted(real["policy"].astype(str).unique())
    in_real = real_side_inits(inits_per_task, real_inits_per_task)
    parts = blocks(in_real, repetitions)
    sim_parts = sim_blocks(parts, inits_per_task, in_real)
    size = len(parts[0])
    if real_trials_per_task > size or max(trials_curve) > size:
        raise DataError(f"a repetition has {size} inits per task, fewer than the real trials asked "
                        f"({real_trials_per_task}, curve up to {max(trials_curve)})")
    in_twin = set() if networks_in_twin is None else set(networks_in_twin["policy"].astype(str))
    crossed = [p for p in policies if p in in_twin]
    all_rate, _ = success_rates(real)
    pairs = adjacent_pairs(all_rate.to_dict(), variants)
    truths, real_orders = [], {m: [] for m in sorted({*trials_curve, real_trials_per_task})}
    sim_truths, sim_orders, twin_truths = [], [], []
    judge_orders = {judge: [] for judge in verdicts}
    comparisons = {judge: [] for judge in verdicts}
    for part, sim_part in zip(parts, sim_parts):
        inside = real["init_id"].isin(part)
        truths.append(truth_order(real[~inside], variants, policies, truth_z))
        if sim is not None:
            in_sim = sim["init_id"].isin(sim_part)
            sim_truths.append(truth_order(sim[~in_sim], variants, policies, truth_z))
            sim_orders.append(order_of(success_rates(sim[in_sim])[0].to_dict()))
        if networks_in_twin is not None:  # pairs with a candidate not crossed stay undecided there
            known = truth_order(networks_in_twin[~networks_in_twin["init_id"].isin(part)], variants, crossed, truth_z)
            twin_truths.append({pair: known.get(pair, 0) for pair in pairs_of(policies)})
        for m in real_orders:
            first = real[real["init_id"].isin(part[:m])]
            real_orders[m].append(order_of(success_rates(first)[0].to_dict()))
        for judge, table in verdicts.items():
            own = table[table["init_id"].astype(int).isin(sim_part)]
            if own.empty:
                raise DataError(f"judge {judge}: no comparison from the inits of repetition {len(comparisons[judge])} "
                                f"({_spans(sim_part)})")
            judge_orders[judge].append(bt_order(own, policies)[0])
            comparisons[judge].append(len(own))
    evaluations = {f"real {m}": repeated(orders, truths, pairs) for m, orders in real_orders.items()}
    if sim is not None:
        evaluations["sim success"] = repeated(sim_orders, truths, pairs)
    evaluations.update({judge: repeated(orders, truths, pairs) for judge, orders in judge_orders.items()})
    beside_real = None
    if level is not None:
        reference = evaluations[f"real {real_trials_per_task}"]
        for card in evaluations.values():
            card["agreement_interval"] = repetition_interval([c["share"] for c in card["per_repetition"]], level)
        beside_real = {"reference": f"real {real_trials_per_task}", "level": level,
                       "paired": "per repetition, over its own inits; a Student-t interval over the repetitions",
                       "differences": {name: diff for name, card in evaluations.items()
                                       if card is not reference and (diff := beside(card, reference, level))}}
    tasks = int(real["task"].nunique())
    out = {
        "repetitions": repetitions, "inits_per_repetition_and_task": size,
        "sim_inits_per_repetition_and_task": len(sim_parts[0]), "tasks": tasks, "policies": policies,
        "variants": variants, "real_trials_per_task": real_trials_per_task,
        "truth": {"definition": "planted pairs by construction; others by the twin's success over the other "
                                f"repetitions' real trials where it differs by more than {truth_z} standard errors",
                  "real_trials_per_policy": tasks * size * (repetitions - 1),
                  "success_all_trials": {p: float(all_rate[p]) for p in policies},
                  "decided_pairs": [sum(1 for s in t.values() if s) for t in truths],
                  "adjacent_pairs": [pair_label(pair) for pair in pairs]},
        "behind_each_repetition": {"sim_rollouts_per_policy": tasks * len(sim_parts[0]),
                                   "real_trials_per_policy": {m: tasks * m for m in real_orders},
                                   "comparisons": {j: [int(n) for n in c] for j, c in comparisons.items()}},
        "evaluations": evaluations,
        **({"beside_real": beside_real} if beside_real is not None else {}),
    }
    if sim is not None:
        out["against_sim_truth"] = {judge: repeated(orders, sim_truths, pairs) for judge, orders in judge_orders.items()}
        out["truth"]["sim_success_all_rollouts"] = {p: float(r) for p, r in success_rates(sim)[0].items()}
    if networks_in_twin is not None:
        rankings = {**({"sim success": sim_orders} if sim is not None else {}), **judge_orders}
        out["against_networks_in_twin"] = {name: repeated(orders, twin_truths, pairs) for name, orders in rankings.items()}
        out["truth"]["networks_in_twin_success_all_rollouts"] = {
            p: float(r) for p, r in success_rates(networks_in_twin)[0].items()}
        out["truth"]["networks_in_twin_left_out"] = [p for p in policies if p not in crossed]
    return out
