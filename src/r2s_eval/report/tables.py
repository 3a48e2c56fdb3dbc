"""LaTeX tables (booktabs). Pure functions of plain data, so they are easy to test and to reuse.

Each function returns a complete ``tabular`` environment; a paper wraps it in its own
``table`` float with a caption. Missing values print as a dash.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from r2s_eval.errors import ConfigError
from r2s_eval.report.summaries import fit_interval, last_checkpoint, reference_interval, success_gaps
from r2s_eval.stats import reference_rates

_LATEX_SPECIAL = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
                  "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}
DASH = "--"


def latex_escape(text: str) -> str:
    return "".join(_LATEX_SPECIAL.get(ch, ch) for ch in str(text))


def _missing(value) -> bool:
    return value is None or (isinstance(value, float | np.floating) and math.isnan(value))


def _fmt(value, decimals: int) -> str:
    return DASH if _missing(value) else f"{value:.{decimals}f}"


def _pct(fraction, decimals: int) -> str:
    return DASH if _missing(fraction) else f"{100 * fraction:.{decimals}f}"


def _row(cells: Sequence[str]) -> str:
    return " & ".join(cells) + r" \\"


def _tabular(colspec: str, header: Sequence[str], body: Sequence[str], footer: Sequence[str] = (),
             notes: Sequence[str] = ()) -> str:
    """A booktabs tabular; ``notes`` (LaTeX text) become footnote rows under the bottom rule."""
    lines = [rf"\begin{{tabular}}{{{colspec}}}", r"\toprule", *header, r"\midrule", *body]
    if footer:
        lines += [r"\midrule", *footer]
    lines += [r"\bottomrule"]
    n = len([ch for ch in colspec if ch in "lcr"])
    lines += [_row([rf"\multicolumn{{{n}}}{{l}}{{\footnotesize {note}}}"]) for note in notes]
    lines += [r"\end{tabular}"]
    return "\n".join(lines) + "\n"


# What each bootstrap resamples, for table notes and the ranking.
INTERVAL_TEXT = {
    "unit": "the distinct task/init rollout pairs of each policy pair resampled within each task",
    "binomial": "every comparison redrawn independently",
}


# The same, short enough for a note under a table.
INTERVAL_SHORT = {"unit": "rollout pairs resampled per task", "binomial": "comparisons redrawn independently"}


def interval_label(interval: str, level: float) -> str:
    """E.g. "95% unit-bootstrap CI"."""
    return f"{100 * level:g}% {interval}-bootstrap CI"


def interval_text(interval: str, level: float) -> str:
    """E.g. "95% unit-bootstrap CI (the distinct task/init rollout pairs ...)" (plain text)."""
    return f"{interval_label(interval, level)} ({INTERVAL_TEXT.get(interval, 'bootstrap')})"


def _nanmean(values) -> float:
    arr = np.array([np.nan if _missing(v) else float(v) for v in values], dtype=float)
    return float(np.nanmean(arr)) if np.isfinite(arr).any() else float("nan")


# ------------------------------------------------------------------------- tasks


def tasks_table(summary: pd.DataFrame, decimals: int = 1) -> str:
    """Per task: #real trajectories, #sim trajectories (successful replays), replay success %;
    a total row pools the episodes. ``summary`` is :func:`~r2s_eval.report.summaries.task_summary`."""
    body = [_row([latex_escape(r.task), str(int(r.real)), str(int(r.sim)), _pct(r.replay_success, decimals)])
            for r in summary.itertuples()]
    footer = []
    if len(summary) > 1:
        real, sim = int(summary["real"].sum()), int(summary["sim"].sum())
        footer = [_row(["Total", str(real), str(sim), _pct(sim / real if real else float("nan"), decimals)])]
    header = [_row(["Task", r"\#Real traj.", r"\#Sim traj.", r"Replay success (\%)"])]
    return _tabular("lrrr", header, body, footer)


# -------------------------------------------------------------- real vs sim success


def realsim_success_table(success: pd.DataFrame, decimals: int = 1) -> str:
    """Per policy (rows) and task (column pairs): real and sim success %, the totals (mean of the per-task rates),
    and two footer rows with the mean absolute real-sim difference and the largest gap over
    policies, in percentage points. ``success`` is
    :func:`~r2s_eval.report.summaries.success_by_task`. The totals appear with two or more tasks."""
    tasks = sorted(t for t in success["task"].unique() if t != "total")
    tasks += ["total"] if len(tasks) > 1 else []  # one task: its columns are the totals
    cells = success.set_index(["policy", "task"])
    gaps = success_gaps(success)
    policies = sorted(success["policy"].unique())
    header = [
        _row(["Policy"] + [rf"\multicolumn{{2}}{{c}}{{{'Total' if t == 'total' else latex_escape(t)}}}" for t in tasks]),
        "".join(rf"\cmidrule(lr){{{2 + 2 * k}-{3 + 2 * k}}}" for k in range(len(tasks))),
        _row([""] + ["Real", "Sim"] * len(tasks)),
    ]
    body = []
    for p in policies:
        row = [latex_escape(p)]
        for t in tasks:
            real, sim = (cells.loc[(p, t), "real"], cells.loc[(p, t), "sim"]) if (p, t) in cells.index else (None, None)
            row += [_pct(real, decimals), _pct(sim, decimals)]
        body.append(_row(row))

    def gap_row(label: str, col: str) -> str:
        values = [gaps.loc[t, col] if t in gaps.index else None for t in tasks]
        return _row([label] + [rf"\multicolumn{{2}}{{c}}{{{_fmt(v, decimals)}}}" for v in values])

    footer = [gap_row(r"Mean $|\Delta|$ (pp)", "mean_abs_pp"), gap_row(r"Largest gap (pp)", "max_abs_pp")]
    return _tabular("l" + "rr" * len(tasks), header, body, footer)


def libero_success_table(reference: pd.DataFrame, suite_of, decimals: int = 1) -> str:
    """LIBERO's own success rate per policy (rows) and suite (columns), then overall: each the
    mean of the per-task rates in it (every task weighs the same, as LIBERO reports), in %.
    ``reference``: the reference table (policy, task, trials, successes); ``suite_of`` maps a
    task name to its suite. A note says how many episodes each task rests on."""
    table = reference.assign(suite=reference["task"].map(suite_of),
                             rate=reference["successes"] / reference["trials"])
    suites = sorted(table["suite"].unique())
    by_suite = table.groupby(["policy", "suite"])["rate"].mean()
    overall = table.groupby("policy")["rate"].mean()
    header = [_row(["Policy", *(latex_escape(s) for s in suites), "Overall"])]
    body = [_row([latex_escape(p), *(_pct(by_suite.get((p, s)), decimals) for s in suites), _pct(overall[p], decimals)])
            for p in overall.sort_values(ascending=False).index]
    trials = sorted(set(table["trials"].astype(int)))
    per_task = f"{trials[0]}" if len(trials) == 1 else f"{trials[0]}--{trials[-1]}"
    notes = [f"Success \\% (mean of per-task rates); {table['task'].nunique()} tasks, {per_task} episodes per task and policy."]
    return _tabular("l" + "r" * (len(suites) + 1), header, body, notes=notes)


# -------------------------------------------------------------------- real-to-sim

# (column title, where the value lives, key): the paper's five columns, then the judge audit.
_REALSIM_COLUMNS = (
    (r"Spearman $\rho\uparrow$", "metrics", "spearman"),
    (r"Pearson $r\uparrow$", "metrics", "pearson"),
    (r"MMRV$\downarrow$", "metrics", "mmrv"),
    (r"BT CI$\downarrow$", "metrics", "ci_width"),
    (r"Agreement$\uparrow$", "audit", "human_agreement"),
    (r"Swap cons.$\uparrow$", "audit", "swap_consistency"),
    (r"A share (same outc.)", "audit", "a_share_same_outcome"),
)


def realsim_table(validations: Mapping[str, dict], audits: Mapping[str, dict] | None = None, decimals: int = 3,
                  metrics_at: str = "average") -> str:
    """Per judge: Spearman rho, Pearson r, MMRV, BT CI width, human agreement, order-swap
    consistency and the share of A answers on same-outcome pairs; plus an average row.

    ``validations``: validate's JSON per judge; ``metrics_at``: "average" (over all
    checkpoints, the paper's convention) or "last" (the last checkpoint). ``audits``: the
    judge-audit JSON per judge. A judge without human annotations, without swapped answers
    or without an audit shows a dash in those columns; the average row averages the judges
    that have a value. Where validate held a judge against the twin's success of the networks
    it ranks too (``against_networks_in_twin``), a row per such judge follows the average. A note under the table names the bootstrap behind the BT CI column
    (validate's ``interval``; older JSON without it: binomial).
    """
    if metrics_at not in ("average", "last"):
        raise ConfigError(f"metrics_at must be 'average' or 'last', got {metrics_at!r}")
    audits = audits or {}
    values = {}
    for judge in sorted(validations):
        src = {"metrics": validations[judge][metrics_at], "audit": audits.get(judge, {})}
        values[judge] = [src[where].get(key) for _, where, key in _REALSIM_COLUMNS]
    body = [_row([latex_escape(j)] + [_fmt(v, decimals) for v in vals]) for j, vals in values.items()]
    footer = []
    if len(values) > 1:
        means = [_nanmean(col) for col in zip(*values.values())]
        footer = [_row(["Average"] + [_fmt(m, decimals) for m in means])]
    # The same judges against the twin's success of the networks they rank (pi^S), where validate
    # has it: its own rows under the average, the audit's columns (the judge's, not the truth's) left out.
    twin = {j: v["against_networks_in_twin"][metrics_at] for j, v in sorted(validations.items())
            if v.get("against_networks_in_twin")}
    if twin:
        footer += [r"\midrule"] + [
            _row([latex_escape(j) + r", vs pi$^S$ in the twin"]
                 + [_fmt(m.get(key), decimals) if where == "metrics" else DASH for _, where, key in _REALSIM_COLUMNS])
            for j, m in twin.items()]
    header = [_row(["Judge"] + [title for title, _, _ in _REALSIM_COLUMNS])]
    shown = sorted({(str(v.get("interval", "binomial")), float(v.get("ci_level", 0.95))) for v in validations.values()})
    where = "average over checkpoints" if metrics_at == "average" else "last checkpoint"
    notes = [latex_escape(f"BT CI: mean {interval_label(interval, level)} width "
                          f"({INTERVAL_SHORT.get(interval, 'bootstrap')}); {where}.")
             for interval, level in shown]
    if twin:
        notes.append(r"vs pi$^S$ in the twin: against the twin's success of the checkpoints the sim ranks; the rows "
                     r"above: against the real reference (pi$^R$'s).")
    return _tabular("l" + "c" * len(_REALSIM_COLUMNS), header, body, footer, notes)


# ------------------------------------------------------------------- BT scores


def _with_ci(value, ci, decimals: int, scale: float = 1.0) -> str:
    cell = _fmt(None if _missing(value) else scale * value, decimals)
    if ci is not None and not _missing(ci[0]) and not _missing(ci[1]):
        cell += rf" {{\scriptsize [{_fmt(scale * ci[0], decimals)}, {_fmt(scale * ci[1], decimals)}]}}"
    return cell


def bt_scores_table(fits: Mapping[str, pd.DataFrame], reference_rate: Mapping[str, float], decimals: int = 1,
                    show_ci: bool = True, reference_ci: Mapping[str, tuple] | None = None,
                    reference_name: str = "Real") -> str:
    """Per policy (rows, by reference success) and judge (columns): the Bradley-Terry score
    s = 100 b at the judge's last checkpoint, with its bootstrap interval; the first column is
    the reference performance, the mean of the per-task real success rates, with its
    interval where ``reference_ci`` ({policy: (low, high)} as fractions) is given
    (``reference_name`` heads it). A note under the table names the bootstrap behind the
    score intervals."""
    last = {j: last_checkpoint(fits[j]) for j in sorted(fits)}
    policies = sorted(set(reference_rate) | set().union(*(set(t.index) for t in last.values())),
                      key=lambda p: (-reference_rate.get(p, -1.0), p))
    reference_ci = reference_ci or {}
    body = []
    for p in policies:
        real_ci = reference_ci.get(p) if show_ci else None
        row = [latex_escape(p), _with_ci(reference_rate.get(p), real_ci, decimals, scale=100)]
        for table in last.values():
            if p not in table.index:
                row.append(DASH)
                continue
            ci = (table.loc[p, "ci_low"], table.loc[p, "ci_high"]) if show_ci else None
            row.append(_with_ci(table.loc[p, "score"], ci, decimals))
        body.append(_row(row))
    checkpoints = ", ".join(f"{latex_escape(j)}: {int(t['checkpoint'].max())}" for j, t in fits.items())
    header = [_row(["Policy", rf"{latex_escape(reference_name)} (\%)"] + [latex_escape(j) for j in last])]
    interval, level = fit_interval(dict(fits))
    note = f"{latex_escape(reference_name)}: mean over tasks."
    if show_ci:
        note += f" Brackets: {100 * level:g}% CIs; BT: {interval} bootstrap."
    # The checkpoint each column stands at and the interval in full, as a comment so the
    # table stays a plain tabular; a short note under it names the interval.
    comment = (f"% BT score s = 100 b [{interval_text(interval, level)}] at the last checkpoint ({checkpoints});"
               " Real: mean of the per-task success rates" + (f" [{100 * level:g}% CI]" if reference_ci else ""))
    return comment + "\n" + _tabular("lr" + "c" * len(last), header, body, notes=[latex_escape(note)])


# ---------------------------------------------------------------- console ranking


def planted_order_line(reference_rate: Mapping[str, float], reference_ci: Mapping[str, tuple],
                       planted_order: Sequence[str], level: float) -> str:
    """Whether the reference recovers a line-up's planted order (best first): per neighbouring
    pair, are the two intervals apart in that order, and do the point estimates follow it."""
    order = [p for p in planted_order if p in reference_rate]
    verdicts = []
    for better, worse in zip(order, order[1:]):
        lo, hi = reference_ci.get(better, (None, None))[0], reference_ci.get(worse, (None, None))[1]
        if _missing(lo) or _missing(hi):
            verdicts.append(f"{better} > {worse}: no interval")
        elif lo > hi:
            verdicts.append(f"{better} > {worse}: separated")
        else:
            verdicts.append(f"{better} > {worse}: NOT separated (intervals overlap)")
    follows = all(reference_rate[a] > reference_rate[b] for a, b in zip(order, order[1:]))
    return (f"planted order {' > '.join(order)}: real success {100 * level:g}% CIs: " + "; ".join(verdicts)
            + f"; point estimates {'follow' if follows else 'do NOT follow'} it")


def adaptive_line(judge: str, account: Mapping) -> str:
    """What an adaptive judging run decided and what it cost (``r2s_eval.judge.adaptive``)."""
    decided = [d for d in account["pairs"] if d["decided"]]
    orders = ", ".join(f"{d['winner']} > {d['policy_j'] if d['winner'] == d['policy_i'] else d['policy_i']}"
                       for d in decided)
    described = account.get("describe_calls") is not None  # two-step judges describe on the way
    cost = f"{account['items']} comparisons; judge calls: " + (
        f"{account['describe_calls']} describe + {account['calls']} compare" if described else f"{account['calls']} compare")
    if account.get("requests") or account.get("describe_requests"):
        cost += "; model requests: " + (f"{account['describe_requests']} describe + {account['requests']} compare"
                                        if described else f"{account['requests']} compare")
    undecided = "; left undecided: " + ", ".join(account["undecided"]) if account["undecided"] else ""
    return (f"{judge}: adaptive judging stopped ({account['stop'].replace('_', ' ')}) after {cost}; "
            f"decided at alpha {account['alpha']:g} over all pairs: {orders or 'none'}{undecided}")


def ranking_text(fits: Mapping[str, pd.DataFrame], reference_rate: Mapping[str, float],
                 reference_ci: Mapping[str, tuple] | None = None, planted_order: Sequence[str] | None = None,
                 reference_name: str = "real success", adaptive: Mapping[str, Mapping] | None = None) -> str:
    """Plain-text ranking at the last checkpoint, each judge beside the reference performance
    (the mean of the per-task success rates, with its interval where ``reference_ci`` gives
    one; ``reference_name`` says what it is). The title names the bootstrap behind the score
    intervals. With a line-up's ``planted_order`` (best first), a line says whether the
    reference recovers it; a judge that judged adaptively (``adaptive``: judge -> its account)
    gets a line with its decisions, its cost and the pairs it left open."""
    policies = sorted(reference_rate, key=lambda p: -reference_rate[p])
    reference_ci = reference_ci or {}
    width = 24 if reference_ci else 16
    header = f"{'policy':<16}{reference_name + ' %':>{width}}"
    rows = {}
    for p in policies:
        cell = f"{100 * reference_rate[p]:.1f}"
        ci = reference_ci.get(p)
        if ci is not None and not _missing(ci[0]) and not _missing(ci[1]):
            cell += f" [{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]"
        rows[p] = f"{p:<16}{cell:>{width}}"
    for judge in sorted(fits):
        fit = fits[judge]
        last = fit[fit["checkpoint"] == fit["checkpoint"].max()].set_index("policy")
        order = last["score"].rank(ascending=False, method="min").astype(int)
        header += f"{judge[:30]:>34}"
        for p in policies:
            cell = f"{last.loc[p, 'score']:.1f} [{last.loc[p, 'ci_low']:.1f}, {last.loc[p, 'ci_high']:.1f}] #{order[p]}"
            rows[p] += f"{cell:>34}"
    n = int(max(f["checkpoint"].max() for f in fits.values())) if fits else 0
    interval, level = fit_interval(dict(fits)) if fits else ("binomial", 0.95)
    adaptive = {judge: account for judge, account in (adaptive or {}).items() if account}
    # An adaptive judge stops where its pairs are decided: it says how much it judged in all.
    judged = (f"{n} comparisons per policy pair" if not adaptive else "; ".join(
        f"{judge}: {adaptive[judge]['items']} comparisons in all, adaptive" if judge in adaptive
        else f"{judge}: {n} per policy pair" for judge in sorted(fits)))
    title = f"Ranking at the last checkpoint ({judged}): BT score [{interval_label(interval, level)}] #rank"
    notes = [f"BT CI: {interval} bootstrap, {INTERVAL_TEXT.get(interval, 'bootstrap')}",
             f"{reference_name} %: mean of the per-task success rates"
             + (f" [{100 * level:g}% CI, trials resampled within each task]" if reference_ci else "")]
    if planted_order and reference_ci:
        notes.append(planted_order_line(reference_rate, reference_ci, planted_order, level))
    notes += [adaptive_line(judge, account) for judge, account in sorted(adaptive.items())]
    return "\n".join([title, header, *rows.values(), *notes]) + "\n"


# ------------------------------------------------------------------- judge card


def _share_cell(card: Mapping | None, decimals: int, count_key: str = "n_pairs") -> str:
    """ "share [low, high] (n)" in percent from a unit_share dict; a dash without a share."""
    if not card or _missing(card.get("share")):
        return DASH
    cell = _pct(card["share"], decimals)
    if not _missing(card.get("ci_low")) and not _missing(card.get("ci_high")):
        cell += rf" {{\scriptsize [{_pct(card['ci_low'], decimals)}, {_pct(card['ci_high'], decimals)}]}}"
    return cell + f" ({int(card.get(count_key, 0))})"


def _rate_cell(value, n, decimals: int) -> str:
    return DASH if _missing(value) else f"{_pct(value, decimals)} ({int(n)})"


def judge_card_table(audits: Mapping[str, dict], decimals: int = 1) -> str:
    """Per judge, its report card (the judge-audit JSON): agreement with the sim outcome on
    mixed-outcome pairs [CI] (pairs), agreement with the planted policy order on pairs that
    both succeeded [CI] (pairs), the share of A answers on same-outcome pairs (pairs), order-swap
    consistency (swapped pairs), and the share of shuffled-label fits that come out flat.
    All in percent; a missing quantity shows a dash."""
    body = []
    levels, perms = set(), set()
    for judge in sorted(audits):
        a = audits[judge]
        outcome, planted = a.get("outcome_agreement"), a.get("planted_order_agreement")
        shuffled = a.get("shuffled_label_control")
        for card in (outcome, planted):
            if card and not _missing(card.get("share")):
                levels.add(float(card.get("ci_level", 0.95)))
        flat = DASH
        if shuffled and not _missing(shuffled.get("permuted_flat_share")):
            perms.add(int(shuffled["n_permutations"]))
            flat = f"{_pct(shuffled['permuted_flat_share'], decimals)} ({int(shuffled['n_permutations'])})"
            flat += r" / real " + ("flat" if shuffled["real"]["flat"] else "not flat")
        body.append(_row([
            latex_escape(judge), _share_cell(outcome, decimals), _share_cell(planted, decimals),
            _rate_cell(a.get("a_share_same_outcome"), a.get("n_same_outcome", 0), decimals),
            _rate_cell(a.get("swap_consistency"), a.get("n_swapped", 0), decimals), flat,
        ]))
    header = [_row(["Judge", r"Outcome agr.$\uparrow$", r"Planted order$\uparrow$", "A share (same outc.)",
                    r"Swap cons.$\uparrow$", "Shuffled flat"])]
    level = f"{100 * next(iter(levels)):g}\\%" if len(levels) == 1 else "95\\%"
    notes = [
        rf"In \%; brackets: {level} CIs, distinct (task, init) units resampled; parentheses: pairs.",
        r"Outcome agr.: verdicts preferring the successful rollout where one succeeded and one failed.",
        r"Planted order: verdicts following the line-up's built-in order where both succeeded.",
        r"Shuffled flat: share of label-permuted BT fits whose CIs all contain 100/$n$ (permutations).",
    ]
    return _tabular("l" + "c" * 5, header, body, notes=notes) + planted_quality_table(audits, decimals, level)


def _yes_no(value) -> str:
    return DASH if value is None else ("yes" if value else "no")


def planted_quality_table(audits: Mapping[str, dict], decimals: int = 1, level: str = "95\\%") -> str:
    """Per judge and variant (a candidate's weights run with an execution change): the share of
    verdicts on pairs that both succeeded preferring the clean run [CI] (pairs), whether the BT intervals put the
    clean run above the variant, whether their success intervals overlap. Empty without variants."""
    body = []
    for judge in sorted(audits):
        for card in audits[judge].get("planted_quality") or ():
            body.append(_row([latex_escape(judge), latex_escape(f"{card['variant']} vs {card['clean']}"),
                              _share_cell(card, decimals), _yes_no(card.get("bt_separated")),
                              _yes_no(card.get("success_overlap"))]))
    if not body:
        return ""
    header = [_row(["Judge", "Variant vs clean", r"Prefers clean$\uparrow$", "BT apart", "Success overlap"])]
    notes = [
        rf"Planted quality: the clean candidate's weights run with an execution change; in \%, {level} CIs over",
        r"distinct (task, init) units; parentheses: pairs that both succeeded. BT apart: the clean run's interval above",
        r"the variant's; success overlap: their reference success intervals overlap.",
    ]
    return "\n" + _tabular("llccc", header, body, notes=notes)


def validation_report(validations: Mapping[str, dict], audits: Mapping[str, dict], fits: Mapping[str, pd.DataFrame],
                      adaptive: Mapping[str, Mapping | None], reference: pd.DataFrame, *, decimals: int, metrics_at,
                      planted_order: Sequence[str] | None, reference_name: str = "real success",
                      suite_of=None) -> tuple[str, str]:
    """The validation table (one row per judge; with ``suite_of``, LIBERO's own success per policy
    and suite below it) and the printed ranking beside the reference's rates (``reference``: the
    reference stage's table) with the interval validate computed for them."""
    table = realsim_table(validations, audits, decimals=decimals, metrics_at=metrics_at)
    if suite_of is not None:
        table += "\n" + libero_success_table(reference, suite_of, decimals=1)
    ranking = ranking_text(fits, reference_rates(reference).to_dict(), reference_interval(validations),
                           planted_order=planted_order, reference_name=reference_name, adaptive=adaptive)
    return table, ranking


def _signed(share: float, decimals: int) -> str:
    """A difference of shares in percentage points, signed."""
    return f"{100 * share:+.{decimals}f}"


def _interval(bounds, decimals: int, signed: bool = False) -> str:
    """[low, high] of shares in percent (signed: as differences), or a dash."""
    if bounds is None:
        return DASH
    fmt = (lambda v: _signed(v, decimals)) if signed else (lambda v: _pct(v, decimals))
    return f"[{fmt(bounds[0])}, {fmt(bounds[1])}]"


def stability_table(summary: Mapping, decimals: int = 1) -> str:
    """The repeated evaluations side by side (r2s_eval.stages.stability): per evaluation (a real
    one at m trials per task, each judge), how often its ranking equals the truth, its mean
    Kendall distance to it, and each adjacent pair's flip rate over the repetitions; in percent
    but the distance."""
    names = list(summary["evaluations"])
    cards = summary["evaluations"]
    pct = lambda v: _pct(v, decimals)  # noqa: E731
    body = [
        _row(["Ranking equals the truth", *(pct(cards[n]["equal_share"]) for n in names)]),
        _row(["Kendall distance (pairs)", *(DASH if cards[n]["kendall_distance"] is None
                                            else f"{cards[n]['kendall_distance']:.{decimals}f}" for n in names)]),
        _row(["Pairs ordered as the truth", *(pct(cards[n]["agreement"]) for n in names)]),
    ]
    beside = summary.get("beside_real")
    if beside:  # what the shares rest on: their intervals, and each one beside the real evaluation's
        level = f"{100 * beside['level']:g}"
        differences = beside["differences"]
        body += [
            _row([rf"\quad {level} \% interval", *(_interval(cards[n].get("agreement_interval"), decimals)
                                                    for n in names)]),
            _row([rf"\quad minus {latex_escape(beside['reference'])} [{level} \%]",
                  *(DASH if n not in differences else
                    f"{_signed(differences[n]['difference'], decimals)} {_interval(differences[n]['interval'], decimals, True)}"
                    for n in names)]),
        ]
    body.append(_row(["Errors in most repetitions (pairs)", *(str(len(cards[n]["repeated_errors"])) for n in names)]))
    def other_truth(title: str, view: Mapping) -> list[str]:
        """The evaluations in ``view`` held against another truth: a title row and two more."""
        return [
            r"\midrule",
            _row([rf"\emph{{{title}}}", *[""] * len(names)]),
            _row(["Pairs ordered as that truth", *(pct(view[n]["agreement"]) if n in view else DASH for n in names)]),
            _row(["Errors in most repetitions (pairs)", *(str(len(view[n]["repeated_errors"])) if n in view else DASH
                                                          for n in names)]),
        ]

    against_sim = summary.get("against_sim_truth") or {}
    if against_sim:  # the judges' own errors: against what the sim they judge holds
        body += other_truth("Against the sim's own truth", against_sim)
    in_twin = summary.get("against_networks_in_twin") or {}
    if in_twin:  # the sim and the judges against the twin's success of the checkpoints they rank
        body += other_truth("Against the twin's truth of the networks ranked", in_twin)
    flips = [_row([latex_escape(pair), *(pct(cards[n]["pairs"][pair]["flip_rate"]) for n in names)])
             for pair in summary["truth"]["adjacent_pairs"]]
    header = [_row(["", *(latex_escape(n if not n.startswith("real ") else f"real, {n[5:]} trials/task")
                          for n in names)])]
    behind = summary["behind_each_repetition"]
    notes = [
        rf"{summary['repetitions']} repetitions, disjoint initial configurations, checkpoints fixed; each rests on "
        rf"{behind['sim_rollouts_per_policy']} sim rollouts per policy",
        rf"(the judges) or {summary['tasks']} tasks $\times$ m real trials per policy; the truth on "
        rf"{summary['truth']['real_trials_per_policy']} other real trials per policy and the planted pairs.",
        r"Errors in most repetitions: decided pairs ordered against the truth in more than half the repetitions.",
        *([r"Sim success: the ranking by the success of the repetition's own sim rollouts. The sim's own truth: the planted",
           r"pairs and the sim's success over the other repetitions' rollouts (a judge's errors that are not the sim's)."]
          if against_sim else []),
        *([r"The twin's truth of the networks ranked: the planted pairs and the twin's success of the checkpoints the sim",
           r"ranks (pi$^S$), over the other repetitions' inits; the real truth is pi$^R$'s, trained on the real data."]
          if in_twin else []),
        *([r"Intervals: Student's t over the repetitions' shares; the difference paired per repetition (the same inits)."]
          if beside else []),
        r"Flip rate: share of repetitions on the minority side of the pair's order (0: always the same; 50: a coin).",
    ]
    return _tabular("l" + "c" * len(names), header, [*body, r"\midrule", _row([r"\emph{Flip rate, adjacent pairs}",
                                                                             *[""] * len(names)]), *flips],
                    notes=notes)


# ------------------------------------------------------------------- judge resolution


def magnitude_label(value: float) -> str:
    """A planted magnitude as the tables and figures print it."""
    return f"{value:g}"


def _success_cell(success: Mapping, decimals: int) -> str:
    """ "changed / clean" success in percent, the sim's then the real's."""
    def world(w):
        if not w or w["changed"]["rate"] is None:
            return DASH
        return f"{_pct(w['changed']['rate'], decimals)}/{_pct(w['clean']['rate'], decimals)}"
    return f"{world(success['sim'])}; {world(success['real'])}"


def resolution_table(cards: Mapping[str, dict], decimals: int = 1) -> str:
    """Per kind and judge: the smallest level that detects the kind (its magnitude, its share of
    pairs that both succeeded preferring the clean run [CI] (pairs), success there), or, where none does,
    "not seen" with the best share and its level; and the share preferring the successful run
    where the outcomes differ, over all levels."""
    body = []
    first = next(iter(cards.values()))
    for kind, summary in first["kinds"].items():
        for judge in sorted(cards):
            card = cards[judge]
            rows = {r["level"]: r for r in card["levels"] if r["kind"] == kind}
            seen = card["kinds"][kind]["smallest_detected"]
            kept = card["kinds"][kind]["smallest_detected_success_kept"]
            at = rows[seen] if seen is not None else rows.get(card["kinds"][kind]["best_level"])
            if at is None:
                verdict = "no pair succeeded twice"
            elif seen is None:
                verdict = f"not seen (best at {magnitude_label(at['magnitude'])})"
            else:
                verdict = magnitude_label(at["magnitude"]) + ("" if kept == seen else
                                                           " (success moved)" if kept is None else
                                                           f" (success kept from {magnitude_label(rows[kept]['magnitude'])})")
            hits = sum((r["different_outcome"]["share"] or 0) * r["different_outcome"]["n_pairs"] for r in rows.values())
            n_diff = sum(r["different_outcome"]["n_pairs"] for r in rows.values())
            body.append(_row([
                latex_escape(kind), latex_escape(judge), latex_escape(summary["key"]), latex_escape(verdict),
                _share_cell(at["both_succeeded"] if at else None, decimals),
                _success_cell(at["success"], decimals) if at else DASH,
                f"{_pct(hits / n_diff, decimals)} ({n_diff})" if n_diff else DASH,
            ]))
    header = [_row(["Kind", "Judge", "Magnitude key", "Smallest seen", r"Prefers clean$\uparrow$",
                    "Success sim; real", r"Success first$\uparrow$"])]
    share = 100 * float(first["detect_share"])
    notes = [
        rf"Smallest seen: the smallest magnitude at which the judge prefers the clean run on $\geq${share:g}\% of the",
        r"pairs that both succeeded, with the interval above 50\%; prefers clean: that share [95\% CI] (pairs), or the best",
        r"level's where none is seen. Success: the changed run's / the clean run's, in \%, sim; real. Success first:",
        r"verdicts preferring the run that succeeded where one did, over all levels (pairs).",
    ]
    return _tabular("llllccc", header, body, notes=notes)
