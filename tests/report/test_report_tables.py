"""The LaTeX tables: structure, numbers, dashes for missing values, and that they compile."""

from __future__ import annotations

import re
import shutil
import subprocess

import pandas as pd
import pytest

from r2s_eval.report.fidelity_report import ablation_rows, ablation_table, fidelity_table
from r2s_eval.stats.fidelity import cross_evaluation

from r2s_eval.report import (
    bt_scores_table,
    judge_card_table,
    latex_escape,
    ranking_text,
    realsim_success_table,
    realsim_table,
    success_by_task,
    tasks_table,
)


def validation(rho, r, mmrv, ci, last=None):
    avg = {"spearman": rho, "pearson": r, "mmrv": mmrv, "ci_width": ci}
    return {"average": avg, "last": last or avg}


def row(table: str, start: str) -> str:
    return next(line for line in table.splitlines() if line.startswith(start))


def columns(colspec: str) -> int:
    return len(re.sub(r"[^lcr]", "", colspec))


def check_structure(table: str) -> None:
    """booktabs rules in order, and every row spans exactly the declared columns."""
    lines = table.strip().splitlines()
    spec = re.match(r"\\begin\{tabular\}\{([^}]*)\}", lines[0])
    assert spec and lines[-1] == r"\end{tabular}"
    rules = [line for line in lines if line in (r"\toprule", r"\midrule", r"\bottomrule")]
    assert rules[0] == r"\toprule" and rules[-1] == r"\bottomrule" and r"\midrule" in rules
    n = columns(spec.group(1))
    for line in lines:
        if line.endswith(r"\\"):
            cells = re.split(r"(?<!\\)&", line[:-2])
            spans = [int(m.group(1)) if (m := re.match(r"\s*\\multicolumn\{(\d+)\}", c)) else 1 for c in cells]
            assert sum(spans) == n, line


def test_realsim_table_rows_average_and_dashes():
    table = realsim_table(
        {"qwen_vl": validation(0.9, 0.8, 0.01, 4.0), "kinematic": validation(0.5, 0.6, 0.1, 6.0)},
        audits={"qwen_vl": {"human_agreement": 0.75, "swap_consistency": None, "a_share_same_outcome": 0.5},
                "kinematic": {"human_agreement": None, "swap_consistency": 0.9, "a_share_same_outcome": 0.7}},
        decimals=2,
    )
    check_structure(table)
    assert row(table, "kinematic") == r"kinematic & 0.50 & 0.60 & 0.10 & 6.00 & -- & 0.90 & 0.70 \\"
    assert row(table, r"qwen\_vl") == r"qwen\_vl & 0.90 & 0.80 & 0.01 & 4.00 & 0.75 & -- & 0.50 \\"
    # The average row averages the judges that have a value.
    assert row(table, "Average") == r"Average & 0.70 & 0.70 & 0.06 & 5.00 & 0.75 & 0.90 & 0.60 \\"


def test_realsim_table_without_audit_and_at_last_checkpoint():
    v = validation(0.5, 0.6, 0.1, 6.0, last={"spearman": 1.0, "pearson": 0.9, "mmrv": 0.0, "ci_width": 3.0})
    table = realsim_table({"kinematic": v}, decimals=1, metrics_at="last")
    check_structure(table)
    assert row(table, "kinematic") == r"kinematic & 1.0 & 0.9 & 0.0 & 3.0 & -- & -- & -- \\"
    assert "Average" not in table  # one judge: no average row
    with pytest.raises(ValueError, match="metrics_at"):
        realsim_table({"kinematic": v}, metrics_at="first")


