"""Paper tables (LaTeX, booktabs) and figures (PDF + PNG) generated from the pipeline's artefacts.

``summaries`` computes the numbers from artefact tables, ``tables`` and ``figures`` lay them
out; ``world`` reports the calibrated world's fidelity per task. The stages in
``r2s_eval.stages`` read the files and call these.
"""

from r2s_eval.report.figures import (
    case_study_figure,
    convergence_figure,
    hardware_effort_figure,
    operator_hours,
    ranking_figure,
    save_figure,
    resolution_figure,
    win_rate_figure,
)
from r2s_eval.report.video_stills import sample_frames
from r2s_eval.report.summaries import (
    fit_interval,
    human_agreement,
    judge_audit,
    judge_averaged_scores,
    last_checkpoint,
    pick_case_study,
    reference_interval,
    success_by_task,
    success_gaps,
    swap_consistency,
    task_summary,
    win_rate_matrix,
)
from r2s_eval.report.tables import (
    bt_scores_table,
    judge_card_table,
    resolution_table,
    latex_escape,
    libero_success_table,
    ranking_text,
    realsim_success_table,
    realsim_table,
    tasks_table,
    validation_report,
)

__all__ = [
    "bt_scores_table",
    "case_study_figure",
    "convergence_figure",
    "fit_interval",
    "hardware_effort_figure",
    "human_agreement",
    "judge_audit",
    "judge_card_table",
    "libero_success_table",
    "judge_averaged_scores",
    "last_checkpoint",
    "latex_escape",
    "operator_hours",
    "pick_case_study",
    "ranking_figure",
    "ranking_text",
    "realsim_success_table",
    "realsim_table",
    "resolution_figure",
    "resolution_table",
    "reference_interval",
    "sample_frames",
    "save_figure",
    "success_by_task",
    "success_gaps",
    "swap_consistency",
    "task_summary",
    "tasks_table",
    "validation_report",
    "win_rate_figure",
    "win_rate_matrix",
]
