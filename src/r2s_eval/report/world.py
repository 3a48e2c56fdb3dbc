"""The calibrated world's fidelity per task, from the pipeline's artefacts.

Per task: scripted-teleop success in the twin, initial-pose error against the twin's truth
(median and 95th percentile, mm and degrees; yaw over objects whose yaw is observable, modulo
their symmetry; test episodes only), replay success within the attempt budget and the
attempts used (test episodes only), and what each costs per episode. :func:`build_report`
returns::

    {"targets": {...},
     "tasks": {task: {"teleop": {"attempts", "successes", "success_rate", "s_per_attempt"},
                      "init_error": {"episodes", "xy_mm_median", "xy_mm_p95", "yaw_deg_median",
                                     "yaw_deg_p95", "objects": {object: {...}}},
                      "replay": {"episodes", "successes", "success_rate", "attempts_mean",
                                 "attempts_max", "attempts_histogram", "s_per_episode"},
                      "meets_targets": bool}},
     "init_s_per_episode": float | null}

and :func:`format_table` lays it out as a text table.
"""

from __future__ import annotations

import pandas as pd

TARGETS = {"teleop_success_min": 0.90, "xy_mm_median_max": 5.0, "yaw_deg_median_max": 5.0, "replay_success_min": 0.95}


def _stats(values: pd.Series) -> tuple[float | None, float | None]:
    if values.empty:
        return None, None
    return float(values.median()), float(values.quantile(0.95))


def teleop_summary(attempts: list[dict]) -> dict:
    out = {}
    for task, rows in pd.DataFrame(attempts).groupby("task", sort=False):
        out[task] = {
            "attempts": int(len(rows)),
            "successes": int(rows["success"].sum()),
            "success_rate": float(rows["success"].mean()),
            "s_per_attempt": float(rows["wall_s"].mean()) if "wall_s" in rows else None,
        }
    return out


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


def replay_summary(log_table: pd.DataFrame) -> dict:
    test = log_table[~log_table["calibration"]] if "calibration" in log_table else log_table
    out = {}
    for task, rows in test.groupby("task", sort=False):
        used = rows.loc[rows["success"], "attempts"]
        out[task] = {
            "episodes": int(len(rows)),
            "successes": int(rows["success"].sum()),
            "success_rate": float(rows["success"].mean()),
            "attempts_mean": float(used.mean()) if len(used) else None,
            "attempts_max": int(used.max()) if len(used) else None,
            "attempts_histogram": {int(k): int(v) for k, v in used.value_counts().sort_index().items()},
            "s_per_episode": float(rows["wall_s"].mean()) if "wall_s" in rows else None,
        }
    return out


def build_report(attempts: list[dict], errors: pd.DataFrame, replay_log: pd.DataFrame,
                 init_s_per_episode: float | None = None) -> dict:
    teleop, init, replay = teleop_summary(attempts), init_error_summary(errors), replay_summary(replay_log)
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
        tasks[task] = {"teleop": t, "init_error": i, "replay": r, "meets_targets": meets}
    return {"targets": TARGETS, "tasks": tasks, "init_s_per_episode": init_s_per_episode}


def _fmt(value, spec: str) -> str:
    width = int("".join(c for c in spec.split(".")[0] if c.isdigit()) or 0)
    return "-".rjust(width) if value is None else format(value, spec)


def format_table(report: dict) -> str:
    header = (f"{'task':16s} {'object':8s} {'teleop':>7s} {'xy med':>7s} {'xy p95':>7s} {'yaw med':>8s} "
              f"{'yaw p95':>8s} {'replay':>7s} {'att.mean':>8s} {'att.max':>7s} {'ok':>3s}")
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
                f"{_fmt(r.get('success_rate') if first else None, '7.1%')} "
                f"{_fmt(r.get('attempts_mean') if first else None, '8.2f')} "
                f"{_fmt(r.get('attempts_max') if first else None, '7d')} "
                f"{('yes' if row['meets_targets'] else 'NO') if first else '':>3s}"
            )
    lines.append("xy in mm, yaw in degrees (objects with observable yaw, modulo symmetry); init and replay over "
                 "test episodes; targets: teleop >= 90 %, medians <= 5 mm and <= 5 deg, replay >= 95 %")
    return "\n".join(lines)
