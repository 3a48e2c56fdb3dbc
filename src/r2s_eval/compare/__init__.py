"""Which comparisons to judge (task-stratified pair sampling, or the adaptive allocation's unit
order, confidence sequences and pair-picking rule in ``sequential``) and the win counts they yield."""

from r2s_eval.compare.sampling import PAIR_COLUMNS, checkpoint_sizes, sample_pairs
from r2s_eval.compare.wins import wins_at_checkpoints

__all__ = ["PAIR_COLUMNS", "checkpoint_sizes", "sample_pairs", "wins_at_checkpoints"]
