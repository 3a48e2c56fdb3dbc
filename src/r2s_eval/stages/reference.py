"""Stage: real-world reference success rates per policy and task.

From closed-loop rollouts on the real side (the twin, or a robot logged the same way), or
from a CSV of hardware trials with columns policy, task, trials, successes.

The table stays per task: a policy's reference performance is the mean of its per-task
rates (every task weighs the same), and its bootstrap interval resamples the trials within
each task, so both are computed from these counts where they are used
(``r2s_eval.stats.reference_rates``; the interval in the validate stage, with the
statistics config and seed). Nothing here depends on that config, so changing it does not
rerun the reference.
"""

from __future__ import annotations

from r2s_eval.stages import _cli
from r2s_eval.stats.reference_table import reference_table
from r2s_eval.utils.io import write_parquet

READS = ()  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    write_parquet(args.out, reference_table(csv=args.csv, rollout_dirs=args.rollouts))


if __name__ == "__main__":
    p = _cli.parser(__doc__, cfg=False)
    p.add_argument("--rollouts", nargs="*", default=[])
    p.add_argument("--csv")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
