"""Bradley-Terry ranking statistics and agreement metrics."""

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
