"""The real-to-sim table: structure, dashes without human annotations, and LaTeX validity."""

from __future__ import annotations

import shutil
import subprocess

import pandas as pd
import pytest

from r2s_eval.report import latex_escape, ranking_text, realsim_table


def validation(rho, r, mmrv, ci):
    return {"average": {"spearman": rho, "pearson": r, "mmrv": mmrv, "ci_width": ci}}


def test_rows_average_and_dash():
    table = realsim_table({"qwen_vl": validation(0.9, 0.8, 0.01, 4.0), "kinematic": validation(0.5, 0.6, 0.1, 6.0)},
                          agreement={"qwen_vl": 0.75}, decimals=2)
    lines = table.splitlines()
    assert lines[0].startswith(r"\begin{tabular}") and r"\toprule" in lines and r"\bottomrule" in lines
    kin = next(line for line in lines if line.startswith("kinematic"))
    assert kin == r"kinematic & 0.50 & 0.60 & 0.10 & 6.00 & -- \\"
    qwen = next(line for line in lines if line.startswith(r"qwen\_vl"))
    assert qwen.endswith(r"0.75 \\")
    avg = next(line for line in lines if line.startswith("Average"))
    assert avg == r"Average & 0.70 & 0.70 & 0.06 & 5.00 & 0.75 \\"


def test_latex_escape():
    assert latex_escape("a_b & 50%") == r"a\_b \& 50\%"


def test_ranking_text_lists_reference_and_scores():
    fit = pd.DataFrame({"checkpoint": [10, 10, 20, 20], "policy": ["a", "b", "a", "b"],
                        "score": [60.0, 40.0, 70.0, 30.0], "ci_low": [50, 30, 65, 25], "ci_high": [70, 50, 75, 35]})
    text = ranking_text({"kinematic": fit}, {"a": 0.8, "b": 0.2})
    assert "20 comparisons" in text
    a_line = next(line for line in text.splitlines() if line.startswith("a "))
    assert "80.0" in a_line and "70.0 [65.0, 75.0] #1" in a_line


@pytest.mark.skipif(shutil.which("pdflatex") is None, reason="pdflatex not installed")
def test_table_compiles(tmp_path):
    body = realsim_table({"kinematic": validation(0.5, 0.6, 0.1, 6.0)})
    doc = "\\documentclass{article}\\usepackage{booktabs}\\begin{document}\n" + body + "\\end{document}\n"
    (tmp_path / "t.tex").write_text(doc)
    proc = subprocess.run(["pdflatex", "-interaction=nonstopmode", "t.tex"], cwd=tmp_path, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-2000:]
