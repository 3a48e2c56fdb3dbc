"""The fidelity report: the same checkpoint in both worlds, the joint calibration against the
twin's truth, what each perturbation family costs, and the spread over training seeds.

Its JSON layout (``results/fidelity/report.json``, built by ``r2s_eval.stages.fidelity``)::

    {"cross": r2s_eval.stats.fidelity.cross_evaluation(...),
     "joints": {"estimated": bool, "arms": {arm: {"estimated_deg": [...], "truth_deg": [...] | null,
                                                "error_deg": [...] | null}},
                "latency": {"estimated_steps": k, "truth_steps": float | null}  (when it was estimated;
                            the twin's latency in control steps, a fraction where it falls mid-step)},
     "ablation": [{"policy", "family", "successes", "trials", "rate", "ci", "full_twin_rate",
                   "cost_pp", "cost_ci_pp"}],
     "seeds": r2s_eval.stats.fidelity.seed_spread(...),
     "cross_trainings": {**cross_evaluation(...), "trainings": {policy: n}, "training_means_pp": {part: {label: pp}}}
             (the crossing over every training of each recipe, the candidate's own cells and each further
             seed's, "act/1" replicate 1 of act; only where the further seeds crossed into the other world),
     "sims": {sim: {"cells", "parts": {"calibration", "calibration_reverse"}, "agreement"}}
             (the crossing both ways in each further sim, as "cross" holds it for the calibrated one),
     "alone": [ablation rows, "family" the effect left on, costs against the twin with none]}
"""

from __future__ import annotations

from collections.abc import Mapping

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from r2s_eval.report.figures import _figure, _rc
from r2s_eval.report.tables import DASH, _row, _tabular, latex_escape
from r2s_eval.stats.fidelity import cross_evaluation, seed_spread
from r2s_eval.stats.proportions import newcombe_difference, success_counts, wilson_interval
from r2s_eval.twin.perturb import NO_EFFECT

WORLD_LABELS = {"R_real": r"$\pi^R$ real", "R_sim": r"$\pi^R$ sim", "S_sim": r"$\pi^S$ sim", "S_real": r"$\pi^S$ real"}


def build_report(reference: pd.DataFrame, sim: pd.DataFrame, cross_sim: pd.DataFrame, cross_real: pd.DataFrame | None,
                 ablated: Mapping[str, pd.DataFrame], seed_episodes: Mapping[tuple[str, int], pd.DataFrame],
                 calibrated: Mapping, truth: Mapping | None, level: float, n_boot: int, seed,
                 latency_truth: float | None = None, sims: Mapping[str, pd.DataFrame] | None = None,
                 alone: Mapping[str, pd.DataFrame] | None = None, real: pd.DataFrame | None = None) -> dict:
    """The report (module docstring) from the reference success table (R_real), episode tables
    (pi^S in the sim, pi^R in the sim, pi^S on the real side; ``ablated``: family -> pi^S's episodes
    in the twin without it; ``seed_episodes``: (world, replicate) -> a further seed's episodes),
    the calibrated sim's world-parameter record and the twin's true joint offsets and commands'
    latency (control steps, its reality effects' seconds times the control rate); ``sims``:
    "SIM:TRAINED_ON" -> the episodes of the checkpoints trained on that arm in a further sim;
    ``alone``: effect -> pi^S's episodes in the twin with that effect alone (``none`` among them);
    ``real``: pi^R's episodes on the real side where the reference was counted from them (then
    every crossing's interval is paired over the shared inits)."""
    world_episodes = {"R_real": real, "R_sim": cross_sim, "S_sim": sim, "S_real": cross_real}
    worlds = {"R_real": reference, "R_sim": success_counts(cross_sim), "S_sim": success_counts(sim),
              "S_real": None if cross_real is None else success_counts(cross_real)}
    seeds: dict[str, dict[int, pd.DataFrame]] = {}
    for (world, replicate), episodes in seed_episodes.items():
        seeds.setdefault(world, {})[replicate] = success_counts(episodes)
    for world, tables in seeds.items():  # replicate 0 is the candidate itself, for the policies with more seeds
        trained = set().union(*(t["policy"] for t in tables.values()))
        tables[0] = worlds[world][worlds[world]["policy"].isin(trained)]
    joints = joint_report(calibrated.get("joints", {}).get("offsets_rad"), truth)
    latency = calibrated.get("joints", {}).get("latency_steps")
    if latency is not None:  # calib_joints estimated it
        joints["latency"] = {"estimated_steps": int(latency),
                             "truth_steps": None if latency_truth is None else round(float(latency_truth), 3)}
    report = {
        "cross": cross_evaluation(worlds, level, n_boot, seed, world_episodes),
        "joints": joints,
        "ablation": ablation_rows(ablated, cross_real, level),
        "seeds": seed_spread(seeds),
        "sims": sims_report(sims or {}, reference, worlds["S_real"], level, n_boot, seed, world_episodes),
        "alone": alone_rows(alone or {}, level),
    }
    trainings = every_training(worlds, world_episodes, seed_episodes)
    if trainings is not None:
        report["cross_trainings"] = crossing_over_trainings(*trainings, level, n_boot, seed)
    return report


