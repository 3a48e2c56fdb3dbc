"""The calibrated world's fidelity per task, from the pipeline's artefacts.

Per task: scripted-teleop success in the twin (and why attempts failed: the operator's phase and
reason, ``r2s_eval.twin.failures``, counted), initial-pose error against the twin's truth
(median and 95th percentile, mm and degrees; yaw over objects whose yaw is observable, modulo
their symmetry; test episodes only), replay success at the first attempt and within the attempt
budget with Wilson intervals, the attempts used (test episodes only), and what each costs per
episode. Given the reference and the sim rollouts, also the real-sim success gap per policy and
task (sim minus real, Newcombe's interval) and over the cells (``r2s_eval.stats.proportions``).
:func:`build_report` returns::

    {"targets": {...},
     "tasks": {task: {"teleop": {"attempts", "successes", "success_rate", "s_per_attempt",
                                 "failures": {"<phase>: <reason>": count}},
                      "init_error": {"episodes", "xy_mm_median", "xy_mm_p95", "yaw_deg_median",
                                     "yaw_deg_p95", "objects": {object: {...}}},
                      "replay": {"episodes", "successes", "success_rate", "success_ci",
                                 "first_attempt_successes", "first_attempt_rate",
                                 "first_attempt_ci", "attempts_mean", "attempts_max",
                                 "attempts_histogram", "s_per_episode"},
                      "realsim_gap": [{"policy", "real", "real_ci", "real_trials", "sim",
                                       "sim_ci", "sim_trials", "gap_pp", "gap_ci_pp"}],
                      "meets_targets": bool}},
     "realsim_gap": {"cells", "mean_abs_gap_pp", "mean_abs_gap_ci_pp", "mean_gap_pp",
                     "mean_gap_ci_pp", "max_abs_gap_pp", "real_trials_per_cell", ...} | null,
     "init_s_per_episode": float | null,
     "calibration": {"cameras": {estimate: {camera: {"position_mm", "rotation_deg"}}}, "used",
                     "appearance": {"fitted", "residual_before", "residual_after"}
                     [, "lens": {estimate: {camera: {"distortion_px", ...}}}]} (the calib_error stage's)}

and :func:`format_table` lays it out as a text table.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from r2s_eval.errors import DataError
from r2s_eval.report.fidelity_report import joint_line, latency_line, part_sentence
from r2s_eval.stats.proportions import gap_summary, success_gap_cells, wilson_interval
from r2s_eval.utils.io import read_json

TARGETS = {"teleop_success_min": 0.90, "xy_mm_median_max": 5.0, "yaw_deg_median_max": 5.0, "replay_success_min": 0.95}


def _stats(values: pd.Series) -> tuple[float | None, float | None]:
    if values.empty:
        return None, None
    return float(values.median()), float(values.quantile(0.95))


def teleop_summary(attempts: list[dict]) -> dict:
    out = {}
    for task, rows in pd.DataFrame(attempts).groupby("task", sort=False):
        failed = rows[~rows["success"]]
        why = (failed["phase"] + ": " + failed["reason"]).value_counts() if "reason" in rows else pd.Series(dtype=int)
        out[task] = {
            "attempts": int(len(rows)),
            "successes": int(rows["success"].sum()),
            "success_rate": float(rows["success"].mean()),
            "s_per_attempt": float(rows["wall_s"].mean()) if "wall_s" in rows else None,
            "failures": {str(k): int(v) for k, v in why.items()},
        }
    return out


def failure_lines(report: dict) -> list[str]:
    """Why the operator's teleop attempts failed, per task (none: no lines)."""
    lines = []
    for task, row in report["tasks"].items():
        failures = (row["teleop"] or {}).get("failures")
        if failures:
            lines.append(f"  {task}: " + ", ".join(f"{n} {what}" for what, n in failures.items()))
    return ["", "failed teleop attempts (phase: reason; r2s_eval.twin.failures):", *lines] if lines else []


def init_error_summary(errors: pd.DataFrame) -> dict:
    out = {}
    for task, rows in errors.groupby("task", sort=False):
        observable = rows[rows["yaw_symmetry"] > 0]
        xy_med, xy_p95 = _stats(rows["error_xy_mm"])
        yaw_med, yaw_p95 = _stats(observable["error_yaw_deg"])
        objects = {}
        for obj, g in rows.groupby("object"):
            o_xy = _stats(g["error_xy_mm"])
            o_yaw = _stats(g["error_yaw_deg"]) if int(g["yaw_symmetry"].iloc[0]) > 0 else (None, None)
            objects[obj] = {"xy_mm_median": o_xy[0], "xy_mm_p95": o_xy[1], "yaw_deg_median": o_yaw[0],
                            "yaw_deg_p95": o_yaw[1], "yaw_symmetry": int(g["yaw_symmetry"].iloc[0])}
        out[task] = {"episodes": int(rows["episode_index"].nunique()), "xy_mm_median": xy_med, "xy_mm_p95": xy_p95,
                     "yaw_deg_median": yaw_med, "yaw_deg_p95": yaw_p95, "objects": objects}
    return out


