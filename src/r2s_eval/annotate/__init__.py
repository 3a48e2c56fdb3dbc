"""People in the loop: a blinded A/B annotation set, the web app that collects the answers, and
their export to the CSV the judge audit reads.

``selection`` draws the set from the compared pairs, ``media`` writes it (videos under opaque
tokens), ``store`` keeps the answers in SQLite, ``server`` serves the page; run the app with
``python -m r2s_eval.annotate serve``.
"""

from r2s_eval.annotate.media import write_annotation_set
from r2s_eval.annotate.selection import CATEGORIES, candidate_pairs, draw_annotation_set, outcome_category
from r2s_eval.annotate.answers import AnnotationError, AnswerStore

__all__ = [
    "CATEGORIES",
    "AnnotationError",
    "AnswerStore",
    "candidate_pairs",
    "draw_annotation_set",
    "outcome_category",
    "write_annotation_set",
]