def training_label(policy: str, replicate: int) -> str:
    """A training's name in the crossing over trainings: the candidate itself, or "act/1"."""
    return policy if replicate == 0 else f"{policy}/{replicate}"


def every_training(worlds: Mapping[str, pd.DataFrame | None], world_episodes: Mapping[str, pd.DataFrame | None],
                   seed_episodes: Mapping[tuple[str, int], pd.DataFrame]) -> tuple[dict, dict] | None:
    """The four worlds' success tables and episodes of every checkpoint trained here (those with
    pi^R in the sim), each further training seed's cells beside the candidate's under
    ``training_label``; None where no further seed ran in all four worlds."""
    crossing = tuple(WORLD_LABELS)  # R_real, R_sim, S_sim, S_real
    replicates = sorted(k for world, k in seed_episodes
                        if world == "R_sim" and all((w, k) in seed_episodes for w in crossing))
    if not replicates or any(worlds.get(w) is None for w in crossing):
        return None
    trained = set(worlds["R_sim"]["policy"])

    def relabel(frame: pd.DataFrame, k: int) -> pd.DataFrame:
        return frame.assign(policy=[training_label(p, k) for p in frame["policy"]])

    tables, episodes = {}, {}
    for world in crossing:
        own = worlds[world][worlds[world]["policy"].isin(trained)]
        tables[world] = pd.concat([own, *(relabel(success_counts(seed_episodes[(world, k)]), k) for k in replicates)],
                                  ignore_index=True)
        own_episodes = world_episodes.get(world)  # a world known by its counts alone is drawn binomially, as ever
        episodes[world] = None if own_episodes is None else pd.concat(
            [own_episodes[own_episodes["policy"].isin(trained)],
             *(relabel(seed_episodes[(world, k)], k) for k in replicates)], ignore_index=True)
    return tables, episodes


def crossing_over_trainings(tables: Mapping[str, pd.DataFrame], episodes: Mapping[str, pd.DataFrame | None],
                            level: float, n_boot: int, seed) -> dict:
    """``cross_evaluation`` over every training (``every_training``), with how many trainings each
    recipe has and each training's own mean gap per part (its tasks' cells): the interval redraws
    the shared inits given these trainings, the per-training means show how far one training
    alone would have moved the number."""
    cross = cross_evaluation(dict(tables), level, n_boot, seed, dict(episodes))
    labels = sorted(set(tables["R_sim"]["policy"]))
    recipes = [label.partition("/")[0] for label in labels]
    cross["trainings"] = {recipe: recipes.count(recipe) for recipe in sorted(set(recipes))}
    cross["training_means_pp"] = {
        part: {label: float(np.mean([c["gap_pp"] for c in summary["cells_gap_pp"] if c["policy"] == label]))
               for label in labels if any(c["policy"] == label for c in summary["cells_gap_pp"])}
        for part, summary in cross["parts"].items()}
    return cross