def test_realsim_table_adds_the_judges_against_the_networks_in_the_twin():
    v = {**validation(0.5, 0.6, 0.1, 6.0), "against_networks_in_twin": validation(0.9, 0.8, 0.02, 5.0)}
    table = realsim_table({"kinematic": v, "video": validation(0.4, 0.3, 0.2, 7.0)}, decimals=2)
    check_structure(table)
    assert row(table, "kinematic &") == r"kinematic & 0.50 & 0.60 & 0.10 & 6.00 & -- & -- & -- \\"
    assert row(table, "Average") == r"Average & 0.45 & 0.45 & 0.15 & 6.50 & -- & -- & -- \\"  # the real reference's
    assert row(table, "kinematic, vs") == r"kinematic, vs pi$^S$ in the twin & 0.90 & 0.80 & 0.02 & 5.00 & -- & -- & -- \\"
    assert "video, vs" not in table and "pi$^R$'s" in table


def test_tasks_table():
    summary = pd.DataFrame({"task": ["cup_on_plate", "stack"], "real": [8, 4], "sim": [6, 1],
                            "replay_success": [0.75, 0.25]})
    table = tasks_table(summary)
    check_structure(table)
    assert row(table, r"cup\_on\_plate") == r"cup\_on\_plate & 8 & 6 & 75.0 \\"
    assert row(table, "stack") == r"stack & 4 & 1 & 25.0 \\"
    assert row(table, "Total") == r"Total & 12 & 7 & 58.3 \\"


def test_realsim_success_table():
    reference = pd.DataFrame({"policy": ["a", "a", "b"], "task": ["t1", "t2", "t1"],
                              "trials": [10, 10, 10], "successes": [8, 5, 2]})
    sim = pd.DataFrame({"policy": ["a"] * 6 + ["b"] * 4, "task": ["t1"] * 4 + ["t2"] * 2 + ["t1", "t1", "t2", "t2"],
                        "success": [1, 1, 1, 0, 1, 0, 0, 0, 1, 1]})
    table = realsim_success_table(success_by_task(reference, sim))
    check_structure(table)
    assert r"\multicolumn{2}{c}{t1} & \multicolumn{2}{c}{t2} & \multicolumn{2}{c}{Total}" in table
    assert row(table, "a ") == r"a & 80.0 & 75.0 & 50.0 & 50.0 & 65.0 & 62.5 \\"  # totals: mean over tasks
    assert row(table, "b ") == r"b & 20.0 & 0.0 & -- & 100.0 & 20.0 & 50.0 \\"
    assert row(table, "Mean") == (r"Mean $|\Delta|$ (pp) & \multicolumn{2}{c}{12.5} & \multicolumn{2}{c}{0.0}"
                                  r" & \multicolumn{2}{c}{16.2} \\")
    assert row(table, "Largest") == (r"Largest gap (pp) & \multicolumn{2}{c}{20.0} & \multicolumn{2}{c}{0.0}"
                                     r" & \multicolumn{2}{c}{30.0} \\")


def test_realsim_success_table_single_task_has_no_total_columns():
    reference = pd.DataFrame({"policy": ["a"], "task": ["t1"], "trials": [4], "successes": [3]})
    sim = pd.DataFrame({"policy": ["a", "a"], "task": ["t1", "t1"], "success": [True, False]})
    table = realsim_success_table(success_by_task(reference, sim))
    check_structure(table)
    assert "Total" not in table and row(table, "a ") == r"a & 75.0 & 50.0 \\"
    assert row(table, "Largest") == r"Largest gap (pp) & \multicolumn{2}{c}{25.0} \\"


