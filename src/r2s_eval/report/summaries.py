"""Numbers behind the tables and figures, computed from the pipeline's artefacts.

Pure functions of DataFrames (no file access), so each one is testable on a few
hand-made rows. Rates are fractions in [0, 1]; the tables turn them into percent.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from r2s_eval.compare import wins_at_checkpoints
from r2s_eval.errors import ConfigError, DataError
from r2s_eval.stats import (
    OUTCOME_CATEGORIES,
    fleiss,
    majority_letters,
    order_swap_consistency,
    outcome_category,
    position_bias,
    shuffled_label_control,
    unanimous,
    unit_share,
    vote_table,
)


def _require(df: pd.DataFrame, cols: Sequence[str], what: str) -> None:
    lacking = [c for c in cols if c not in df.columns]
    if lacking:
        raise DataError(f"{what} lacks columns {lacking} (has {list(df.columns)})")


def _nan_to_none(value: float) -> float | None:
    return None if value is None or (isinstance(value, float) and math.isnan(value)) else float(value)


# ----------------------------------------------------------------------- tasks


def task_summary(index: pd.DataFrame, replay_log: pd.DataFrame) -> pd.DataFrame:
    """Per task: real trajectories (ingested episodes), sim trajectories (successful replays)
    and the replay success rate.

    ``index`` is ingest's episode index (episode_index, task); ``replay_log`` is replay's log
    (episode_index, task, success). Every ingested episode must have been replayed.
    Returns columns task, real, sim, replay_success (fraction), sorted by task.
    """
    _require(index, ["episode_index", "task"], "episode index")
    _require(replay_log, ["episode_index", "task", "success"], "replay log")
    missing = sorted(set(index["episode_index"]) - set(replay_log["episode_index"]))
    if missing:
        raise DataError(f"replay log has no row for ingested episodes {missing[:10]}")
    real = index.groupby("task").size().rename("real")
    log = replay_log[replay_log["episode_index"].isin(index["episode_index"])]
    sim = log.groupby("task")["success"].agg(["sum", "size"])
    table = pd.concat([real, sim["sum"].rename("sim")], axis=1).fillna(0).astype(int)
    table["replay_success"] = table["sim"] / sim["size"].reindex(table.index)
    return table.rename_axis("task").reset_index().sort_values("task", ignore_index=True)


# ------------------------------------------------------------ real vs sim success


def success_by_task(reference: pd.DataFrame, sim_episodes: pd.DataFrame) -> pd.DataFrame:
    """Real and sim success rate per (policy, task), plus each policy's total.

    ``reference``: the reference table (policy, task, trials, successes); ``sim_episodes``:
    sim rollout episodes (policy, task, success). Returns one row per (policy, task) that
    either side has, with columns policy, task, real, sim (fractions; NaN where a side lacks
    that cell), real_trials, sim_trials, and rows with task ``"total"`` holding the mean of
    the per-task rates over the tasks a side has (the method's policy-level performance:
    every task weighs the same) and the summed trials.
    """
    _require(reference, ["policy", "task", "trials", "successes"], "reference success table")
    _require(sim_episodes, ["policy", "task", "success"], "sim rollout episodes")
    real = reference.groupby(["policy", "task"])[["successes", "trials"]].sum().add_suffix("_real")
    sim = sim_episodes.assign(success=sim_episodes["success"].astype(bool)).groupby(["policy", "task"])["success"].agg(
        successes_sim="sum", trials_sim="size")
    cells = real.join(sim, how="outer")
    rates = pd.DataFrame({
        "real": cells["successes_real"] / cells["trials_real"].where(cells["trials_real"] > 0),
        "sim": cells["successes_sim"] / cells["trials_sim"].where(cells["trials_sim"] > 0),
        "real_trials": cells["trials_real"].fillna(0).astype(int),
        "sim_trials": cells["trials_sim"].fillna(0).astype(int),
    })
    by_policy = rates.groupby(level="policy")
    totals = pd.concat([by_policy[["real", "sim"]].mean(), by_policy[["real_trials", "sim_trials"]].sum()], axis=1)
    totals.index = pd.MultiIndex.from_product([totals.index, ["total"]], names=["policy", "task"])
    return pd.concat([rates, totals])[["real", "sim", "real_trials", "sim_trials"]].reset_index()


def success_gaps(success: pd.DataFrame) -> pd.DataFrame:
    """Per task column (and ``"total"``): mean |real - sim| and the largest gap over policies,
    in percentage points, over the policies that have both sides. Index: task."""
    both = success.dropna(subset=["real", "sim"])
    gap = (100 * (both["real"] - both["sim"]).abs()).groupby(both["task"])
    return pd.DataFrame({"mean_abs_pp": gap.mean(), "max_abs_pp": gap.max()})


# ------------------------------------------------------------------ judge audit


def _annotation_votes(annotations: pd.DataFrame, known: set[str], source: str) -> pd.DataFrame:
    """One row per annotation: pair (the two episodes in the orientation of the pair's first
    annotation), letter (for that orientation) and annotator; rows checked and named in errors."""
    _require(annotations, ["episode_a", "episode_b", "choice"], f"{source}")
    flip = {"A": "B", "B": "A"}
    who = (annotations["annotator"].astype(str).tolist() if "annotator" in annotations.columns
           else [f"row {k}" for k in range(len(annotations))])  # without names, every row its own annotator
    oriented: dict[frozenset, tuple[str, str]] = {}
    seen: dict[tuple, int] = {}
    rows = []
    for row, (ea, eb, choice, annotator) in enumerate(zip(
            annotations["episode_a"].astype(str), annotations["episode_b"].astype(str),
            annotations["choice"].astype(str).str.strip().str.upper(), who)):
        if choice not in flip:
            raise DataError(f"{source}, row {row} (episodes {ea} / {eb}): choice must be A or B, got {choice!r}")
        for e in (ea, eb):
            if e not in known:
                raise DataError(f"{source}, row {row}: episode {e} has no sim rollout")
        if ea == eb:
            raise DataError(f"{source}, row {row}: episode {ea} is compared with itself")
        pair = oriented.setdefault(frozenset((ea, eb)), (ea, eb))
        if (annotator, pair) in seen:
            raise DataError(f"{source}, rows {seen[(annotator, pair)]} and {row}: annotator {annotator} answered "
                             f"episodes {ea} / {eb} twice")
        seen[(annotator, pair)] = row
        rows.append((pair, choice if pair == (ea, eb) else flip[choice], annotator))
    return pd.DataFrame(rows, columns=["pair", "letter", "annotator"])


def _pair_units(pairs: Sequence[tuple[str, str]], sim_episodes: pd.DataFrame) -> list:
    """The (task, init) of each pair of rollouts; without those columns, each pair its own unit."""
    if {"task", "init_id"} <= set(sim_episodes.columns):
        unit = dict(zip(sim_episodes["episode_id"].astype(str),
                        zip(sim_episodes["task"].astype(str), sim_episodes["init_id"].astype(str))))
        return [unit[a] for a, _ in pairs]
    return [("", f"{a}/{b}") for a, b in pairs]


def human_agreement(verdicts: pd.DataFrame, annotations: pd.DataFrame, sim_episodes: pd.DataFrame, *,
                    source: str = "annotations", n_boot: int, level: float, seed: int) -> dict:
    """Human annotators among themselves and against the judge, overall and by outcome category.

    ``annotations``: one row per (pair, annotator) with episode_a, episode_b, choice ('A' or 'B'
    for the videos in that order) and optionally annotator (without it, each row counts as its own
    annotator). Pairs are unordered: an annotation in the other order counts with its letter
    flipped. Among the annotators: the majority vote per pair (``pairs``: the votes and the
    majority's episode, None for a tie), the share of unanimous pairs and Fleiss' kappa
    (:func:`~r2s_eval.stats.fleiss`). Against the judge: the
    share of its verdicts on annotated pairs with a majority that pick the majority's video
    (every verdict counts, in whichever order the judge saw the pair); annotated pairs the judge
    never compared (e.g. an excluded comparison) are counted, not scored. Shares carry unit
    bootstrap intervals over the (task, init) units (:func:`~r2s_eval.stats.unit_share`).
    ``source`` names the file in errors.
    """
    success = dict(zip(sim_episodes["episode_id"].astype(str), sim_episodes["success"].astype(bool)))
    votes_long = _annotation_votes(annotations, set(success), source)
    votes = vote_table(votes_long["pair"], votes_long["letter"])
    pairs = list(votes.index)
    majority = majority_letters(votes)
    winner = {p: (p[0] if m == "A" else p[1]) for p, m in majority.items() if m is not None}
    category = {p: outcome_category(success[p[0]], success[p[1]]) for p in pairs}
    units = dict(zip(pairs, _pair_units(pairs, sim_episodes)))
    shares = {"n_boot": n_boot, "level": level, "seed": seed}

    ea, eb = verdicts["episode_a"].astype(str).tolist(), verdicts["episode_b"].astype(str).tolist()
    letters = verdicts["verdict"].astype(str).str.strip().str.upper().tolist()
    key = {frozenset(p): p for p in pairs}
    judged = [key.get(frozenset((a, b))) for a, b in zip(ea, eb)]
    scored = [k for k, p in enumerate(judged) if p in winner]
    hits = [(ea[k] if letters[k] == "A" else eb[k]) == winner[judged[k]] for k in scored]
    verdict_units = _units(verdicts)
    judged_pairs = {p for p in judged if p is not None}

    def block(keep: set) -> dict:
        sub = votes.loc[[p for p in pairs if p in keep]]
        agree = [k for k, s in enumerate(scored) if judged[s] in keep]
        same = unanimous(sub)
        out = {"n_pairs": len(sub), "n_majority_pairs": int(majority.loc[sub.index].notna().sum()),
               "unanimous": unit_share(same.to_numpy(), [units[p] for p in same.index], **shares),
               "fleiss": fleiss(sub),
               "judge_agreement": unit_share([hits[k] for k in agree], [verdict_units[scored[k]] for k in agree],
                                             **shares)}
        out["judge_agreement"]["n_pairs_judged"] = len({judged[scored[k]] for k in agree})
        return out

    detail = {"source": source, "n_annotations": len(votes_long), "n_annotators": int(votes_long["annotator"].nunique()),
              "votes_per_pair": {str(n): int(c) for n, c in (votes["A"] + votes["B"]).value_counts().sort_index().items()},
              "n_tied_pairs": int(majority.isna().sum()), "n_unjudged_pairs": len(set(pairs) - judged_pairs),
              **block(set(pairs)),
              "pairs": [{"episode_a": p[0], "episode_b": p[1], "votes_a": int(votes.at[p, "A"]),
                         "votes_b": int(votes.at[p, "B"]), "majority": winner.get(p), "category": category[p]}
                        for p in pairs],
              "by_category": {c: block({p for p in pairs if category[p] == c})
                              for c in OUTCOME_CATEGORIES if c in category.values()}}
    return {"human_agreement": detail["judge_agreement"]["share"], "n_annotated_pairs": len(pairs),
            "n_annotations": len(votes_long), "human": detail}


def _present(verdicts: pd.DataFrame, candidates: Sequence[str]) -> str | None:
    return next((c for c in candidates if c in verdicts.columns), None)


def _answered(column: pd.Series) -> np.ndarray:
    """Rows that carry a swapped answer: not null and not empty (the judge stage writes "" for
    pairs it did not audit or whose swapped answer was invalid)."""
    return (column.notna() & (column.astype(str).str.strip() != "")).to_numpy()


def swap_consistency(verdicts: pd.DataFrame, letter_columns: Sequence[str], winner_columns: Sequence[str]) -> dict:
    """Order-swap consistency from whichever swapped-answer column the verdicts carry.

    A letter column holds the answer given with the two videos shown in swapped order (the
    answer is consistent when the letters differ); a winner column holds the policy picked in
    the swapped query (consistent when it equals ``winner``). Rows without a swapped answer
    (null or empty: not audited) are skipped; no such column or no audited row gives None.
    """
    letter_col, winner_col = _present(verdicts, letter_columns), _present(verdicts, winner_columns)
    none = {"swap_consistency": None, "n_swapped": 0, "swap_column": letter_col or winner_col}
    if letter_col is not None:
        audited = verdicts[_answered(verdicts[letter_col])]
        if not len(audited):
            return none
        rate = order_swap_consistency(audited["verdict"].tolist(), audited[letter_col].tolist())
        return {"swap_consistency": rate, "n_swapped": len(audited), "swap_column": letter_col}
    if winner_col is not None:
        audited = verdicts[_answered(verdicts[winner_col])]
        if not len(audited):
            return none
        same = audited[winner_col].astype(str).to_numpy() == audited["winner"].astype(str).to_numpy()
        return {"swap_consistency": float(same.mean()), "n_swapped": len(audited), "swap_column": winner_col}
    return none


def _units(verdicts: pd.DataFrame) -> list:
    """Each comparison's unit, (task, init_id); verdicts without them: each comparison its own."""
    if "task" in verdicts.columns and "init_id" in verdicts.columns:
        return list(zip(verdicts["task"].astype(str), verdicts["init_id"].astype(str)))
    return [("", str(k)) for k in range(len(verdicts))]


def outcome_agreement(verdicts: pd.DataFrame, success: dict[str, bool], *, n_boot: int,
                      level: float, seed: int) -> dict:
    """On pairs where one rollout succeeded and the other failed (sim outcomes): the share of
    verdicts preferring the successful one, with its unit-bootstrap interval over the
    distinct (task, init) units (:func:`~r2s_eval.stats.unit_share`)."""
    ea, eb = verdicts["episode_a"].astype(str).to_numpy(), verdicts["episode_b"].astype(str).to_numpy()
    sa = np.array([success[e] for e in ea], dtype=bool)
    sb = np.array([success[e] for e in eb], dtype=bool)
    picked_a = verdicts["verdict"].astype(str).str.strip().str.upper().to_numpy() == "A"
    mixed = sa != sb
    hits = np.where(picked_a, sa, sb)[mixed]
    units = [u for u, m in zip(_units(verdicts), mixed) if m]
    return unit_share(hits, units, n_boot=n_boot, level=level, seed=seed)


def planted_order_agreement(verdicts: pd.DataFrame, success: dict[str, bool], planted_order: Sequence[str] | None,
                            *, n_boot: int, level: float, seed: int) -> dict | None:
    """On pairs that both succeeded in the sim between two policies of ``planted_order`` (best
    first): the share of verdicts preferring the policy placed earlier, with its unit-bootstrap
    interval. Only there: between two failures a built-in judge may call a tie (docs/judges.md,
    "Success before style"). None when no order is given."""
    if not planted_order:
        return None
    rank = {str(p): k for k, p in enumerate(planted_order)}
    pi, pj = verdicts["policy_i"].astype(str).to_numpy(), verdicts["policy_j"].astype(str).to_numpy()
    both = np.array([success[a] and success[b] for a, b in zip(verdicts["episode_a"].astype(str),
                                                                verdicts["episode_b"].astype(str))], dtype=bool)
    ranked = np.array([a in rank and b in rank for a, b in zip(pi, pj)], dtype=bool)
    keep = both & ranked
    better = np.array([a if rank.get(a, 0) < rank.get(b, 0) else b for a, b in zip(pi, pj)])
    hits = (verdicts["winner"].astype(str).to_numpy() == better)[keep]
    units = [u for u, k in zip(_units(verdicts), keep) if k]
    out = unit_share(hits, units, n_boot=n_boot, level=level, seed=seed)
    out["planted_order"] = [str(p) for p in planted_order]
    out["n_unranked_pairs"] = int((both & ~ranked).sum())  # such pairs with a policy outside the order
    return out


def planted_quality(verdicts: pd.DataFrame, success: dict[str, bool], variants: Mapping[str, str], *,
                    fit: pd.DataFrame | None = None, reference_ci: Mapping[str, tuple] | None = None,
                    n_boot: int, level: float, seed: int) -> list[dict]:
    """Per variant (``variants``: {variant: the candidate whose weights it runs, the clean one}),
    on the comparisons of the two whose rollouts both succeeded in the sim: the share of verdicts
    preferring the clean run, with its unit-bootstrap interval. Only there: the built-in judges
    weigh how a run moved between two successes, never between two failures, which they call a
    tie or compare by how far each got (docs/judges.md, "Success before style"). With ``fit`` (the judge's BT
    table), whether the two scores' intervals at the last checkpoint are apart with the clean one
    above (``bt_separated``); with ``reference_ci`` ({policy: (low, high)}, the reference's
    success intervals), whether those overlap (``success_overlap``): a quality difference the
    judge sees where success cannot tell the two apart."""
    pi, pj = verdicts["policy_i"].astype(str).to_numpy(), verdicts["policy_j"].astype(str).to_numpy()
    both = np.array([success[a] and success[b] for a, b in zip(verdicts["episode_a"].astype(str),
                                                                verdicts["episode_b"].astype(str))], dtype=bool)
    winner = verdicts["winner"].astype(str).to_numpy()
    units = _units(verdicts)
    last = last_checkpoint(fit) if fit is not None else None
    out = []
    for variant, clean in sorted(variants.items()):
        pair = ((pi == variant) & (pj == clean)) | ((pi == clean) & (pj == variant))
        keep = pair & both
        card = unit_share(winner[keep] == clean, [u for u, k in zip(units, keep) if k], n_boot=n_boot, level=level,
                          seed=seed)
        card.update(variant=variant, clean=clean, n_pair_verdicts=int(pair.sum()))
        if last is not None and {variant, clean} <= set(last.index):
            card.update(bt_clean=[float(last.loc[clean, c]) for c in ("score", "ci_low", "ci_high")],
                        bt_variant=[float(last.loc[variant, c]) for c in ("score", "ci_low", "ci_high")])
            card["bt_separated"] = bool(last.loc[clean, "ci_low"] > last.loc[variant, "ci_high"])
        if reference_ci and variant in reference_ci and clean in reference_ci:
            (lo_c, hi_c), (lo_v, hi_v) = reference_ci[clean], reference_ci[variant]
            card["success_ci_clean"], card["success_ci_variant"] = [lo_c, hi_c], [lo_v, hi_v]
            card["success_overlap"] = bool(max(lo_c, lo_v) <= min(hi_c, hi_v))
        out.append(card)
    return out


def shuffled_labels(verdicts: pd.DataFrame, *, n_permutations: int, n_boot: int, level: float,
                    seed: int) -> dict | None:
    """The shuffled-label control of the BT fit (:func:`~r2s_eval.stats.shuffled_label_control`)
    on all judged comparisons; None without (task, init_id) columns or permutations."""
    if n_permutations <= 0 or not {"task", "init_id"} <= set(verdicts.columns):
        return None
    pi, pj = verdicts["policy_i"].astype(str), verdicts["policy_j"].astype(str)
    policies = sorted(set(pi) | set(pj))
    return shuffled_label_control(
        pi.tolist(), pj.tolist(), (verdicts["winner"].astype(str) == pi).to_numpy(),
        verdicts["task"].astype(str).tolist(),
        verdicts["init_id"].astype(str).tolist(), policies=policies, n_permutations=n_permutations, n_boot=n_boot,
        level=level, seed=seed,
    )


def judge_audit(verdicts: pd.DataFrame, sim_episodes: pd.DataFrame, *, annotations: pd.DataFrame | None = None,
                annotations_source: str = "annotations", swapped_letter_columns: Sequence[str] = (),
                swapped_winner_columns: Sequence[str] = (), planted_order: Sequence[str] | None = None,
                planted_variants: Mapping[str, str] | None = None, fit: pd.DataFrame | None = None,
                reference_ci: Mapping[str, tuple] | None = None,
                n_boot: int, ci_level: float, seed: int, shuffled_permutations: int) -> dict:
    """How far one judge can be trusted beyond the ranking metrics: its report card.

    Position bias (share of A answers, overall and on pairs whose two rollouts had the same
    outcome), order-swap consistency where the verdicts carry swapped answers, agreement
    with human annotators where annotations are given (``human_agreement``: the share, and
    ``human``: the annotators' own agreement and everything by outcome category), agreement with the sim outcomes on
    mixed-outcome pairs (``outcome_agreement``), agreement with a planted policy order on
    same-outcome pairs (``planted_order_agreement``, None without ``planted_order``), planted
    quality per variant (``planted_quality``: :func:`planted_quality`; empty without variants) and the
    shuffled-label control of the BT fit (``shuffled_label_control``). Missing quantities
    are None; each share comes with the counts it rests on.
    """
    _require(verdicts, ["episode_a", "episode_b", "verdict", "winner"], "verdicts")
    _require(sim_episodes, ["episode_id", "success"], "sim rollout episodes")
    success = dict(zip(sim_episodes["episode_id"].astype(str), sim_episodes["success"].astype(bool)))
    unknown = sorted((set(verdicts["episode_a"].astype(str)) | set(verdicts["episode_b"].astype(str))) - set(success))
    if unknown:
        raise DataError(f"verdicts name episodes with no sim rollout: {unknown[:5]}")
    same = np.array([success[a] == success[b] for a, b in zip(verdicts["episode_a"].astype(str),
                                                               verdicts["episode_b"].astype(str))], dtype=bool)
    bias = position_bias(verdicts["verdict"].tolist(), same)
    out = {"n_verdicts": bias.n, "a_share": bias.overall, "a_share_same_outcome": _nan_to_none(bias.same_outcome),
           "n_same_outcome": bias.n_same_outcome}
    out["n_a_answers"] = int(round(bias.overall * bias.n))
    out["n_a_same_outcome"] = int(round(bias.same_outcome * bias.n_same_outcome)) if bias.n_same_outcome else 0
    swap = swap_consistency(verdicts, swapped_letter_columns, swapped_winner_columns)
    swap["n_swap_consistent"] = (int(round(swap["swap_consistency"] * swap["n_swapped"]))
                                 if swap["swap_consistency"] is not None else 0)
    out.update(swap)
    shares = {"n_boot": n_boot, "level": ci_level, "seed": seed}
    if annotations is not None:
        out.update(human_agreement(verdicts, annotations, sim_episodes, source=annotations_source, **shares))
    else:
        out.update({"human_agreement": None, "n_annotated_pairs": 0, "n_annotations": 0, "human": None})
    out["outcome_agreement"] = outcome_agreement(verdicts, success, **shares)
    out["planted_order_agreement"] = planted_order_agreement(verdicts, success, planted_order, **shares)
    out["planted_quality"] = planted_quality(verdicts, success, planted_variants or {}, fit=fit,
                                             reference_ci=reference_ci, **shares)
    out["shuffled_label_control"] = shuffled_labels(verdicts, n_permutations=shuffled_permutations, **shares)
    return out


# --------------------------------------------------------------------- win rates


def win_rate_matrix(verdicts: pd.DataFrame) -> pd.DataFrame:
    """``rate[i, j]``: share of the comparisons of policies i and j that the judge gave to i,
    over all judged comparisons (the last checkpoint). Diagonal NaN; rows and columns ordered
    by overall win share, best first."""
    _require(verdicts, ["policy_i", "policy_j", "pair_index"], "verdicts")
    policies = sorted(set(verdicts["policy_i"].astype(str)) | set(verdicts["policy_j"].astype(str)))
    n = int(verdicts.groupby(["policy_i", "policy_j"])["pair_index"].size().min())
    wins = wins_at_checkpoints(verdicts, policies, [n])[0].astype(float)
    total = wins + wins.T
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = np.where(total > 0, wins / total, np.nan)
    np.fill_diagonal(rate, np.nan)
    order = np.argsort(-wins.sum(axis=1) / np.maximum(total.sum(axis=1), 1), kind="stable")
    names = [policies[k] for k in order]
    return pd.DataFrame(rate[np.ix_(order, order)], index=names, columns=names)


# --------------------------------------------------------------- overall ranking


def last_checkpoint(fit: pd.DataFrame) -> pd.DataFrame:
    """The rows of a fit table at its last checkpoint, indexed by policy."""
    _require(fit, ["checkpoint", "policy", "score", "ci_low", "ci_high"], "fit table")
    return fit[fit["checkpoint"] == fit["checkpoint"].max()].set_index("policy").sort_index()


def judge_averaged_scores(fits: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """Per policy at the last checkpoint: the score, CI bounds and checkpoint averaged over
    judges, plus one ``score:<judge>`` column per judge."""
    if not fits:
        raise DataError("no fit tables given")
    last = {judge: last_checkpoint(fit) for judge, fit in fits.items()}
    policies = sorted(set().union(*(set(t.index) for t in last.values())))
    for judge, table in last.items():
        lacking = sorted(set(policies) - set(table.index))
        if lacking:
            raise DataError(f"judge {judge}: no score for policies {lacking} at its last checkpoint")
    out = pd.DataFrame(index=pd.Index(policies, name="policy"))
    for col in ("score", "ci_low", "ci_high"):
        out[col] = np.mean([last[j].loc[policies, col].to_numpy() for j in sorted(last)], axis=0)
    for judge in sorted(last):
        out[f"score:{judge}"] = last[judge].loc[policies, "score"].to_numpy()
    return out


def fit_interval(fits: dict[str, pd.DataFrame] | pd.DataFrame) -> tuple[str, float]:
    """(interval, level) of the score intervals in fit tables: the bootstrap that their
    ``ci_low``/``ci_high`` columns come from (``interval``, ``ci_level`` columns; tables
    without them predate the unit bootstrap and hold the binomial one at 95%). Judges must
    agree."""
    tables = [fits] if isinstance(fits, pd.DataFrame) else list(fits.values())
    found = set()
    for fit in tables:
        interval = str(fit["interval"].iloc[0]) if "interval" in fit.columns and len(fit) else "binomial"
        level = float(fit["ci_level"].iloc[0]) if "ci_level" in fit.columns and len(fit) else 0.95
        found.add((interval, level))
    if len(found) > 1:
        raise DataError(f"fit tables disagree on their score interval: {sorted(found)}")
    return found.pop() if found else ("binomial", 0.95)


def reference_interval(validations: dict[str, dict]) -> dict[str, tuple[float | None, float | None]]:
    """{policy: (ci_low, ci_high)} of the reference performance from validate's JSON (every
    judge's holds the same reference); empty when none carries one."""
    for judge in sorted(validations):
        ref = validations[judge].get("reference") or {}
        if "ci_low" in ref and "ci_high" in ref:
            return {p: (ref["ci_low"][p], ref["ci_high"].get(p)) for p in ref["ci_low"]}
    return {}


# -------------------------------------------------------------------- case study


def pick_case_study(verdicts: pd.DataFrame, sim_episodes: pd.DataFrame, outcomes: str | Sequence[str] = "success",
                    rank: int = 0) -> dict:
    """A judged pair whose two rollouts had the same outcome, so the preference rests on how
    the task was done, not on whether.

    ``outcomes``: one of, or a list tried in order of, "success" (both rollouts succeeded),
    "failure" (both failed) and "any"; the first outcome with more than ``rank`` candidates
    is used (e.g. ``["success", "failure"]`` falls back to two failures when no two
    successful rollouts were compared). Candidates are distinct video pairs in (policy_i,
    policy_j, pair_index) order. Returns the preferred and the other episode's rows (dicts),
    the verdict row, the outcome used and the number of candidates.
    """
    _require(verdicts, ["episode_a", "episode_b", "verdict", "policy_a", "policy_b", "policy_i", "policy_j",
                        "pair_index"], "verdicts")
    _require(sim_episodes, ["episode_id", "success", "video_path"], "sim rollout episodes")
    outcomes = [outcomes] if isinstance(outcomes, str) else list(outcomes)
    bad = [o for o in outcomes if o not in ("success", "failure", "any")]
    if bad or not outcomes:
        raise ConfigError(f"case-study outcomes must be success, failure or any, got {outcomes!r}")
    episodes = sim_episodes.assign(episode_id=sim_episodes["episode_id"].astype(str)).set_index("episode_id")
    ok = episodes["success"].astype(bool)
    v = verdicts.assign(episode_a=verdicts["episode_a"].astype(str), episode_b=verdicts["episode_b"].astype(str))
    unknown = sorted((set(v["episode_a"]) | set(v["episode_b"])) - set(ok.index))
    if unknown:
        raise DataError(f"verdicts name episodes with no sim rollout: {unknown[:5]}")
    sa, sb = ok.loc[v["episode_a"]].to_numpy(), ok.loc[v["episode_b"]].to_numpy()
    counts = {}
    for outcome in outcomes:
        keep = sa == sb
        if outcome != "any":
            keep &= sa == (outcome == "success")
        candidates = (v[keep].sort_values(["policy_i", "policy_j", "pair_index"])
                      .drop_duplicates(["episode_a", "episode_b"]))
        counts[outcome] = len(candidates)
        if int(rank) < len(candidates):
            break
    else:
        raise DataError(f"no case study at rank {rank}: candidate pairs with the same outcome per outcome tried: {counts}")
    row = candidates.iloc[int(rank)]
    preferred, other = (row.episode_a, row.episode_b) if str(row.verdict).upper() == "A" else (row.episode_b, row.episode_a)
    return {
        "preferred": {"episode_id": preferred, **episodes.loc[preferred].to_dict()},
        "other": {"episode_id": other, **episodes.loc[other].to_dict()},
        "verdict": row.to_dict(),
        "outcome": outcome,
        "n_candidates": len(candidates),
    }