CROSSING_PARTS = ("calibration", "calibration_reverse")  # the same weights in the twin and in a sim


def sims_report(sims: Mapping[str, pd.DataFrame], reference: pd.DataFrame, s_real: pd.DataFrame | None, level: float,
                n_boot: int, seed, real_episodes: Mapping[str, pd.DataFrame | None] | None = None) -> dict:
    """Per further sim, the crossing both ways: pi^R there against pi^R on the real side and pi^S
    on the real side against pi^S there (``cross_evaluation``'s calibration parts, its cells and
    the same-policy agreement). ``sims``: "SIM:TRAINED_ON" -> episodes; ``real_episodes``: the
    real side's episodes (R_real, S_real) where at hand, for paired intervals."""
    arms: dict[str, dict[str, pd.DataFrame]] = {}
    for key, episodes in sims.items():
        sim, _, trained_on = key.partition(":")
        arms.setdefault(sim, {})[trained_on] = episodes
    real_episodes = {k: v for k, v in (real_episodes or {}).items() if k in ("R_real", "S_real")}
    out = {}
    for sim, arm in sorted(arms.items()):
        tables = {trained_on: success_counts(episodes) for trained_on, episodes in arm.items()}
        cross = cross_evaluation({"R_real": reference, "R_sim": tables.get("real"), "S_sim": tables.get("sim"),
                                  "S_real": s_real}, level, n_boot, seed,
                                 {**real_episodes, "R_sim": arm.get("real"), "S_sim": arm.get("sim")})
        out[sim] = {"cells": [c for c in cross["cells"] if "R_sim" in c or "S_sim" in c],
                    "parts": {k: v for k, v in cross["parts"].items() if k in CROSSING_PARTS},
                    "agreement": cross["agreement"]}
    return out


def alone_rows(alone: Mapping[str, pd.DataFrame], level: float) -> list[dict]:
    """``ablation_rows`` of the twin with each effect alone, each cost against the twin with none."""
    if not alone:
        return []
    if NO_EFFECT not in alone:
        raise ValueError(f"the twin with each effect alone needs its reference, the twin with {NO_EFFECT!r}")
    return ablation_rows({e: episodes for e, episodes in alone.items() if e != NO_EFFECT}, alone[NO_EFFECT], level)


def sim_rates(report: Mapping) -> dict[str, float]:
    """pi^S's pooled success in the sim per policy (the ablation figure's reference line)."""
    pooled: dict[str, list[int]] = {}
    for c in report["cross"]["cells"]:
        if "S_sim" in c:
            s, n = pooled.setdefault(c["policy"], [0, 0]), c["S_sim"]
            s[0], s[1] = s[0] + n["successes"], s[1] + n["trials"]
    return {policy: s / n for policy, (s, n) in pooled.items()}


def joint_report(estimated: Mapping | None, truth: Mapping | None) -> dict:
    """Per arm, the estimated joint offsets against the twin's (when there is one), in degrees."""
    if not estimated:
        return {"estimated": False, "arms": {}}
    arms = {}
    for arm, values in estimated.items():
        est = np.rad2deg(np.asarray(values, float))
        true = None if truth is None or arm not in truth else np.rad2deg(np.asarray(truth[arm], float))
        arms[arm] = {"estimated_deg": est.tolist(), "truth_deg": None if true is None else true.tolist(),
                     "error_deg": None if true is None else (est - true).tolist()}
    return {"estimated": True, "arms": arms}


