"""LaTeX tables (booktabs). Pure functions of plain data, so they are easy to test and to reuse.

Each function returns a complete ``tabular`` environment; a paper wraps it in its own
``table`` float with a caption. Missing values print as a dash.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from r2s_eval.report.summaries import last_checkpoint, success_gaps

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


def _tabular(colspec: str, header: Sequence[str], body: Sequence[str], footer: Sequence[str] = ()) -> str:
    lines = [rf"\begin{{tabular}}{{{colspec}}}", r"\toprule", *header, r"\midrule", *body]
    if footer:
        lines += [r"\midrule", *footer]
    lines += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(lines) + "\n"


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
    """Per policy (rows) and task (column pairs): real and sim success %, the pooled totals,
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
    that have a value.
    """
    if metrics_at not in ("average", "last"):
        raise ValueError(f"metrics_at must be 'average' or 'last', got {metrics_at!r}")
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
    header = [_row(["Judge"] + [title for title, _, _ in _REALSIM_COLUMNS])]
    return _tabular("l" + "c" * len(_REALSIM_COLUMNS), header, body, footer)


# ------------------------------------------------------------------- BT scores


def bt_scores_table(fits: Mapping[str, pd.DataFrame], reference_rate: Mapping[str, float], decimals: int = 1,
                    show_ci: bool = True) -> str:
    """Per policy (rows, by reference success) and judge (columns): the Bradley-Terry score
    s = 100 b at the judge's last checkpoint, with its bootstrap interval; the first column is
    the reference (real) success rate."""
    last = {j: last_checkpoint(fits[j]) for j in sorted(fits)}
    policies = sorted(set(reference_rate) | set().union(*(set(t.index) for t in last.values())),
                      key=lambda p: (-reference_rate.get(p, -1.0), p))
    body = []
    for p in policies:
        row = [latex_escape(p), _pct(reference_rate.get(p), decimals)]
        for table in last.values():
            if p not in table.index:
                row.append(DASH)
                continue
            cell = _fmt(table.loc[p, "score"], decimals)
            if show_ci:
                cell += rf" {{\scriptsize [{_fmt(table.loc[p, 'ci_low'], decimals)}, {_fmt(table.loc[p, 'ci_high'], decimals)}]}}"
            row.append(cell)
        body.append(_row(row))
    checkpoints = ", ".join(f"{latex_escape(j)}: {int(t['checkpoint'].max())}" for j, t in fits.items())
    header = [_row(["Policy", r"Real (\%)"] + [latex_escape(j) for j in last])]
    # The checkpoint each column stands at, as a comment so the table stays a plain tabular.
    return f"% BT score s = 100 b [bootstrap CI] at the last checkpoint ({checkpoints})\n" + _tabular(
        "lr" + "c" * len(last), header, body)


# ---------------------------------------------------------------- console ranking


def ranking_text(fits: Mapping[str, pd.DataFrame], reference_rate: Mapping[str, float]) -> str:
    """Plain-text ranking at the last checkpoint, each judge beside the reference success rate."""
    policies = sorted(reference_rate, key=lambda p: -reference_rate[p])
    header = f"{'policy':<16}{'real success %':>16}"
    rows = {p: f"{p:<16}{100 * reference_rate[p]:>16.1f}" for p in policies}
    for judge in sorted(fits):
        fit = fits[judge]
        last = fit[fit["checkpoint"] == fit["checkpoint"].max()].set_index("policy")
        order = last["score"].rank(ascending=False, method="min").astype(int)
        header += f"{judge[:30]:>34}"
        for p in policies:
            cell = f"{last.loc[p, 'score']:.1f} [{last.loc[p, 'ci_low']:.1f}, {last.loc[p, 'ci_high']:.1f}] #{order[p]}"
            rows[p] += f"{cell:>34}"
    n = int(max(f["checkpoint"].max() for f in fits.values())) if fits else 0
    title = f"Ranking at the last checkpoint ({n} comparisons per policy pair): BT score [95% CI] #rank"
    return "\n".join([title, header, *rows.values()]) + "\n"
