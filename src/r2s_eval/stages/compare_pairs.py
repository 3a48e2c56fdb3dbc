"""Stage: sample task-stratified A/B pairs at nested checkpoints (one sequence per policy pair)."""

from __future__ import annotations

from r2s_eval.compare import checkpoint_sizes, sample_pairs
from r2s_eval.stages import _cli
from r2s_eval.stages._rollouts import load_episodes
from r2s_eval.utils.io import write_parquet

READS = ("compare", "seed")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    episodes = load_episodes(args.rollouts)
    policies = sorted(episodes["policy"].unique())
    checkpoints = checkpoint_sizes(args.cfg["compare"]["checkpoints"])
    pairs = sample_pairs(episodes, policies, checkpoints, seed=int(args.cfg["seed"]))
    write_parquet(args.out, pairs, metadata={"stage": "compare_pairs", "checkpoints": checkpoints, "policies": policies})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--rollouts", nargs="+", required=True)
    p.add_argument("--out", required=True)
    _cli.run(main, p)
