"""LaTeX tables. Pure functions of plain data, so they are easy to test and to reuse."""

from __future__ import annotations

import math
from collections.abc import Mapping

import pandas as pd

_LATEX_SPECIAL = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
                  "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}


def latex_escape(text: str) -> str:
    return "".join(_LATEX_SPECIAL.get(ch, ch) for ch in str(text))


def _fmt(value, decimals: int) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "--"
    return f"{value:.{decimals}f}"


def realsim_table(validations: Mapping[str, dict], agreement: Mapping[str, float] | None = None, decimals: int = 3) -> str:
    """Per judge: Spearman rho, Pearson r, MMRV, BT CI width, human agreement; plus an average row.

    Metrics are averages over all checkpoints (the paper's convention). A judge without human
    annotations shows a dash for agreement.
    """
    agreement = agreement or {}
    cols = ["spearman", "pearson", "mmrv", "ci_width"]
    lines = [
        r"\begin{tabular}{lccccc}",
        r"\toprule",
        r"Judge & Spearman $\rho\uparrow$ & Pearson $r\uparrow$ & MMRV$\downarrow$ & BT CI$\downarrow$ & Agreement$\uparrow$ \\",
        r"\midrule",
    ]
    for judge in sorted(validations):
        avg = validations[judge]["average"]
        cells = [_fmt(avg[c], decimals) for c in cols] + [_fmt(agreement.get(judge), decimals)]
        lines.append(latex_escape(judge) + " & " + " & ".join(cells) + r" \\")
    if len(validations) > 1:
        lines.append(r"\midrule")
        mean = {c: sum(v["average"][c] for v in validations.values()) / len(validations) for c in cols}
        agree = [agreement[j] for j in validations if j in agreement]
        cells = [_fmt(mean[c], decimals) for c in cols] + [_fmt(sum(agree) / len(agree) if agree else None, decimals)]
        lines.append("Average & " + " & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(lines) + "\n"


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
