"""A judge that knows the world it judges: its tasks (what each instruction asks for, what the
objects look like) and its robot's units. The judge package never imports the simulator, so the
two meet here, above both; the stages that describe or compare rollouts build their judge here,
and write (and gather) the descriptions and verdicts with the metadata the later stages read.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from r2s_eval.errors import DataError
from r2s_eval.judge import Judge, make_judge
from r2s_eval.judge.cached_runner import sum_stats
from r2s_eval.sim.robot import world_robot
from r2s_eval.sim.tasks import world_tasks
from r2s_eval.utils.io import read_parquet_metadata, write_parquet


def world_judge(judge_cfg: Mapping[str, Any], transport: Mapping[str, Any], *, objects: Mapping, tasks: Mapping,
                robot: Mapping) -> Judge:
    """The judge of ``judge_cfg`` reached through ``transport`` (server address, timeouts,
    concurrency: kept apart so they never rerun judging), told the world's tasks (``objects`` and
    ``tasks``, the ``world`` config's) and its robot (``world.robot``: its units, not its cameras)."""
    judge = make_judge({**judge_cfg, **transport})
    judge.know_tasks(world_tasks({"objects": objects, "tasks": tasks}))
    judge.know_robot(world_robot({"robot": robot, "rig": {}}))
    return judge


def write_descriptions(path: str | Path, descriptions: pd.DataFrame, judge_name: str) -> None:
    """The descriptions table, its metadata naming the judge and its costs (``attrs["stats"]``)."""
    write_parquet(path, descriptions, metadata={"stage": "describe", "judge": judge_name,
                                                "stats": descriptions.attrs["stats"]})


def write_verdicts(path: str | Path, verdicts: pd.DataFrame, judge_name: str) -> None:
    """The verdicts table, its metadata naming the judge and its costs (the exclusions, kept in
    ``compare_stats.json``, left out)."""
    stats = {k: v for k, v in verdicts.attrs["stats"].items() if k != "exclusions"}
    write_parquet(path, verdicts, metadata={"stage": "judge_pairs", "judge": judge_name, "stats": stats})


def gather_descriptions(parts: list[str]) -> tuple[pd.DataFrame, dict]:
    """The describe parts' rows in order (one judge, each episode once), and their summed stats
    (every count; the wall time too)."""
    tables, part_stats, judge = [], [], None
    for part in parts:
        meta = read_parquet_metadata(part)
        if meta.get("stage") != "describe" or "stats" not in meta:
            raise DataError(f"{part}: not the output of the describe stage")
        if judge is not None and meta["judge"] != judge:
            raise DataError(f"{part}: described by judge {meta['judge']!r}, the other parts by {judge!r}")
        judge = meta["judge"]
        part_stats.append(meta["stats"])
        tables.append(pd.read_parquet(part))
    stats = {**sum_stats(part_stats), "judge": judge}
    table = pd.concat(tables, ignore_index=True)
    dup = table["episode_id"][table["episode_id"].duplicated()].unique().tolist()
    if dup:
        raise DataError(f"episodes described in more than one part: {dup[:5]}")
    return table, stats
