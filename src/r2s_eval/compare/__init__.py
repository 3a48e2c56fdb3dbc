"""Which comparisons to judge (task-stratified pair sampling) and the win counts they yield."""

from r2s_eval.compare.sampling import PAIR_COLUMNS, checkpoint_sizes, sample_pairs
from r2s_eval.compare.wins import wins_at_checkpoints

__all__ = ["PAIR_COLUMNS", "checkpoint_sizes", "sample_pairs", "wins_at_checkpoints"]