def ablation_rows(ablated: Mapping[str, pd.DataFrame], full_twin: pd.DataFrame | None, level: float) -> list[dict]:
    """Per (policy, family): pi^S's success in the twin with that family taken away, and what the
    family costs (that rate minus the full twin's, Newcombe interval). ``ablated``: family ->
    episodes (policy, success) rolled out there; ``full_twin``: pi^S's episodes in the twin."""
    rows = []
    for family, episodes in ablated.items():
        for policy, outcome in episodes.groupby("policy")["success"]:
            s, n = int(outcome.sum()), int(outcome.size)
            row = {"policy": policy, "family": family, "successes": s, "trials": n, "rate": s / n,
                   "ci": list(wilson_interval(s, n, level)), "full_twin_rate": None, "cost_pp": None, "cost_ci_pp": None}
            if full_twin is not None:
                base = full_twin.loc[full_twin["policy"] == policy, "success"]
                if len(base):
                    s0, n0 = int(base.sum()), int(base.size)
                    low, high = newcombe_difference(s, n, s0, n0, level)
                    row.update(full_twin_rate=s0 / n0, cost_pp=100 * (s / n - s0 / n0), cost_ci_pp=[100 * low, 100 * high])
            rows.append(row)
    return sorted(rows, key=lambda r: (r["policy"], r["family"]))


def _rate(cell: Mapping | None, decimals: int) -> str:
    return DASH if cell is None else f"{100 * cell['rate']:.{decimals}f}"


def _gap(part: Mapping | None, policy: str, task: str, decimals: int) -> str:
    for c in (part or {}).get("cells_gap_pp", []):
        if c["policy"] == policy and c["task"] == task:
            return f"{c['gap_pp']:+.{decimals}f} [{c['ci_pp'][0]:+.{decimals}f}, {c['ci_pp'][1]:+.{decimals}f}]"
    return DASH


def fidelity_table(report: Mapping, decimals: int = 1) -> str:
    """LaTeX: per task and policy, success of each checkpoint in each world (%) and the gap's
    calibration and training parts (pp, with intervals); under it each part's mean |gap|."""
    cross = report["cross"]
    parts = cross["parts"]
    worlds = [w for w in WORLD_LABELS if any(w in c for c in cross["cells"])]
    header = [_row(["Task", "Policy", *[WORLD_LABELS[w] for w in worlds], "Calibration (pp)", "Training (pp)"])]
    body = [_row([latex_escape(c["task"]), latex_escape(c["policy"]), *[_rate(c.get(w), decimals) for w in worlds],
                  _gap(parts.get("calibration"), c["policy"], c["task"], decimals),
                  _gap(parts.get("training"), c["policy"], c["task"], decimals)]) for c in cross["cells"]]
    notes = [latex_part_sentence(name, summary, decimals) for name, summary in parts.items() if summary.get("cells")]
    if "cross_trainings" in report:
        over = report["cross_trainings"]
        notes += [f"Over every training ({latex_escape(_trainings_text(over))}): "
                  + latex_part_sentence(name, summary, decimals)
                  for name, summary in over["parts"].items() if name in CROSSING_PARTS and summary.get("cells")]
    level = 100 * cross["ci_level"]
    notes.append(f"Calibration: $\\pi^R$ sim $-$ $\\pi^R$ real (same weights); training: $\\pi^S$ sim $-$ $\\pi^R$ sim "
                 f"(same world); {level:g}\\% Newcombe intervals per cell, percentile bootstrap for means.")
    return _tabular("ll" + "r" * len(worlds) + "rr", header, body, notes=notes)


def _trainings_text(over: Mapping) -> str:
    """"act 3, act_close 3 trainings" from the crossing over trainings."""
    return ", ".join(f"{p} {n}" for p, n in over["trainings"].items()) + " trainings"


def _drawn(summary: Mapping) -> str:
    """How the part's intervals were drawn, in a few words."""
    return "paired over the shared inits" if summary.get("paired") else "each side drawn on its own"


