# Paper tables (LaTeX, booktabs) and figures (PDF + PNG), generated from the artefacts.
# Each report has its own rule and reads only its own slice of conf/report, so changing one
# plotting option reruns that report alone. `snakemake reports` builds them all.
SIM_ROLLOUTS = expand("results/rollout/sim/{policy}", policy=POLICIES)
FIGURE_EXTS = ["pdf", "png"]
HUMAN_ANNOTATIONS = CFG["report"]["judge_audit"]["human_annotations"]
# What the reference is, in the figures' and the tables' words.
REFERENCE_NAME = "LIBERO success" if LIBERO else "real success"
REFERENCE_COLUMN = "LIBERO" if LIBERO else "Real"

# Tables and figures of either setting; then each setting's own.
SHARED_REPORTS = [
    "reports/bt_scores_table.tex",
    "reports/judge_card_table.tex",
    *expand("reports/win_rate_matrix_{judge}.{ext}", judge=JUDGES, ext=FIGURE_EXTS),
    *expand("reports/bt_convergence.{ext}", ext=FIGURE_EXTS),
    *expand("reports/overall_ranking.{ext}", ext=FIGURE_EXTS),
    *expand("reports/case_study_{judge}.{ext}", judge=JUDGES, ext=FIGURE_EXTS),
    "reports/index.html",
]
# The perturbation ablation (workflow/rules/fidelity.smk) runs with the twin, for the policies named.
ABLATION_POLICIES = [] if LIBERO or not TWIN else CFG["fidelity"]["ablation"]["policies"]
FIDELITY_ABLATION = (["reports/fidelity_ablation_table.tex", *expand("reports/fidelity_ablation.{ext}", ext=FIGURE_EXTS)]
                     if ABLATION_POLICIES else [])
# The crossing in further sims (fidelity.sims) and the twin's effects alone (fidelity.ablation.alone).
FIDELITY_MORE_TABLES = ((["reports/fidelity_sims_table.tex"] if not LIBERO and CFG["fidelity"]["sims"] else [])
                        + (["reports/fidelity_alone_table.tex"] if ABLATION_POLICIES and CFG["fidelity"]["ablation"]["alone"]
                           else []))
if LIBERO:
    REPORTS = ["reports/libero_table.tex", *SHARED_REPORTS]
else:
    REPORTS = [
        "reports/tasks_table.tex",
        "reports/realsim_success_table.tex",
        "reports/realsim_table.tex",
        *expand("reports/hardware_effort.{ext}", ext=FIGURE_EXTS),
        "reports/fidelity_table.tex",
        *FIDELITY_ABLATION,
        *FIDELITY_MORE_TABLES,
        *SHARED_REPORTS,
    ]
# The evaluation repeated on disjoint blocks of inits (stability.repetitions; the twin's trials are the truth).
STABILITY = TWIN and CFG["stability"]["repetitions"] >= 2
if STABILITY:
    REPORTS += ["reports/stability_table.tex", *expand("reports/stability.{ext}", ext=FIGURE_EXTS)]
# Each judge's resolution over the planted kinds (conf/resolution; workflow/rules/resolution.smk).
SWEEP_RUNS = [CFG["resolution"]["policy"], *SWEEP_CFG] if SWEEP else []
if SWEEP:
    REPORTS += ["reports/judge_resolution_table.tex", *expand("reports/judge_resolution.{ext}", ext=FIGURE_EXTS)]


rule reports:
    input:
        REPORTS,


rule tasks_table:
    input:
        index="results/ingest/episodes.parquet",
        replay_log="results/replay/log.parquet",
    output:
        "reports/tasks_table.tex",
    params:
        cfg=stage_params("tasks_table"),
    log:
        "logs/report/tasks_table.log",
    shell:
        "{PY} -m r2s_eval.stages.tasks_table --cfg {params.cfg:q} --index {input.index}"
        " --replay-log {input.replay_log} --out {output} --log {log}"


rule realsim_success_table:
    input:
        reference="results/reference/success.parquet",
        rollouts=SIM_ROLLOUTS,
    output:
        "reports/realsim_success_table.tex",
    params:
        cfg=stage_params("realsim_success_table"),
    log:
        "logs/report/realsim_success_table.log",
    shell:
        "{PY} -m r2s_eval.stages.realsim_success_table --cfg {params.cfg:q} --reference {input.reference}"
        " --rollouts {input.rollouts} --out {output} --log {log}"


# A line-up with variants (planted quality) also reads the judge's fit and the reference's
# intervals: are the clean and the variant apart in BT while their success is not?
PLANTED = ({"fit": "results/fit/{judge}.parquet", "validation": "results/validate/{judge}.json"}
           if VARIANTS else {})
# What the stages that read the line-up's variants are given (nothing without any: no rerun).
PLANTED_VARIANTS = {"planted_variants": VARIANTS} if VARIANTS else {}


