"""The judging stages' judge knows the world it judges; its tables carry the metadata later stages read."""

from __future__ import annotations

import pandas as pd

from r2s_eval.sim.tasks import world_tasks
from tests.helpers.worlds import bundled_world
from r2s_eval.utils.io import read_parquet_metadata as _read_metadata
from r2s_eval.world_judging import gather_descriptions, world_judge, write_descriptions, write_verdicts


def test_world_judge_is_told_the_world_s_tasks_and_transport_keys_come_apart():
    world = bundled_world()
    judge = world_judge({"backend": "video"}, {"concurrency": 3}, objects=world["objects"], tasks=world["tasks"],
                        robot=world["robot"])
    assert judge.tasks == world_tasks(world) and judge.stage_cfg["concurrency"] == 3
    again = world_judge({"backend": "video"}, {"concurrency": 1}, objects=world["objects"], tasks=world["tasks"],
                        robot=world["robot"])
    assert again.identity() == judge.identity()  # where and how fast it is asked changes no answer


def read_parquet_metadata(path) -> dict:
    """The metadata without the provenance (set by whichever stage ran before in this process)."""
    return {k: v for k, v in _read_metadata(path).items() if k != "provenance"}


def test_written_descriptions_gather_and_verdicts_leave_their_exclusions_out(tmp_path):
    part = pd.DataFrame({"episode_id": ["e1", "e2"], "description": ["a", "b"]})
    part.attrs["stats"] = {"calls": 2, "cache_hits": 0, "wall_s": 1.0}
    write_descriptions(tmp_path / "a.parquet", part, "vlm")
    assert read_parquet_metadata(tmp_path / "a.parquet") == {"stage": "describe", "judge": "vlm",
                                                             "stats": {"calls": 2, "cache_hits": 0, "wall_s": 1.0}}
    table, stats = gather_descriptions([str(tmp_path / "a.parquet")])
    assert table["episode_id"].tolist() == ["e1", "e2"] and stats["judge"] == "vlm" and stats["calls"] == 2

    verdicts = pd.DataFrame({"pair_index": [0], "verdict": ["A"]})
    verdicts.attrs["stats"] = {"calls": 1, "exclusions": [{"pair_index": 0}]}
    write_verdicts(tmp_path / "v.parquet", verdicts, "vlm")
    assert read_parquet_metadata(tmp_path / "v.parquet") == {"stage": "judge_pairs", "judge": "vlm",
                                                             "stats": {"calls": 1}}