def _ci(interval: tuple[float, float] | None) -> list[float] | None:
    return None if interval is None else [interval[0], interval[1]]


def replay_summary(log_table: pd.DataFrame, level: float) -> dict:
    test = log_table[~log_table["calibration"]] if "calibration" in log_table else log_table
    out = {}
    for task, rows in test.groupby("task", sort=False):
        used = rows.loc[rows["success"], "attempts"]
        first = int((rows["success"] & (rows["attempts"] == 1)).sum())
        out[task] = {
            "episodes": int(len(rows)),
            "successes": int(rows["success"].sum()),
            "success_rate": float(rows["success"].mean()),
            "success_ci": _ci(wilson_interval(int(rows["success"].sum()), len(rows), level)),
            "first_attempt_successes": first,
            "first_attempt_rate": first / len(rows),
            "first_attempt_ci": _ci(wilson_interval(first, len(rows), level)),
            "attempts_mean": float(used.mean()) if len(used) else None,
            "attempts_max": int(used.max()) if len(used) else None,
            "attempts_histogram": {int(k): int(v) for k, v in used.value_counts().sort_index().items()},
            "s_per_episode": float(rows["wall_s"].mean()) if "wall_s" in rows else None,
        }
    return out


def gap_by_task(cells: pd.DataFrame) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for c in cells.itertuples():
        out.setdefault(c.task, []).append({
            "policy": c.policy, "real": c.real, "real_ci": [c.real_ci_low, c.real_ci_high],
            "real_trials": c.real_trials, "sim": c.sim, "sim_ci": [c.sim_ci_low, c.sim_ci_high],
            "sim_trials": c.sim_trials, "gap_pp": 100 * c.gap,
            "gap_ci_pp": [100 * c.gap_ci_low, 100 * c.gap_ci_high]})
    return out


def build_report(attempts: list[dict], errors: pd.DataFrame, replay_log: pd.DataFrame,
                 init_s_per_episode: float | None = None, reference: pd.DataFrame | None = None,
                 sim_episodes: pd.DataFrame | None = None, *, level: float, n_boot: int,
                 seed: int, fidelity: dict | None = None, calibration: dict | None = None) -> dict:
    """The report above; the real-sim gap needs both ``reference`` and ``sim_episodes``; given
    the fidelity report and the calib_error stage's scores, their summaries too."""
    teleop, init = teleop_summary(attempts), init_error_summary(errors)
    replay = replay_summary(replay_log, level)
    cells = None
    if reference is not None and sim_episodes is not None:
        cells = success_gap_cells(reference, sim_episodes, level)
    gaps = gap_by_task(cells) if cells is not None else {}
    tasks = {}
    for task in dict.fromkeys([*teleop, *init, *replay]):
        t, i, r = teleop.get(task), init.get(task), replay.get(task)
        # Pose targets hold for every object of the task, not only pooled over them.
        poses_ok = i is not None and all(
            o["xy_mm_median"] is not None and o["xy_mm_median"] <= TARGETS["xy_mm_median_max"]
            and (o["yaw_deg_median"] is None or o["yaw_deg_median"] <= TARGETS["yaw_deg_median_max"])
            for o in i["objects"].values()
        )
        meets = bool(
            t is not None and t["success_rate"] >= TARGETS["teleop_success_min"] and poses_ok
            and r is not None and r["success_rate"] >= TARGETS["replay_success_min"]
        )
        tasks[task] = {"teleop": t, "init_error": i, "replay": r, "realsim_gap": gaps.get(task, []),
                       "meets_targets": meets}
    summary = gap_summary(cells, level, n_boot, seed) if cells is not None else None
    report = {"targets": TARGETS, "tasks": tasks, "realsim_gap": summary, "init_s_per_episode": init_s_per_episode}
    if fidelity is not None:
        report["fidelity"] = fidelity_summary(fidelity)
    if calibration is not None:
        report["calibration"] = calibration_summary(calibration)
    return report


