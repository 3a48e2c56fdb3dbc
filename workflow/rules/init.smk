# Estimate every episode's initial object poses from its first head-camera frame.
rule init_estimate:
    # The calibrated sim's chain gates everything sim-side: run it before any training.
    priority: SIM_CHAIN_PRIORITY
    input:
        index="results/ingest/episodes.parquet",
        frames="results/ingest/first_frames",
    output:
        "results/init/estimates.parquet",
    params:
        cfg=params_of("calib", "world"),
    log:
        "logs/init_estimate.log",
    shell:
        "{PY} -m r2s_eval.stages.init_estimate --cfg {params.cfg:q} --index {input.index}"
        " --frames {input.frames} --out {output} > {log} 2>&1"


if TWIN:

    # The only reader of the twin's true poses: it scores the estimate, nothing consumes it.
    rule init_error:
        input:
            estimates="results/init/estimates.parquet",
            truth="results/real/init_truth.parquet",
        output:
            table="results/init/error.parquet",
            summary="results/init/error_summary.json",
        log:
            "logs/init_error.log",
        shell:
            "{PY} -m r2s_eval.stages.init_error --estimates {input.estimates} --truth {input.truth}"
            " --table {output.table} --summary {output.summary} > {log} 2>&1"
