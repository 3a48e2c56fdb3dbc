"""Stage: one judge's descriptions of every policy's rollouts, gathered into one table.

`describe` runs per policy, as soon as that policy's rollouts exist; this stage puts the parts
together in the line-up's order and adds up their judge costs (calls, cache hits, requests,
tokens, time) into ``describe_stats.json``.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from r2s_eval.errors import DataError
from r2s_eval.judge.cached_runner import sum_stats
from r2s_eval.stages import _cli
from r2s_eval.utils.io import read_parquet_metadata, write_json, write_parquet

READS = ()  # config paths the --cfg slice holds (see _reads.py)


def gather(parts: list[str]) -> tuple[pd.DataFrame, dict]:
    """The parts' rows in order, and their summed stats (every count; the wall time too)."""
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


def main(args) -> None:
    table, stats = gather(args.parts)
    out = Path(args.out)
    write_parquet(out, table, metadata={"stage": "describe", "judge": stats["judge"], "stats": stats})
    write_json(out.with_name("describe_stats.json"), stats, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__, cfg=False)
    p.add_argument("--parts", nargs="+", required=True, help="describe outputs, one per policy")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
