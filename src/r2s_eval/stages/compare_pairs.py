"""Stage: which comparisons to judge, one sequence per policy pair.

The fixed allocation samples task-stratified A/B pairs at nested checkpoints (``sample_pairs``);
the adaptive one lays out every pair's distinct (task, init) units in seeded blocks
(``unit_order``), which the judge stage takes as the answers decide.
"""

from __future__ import annotations

from r2s_eval.compare import checkpoint_sizes, sample_pairs
from r2s_eval.compare.sequential import unit_order
from r2s_eval.stages import _cli
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.utils.io import write_parquet

READS = ("compare.checkpoints", "compare.allocation", "seed")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    episodes = load_episodes(args.rollouts)
    policies = sorted(episodes["policy"].unique())
    cfg = args.cfg
    checkpoints = checkpoint_sizes(cfg["compare.checkpoints"])
    seed = int(cfg["seed"])
    if cfg["compare.allocation"] == "adaptive":
        pairs = unit_order(episodes, policies, seed)
    else:
        pairs = sample_pairs(episodes, policies, checkpoints, seed=seed)
    write_parquet(args.out, pairs, metadata={"stage": "compare_pairs", "checkpoints": checkpoints,
                                             "policies": policies, "allocation": cfg["compare.allocation"]})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--rollouts", nargs="+", required=True)
    p.add_argument("--out", required=True)
    _cli.run(main, p)
