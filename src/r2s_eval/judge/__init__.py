"""Judges: describe each recorded rollout along four criteria, then prefer one of two descriptions.

Public API:
  * records: ``RolloutInput``, ``CriterionNote``, ``Description``, ``Verdict``, ``CRITERIA``,
    ``PROGRESS_LABELS``;
  * interface: ``Judge`` (subclass it and decorate with ``@register_judge("<backend>")``, then
    import the module here), ``make_judge(cfg)`` keyed by ``cfg["backend"]``;
  * built-in backend "kinematic": ``KinematicJudge``, an offline trajectory heuristic, not a VLM;
  * stage drivers: ``describe_rollouts``, ``judge_pairs`` (cached, resumable).
"""

from r2s_eval.judge.base import (
    CRITERIA,
    PROGRESS_LABELS,
    CriterionNote,
    Description,
    Judge,
    RolloutInput,
    Verdict,
    available_backends,
    make_judge,
    register_judge,
)
from r2s_eval.judge.kinematic import KinematicJudge
from r2s_eval.judge.stages import StageStats, describe_rollouts, judge_pairs

__all__ = [
    "CRITERIA",
    "PROGRESS_LABELS",
    "CriterionNote",
    "Description",
    "Judge",
    "KinematicJudge",
    "RolloutInput",
    "StageStats",
    "Verdict",
    "available_backends",
    "describe_rollouts",
    "judge_pairs",
    "make_judge",
    "register_judge",
]
