"""Judges: describe each recorded rollout along four criteria, then prefer one of two descriptions.

Public API:
  * records: ``RolloutInput``, ``CriterionNote``, ``Description``, ``Verdict``, ``CRITERIA``,
    ``PROGRESS_LABELS``;
  * interface: ``Judge`` (subclass it and decorate with ``@register_judge("<backend>")``, then
    import the module here), ``make_judge(cfg)`` keyed by ``cfg["backend"]``;
  * built-in backend "kinematic": ``KinematicJudge``, an offline trajectory heuristic, not a VLM
    (privileged: it reads the simulator trajectory);
  * built-in backend "video": ``VideoJudge``, an offline pixel heuristic, not a VLM, that reads
    only the video and the instruction;
  * VLM backends (two-step method in ``vlm.VLMJudge``): "openai" (``OpenAIJudge``, any
    OpenAI-compatible chat-completions server) and "transformers" (``TransformersJudge``, a local
    model);
  * stage drivers (``drivers``): ``describe_rollouts``, ``judge_pairs`` (cached, resumable, with
    invalid-answer replacement and the order-swap audit ``swap_audited``), built on the cached
    parallel runner (``runner``: ``StageStats``), the judge's questions (``questions``), its
    scratch folder (``scratch``), the replacement reserve (``replacement``) and the order-swap
    audit (``swap_audit``); ``adaptive.judge_adaptively`` (``compare.allocation: adaptive``) asks
    block after block for the policy pairs still open and describes rollouts on the way.
"""

from r2s_eval.judge.base import (
    CRITERIA,
    PROGRESS_LABELS,
    CriterionNote,
    STAGE_OPTIONS,
    Description,
    InvalidAnswer,
    Judge,
    RolloutInput,
    Verdict,
    available_backends,
    make_judge,
    register_judge,
    stage_defaults,
)
from r2s_eval.judge.drivers import describe_rollouts, judge_pairs
from r2s_eval.judge.kinematic import KinematicJudge
from r2s_eval.judge.openai_backend import OpenAIJudge
from r2s_eval.judge.cached_runner import StageStats
from r2s_eval.judge.swap_audit import swap_audited
from r2s_eval.judge.transformers_backend import TransformersJudge
from r2s_eval.judge.video_judge import VideoJudge
from r2s_eval.judge.vlm import VLMJudge

__all__ = [
    "CRITERIA",
    "STAGE_OPTIONS",
    "PROGRESS_LABELS",
    "CriterionNote",
    "Description",
    "InvalidAnswer",
    "Judge",
    "KinematicJudge",
    "OpenAIJudge",
    "RolloutInput",
    "StageStats",
    "TransformersJudge",
    "VLMJudge",
    "VideoJudge",
    "Verdict",
    "available_backends",
    "describe_rollouts",
    "judge_pairs",
    "make_judge",
    "register_judge",
    "stage_defaults",
    "swap_audited",
]
