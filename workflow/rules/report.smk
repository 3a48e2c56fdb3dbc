# Paper tables and figures, generated from the artefacts.
rule realsim_table:
    input:
        validation=expand("results/validate/{judge}.json", judge=JUDGES),
        fits=expand("results/fit/{judge}.parquet", judge=JUDGES),
        reference="results/reference/success.parquet",
    output:
        table="reports/realsim_table.tex",
        ranking="reports/ranking.txt",
    params:
        cfg=params_of("report.realsim_table"),
    log:
        "logs/realsim_table.log",
    shell:
        "{PY} -m r2s_eval.stages.realsim_table --cfg {params.cfg:q} --validation {input.validation}"
        " --fits {input.fits} --reference {input.reference} --table {output.table}"
        " --ranking {output.ranking} > {log} 2>&1"
