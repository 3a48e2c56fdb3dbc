# Replay the recorded joint actions in the calibrated sim, retrying from perturbed poses.
rule replay:
    # The calibrated sim's chain gates everything sim-side: run it before any training.
    priority: SIM_CHAIN_PRIORITY
    input:
        dataset=REAL_DATASET,
        index="results/ingest/episodes.parquet",
        estimates="results/init/estimates.parquet",
        world="results/calib/world_params.json",
    output:
        dataset=directory("results/replay/dataset"),
        log_table="results/replay/log.parquet",
    params:
        cfg=stage_params("replay"),
    log:
        "logs/replay.log",
    shell:
        "{PY} -m r2s_eval.stages.replay --cfg {params.cfg:q} --dataset {input.dataset}"
        " --index {input.index} --estimates {input.estimates} --world-params {input.world}"
        " --out-dataset {output.dataset}"
        " --out-log {output.log_table} --log {log}"


if TWIN:

    # The calibrated world's fidelity per task (teleop success, initial-pose error, replay
    # success at the first attempt and after retries, per-episode costs, the real-sim success
    # gap per policy), printed into the log and kept as JSON.
    rule world_report:
        input:
            truth="results/real/init_truth.parquet",
            errors="results/init/error.parquet",
            replay="results/replay/log.parquet",
            estimates="results/init/estimates.parquet",
            reference="results/reference/success.parquet",
            rollouts=expand("results/rollout/sim/{policy}", policy=POLICIES),
            fidelity="results/fidelity/report.json",
            calibration="results/calib/error.json",
        output:
            "results/world/report.json",
        params:
            cfg=stage_params("world_report"),
        log:
            "logs/world_report.log",
        shell:
            "{PY} -m r2s_eval.stages.world_report --cfg {params.cfg:q} --truth {input.truth} --errors {input.errors}"
            " --replay {input.replay} --estimates {input.estimates} --reference {input.reference}"
            " --rollouts {input.rollouts} --fidelity {input.fidelity} --calibration {input.calibration}"
            " --out {output} --log {log}"
