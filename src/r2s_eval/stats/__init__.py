"""Bradley-Terry ranking statistics and agreement metrics.

Convention: ``wins[i, j]`` counts how often a rollout of policy ``i`` was preferred
over one of policy ``j`` (diagonal zero); strengths sum to 1 and the reported score
is ``s = 100 b``.  Two bootstraps give intervals: the binomial one
(:func:`bootstrap_bradley_terry`, every comparison independent) and the unit one
(:func:`unit_bootstrap_bradley_terry`, the distinct task/init rollout pairs resampled
within each task).
"""

from r2s_eval.stats.annotators import (
    OUTCOME_CATEGORIES,
    fleiss,
    majority_letters,
    outcome_category,
    unanimous,
    vote_table,
)
from r2s_eval.stats.audit import flat_within_ci, shuffled_label_control, unit_share
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
from r2s_eval.stats.checkpoints import (
    INTERVALS,
    CheckpointMetrics,
    bootstrap_checkpoints,
    check_interval,
    checkpoint_metrics,
    metric_ci_tables,
    metric_intervals,
    metric_replicates,
    percentile_interval,
    ranking_metrics,
)
from r2s_eval.stats.fit_table import fit_checkpoints, units_of, with_units
from r2s_eval.stats.metrics import (
    PositionBias,
    ci_aware_rank,
    human_agreement_rate,
    majority_vote,
    mmrv,
    mmrv_batch,
    order_swap_consistency,
    pearson,
    pearson_batch,
    position_bias,
    spearman,
    spearman_batch,
)
from r2s_eval.stats.reference import (
    bootstrap_task_mean_success,
    reference_bootstrap,
    reference_rates,
    task_mean_success,
)
from r2s_eval.stats.units import (
    ComparisonUnits,
    comparison_units,
    unit_bootstrap_bradley_terry,
    unit_bootstrap_wins,
)
from r2s_eval.stats.validation import validate

__all__ = [
    "OUTCOME_CATEGORIES",
    "fleiss",
    "majority_letters",
    "outcome_category",
    "unanimous",
    "vote_table",
    "INTERVALS",
    "CheckpointMetrics",
    "ComparisonUnits",
    "DisconnectedComparisonsError",
    "PositionBias",
    "bootstrap_bradley_terry",
    "bootstrap_checkpoints",
    "bootstrap_task_mean_success",
    "bootstrap_wins",
    "bt_ci_width",
    "bt_confidence_intervals",
    "bt_scores",
    "check_interval",
    "checkpoint_metrics",
    "ci_aware_rank",
    "comparison_groups",
    "comparison_units",
    "fit_bradley_terry",
    "fit_bradley_terry_batch",
    "fit_checkpoints",
    "flat_within_ci",
    "human_agreement_rate",
    "majority_vote",
    "metric_ci_tables",
    "metric_intervals",
    "metric_replicates",
    "mmrv",
    "mmrv_batch",
    "order_swap_consistency",
    "pearson",
    "pearson_batch",
    "percentile_interval",
    "position_bias",
    "ranking_metrics",
    "reference_bootstrap",
    "reference_rates",
    "shuffled_label_control",
    "spearman",
    "spearman_batch",
    "task_mean_success",
    "unit_bootstrap_bradley_terry",
    "unit_bootstrap_wins",
    "unit_share",
    "units_of",
    "validate",
    "with_units",
]
