"""Stage: a tiny randomly initialised SmolVLA checkpoint (smoke runs' stand-in for a lab's VLA).

Built offline through LeRobot's own classes (``r2s_eval.policies.tiny``) with the observation and
action widths given; its actions mean nothing.
"""

from __future__ import annotations

from pathlib import Path

from r2s_eval.policies.tiny import build_tiny_checkpoint
from r2s_eval.stages import _cli
from r2s_eval.utils.numerics import deterministic_torch

READS = ()  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    deterministic_torch(1)
    build_tiny_checkpoint(Path(args.out), cameras=args.cameras, state_dim=args.state_dim,
                          action_dim=args.action_dim, seed=args.seed, chunk_size=args.chunk_size)


if __name__ == "__main__":
    p = _cli.parser(__doc__, cfg=False)
    p.add_argument("--cameras", nargs="+", required=True, help="observation keys of its cameras")
    p.add_argument("--state-dim", type=int, required=True)
    p.add_argument("--action-dim", type=int, required=True)
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--chunk-size", type=int, required=True)
    p.add_argument("--out", required=True)
    _cli.run(main, p)