def test_bt_scores_table(make_fit):
    fits = {
        "j1": make_fit({10: {"a": (20.0, 10.0, 30.0), "b": (80.0, 70.0, 90.0)},
                        20: {"a": (25.0, 15.0, 35.0), "b": (75.0, 65.0, 85.0)}}),
        "j_2": make_fit({20: {"a": (40.0, 30.0, 50.0), "b": (60.0, 50.0, 70.0)}}),
    }
    table = bt_scores_table(fits, {"a": 0.9, "b": 0.3})
    check_structure(table.split("\n", 1)[1])  # after the comment line naming the checkpoints
    assert table.startswith("% BT score") and "j1: 20" in table.splitlines()[0]
    assert row(table, "Policy") == r"Policy & Real (\%) & j1 & j\_2 \\"
    body = [line for line in table.splitlines() if line.startswith(("a ", "b "))]
    assert body == [  # ordered by reference success, scores at the last checkpoint
        r"a & 90.0 & 25.0 {\scriptsize [15.0, 35.0]} & 40.0 {\scriptsize [30.0, 50.0]} \\",
        r"b & 30.0 & 75.0 {\scriptsize [65.0, 85.0]} & 60.0 {\scriptsize [50.0, 70.0]} \\",
    ]
    plain = bt_scores_table(fits, {"a": 0.9, "b": 0.3}, decimals=0, show_ci=False)
    assert row(plain, "a ") == r"a & 90 & 25 & 40 \\"


def test_latex_escape():
    assert latex_escape("a_b & 50%") == r"a\_b \& 50\%"


def test_ranking_text_lists_reference_and_scores():
    fit = pd.DataFrame({"checkpoint": [10, 10, 20, 20], "policy": ["a", "b", "a", "b"],
                        "score": [60.0, 40.0, 70.0, 30.0], "ci_low": [50, 30, 65, 25], "ci_high": [70, 50, 75, 35]})
    text = ranking_text({"kinematic": fit}, {"a": 0.8, "b": 0.2})
    assert "20 comparisons" in text
    a_line = next(line for line in text.splitlines() if line.startswith("a "))
    assert "80.0" in a_line and "70.0 [65.0, 75.0] #1" in a_line


def all_tables(make_fit) -> list[str]:
    fits = {"kinematic": make_fit({10: {"a_1": (60.0, 50.0, 70.0), "b": (40.0, 30.0, 50.0)}})}
    success = success_by_task(
        pd.DataFrame({"policy": ["a_1", "b"], "task": ["cup_on_plate"] * 2, "trials": [5, 5], "successes": [4, 1]}),
        pd.DataFrame({"policy": ["a_1", "b"], "task": ["cup_on_plate"] * 2, "success": [True, False]}),
    )
    return [
        tasks_table(pd.DataFrame({"task": ["cup_on_plate"], "real": [8], "sim": [6], "replay_success": [0.75]})),
        realsim_success_table(success),
        realsim_table({"kinematic": validation(0.5, 0.6, 0.1, 6.0)}, {"kinematic": {"a_share_same_outcome": 0.5}}),
        bt_scores_table(fits, {"a_1": 0.8, "b": 0.2}),
        judge_card_table({"kinematic": CARD, "vlm_judge": {}}),
        fidelity_table(fidelity_report()),
        ablation_table(ablation_rows({"camera": pd.DataFrame({"policy": ["a_1"] * 4, "success": [True, True, False, False]})},
                                     pd.DataFrame({"policy": ["a_1"] * 4, "success": [True, False, False, False]}), 0.95)),
    ]


def fidelity_report() -> dict:
    def counts(successes):
        return pd.DataFrame({"policy": ["a_1"], "task": ["cup_on_plate"], "successes": [successes], "trials": [10]})

    worlds = {"R_real": counts(6), "R_sim": counts(5), "S_sim": counts(4), "S_real": counts(3)}
    return {"cross": cross_evaluation(worlds, level=0.95, n_boot=50, seed=0)}


def test_tables_structure(make_fit):
    for table in all_tables(make_fit):
        check_structure(table.split("\n", 1)[1] if table.startswith("%") else table)


@pytest.mark.skipif(shutil.which("pdflatex") is None, reason="pdflatex not installed (structure is checked above)")
def test_tables_compile(tmp_path, make_fit):
    body = "\n\\bigskip\n".join(all_tables(make_fit))
    doc = "\\documentclass{article}\\usepackage{booktabs}\\begin{document}\n" + body + "\\end{document}\n"
    (tmp_path / "t.tex").write_text(doc)
    proc = subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", "t.tex"], check=False, cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout[-2000:]
    assert (tmp_path / "t.pdf").stat().st_size > 1000


