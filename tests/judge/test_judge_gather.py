"""Per-policy descriptions gathered into a judge's one table, with their costs added up."""

from __future__ import annotations

import json
import subprocess
import sys

import pandas as pd
import pytest

from r2s_eval.errors import DataError
from r2s_eval.world_judging import gather_descriptions
from r2s_eval.utils.io import read_parquet_metadata, write_parquet


def _part(path, judge: str, ids: list[str], calls: int, hits: int, wall_s: float):
    rows = pd.DataFrame({"episode_id": ids, "judge": judge, "description": [f"{{\"id\": \"{i}\"}}" for i in ids]})
    stats = {"stage": "describe", "judge": judge, "items": len(ids), "unique_keys": len(ids), "calls": calls,
             "cache_hits": hits, "tokens_in": 10 * calls, "wall_s": wall_s, "incomplete": 0}
    write_parquet(path, rows, metadata={"stage": "describe", "judge": judge, "stats": stats})
    return str(path)


def test_parts_are_gathered_in_order_and_their_costs_added(tmp_path):
    parts = [_part(tmp_path / "a.parquet", "vlm", ["e1", "e2"], calls=2, hits=0, wall_s=3.0),
             _part(tmp_path / "b.parquet", "vlm", ["e3"], calls=0, hits=1, wall_s=0.5)]
    out = tmp_path / "judge" / "descriptions.parquet"
    done = subprocess.run([sys.executable, "-m", "r2s_eval.stages.descriptions", "--parts", *parts, "--out", str(out)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert pd.read_parquet(out)["episode_id"].tolist() == ["e1", "e2", "e3"]
    stats = json.loads(out.with_name("describe_stats.json").read_text())
    assert {k: stats[k] for k in ("judge", "items", "calls", "cache_hits", "tokens_in", "wall_s")} == \
        {"judge": "vlm", "items": 3, "calls": 2, "cache_hits": 1, "tokens_in": 20, "wall_s": 3.5}
    assert read_parquet_metadata(out)["stats"]["items"] == 3 and read_parquet_metadata(out)["judge"] == "vlm"


def test_parts_of_another_judge_or_described_twice_are_refused(tmp_path):
    a = _part(tmp_path / "a.parquet", "vlm", ["e1"], 1, 0, 1.0)
    with pytest.raises(DataError, match=r"b.parquet: described by judge 'other', the other parts by 'vlm'"):
        gather_descriptions([a, _part(tmp_path / "b.parquet", "other", ["e2"], 1, 0, 1.0)])
    with pytest.raises(DataError, match=r"more than one part: \['e1'\]"):
        gather_descriptions([a, _part(tmp_path / "c.parquet", "vlm", ["e1"], 1, 0, 1.0)])
    write_parquet(tmp_path / "d.parquet", pd.DataFrame({"episode_id": ["e9"]}), metadata={"stage": "fit"})
    with pytest.raises(DataError, match=r"d.parquet: not the output of the describe stage"):
        gather_descriptions([a, str(tmp_path / "d.parquet")])
