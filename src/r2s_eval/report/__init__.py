"""Paper tables (LaTeX, booktabs) and figures generated from the pipeline's artefacts."""

from r2s_eval.report.tables import latex_escape, ranking_text, realsim_table

__all__ = ["latex_escape", "ranking_text", "realsim_table"]
