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
        cfg=stage_params("replay"),
    log:
        "logs/replay.log",
    shell:
        "{PY} -m r2s_eval.stages.replay --cfg {params.cfg:q} --dataset {input.dataset}"
        " --index {input.index} --estimates {input.estimates} --out-dataset {output.dataset}"
        " --out-log {output.log_table} --log {log}"


if TWIN:

    # The calibrated world's fidelity per task (teleop success, initial-pose error, replay
    # success and attempts, per-episode costs), printed into the log and kept as JSON.
    rule world_report:
        input:
            truth="results/real/init_truth.parquet",
            errors="results/init/error.parquet",
            replay="results/replay/log.parquet",
            estimates="results/init/estimates.parquet",
        output:
            "results/world/report.json",
        log:
            "logs/world_report.log",
        shell:
            "{PY} -m r2s_eval.stages.world_report --truth {input.truth} --errors {input.errors}"
            " --replay {input.replay} --estimates {input.estimates} --out {output} --log {log}"