def unit_fit(make_fit, scores):
    """A fit table as the fit stage writes it: ci_low/ci_high are the unit interval."""
    fit = make_fit(scores)
    fit["interval"], fit["ci_level"] = "unit", 0.95
    fit["ci_low_unit"], fit["ci_high_unit"] = fit["ci_low"], fit["ci_high"]
    fit["ci_low_binomial"], fit["ci_high_binomial"] = fit["score"] - 1, fit["score"] + 1
    return fit


def test_ranking_text_names_the_interval_and_the_reference_definition(make_fit):
    fit = unit_fit(make_fit, {10: {"a": (70.0, 60.0, 80.0), "b": (30.0, 20.0, 40.0)}})
    text = ranking_text({"kinematic": fit}, {"a": 0.8, "b": 0.2}, {"a": (0.7, 0.9), "b": (0.1, 0.35)})
    title, header, *rest = text.splitlines()
    assert title.endswith("BT score [95% unit-bootstrap CI] #rank")
    assert "real success %" in header
    a_line = next(line for line in rest if line.startswith("a "))
    assert "80.0 [70.0, 90.0]" in a_line and "70.0 [60.0, 80.0] #1" in a_line
    assert any("task/init rollout pairs" in line for line in rest)
    assert any(line.startswith("real success %: mean of the per-task success rates") for line in rest)
    # Older fit tables (no interval column) held the binomial interval.
    old = ranking_text({"kinematic": make_fit({10: {"a": (70.0, 60.0, 80.0)}})}, {"a": 0.8})
    assert "[95% binomial-bootstrap CI]" in old.splitlines()[0]
    fit_b = fit.assign(interval="binomial")
    with pytest.raises(ValueError, match="disagree"):
        ranking_text({"j1": fit, "j2": fit_b}, {"a": 0.8, "b": 0.2})


def test_ranking_says_whether_the_reference_recovers_the_planted_order(make_fit):
    fit = unit_fit(make_fit, {10: {"a": (60.0, 50.0, 70.0), "b": (30.0, 20.0, 40.0), "c": (10.0, 0.0, 20.0)}})
    rate = {"a": 0.8, "b": 0.5, "c": 0.1}
    apart = ranking_text({"k": fit}, rate, {"a": (0.7, 0.9), "b": (0.4, 0.6), "c": (0.0, 0.2)}, planted_order=["a", "b", "c"])
    assert apart.splitlines()[-1] == ("planted order a > b > c: real success 95% CIs: a > b: separated; "
                                      "b > c: separated; point estimates follow it")
    overlap = ranking_text({"k": fit}, rate, {"a": (0.45, 0.9), "b": (0.4, 0.6), "c": (0.0, 0.2)},
                           planted_order=["b", "a", "c"])
    assert overlap.splitlines()[-1] == ("planted order b > a > c: real success 95% CIs: b > a: NOT separated "
                                        "(intervals overlap); a > c: separated; point estimates do NOT follow it")
    assert "planted order" not in ranking_text({"k": fit}, rate, {"a": (0.7, 0.9)})


