"""Bradley-Terry ranking statistics and agreement metrics.

Convention: ``wins[i, j]`` counts how often a rollout of policy ``i`` was preferred
over one of policy ``j`` (diagonal zero); strengths sum to 1 and the reported score
is ``s = 100 b``.
"""

from r2s_eval.stats.bradley_terry import (
    DisconnectedComparisonsError,
    bootstrap_bradley_terry,
    bootstrap_wins,
    bt_ci_width,
    bt_confidence_intervals,
    bt_scores,
    comparison_groups,
    fit_bradley_terry,
    fit_bradley_terry_batch,
)
from r2s_eval.stats.checkpoints import CheckpointMetrics, checkpoint_metrics
from r2s_eval.stats.metrics import (
    PositionBias,
    ci_aware_rank,
    human_agreement_rate,
    majority_vote,
    mmrv,
    order_swap_consistency,
    pearson,
    position_bias,
    spearman,
)

__all__ = [
    "CheckpointMetrics",
    "DisconnectedComparisonsError",
    "PositionBias",
    "bootstrap_bradley_terry",
    "bootstrap_wins",
    "bt_ci_width",
    "bt_confidence_intervals",
    "bt_scores",
    "checkpoint_metrics",
    "ci_aware_rank",
    "comparison_groups",
    "fit_bradley_terry",
    "fit_bradley_terry_batch",
    "human_agreement_rate",
    "majority_vote",
    "mmrv",
    "order_swap_consistency",
    "pearson",
    "position_bias",
    "spearman",
]