def fidelity_summary(fidelity: dict) -> dict:
    """What the world report shows of the fidelity report: each part of the real-sim gap
    (summaries, not cells), the same-policy agreement and the joint offsets against the twin's."""
    parts = {name: {k: v for k, v in part.items() if k != "cells_gap_pp"}
             for name, part in fidelity["cross"]["parts"].items()}
    return {"parts": parts, "agreement": fidelity["cross"]["agreement"], "joints": fidelity["joints"]}


def calibration_summary(scores: dict) -> dict:
    """What the world report shows of the calib_error stage's scores (its provenance aside)."""
    summary = {k: scores[k] for k in ("cameras", "used", "appearance")}
    if "lens" in scores:  # only when an estimate fitted the cameras' lenses
        summary["lens"] = scores["lens"]
    return summary


CAMERA_GOALS = {"board": (2.0, 0.2), "silhouette": (5.0, 0.5)}  # (mm, deg) against the twin's truth


def camera_lines(calibration: dict) -> list[str]:
    """The cameras' pose errors against the twin's truth, per estimate (the model's poses first),
    and the appearance fit's colour error before and after."""
    estimates = {m: calibration["cameras"][m] for m in sorted(calibration["cameras"], key=lambda m: m != "model")}
    header = f"{'camera':14s} " + " ".join(f"{m:>22s}" for m in estimates)
    lines = [f"camera pose error against the twin (model: the model file's poses); the calibrated sim uses: "
             f"{calibration['used']}",
             header, "-" * len(header)]
    names = sorted({c for per in estimates.values() for c in per})
    for cam in names:
        cells = []
        for per in estimates.values():
            e = per.get(cam)
            cells.append(f"{e['position_mm']:8.2f} mm {e['rotation_deg']:6.3f} deg" if e else "-")
        lines.append(f"{cam:14s} " + " ".join(f"{c:>22s}" for c in cells))
    lines.append("goals: " + ", ".join(f"{m} <= {mm:g} mm and <= {deg:g} deg" for m, (mm, deg) in CAMERA_GOALS.items()))
    for method, lenses in (calibration.get("lens") or {}).items():
        for cam, e in sorted(lenses.items()):
            lines.append(f"lens {cam} ({method}, {e['image_size'][1]} x {e['image_size'][0]} px): distortion "
                         f"{e['distortion_px']:.2f} px RMS ({e['distortion_max_px']:.2f} max; no lens "
                         f"{e['model_px']:.2f}), focal {e['focal_pct']['fx']:+.2f} / {e['focal_pct']['fy']:+.2f} %, "
                         f"principal point {e['principal_point_px']:.2f} px off")
    for cam, e in sorted((calibration.get("background") or {}).items()):
        lines.append(f"background {cam}: mean colour error of {e['frames']} first frames {e['without_plate']:.1f} with "
                     f"the sim's own surroundings, {e['with_plate']:.1f} over the plate from the recordings (0-255)")
        s = e.get("shadows") or {}
        if s.get("pixels"):
            lines.append(f"shadows {cam}: where the sim shades the room ({s['pixels']} px of {s['frames']} frames) the "
                         f"recordings are at {100 * s['recorded']:.0f} % of the plate, the sim at {100 * s['sim']:.0f} %; "
                         f"elsewhere the recordings at {100 * s['unshaded_recorded']:.0f} %")
    appearance = calibration.get("appearance") or {}
    if appearance.get("fitted"):
        lines.append(f"appearance: mean colour error of the first frames {appearance['residual_before']:.1f} -> "
                     f"{appearance['residual_after']:.1f} (0-255) with the fitted light and colours")
    if "light_scale" in appearance:
        light, colours = appearance["light_scale"], appearance["object_rgb_error"]
        lines.append(f"appearance against the twin: light x{light['sim']:.3f} (the twin's x{light['twin']:.3f}); "
                     "each object's colour off the twin's by " + ", ".join(
                         f"{name} {e['sim']:.1f}" for name, e in colours.items())
                     + " (0-255; the world file's colours: " + ", ".join(
                         f"{name} {e['model']:.1f}" for name, e in colours.items()) + ")")
    if "key_light_deg" in appearance:
        lines.append(f"shadows: sim {'on' if appearance['shadows'] else 'off'}, twin "
                     f"{'on' if appearance['twin_shadows'] else 'off'}; the key light "
                     f"{appearance['key_light_deg']:.1f} deg from the twin's")
    return lines


def _fmt(value, spec: str) -> str:
    width = int("".join(c for c in spec.split(".")[0] if c.isdigit()) or 0)
    return "-".rjust(width) if value is None else format(value, spec)


def _pct_ci(value, ci) -> str:
    if value is None:
        return "-"
    return f"{100 * value:.0f} [{100 * ci[0]:.0f}, {100 * ci[1]:.0f}]" if ci else f"{100 * value:.0f}"