def part_sentence(name: str, summary: Mapping, decimals: int = 1) -> str:
    """One line: a part's mean absolute gap and signed mean with their intervals, largest, cells,
    and how the intervals were drawn."""
    lo, hi = summary["mean_abs_gap_ci_pp"]
    signed_lo, signed_hi = summary["mean_gap_ci_pp"]
    return (f"{name} ({summary['compares']}): mean |gap| {summary['mean_abs_gap_pp']:.{decimals}f} pp "
            f"[{lo:.{decimals}f}, {hi:.{decimals}f}], mean {summary['mean_gap_pp']:+.{decimals}f} pp "
            f"[{signed_lo:+.{decimals}f}, {signed_hi:+.{decimals}f}], largest "
            f"{summary['max_abs_gap_pp']:.{decimals}f} pp over {summary['cells']} cells ({_drawn(summary)})")


def ablation_table(rows: list[Mapping], decimals: int = 1, alone: bool = False) -> str:
    """LaTeX: per ablation policy and family, pi^S's success in the twin without that family (%)
    and what the family costs (pp, with its interval); ``alone``: the rows of ``alone_rows``, the
    twin with only that effect, each cost against the twin with none."""
    header = [_row(["Policy", "Effect alone" if alone else "Without", r"$\pi^S$ in the twin (\%)", "Trials",
                    "Cost (pp)"])]
    body = []
    for r in rows:
        cost = DASH if r["cost_pp"] is None else (f"{r['cost_pp']:+.{decimals}f} [{r['cost_ci_pp'][0]:+.{decimals}f}, "
                                                  f"{r['cost_ci_pp'][1]:+.{decimals}f}]")
        family = "every family" if r["family"] == "all" else r["family"]
        body.append(_row([latex_escape(r["policy"]), latex_escape(family),
                          f"{100 * r['rate']:.{decimals}f} [{100 * r['ci'][0]:.{decimals}f}, {100 * r['ci'][1]:.{decimals}f}]",
                          str(r["trials"]), cost]))
    base = {r["policy"]: r["full_twin_rate"] for r in rows if r["full_twin_rate"] is not None}
    rates = ", ".join(f"{latex_escape(p)} {100 * v:.{decimals}f}\\%" for p, v in base.items())
    what = ("with the effect alone minus in the twin with none of its effects" if alone
            else "without the family minus in the full twin")
    notes = [f"Cost: success {what} ({rates}); Wilson intervals per rate, Newcombe per cost."]
    return _tabular("llrrr", header, body, notes=notes)


def alone_table(rows: list[Mapping], decimals: int = 1) -> str:
    """``ablation_table`` of the twin with each effect alone."""
    return ablation_table(rows, decimals, alone=True)


def _pooled(cells: list[Mapping], world: str) -> str:
    s = sum(c[world]["successes"] for c in cells if world in c)
    n = sum(c[world]["trials"] for c in cells if world in c)
    return DASH if not n else f"{100 * s / n:.1f}"


def _mean_gap(part: Mapping | None, decimals: int) -> str:
    if not part or not part.get("cells"):
        return DASH
    lo, hi = part["mean_gap_ci_pp"]
    return f"{part['mean_gap_pp']:+.{decimals}f} [{lo:+.{decimals}f}, {hi:+.{decimals}f}]"