rule judge_audit:
    input:
        verdicts="results/judge/{judge}/verdicts.parquet",
        rollouts=SIM_ROLLOUTS,
        annotations=[HUMAN_ANNOTATIONS] if HUMAN_ANNOTATIONS else [],
        **PLANTED,
    output:
        "results/audit/{judge}.json",
    params:
        cfg=stage_params("judge_audit", **PLANTED_VARIANTS),
        annotations=f"--annotations {HUMAN_ANNOTATIONS}" if HUMAN_ANNOTATIONS else "",
        planted=lambda w, input: f"--fit {input.fit} --validation {input.validation}" if VARIANTS else "",
    log:
        "logs/report/judge_audit/{judge}.log",
    shell:
        "{PY} -m r2s_eval.stages.judge_audit --cfg {params.cfg:q} --judge {wildcards.judge}"
        " --verdicts {input.verdicts} --rollouts {input.rollouts} {params.annotations} {params.planted}"
        " --out {output} --log {log}"


rule judge_card_table:
    input:
        expand("results/audit/{judge}.json", judge=JUDGES),
    output:
        "reports/judge_card_table.tex",
    params:
        cfg=stage_params("judge_card_table"),
    log:
        "logs/report/judge_card_table.log",
    shell:
        "{PY} -m r2s_eval.stages.judge_card_table --cfg {params.cfg:q} --audits {input} --out {output} --log {log}"


if LIBERO:

    # LIBERO: the same judge rows, validated against LIBERO's success rate, and that rate per suite.
    rule libero_table:
        input:
            validation=expand("results/validate/{judge}.json", judge=JUDGES),
            audits=expand("results/audit/{judge}.json", judge=JUDGES),
            fits=expand("results/fit/{judge}.parquet", judge=JUDGES),
            reference="results/reference/success.parquet",
        output:
            table="reports/libero_table.tex",
            ranking="reports/ranking.txt",
        params:
            cfg=stage_params("libero_table"),
        log:
            "logs/libero_table.log",
        shell:
            "{PY} -m r2s_eval.stages.libero_table --cfg {params.cfg:q} --validation {input.validation}"
            " --audits {input.audits} --fits {input.fits} --reference {input.reference} --table {output.table}"
            " --ranking {output.ranking} --log {log}"

else:

    rule realsim_table:
        input:
            validation=expand("results/validate/{judge}.json", judge=JUDGES),
            audits=expand("results/audit/{judge}.json", judge=JUDGES),
            fits=expand("results/fit/{judge}.parquet", judge=JUDGES),
            reference="results/reference/success.parquet",
        output:
            table="reports/realsim_table.tex",
            ranking="reports/ranking.txt",
        params:
            cfg=stage_params("realsim_table"),
        log:
            "logs/realsim_table.log",
        shell:
            "{PY} -m r2s_eval.stages.realsim_table --cfg {params.cfg:q} --validation {input.validation}"
            " --audits {input.audits} --fits {input.fits} --reference {input.reference} --table {output.table}"
            " --ranking {output.ranking} --log {log}"


rule bt_scores_table:
    input:
        fits=expand("results/fit/{judge}.parquet", judge=JUDGES),
        reference="results/reference/success.parquet",
        validation=expand("results/validate/{judge}.json", judge=JUDGES),  # the reference's CI
    output:
        "reports/bt_scores_table.tex",
    params:
        cfg=stage_params("bt_scores_table"),
        reference_name=REFERENCE_COLUMN,
    log:
        "logs/report/bt_scores_table.log",
    shell:
        "{PY} -m r2s_eval.stages.bt_scores_table --cfg {params.cfg:q} --fits {input.fits}"
        " --reference {input.reference} --validation {input.validation} --out {output}"
        " --reference-name {params.reference_name:q} --log {log}"


rule win_rate_matrix:
    input:
        "results/judge/{judge}/verdicts.parquet",
    output:
        pdf="reports/win_rate_matrix_{judge}.pdf",
        png="reports/win_rate_matrix_{judge}.png",
    params:
        cfg=stage_params("win_rate_figure"),
    log:
        "logs/report/win_rate_matrix/{judge}.log",
    shell:
        "{PY} -m r2s_eval.stages.win_rate_figure --cfg {params.cfg:q} --judge {wildcards.judge}"
        " --verdicts {input} --pdf {output.pdf} --png {output.png} --log {log}"


rule bt_convergence:
    input:
        expand("results/fit/{judge}.parquet", judge=JUDGES),
    output:
        pdf="reports/bt_convergence.pdf",
        png="reports/bt_convergence.png",
    params:
        cfg=stage_params("bt_convergence_figure"),
    log:
        "logs/report/bt_convergence.log",
    shell:
        "{PY} -m r2s_eval.stages.bt_convergence_figure --cfg {params.cfg:q} --fits {input}"
        " --pdf {output.pdf} --png {output.png} --log {log}"