DEFAULT_REPORT = "results/world/report.json"  # where the workflow writes it, from the working directory


def saved_table(path: str | Path = DEFAULT_REPORT) -> str:
    """The table of a world report the workflow wrote."""
    if not Path(path).is_file():
        raise DataError(f"{path}: no world report here; the workflow writes it (snakemake -j 2 {DEFAULT_REPORT}) "
                        f"in the run's working directory")
    return format_table(read_json(path))


def format_table(report: dict) -> str:
    header = (f"{'task':16s} {'object':8s} {'teleop':>7s} {'xy med':>7s} {'xy p95':>7s} {'yaw med':>8s} "
              f"{'yaw p95':>8s} {'replay 1st %':>13s} {'replay %':>13s} {'att.mean':>8s} {'att.max':>7s} {'ok':>3s}")
    lines = [header, "-" * len(header)]
    for task, row in report["tasks"].items():
        t, i, r = row["teleop"] or {}, row["init_error"] or {}, row["replay"] or {}
        objects = list((i.get("objects") or {}).items()) or [("-", {})]
        for k, (obj, o) in enumerate(objects):
            first = k == 0
            lines.append(
                f"{task if first else '':16s} {obj:8s} {_fmt(t.get('success_rate') if first else None, '7.1%')} "
                f"{_fmt(o.get('xy_mm_median'), '7.1f')} {_fmt(o.get('xy_mm_p95'), '7.1f')} "
                f"{_fmt(o.get('yaw_deg_median'), '8.1f')} {_fmt(o.get('yaw_deg_p95'), '8.1f')} "
                f"{(_pct_ci(r.get('first_attempt_rate'), r.get('first_attempt_ci')) if first else ''):>13s} "
                f"{(_pct_ci(r.get('success_rate'), r.get('success_ci')) if first else ''):>13s} "
                f"{_fmt(r.get('attempts_mean') if first else None, '8.2f')} "
                f"{_fmt(r.get('attempts_max') if first else None, '7d')} "
                f"{('yes' if row['meets_targets'] else 'NO') if first else '':>3s}"
            )
    lines.append("xy in mm, yaw in degrees (objects with observable yaw, modulo symmetry); init and replay over "
                 "test episodes, replay % with Wilson intervals; targets: teleop >= 90 %, medians <= 5 mm and "
                 "<= 5 deg, replay >= 95 %")
    lines += failure_lines(report)
    summary = report.get("realsim_gap")
    if summary and summary.get("cells"):
        gap_header = f"{'task':16s} {'policy':16s} {'real %':>13s} {'sim %':>13s} {'sim - real (pp)':>17s}"
        lines += ["", gap_header, "-" * len(gap_header)]
        for task, row in report["tasks"].items():
            for c in row.get("realsim_gap") or []:
                gap = f"{c['gap_pp']:+.0f} [{c['gap_ci_pp'][0]:+.0f}, {c['gap_ci_pp'][1]:+.0f}]"
                lines.append(f"{task:16s} {c['policy']:16s} {_pct_ci(c['real'], c['real_ci']):>13s} "
                             f"{_pct_ci(c['sim'], c['sim_ci']):>13s} {gap:>17s}")
        lo, hi = summary["mean_abs_gap_ci_pp"]
        slo, shi = summary["mean_gap_ci_pp"]
        lines.append(
            f"real-sim gap over {summary['cells']} policy-task cells: mean |sim - real| {summary['mean_abs_gap_pp']:.1f} pp "
            f"[{lo:.1f}, {hi:.1f}], mean sim - real {summary['mean_gap_pp']:+.1f} pp [{slo:+.1f}, {shi:+.1f}], "
            f"largest {summary['max_abs_gap_pp']:.1f} pp; trials per cell: real {summary['real_trials_per_cell']}, "
            f"sim {summary['sim_trials_per_cell']} ({100 * summary['ci_level']:g}% intervals: Wilson per rate, "
            f"Newcombe per gap, {summary['interval']})")
    calibration = report.get("calibration")
    if calibration:
        lines += ["", *camera_lines(calibration)]
    fidelity = report.get("fidelity")
    if fidelity:
        lines += ["", "the gap split (same checkpoint in both worlds; reports/fidelity_table.tex):"]
        lines += [f"  {part_sentence(name, part)}" for name, part in fidelity["parts"].items() if part.get("cells")]
        lines += [f"  {joint_line(arm, j)}" for arm, j in fidelity["joints"]["arms"].items()]
        if "latency" in fidelity["joints"]:
            lines.append(f"  {latency_line(fidelity['joints']['latency'])}")
    return "\n".join(lines)