def sims_table(report: Mapping, decimals: int = 1) -> str:
    """LaTeX: the crossing both ways in the calibrated sim and in each further sim: the
    checkpoints' pooled success there (%) and the mean signed gap over the cells (pp, with its
    interval): pi^R there minus pi^R on the real side, pi^S on the real side minus pi^S there."""
    header = [_row(["Sim", r"$\pi^R$ sim (\%)", r"$\pi^R$ sim $-$ real (pp)", r"$\pi^S$ sim (\%)",
                    r"$\pi^S$ real $-$ sim (pp)"])]
    cross = report["cross"]
    trained = {c["policy"] for c in cross["cells"] if "R_sim" in c}
    rows = {"calibrated": {"cells": [c for c in cross["cells"] if c["policy"] in trained], "parts": cross["parts"]}}
    if "cross_trainings" in report:  # the same sim over every training of each recipe
        over = report["cross_trainings"]
        rows["calibrated, every training"] = {
            "cells": [c for c in over["cells"] if "R_sim" in c], "parts": over["parts"]}
    rows.update(report["sims"])
    body = [_row([latex_escape(name.replace("_", " ")), _pooled(r["cells"], "R_sim"),
                  _mean_gap(r["parts"].get("calibration"), decimals), _pooled(r["cells"], "S_sim"),
                  _mean_gap(r["parts"].get("calibration_reverse"), decimals)]) for name, r in rows.items()]
    real = rows["calibrated"]["cells"]
    level = 100 * cross["ci_level"]
    paired = any(part.get("paired") for r in rows.values() for part in r["parts"].values())
    notes = [f"The same checkpoints in every sim, from the same initial configurations; on the real side "
             f"$\\pi^R$ {_pooled(real, 'R_real')}\\%, $\\pi^S$ {_pooled(real, 'S_real')}\\% "
             f"({', '.join(sorted(latex_escape(p) for p in trained))}). Mean signed gap over the policy-task cells, "
             f"{level:g}\\% percentile-bootstrap interval"
             f"{', paired over the shared inits where both sides ran them' if paired else ''}."]
    if "cross_trainings" in report:
        notes.append(f"Every training: each recipe's further training seeds beside the candidate "
                     f"({latex_escape(_trainings_text(report['cross_trainings']))}), the interval given those trainings.")
    return _tabular("lrrrr", header, body, notes=notes)


def latex_part_sentence(name: str, summary: Mapping, decimals: int = 1) -> str:
    """`part_sentence` as LaTeX text."""
    lo, hi = summary["mean_abs_gap_ci_pp"]
    signed_lo, signed_hi = summary["mean_gap_ci_pp"]
    plus, minus = summary["compares"].split(" - ")
    return (f"{latex_escape(name.replace('_', ' '))} ({WORLD_LABELS[plus]} $-$ {WORLD_LABELS[minus]}): mean $|$gap$|$ "
            f"{summary['mean_abs_gap_pp']:.{decimals}f} pp [{lo:.{decimals}f}, {hi:.{decimals}f}], mean "
            f"{summary['mean_gap_pp']:+.{decimals}f} pp [{signed_lo:+.{decimals}f}, {signed_hi:+.{decimals}f}], "
            f"largest {summary['max_abs_gap_pp']:.{decimals}f} pp, "
            f"{summary['cells']} cells, intervals {_drawn(summary)}")


def format_report(report: Mapping) -> str:
    """The report as text (the stage's log, the numbers in docs/suite.md)."""
    cross = report["cross"]
    lines = [f"{'task':16s} {'policy':12s} " + " ".join(f"{w:>16s}" for w in WORLD_LABELS)]
    for c in cross["cells"]:
        cells = []
        for w in WORLD_LABELS:
            v = c.get(w)
            cells.append(f"{'-':>16s}" if v is None else
                         f"{100 * v['rate']:5.1f} [{100 * v['ci'][0]:3.0f},{100 * v['ci'][1]:3.0f}]".rjust(16))
        lines.append(f"{c['task']:16s} {c['policy']:12s} " + " ".join(cells))
    lines += [part_sentence(name, s) for name, s in cross["parts"].items() if s.get("cells")]
    for name, a in cross.get("agreement", {}).items():
        pearson = "undefined" if a["pearson"] is None else f"{a['pearson']:.3f}"
        lines.append(f"same-policy agreement of {name} with R_real over {len(a['policies'])} policies: "
                     f"Pearson {pearson}, MMRV {a['mmrv_pp']:.1f} pp")
    if "cross_trainings" in report:
        over = report["cross_trainings"]
        lines += [f"over every training ({_trainings_text(over)}): " + part_sentence(name, s)
                  for name, s in over["parts"].items() if s.get("cells")]
        for name, means in over["training_means_pp"].items():
            lines.append(f"{name} per training (pp): " + ", ".join(f"{label} {v:+.1f}" for label, v in means.items()))
    lines += [joint_line(arm, j) for arm, j in report["joints"]["arms"].items()]
    if "latency" in report["joints"]:
        lines.append(latency_line(report["joints"]["latency"]))
    lines += [ablation_line(f"ablation {r['policy']} without {r['family']:10s}", r) for r in report["ablation"]]
    for sim, r in report.get("sims", {}).items():
        lines += [f"in {sim}: " + part_sentence(name, part) for name, part in r["parts"].items() if part.get("cells")]
    lines += [ablation_line(f"alone {r['policy']} with {r['family']:13s}", r) for r in report.get("alone", [])]
    for s in report["seeds"]:
        lines.append(f"seeds {s['world']:6s} {s['policy']:12s} {s['task']:16s} "
                     f"{[round(r, 1) for r in s['rates_pct']]} range {s['range_pp']:.1f} pp")
    return "\n".join(lines)