rule overall_ranking:
    input:
        fits=expand("results/fit/{judge}.parquet", judge=JUDGES),
        reference="results/reference/success.parquet",
        validation=expand("results/validate/{judge}.json", judge=JUDGES),  # the reference's CI
    output:
        pdf="reports/overall_ranking.pdf",
        png="reports/overall_ranking.png",
    params:
        cfg=stage_params("overall_ranking_figure"),
        reference_name=REFERENCE_NAME,
    log:
        "logs/report/overall_ranking.log",
    shell:
        "{PY} -m r2s_eval.stages.overall_ranking_figure --cfg {params.cfg:q} --fits {input.fits}"
        " --reference {input.reference} --validation {input.validation} --pdf {output.pdf} --png {output.png}"
        " --reference-name {params.reference_name:q} --log {log}"


rule hardware_effort:
    input:
        reference="results/reference/success.parquet",
    output:
        pdf="reports/hardware_effort.pdf",
        png="reports/hardware_effort.png",
    params:
        cfg=stage_params("hardware_effort_figure"),
    log:
        "logs/report/hardware_effort.log",
    shell:
        "{PY} -m r2s_eval.stages.hardware_effort_figure --cfg {params.cfg:q} --reference {input.reference}"
        " --pdf {output.pdf} --png {output.png} --log {log}"


rule case_study:
    input:
        verdicts="results/judge/{judge}/verdicts.parquet",
        rollouts=SIM_ROLLOUTS,
    output:
        pdf="reports/case_study_{judge}.pdf",
        png="reports/case_study_{judge}.png",
    params:
        cfg=stage_params("case_study_figure"),
    log:
        "logs/report/case_study/{judge}.log",
    shell:
        "{PY} -m r2s_eval.stages.case_study_figure --cfg {params.cfg:q} --judge {wildcards.judge}"
        " --verdicts {input.verdicts} --rollouts {input.rollouts} --pdf {output.pdf} --png {output.png}"
        " --log {log}"


# The static results browser. It links the figures where they lie, so a figure redrawn after a
# plotting change shows without rebuilding the page: they are inputs only so that they exist.
BROWSER_FIGURES = [
    "reports/bt_convergence.png",
    "reports/overall_ranking.png",
    *expand("reports/win_rate_matrix_{judge}.png", judge=JUDGES),
    *expand("reports/case_study_{judge}.png", judge=JUDGES),
]
DESCRIBED_JUDGES = [j for j in JUDGES if judge_option(j, "mode") == "two_step"]


rule results_browser:
    input:
        fits=expand("results/fit/{judge}.parquet", judge=JUDGES),
        validation=expand("results/validate/{judge}.json", judge=JUDGES),
        audits=expand("results/audit/{judge}.json", judge=JUDGES),
        verdicts=expand("results/judge/{judge}/verdicts.parquet", judge=JUDGES),
        descriptions=expand("results/judge/{judge}/descriptions.parquet", judge=DESCRIBED_JUDGES),
        rollouts=SIM_ROLLOUTS,
        figures=[ancient(f) for f in BROWSER_FIGURES],
    output:
        page="reports/index.html",
        media=directory("reports/browser"),
    params:
        cfg=stage_params("results_browser"),
        descriptions=lambda wc, input: f"--descriptions {' '.join(input.descriptions)}" if input.descriptions else "",
    log:
        "logs/report/results_browser.log",
    shell:
        "{PY} -m r2s_eval.stages.results_browser --cfg {params.cfg:q} --fits {input.fits}"
        " --validation {input.validation} --audits {input.audits} --verdicts {input.verdicts} {params.descriptions}"
        " --rollouts {input.rollouts} --figures {input.figures} --out {output.page} --media {output.media} --log {log}"


if STABILITY:

    rule stability:
        input:
            real=expand("results/rollout/real/{policy}", policy=POLICIES),
            sim=expand("results/rollout/sim/{policy}", policy=POLICIES),
            verdicts=expand("results/judge/{judge}/verdicts.parquet", judge=JUDGES),
            # stability.networks_in_twin: the checkpoints the sim ranks, rolled out in the twin
            # (those trained here; a candidate from elsewhere is left out of that view)
            networks=expand("results/cross/real/{policy}", policy=CROSSED if CFG["stability"]["networks_in_twin"] else []),
        output:
            summary="results/stability/summary.json",
            table="reports/stability_table.tex",
            pdf="reports/stability.pdf",
            png="reports/stability.png",
        params:
            cfg=stage_params("stability", **PLANTED_VARIANTS),
        log:
            "logs/report/stability.log",
        shell:
            "{PY} -m r2s_eval.stages.stability --cfg {params.cfg:q} --real-rollouts {input.real} --sim-rollouts {input.sim}"
            " --networks-in-twin {input.networks} --verdicts {input.verdicts} --out {output.summary} --table {output.table}"
            " --pdf {output.pdf} --png {output.png} --log {log}"
