"""Figures (matplotlib, headless). Each function takes plain data plus its plotting options
(the figure's slice of ``conf/report``, which owns every default: pass all its keys) and returns
a Figure; :func:`save_figure` writes it as PDF and PNG.

Common options: ``width_in``, ``height_in`` (inches; per panel where a figure has a grid of
panels, as noted), ``font_size``, ``dpi`` (PNG only).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from r2s_eval.errors import DataError
from r2s_eval.report.summaries import fit_interval
from r2s_eval.report.tables import magnitude_label
from r2s_eval.stats import spearman
from r2s_eval.utils.io import atomic_path, provenance_line

HARDWARE_COMPONENTS = ("execution", "reset", "monitoring", "recording")


def _rc(opts: Mapping) -> dict:
    return {"font.size": float(opts["font_size"])}


def _figure(width_in: float, height_in: float) -> Figure:
    # A bare Figure (no pyplot): no global figure registry, no GUI backend, nothing to close.
    return Figure(figsize=(width_in, height_in), layout="constrained")


def save_figure(fig: Figure, pdf: str | Path, png: str | Path, dpi: int = 200) -> None:
    """Write ``fig`` as PDF and PNG (atomically). The PDF embeds TrueType fonts (editable
    text) and carries no creation date, so the same data and options give the same bytes. Both
    record the provenance of the stage that drew them (PDF keywords, a PNG text chunk)."""
    made_by = provenance_line()
    with matplotlib.rc_context({"pdf.fonttype": 42}):
        with atomic_path(pdf) as tmp:
            fig.savefig(tmp, format="pdf", bbox_inches="tight",
                        metadata={"CreationDate": None, "ModDate": None, **({"Keywords": made_by} if made_by else {})})
        with atomic_path(png) as tmp:
            fig.savefig(tmp, format="png", dpi=int(dpi), bbox_inches="tight",
                        metadata={"r2s_eval": made_by} if made_by else None)


# ------------------------------------------------------------------ win rates


def win_rate_figure(rates: pd.DataFrame, judge: str, opts: Mapping) -> Figure:
    """Heatmap of ``rates`` (row policy's win share against the column policy), annotated
    with percentages. Options: cmap, annotate, decimals."""
    with matplotlib.rc_context(_rc(opts)):
        fig = _figure(opts["width_in"], opts["height_in"])
        ax = fig.subplots()
        data = 100 * rates.to_numpy(dtype=float)
        im = ax.imshow(np.ma.masked_invalid(data), cmap=opts["cmap"], vmin=0, vmax=100)
        names = list(rates.index)
        ax.set_xticks(range(len(names)), names, rotation=35, ha="right")
        ax.set_yticks(range(len(names)), names)
        ax.set_xlabel("against (column policy)")
        ax.set_ylabel("row policy")
        ax.set_title(f"Win rate, judge {judge}")
        if opts["annotate"]:
            decimals = int(opts["decimals"])
            for i in range(len(names)):
                for j in range(len(names)):
                    if np.isfinite(data[i, j]):
                        dark = abs(data[i, j] - 50) > 30  # white text on the saturated ends of the map
                        ax.text(j, i, f"{data[i, j]:.{decimals}f}", ha="center", va="center",
                                color="white" if dark else "black")
        fig.colorbar(im, ax=ax, label="row wins (%)")
    return fig


# ---------------------------------------------------------------- convergence


def convergence_figure(fits: Mapping[str, pd.DataFrame], opts: Mapping) -> Figure:
    """One panel per judge: each policy's BT score over the checkpoints with its bootstrap
    interval as a band (the fits' ``interval``, named in the figure title). Options: columns
    (panels per row), band_alpha, marker; width_in and height_in are per panel."""
    judges = sorted(fits)
    if not judges:
        raise DataError("no fit tables to plot")
    ncols = max(1, min(int(opts["columns"]), len(judges)))
    nrows = math.ceil(len(judges) / ncols)
    with matplotlib.rc_context(_rc(opts)):
        fig = _figure(opts["width_in"] * ncols, opts["height_in"] * nrows)
        axes = fig.subplots(nrows, ncols, squeeze=False, sharey=True)
        policies = sorted(set().union(*(set(fits[j]["policy"]) for j in judges)))
        colors = {p: matplotlib.colormaps["tab10"](k % 10) for k, p in enumerate(policies)}
        for ax, judge in zip(axes.flat, judges):
            for policy, g in fits[judge].groupby("policy"):
                g = g.sort_values("checkpoint")
                ax.plot(g["checkpoint"], g["score"], marker=opts["marker"], ms=3, color=colors[policy],
                        label=policy)
                ax.fill_between(g["checkpoint"], g["ci_low"], g["ci_high"], color=colors[policy],
                                alpha=float(opts["band_alpha"]), linewidth=0)
            ax.set_title(judge)
            ax.set_xlabel("comparisons per policy pair")
            checkpoints = np.unique(fits[judge]["checkpoint"])
            if len(checkpoints) <= 8:  # few checkpoints: tick each one
                ax.set_xticks(checkpoints)
            else:
                ax.xaxis.set_major_locator(MaxNLocator(integer=True))
            ax.grid(alpha=0.3)
        for ax in axes[:, 0]:
            ax.set_ylabel("BT score $s$")
        for ax in list(axes.flat)[len(judges):]:
            ax.set_visible(False)
        handles, labels = axes.flat[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncols=min(len(labels), 4), frameon=False)
        interval, level = fit_interval(dict(fits))
        fig.suptitle(f"bands: {100 * level:g}% {interval}-bootstrap interval", fontsize="medium")
    return fig


# -------------------------------------------------------------- overall ranking


def ranking_figure(averaged: pd.DataFrame, reference_rate: Mapping[str, float], opts: Mapping,
                   reference_ci: Mapping[str, tuple] | None = None, reference_name: str = "real success") -> Figure:
    """Two panels sharing the policy axis, ordered by reference success: the judge-averaged
    BT score at the last checkpoint (bars, judge-averaged bootstrap interval as error bars,
    each judge as a dot) and the reference performance, the mean of the per-task success
    rates (with ``reference_ci``, {policy: (low, high)} as fractions, as error bars).
    Options: score_color, reference_color."""
    missing = sorted(set(averaged.index) - set(reference_rate))
    if missing:
        raise DataError(f"no reference success rate for policies {missing}")
    policies = sorted(averaged.index, key=lambda p: (reference_rate[p], p))  # best at the top of a barh plot
    avg = averaged.loc[policies]
    ref = np.array([100 * reference_rate[p] for p in policies])
    y = np.arange(len(policies))
    judges = [c.split(":", 1)[1] for c in avg.columns if c.startswith("score:")]
    with matplotlib.rc_context(_rc(opts)):
        fig = _figure(opts["width_in"], opts["height_in"])
        ax_s, ax_r = fig.subplots(1, 2, sharey=True)
        err = np.vstack([avg["score"] - avg["ci_low"], avg["ci_high"] - avg["score"]]).clip(min=0)
        ax_s.barh(y, avg["score"], xerr=err, color=opts["score_color"], capsize=3)
        if len(judges) > 1:
            for judge in judges:
                ax_s.plot(avg[f"score:{judge}"], y, "k.", ms=4)
        ax_s.set_yticks(y, policies)
        ax_s.set_xlabel("BT score $s$ (judge average)")
        ax_s.set_title(f"Preference ({len(judges)} judge{'s' if len(judges) != 1 else ''})")
        ref_err = None
        if reference_ci:
            bounds = np.array([[100 * (reference_ci.get(p) or (np.nan, np.nan))[k] for p in policies] for k in (0, 1)],
                              dtype=float)
            ref_err = np.nan_to_num(np.vstack([ref - bounds[0], bounds[1] - ref]).clip(min=0))
        ax_r.barh(y, ref, xerr=ref_err, color=opts["reference_color"],
                  capsize=3 if ref_err is not None else 0)
        ax_r.set_xlabel(f"{reference_name} (%, mean over tasks)")
        ax_r.set_xlim(0, 100)
        ax_r.set_title("Reference")
        rho = spearman(avg["score"].to_numpy(), ref) if len(policies) > 1 else float("nan")
        fig.suptitle(f"Overall ranking (Spearman $\\rho$ = {rho:.2f})" if np.isfinite(rho) else "Overall ranking")
        for ax in (ax_s, ax_r):
            ax.grid(axis="x", alpha=0.3)
    return fig


# -------------------------------------------------------------- hardware effort


def operator_hours(seconds_per_trial: Mapping[str, float], n_policies: int, tasks: int, trials_per_task) -> dict:
    """Operator hours per component to evaluate ``n_policies`` on ``tasks`` x ``trials_per_task``
    real trials each (``trials_per_task`` may be an array)."""
    missing = [c for c in HARDWARE_COMPONENTS if c not in seconds_per_trial]
    if missing:
        raise DataError(f"seconds_per_trial lacks components {missing}")
    trials = n_policies * tasks * np.asarray(trials_per_task, dtype=float)
    return {c: trials * float(seconds_per_trial[c]) / 3600 for c in HARDWARE_COMPONENTS}


def hardware_effort_figure(seconds_per_trial: Mapping[str, float], n_policies: int, current: tuple[int, int],
                           opts: Mapping) -> Figure:
    """Operator time of a real-world evaluation against r2s-eval's zero repeated hardware time.

    Left: hours per component (stacked) for ``n_policies`` as the trials per policy (tasks x
    trials per task) grow, this experiment's ``current = (tasks, trials per task)`` marked.
    Right: total hours against trials per task, one line per number of tasks in
    ``opts["tasks"]``. Options: tasks (list), max_trials_per_task.
    """
    n_tasks, n_trials = current
    max_trials = int(opts["max_trials_per_task"])
    task_counts = [int(t) for t in opts["tasks"]]
    per_task = np.arange(0, max_trials + 1)
    with matplotlib.rc_context(_rc(opts)):
        fig = _figure(opts["width_in"], opts["height_in"])
        ax_a, ax_b = fig.subplots(1, 2)
        total_trials = per_task * max(n_tasks, 1)
        hours = operator_hours(seconds_per_trial, n_policies, max(n_tasks, 1), per_task)
        ax_a.stackplot(total_trials, *[hours[c] for c in HARDWARE_COMPONENTS], labels=HARDWARE_COMPONENTS, alpha=0.85)
        ax_a.plot(total_trials, np.zeros_like(total_trials, dtype=float), "k-", lw=2,
                  label="r2s-eval (no repeated hardware time)")
        now = sum(operator_hours(seconds_per_trial, n_policies, n_tasks, n_trials).values())
        ax_a.plot([n_tasks * n_trials], [now], "ko", ms=5)
        ax_a.annotate(f"this run: {float(now):.1f} h", (n_tasks * n_trials, float(now)), textcoords="offset points",
                      xytext=(5, 5))
        ax_a.set_xlabel(f"real trials per policy (tasks x trials, {n_tasks} task{'s' if n_tasks != 1 else ''})")
        ax_a.set_ylabel("operator time (h)")
        ax_a.set_title(f"{n_policies} policies: where the time goes")
        ax_a.legend(loc="upper left", frameon=False)
        for t in task_counts:
            total = sum(operator_hours(seconds_per_trial, n_policies, t, per_task).values())
            ax_b.plot(per_task, total, label=f"{t} task{'s' if t != 1 else ''}")
        ax_b.plot(per_task, np.zeros_like(per_task, dtype=float), "k-", lw=2, label="r2s-eval")
        ax_b.set_xlabel("trials per task")
        ax_b.set_ylabel("operator time (h)")
        ax_b.set_title("growth with tasks x trials")
        ax_b.legend(frameon=False)
        for ax in (ax_a, ax_b):
            ax.grid(alpha=0.3)
            ax.set_xlim(left=0)
            ax.set_ylim(bottom=-0.02 * ax.get_ylim()[1])
    return fig


# ------------------------------------------------------------------ case study


def case_study_figure(rows: Sequence[tuple[str, Sequence[np.ndarray], Sequence[float]]], title: str, caption: str,
                      opts: Mapping) -> Figure:
    """Frames of rollouts side by side, one row per rollout: ``rows`` holds (row label,
    frames, frame times in seconds). ``caption`` (e.g. the judge's rationale) is wrapped
    under the title. Options: wrap_chars; width_in and height_in are per frame."""
    ncols = max(len(frames) for _, frames, _ in rows)
    with matplotlib.rc_context(_rc(opts)):
        fig = _figure(opts["width_in"] * ncols, opts["height_in"] * len(rows) + 0.8)
        axes = fig.subplots(len(rows), ncols, squeeze=False)
        for r, (label, frames, times) in enumerate(rows):
            for c in range(ncols):
                ax = axes[r, c]
                ax.set_xticks([])
                ax.set_yticks([])
                if c < len(frames):
                    ax.imshow(frames[c])
                    ax.set_xlabel(f"t = {times[c]:.1f} s")
                else:
                    ax.set_visible(False)
            axes[r, 0].set_ylabel(label)
        wrapped = textwrap.fill(caption, int(opts["wrap_chars"]))
        fig.suptitle(f"{title}\n{wrapped}" if caption else title, fontsize=float(opts["font_size"]))
    return fig


# ------------------------------------------------------------------- stability


def stability_figure(summary: Mapping, opts: Mapping) -> Figure:
    """Agreement with the truth against the real trials an evaluation spends (per task and
    policy, after the teleop data): real evaluations at m trials (a line; the repetitions' mean,
    its interval as a band) and each judge's sim ranking at none (a marker with its interval);
    where the summary holds it, the same ranking against the twin's truth of the networks it
    ranks (a hollow marker beside it). The interval is the summary's ``agreement_interval`` (the
    Student-t interval over the repetitions); a card without one shows the repetitions' range."""
    cards = summary["evaluations"]
    real = sorted((int(name.split()[1]), card) for name, card in cards.items() if name.startswith("real "))
    judges = [(name, card) for name, card in cards.items() if not name.startswith("real ")]

    def spread(card):
        shares = [100 * c["share"] for c in card["per_repetition"] if c["share"] is not None]
        if not shares:
            return np.nan, np.nan, np.nan
        interval = card.get("agreement_interval")
        low, high = (100 * interval[0], 100 * interval[1]) if interval else (min(shares), max(shares))
        return np.mean(shares), low, high

    with matplotlib.rc_context(_rc(opts)):
        fig = _figure(opts["width_in"], opts["height_in"])
        ax = fig.subplots()
        m = np.array([k for k, _ in real], dtype=float)
        mean, low, high = (np.array(v) for v in zip(*(spread(card) for _, card in real))) if real else ([],) * 3
        ax.plot(m, mean, "o-", color=opts["real_color"], label="real evaluation")
        ax.fill_between(m, low, high, color=opts["real_color"], alpha=0.2, linewidth=0)
        in_twin = summary.get("against_networks_in_twin") or {}
        for k, (name, card) in enumerate(judges):
            avg, lo, hi = spread(card)
            # Side by side around 0 (all spend no real trials), so their ranges do not overlap.
            x = 0.4 * (k - (len(judges) - 1) / 2)
            marker = opts["judge_markers"][k % len(opts["judge_markers"])]
            bar = ax.errorbar([x], [avg], yerr=[[avg - lo], [hi - avg]], fmt=marker, capsize=3,
                              label="sim success counted" if name == "sim success" else f"r2s-eval, {name} judge")
            if name in in_twin:
                avg, lo, hi = spread(in_twin[name])
                ax.errorbar([x + 0.15], [avg], yerr=[[avg - lo], [hi - avg]], fmt=marker, capsize=3,
                            color=bar.lines[0].get_color(), markerfacecolor="none",
                            label="hollow: against the twin's truth of the networks ranked" if k == 0 else None)
        ax.set_xlabel("real trials per task and policy")
        ax.set_ylabel("pairs ordered as the truth (%)")
        ax.set_ylim(0, 102)
        ax.set_xlim(-1, (m.max() if len(m) else 20) + 1)
        level = (summary.get("beside_real") or {}).get("level")
        spans = f"{100 * level:g} % intervals over them" if level else "their range"
        title = f"{summary['repetitions']} repetitions ({spans}), {len(summary['policies'])} candidates"
        sim_inits = summary.get("sim_inits_per_repetition_and_task")
        if sim_inits:  # what the points at 0 real trials rank from
            title += f"\nthe sim's points from {sim_inits} sim rollouts per task and policy"
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize="small")
    return fig


# ------------------------------------------------------------------ judge resolution


def resolution_figure(cards: Mapping[str, dict], opts: Mapping):
    """One panel per kind: each judge's share of pairs that both succeeded preferring the clean run
    (points with their intervals) against the magnitude, the detection share and one half as
    lines, and the changed run's success in both worlds (dashed, right axis)."""
    first = next(iter(cards.values()))
    kinds = list(first["kinds"])
    with matplotlib.rc_context(_rc(opts)):
        cols = min(len(kinds), int(opts["columns"]))
        rows_n = -(-len(kinds) // cols)
        fig = _figure(opts["panel_width_in"] * cols, opts["panel_height_in"] * rows_n)
        axes = np.atleast_1d(fig.subplots(rows_n, cols, squeeze=False)).ravel()
        for ax, kind in zip(axes, kinds):
            for k, judge in enumerate(sorted(cards)):
                rows = sorted((r for r in cards[judge]["levels"] if r["kind"] == kind), key=lambda r: r["level"])
                x = np.arange(1, len(rows) + 1) + 0.08 * (k - (len(cards) - 1) / 2)
                share, low, high = (np.array([np.nan if r["both_succeeded"][key] is None else 100 * r["both_succeeded"][key]
                                              for r in rows]) for key in ("share", "ci_low", "ci_high"))
                ax.errorbar(x, share, yerr=[share - low, high - share], marker=opts["judge_markers"][k % len(opts["judge_markers"])],
                            capsize=2, label=judge)
            rows = sorted((r for r in first["levels"] if r["kind"] == kind), key=lambda r: r["level"])
            ax.axhline(100 * float(first["detect_share"]), color="0.4", linewidth=0.8)
            ax.axhline(50, color="0.7", linewidth=0.8, linestyle=":")
            ax.set_xticks(np.arange(1, len(rows) + 1), [magnitude_label(r["magnitude"]) for r in rows])
            ax.set_xlabel(rows[0]["key"] if rows else kind)
            ax.set_ylim(0, 102)
            ax.set_title(kind)
            twin = ax.twinx()
            for world, style in (("sim", "--"), ("real", ":")):
                rates = [r["success"][world]["changed"]["rate"] if r["success"][world] else None for r in rows]
                if any(v is not None for v in rates):
                    twin.plot(np.arange(1, len(rows) + 1), [np.nan if v is None else 100 * v for v in rates],
                              style, color=opts["success_color"], label=f"success ({world})")
            twin.set_ylim(0, 102)
            twin.tick_params(axis="y", colors=opts["success_color"])
            if ax is axes[min(cols, len(kinds)) - 1] or kind == kinds[-1]:
                twin.set_ylabel("changed run's success (%)", color=opts["success_color"])
        for ax in axes[:: cols]:
            ax.set_ylabel("prefers clean (%)")
        for ax in axes[len(kinds):]:
            ax.set_visible(False)
        handles, labels = axes[0].get_legend_handles_labels()
        extra = axes[0].figure.axes[-1].get_legend_handles_labels() if len(kinds) else ([], [])
        fig.legend(handles + extra[0], labels + extra[1], loc="outside lower center", ncols=4, fontsize="small")
    return fig