def ablation_line(label: str, row: Mapping) -> str:
    """One ablation row (``ablation_rows``) as text: its rate, interval, counts and cost."""
    cost = "" if row["cost_pp"] is None else (f", cost {row['cost_pp']:+.1f} pp "
                                              f"[{row['cost_ci_pp'][0]:+.1f}, {row['cost_ci_pp'][1]:+.1f}]")
    return (f"{label}: {100 * row['rate']:5.1f} % [{100 * row['ci'][0]:.1f}, {100 * row['ci'][1]:.1f}] "
            f"({row['successes']}/{row['trials']}){cost}")


def joint_line(arm: str, joints: Mapping) -> str:
    """One arm's estimated joint offsets (and the twin's, with the largest error) as text."""
    line = f"joint offsets {arm} (deg): estimated {np.round(joints['estimated_deg'], 2).tolist()}"
    if joints["truth_deg"] is not None:
        line += (f", twin {np.round(joints['truth_deg'], 2).tolist()}, largest error "
                 f"{np.abs(joints['error_deg']).max():.3f} deg")
    return line


def latency_line(latency: Mapping) -> str:
    """The estimated commands' latency (and the twin's) as text."""
    line = f"commands' latency (control steps): estimated {latency['estimated_steps']}"
    return line if latency["truth_steps"] is None else line + f", twin {latency['truth_steps']:g}"


def ablation_figure(rows: list[Mapping], sim_rates: Mapping[str, float], opts: Mapping) -> Figure:
    """Per ablation policy, pi^S's success in the twin with each family taken away (bars with
    intervals), against the full twin (dashed) and the calibrated sim (dotted)."""
    policies = sorted({r["policy"] for r in rows})
    with matplotlib.rc_context(_rc(opts)):
        fig = _figure(float(opts["width_in"]) * len(policies), float(opts["height_in"]))
        axes = fig.subplots(1, len(policies), squeeze=False)[0]
        for ax, policy in zip(axes, policies):
            mine = [r for r in rows if r["policy"] == policy]
            y = np.arange(len(mine))
            rates = np.array([100 * r["rate"] for r in mine])
            # A Wilson bound at 0 or n successes can sit a rounding error past the rate.
            err = np.clip([[100 * (r["rate"] - r["ci"][0]) for r in mine], [100 * (r["ci"][1] - r["rate"]) for r in mine]],
                          0, None)
            ax.barh(y, rates, xerr=err, color="#4c72b0", capsize=3)
            ax.set_yticks(y, [f"without {'every family' if r['family'] == 'all' else r['family']}" for r in mine])
            full = mine[0]["full_twin_rate"]
            if full is not None:
                ax.axvline(100 * full, color="#c44e52", linestyle="--", label="full twin")
            if policy in sim_rates:
                ax.axvline(100 * sim_rates[policy], color="#55a868", linestyle=":", label="calibrated sim")
            ax.set_xlim(0, 100)
            ax.set_xlabel(r"success of $\pi^S$ in the twin (%)")
            ax.set_title(policy)
            ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize="small", frameon=False)
    return fig

