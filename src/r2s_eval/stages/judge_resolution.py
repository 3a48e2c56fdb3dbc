"""Stage: one judge's resolution (conf/resolution): it compares the clean run with each planted
level's run from the same init, and its shares per level go beside every level's success.

The judge sees what it always sees (two descriptions, or two videos) under opaque episode ids; the
outcomes, read from the sim's success check, only sort its answers afterwards.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from r2s_eval.compare.resolution import sweep_levels, sweep_pairs
from r2s_eval.judge import judge_pairs
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.stages import _cli
from r2s_eval.stats.resolution import kind_summaries, level_rows
from r2s_eval.utils.io import write_json
from r2s_eval.world_judging import gather_descriptions, world_judge, write_verdicts

READS = ("resolution", "seed", "stats.n_boot", "stats.ci_level", "world.objects", "world.tasks", "world.robot")
PROVIDED = ("judge", "name")  # keys the rule adds for this job

log = logging.getLogger("r2s_eval.judge_resolution")


def main(args) -> None:
    cfg = args.cfg
    resolution, seed = cfg["resolution"], int(cfg["seed"])
    clean, levels = resolution["policy"], sweep_levels(cfg["resolution"])
    judge = world_judge(cfg["judge"], json.loads(args.transport), objects=cfg["world.objects"],
                        tasks=cfg["world.tasks"], robot=cfg["world.robot"])
    sim, real = load_episodes(args.sim), load_episodes(args.real) if args.real else None
    if resolution["tasks"] is not None:  # the clean run's other tasks are no part of the sweep
        sim = sim[sim["task"].isin(resolution["tasks"])]
        real = None if real is None else real[real["task"].isin(resolution["tasks"])]
    pairs = sweep_pairs(sim, clean, levels, seed)
    descriptions = gather_descriptions(args.descriptions)[0] if args.descriptions else None
    out = Path(args.verdicts)
    verdicts = judge_pairs(pairs, descriptions, judge, args.cache, stats_path=out.with_name("compare_stats.json"),
                           episodes_df=sim, episodes_dir=Path("."))
    write_verdicts(out, verdicts, cfg["name"])
    rows = level_rows(verdicts, sim, real, clean, levels,
                      detect_share=float(resolution["detect_share"]), n_boot=int(cfg["stats.n_boot"]),
                      ci_level=float(cfg["stats.ci_level"]), seed=seed)
    kinds = kind_summaries(rows)
    write_json(args.out, {"judge": cfg["name"], "policy": clean, "detect_share": resolution["detect_share"],
                          "comparisons": len(verdicts), "levels": rows, "kinds": kinds}, provenance=True)
    for kind, summary in kinds.items():
        log.info("%s: smallest level detected %s (with success kept %s)", kind, summary["smallest_detected"],
                 summary["smallest_detected_success_kept"])


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--sim", nargs="+", required=True, help="sim rollout folders: the clean candidate's and every level's")
    p.add_argument("--real", nargs="*", default=[], help="the same runs' real rollout folders (their success)")
    p.add_argument("--descriptions", nargs="*", default=[], help="the judge's describe parts (two-step judges)")
    p.add_argument("--cache", required=True)
    p.add_argument("--transport", default="{}", help="JSON: the judge's transport keys")
    p.add_argument("--verdicts", required=True)
    p.add_argument("--out", required=True, help="the resolution summary (JSON)")
    _cli.run(main, p)
