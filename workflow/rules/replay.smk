# Replay the recorded joint actions in the calibrated sim, retrying from perturbed poses.
rule replay:
    # The calibrated sim's chain gates everything sim-side: run it before any training.
    priority: SIM_CHAIN_PRIORITY
    input:
        dataset=REAL_DATASET,
        index="results/ingest/episodes.parquet",
        estimates="results/init/estimates.parquet",
    output:
        dataset=directory("results/replay/dataset"),
        log_table="results/replay/log.parquet",
    params:
        cfg=params_of("replay", "world", "seed"),
    log:
        "logs/replay.log",
    shell:
        "{PY} -m r2s_eval.stages.replay --cfg {params.cfg:q} --dataset {input.dataset}"
        " --index {input.index} --estimates {input.estimates} --out-dataset {output.dataset}"
        " --out-log {output.log_table} > {log} 2>&1"