def test_ranking_says_what_adaptive_judging_decided_and_cost(make_fit):
    fit = unit_fit(make_fit, {10: {"a": (60.0, 50.0, 70.0), "b": (30.0, 20.0, 40.0), "c": (10.0, 0.0, 20.0)}})
    pairs = [{"policy_i": "a", "policy_j": "b", "decided": False, "winner": None},
             {"policy_i": "a", "policy_j": "c", "decided": True, "winner": "a"},
             {"policy_i": "b", "policy_j": "c", "decided": True, "winner": "b"}]
    account = {"alpha": 0.05, "stop": "units_exhausted", "items": 84, "calls": 84, "requests": 0,
               "describe_calls": 40, "describe_requests": 0, "undecided": ["a vs b"], "pairs": pairs}
    text = ranking_text({"k": fit, "v": fit}, {"a": 0.8, "b": 0.5, "c": 0.1}, adaptive={"k": account, "v": None})
    assert text.splitlines()[0].startswith("Ranking at the last checkpoint (k: 84 comparisons in all, adaptive; "
                                           "v: 10 per policy pair): BT score")
    assert "(10 comparisons per policy pair)" in ranking_text({"k": fit}, {"a": 0.8, "b": 0.5, "c": 0.1})
    assert text.splitlines()[-1] == ("k: adaptive judging stopped (units exhausted) after 84 comparisons; judge calls: "
                                     "40 describe + 84 compare; decided at alpha 0.05 over all pairs: a > c, b > c; "
                                     "left undecided: a vs b")
    vlm = {**account, "describe_calls": None, "requests": 90, "undecided": [], "stop": "all_decided"}
    line = ranking_text({"k": fit}, {"a": 0.8, "b": 0.5, "c": 0.1}, adaptive={"k": vlm}).splitlines()[-1]
    assert line.endswith("84 compare; model requests: 90 compare; decided at alpha 0.05 over all pairs: a > c, b > c")


def test_realsim_table_note_names_the_interval():
    v = validation(0.5, 0.6, 0.1, 6.0)
    v.update(interval="unit", ci_level=0.95)
    table = realsim_table({"kinematic": v})
    check_structure(table)
    lines = table.strip().splitlines()
    assert lines[-3] == r"\bottomrule"
    assert lines[-2] == (r"\multicolumn{8}{l}{\footnotesize BT CI: mean 95\% unit-bootstrap CI width (rollout pairs"
                         r" resampled per task); average over checkpoints.} \\")
    v["interval"] = "binomial"
    last = realsim_table({"kinematic": v}, metrics_at="last")
    assert r"95\% binomial-bootstrap CI width (comparisons redrawn independently); last checkpoint." in last


def test_bt_scores_table_reference_interval_and_note(make_fit):
    fits = {"j1": unit_fit(make_fit, {20: {"a": (25.0, 15.0, 35.0), "b": (75.0, 65.0, 85.0)}})}
    table = bt_scores_table(fits, {"a": 0.9, "b": 0.3}, reference_ci={"a": (0.8, 0.95), "b": (0.2, 0.4)})
    check_structure(table.split("\n", 1)[1])
    comment = table.splitlines()[0]
    assert "unit-bootstrap CI" in comment and "mean of the per-task success rates" in comment
    assert row(table, "a ") == r"a & 90.0 {\scriptsize [80.0, 95.0]} & 25.0 {\scriptsize [15.0, 35.0]} \\"
    assert r"BT: unit bootstrap" in table
    plain = bt_scores_table(fits, {"a": 0.9, "b": 0.3}, show_ci=False, reference_ci={"a": (0.8, 0.95)})
    assert row(plain, "a ") == r"a & 90.0 & 25.0 \\" and "Brackets" not in plain


CARD = {
    "a_share_same_outcome": 0.5, "n_same_outcome": 40, "swap_consistency": 0.9, "n_swapped": 30,
    "outcome_agreement": {"share": 0.8, "ci_low": 0.7, "ci_high": 0.9, "n_pairs": 120, "n_units": 12, "ci_level": 0.95},
    "planted_order_agreement": None,
    "shuffled_label_control": {"n_permutations": 20, "permuted_flat_share": 0.85, "real": {"flat": False}},
}


def test_judge_card_table_rows():
    table = judge_card_table({"kinematic": CARD, "vlm_judge": {}})
    check_structure(table)
    lines = table.splitlines()
    header = next(line for line in lines if line.startswith("Judge"))
    assert header.count("&") == 5
    assert (r"kinematic & 80.0 {\scriptsize [70.0, 90.0]} (120) & -- & 50.0 (40) & 90.0 (30)"
            r" & 85.0 (20) / real not flat \\") in lines
    assert r"vlm\_judge & -- & -- & -- & -- & -- \\" in lines
    assert "Outcome agr." in table and "100/$n$" in table
