"""Stage: one judge's descriptions of every policy's rollouts, gathered into one table.

`describe` runs per policy, as soon as that policy's rollouts exist; this stage puts the parts
together in the line-up's order and adds up their judge costs (calls, cache hits, requests,
tokens, time) into ``describe_stats.json``.
"""

from __future__ import annotations

from pathlib import Path

from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_json, write_parquet
from r2s_eval.world_judging import gather_descriptions

READS = ()  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    table, stats = gather_descriptions(args.parts)
    out = Path(args.out)
    write_parquet(out, table, metadata={"stage": "describe", "judge": stats["judge"], "stats": stats})
    write_json(out.with_name("describe_stats.json"), stats, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__, cfg=False)
    p.add_argument("--parts", nargs="+", required=True, help="describe outputs, one per policy")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
