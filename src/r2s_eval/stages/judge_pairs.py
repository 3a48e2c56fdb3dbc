"""Stage: the judge answers A or B for every sampled pair (cached by content).

Two-step judges compare the descriptions; one-step judges watch both videos. Replacements for
excluded comparisons come from the seeded continuation of the pair sequences
(``sample_reserve``), drawn from the same rollouts with the same seed as the pairs themselves.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq

from r2s_eval.compare.sampling import sample_pairs, sample_reserve
from r2s_eval.judge import judge_pairs, make_judge
from r2s_eval.stages import _cli
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.utils.io import write_parquet
from r2s_eval.errors import DataError

READS = ("seed",)  # config paths the --cfg slice holds (see _reads.py)
PROVIDED = ("judge", "name")  # keys the rule adds for this job


def reserve_for(pairs: pd.DataFrame, pairs_path: str, episodes: pd.DataFrame, seed: int, n_reserve: int) -> pd.DataFrame:
    """The pairs' seeded continuation; checks first that the pairs came from these rollouts and seed."""
    meta = json.loads((pq.read_schema(pairs_path).metadata or {}).get(b"r2s_eval", b"{}"))
    policies = meta.get("policies") or sorted(set(pairs["policy_i"]) | set(pairs["policy_j"]))
    checkpoints = meta.get("checkpoints") or [int(pairs["pair_index"].max()) + 1]
    again = sample_pairs(episodes, policies, checkpoints, seed)
    cols = ["policy_i", "policy_j", "pair_index", "episode_a", "episode_b"]
    if again[cols].astype(str).values.tolist() != pairs[cols].astype(str).values.tolist():
        raise DataError(f"{pairs_path} was not sampled from these rollouts with seed {seed}; rerun compare_pairs")
    return sample_reserve(episodes, policies, checkpoints, seed, n_reserve)


def main(args) -> None:
    # Transport keys (server address, timeouts, concurrency) come apart: they never rerun judging.
    judge = make_judge({**args.cfg["judge"], **json.loads(args.transport)})
    pairs = pd.read_parquet(args.pairs)
    episodes = load_episodes(args.rollouts)
    descriptions = pd.read_parquet(args.descriptions) if args.descriptions else None
    reserve = reserve_for(pairs, args.pairs, episodes, int(args.cfg["seed"]), int(judge.stage_cfg["reserve"]))
    out = Path(args.out)
    verdicts = judge_pairs(
        pairs, descriptions, judge, args.cache, stats_path=out.with_name("compare_stats.json"),
        reserve_df=reserve, episodes_df=episodes, episodes_dir=Path("."),
    )
    stats = {k: v for k, v in verdicts.attrs["stats"].items() if k != "exclusions"}
    write_parquet(out, verdicts, metadata={"stage": "judge_pairs", "judge": args.cfg["name"], "stats": stats})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--pairs", required=True)
    p.add_argument("--rollouts", nargs="+", required=True)
    p.add_argument("--descriptions", default=None, help="descriptions table (two-step judges)")
    p.add_argument("--cache", required=True)
    p.add_argument("--transport", default="{}", help="JSON: the judge's transport keys")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
