# Initial object poses from each episode's first head-camera frame: per-task offsets are
# fitted once on held-out calibration episodes (init_offsets), then frozen and added to
# every estimate (init_estimate).
def measured_poses(wildcards):
    """Measured poses of the calibration episodes: the twin's log, or the user's CSV (optional)."""
    if TWIN:
        return {"measured": "results/real/init_truth.parquet"}
    path = CFG["calib"]["calibration"].get("measured_poses")
    return {"measured": path} if path else {}


rule init_offsets:
    priority: SIM_CHAIN_PRIORITY
    input:
        unpack(measured_poses),
        index="results/ingest/episodes.parquet",
        frames="results/ingest/first_frames",
    output:
        "results/init/offsets.json",
    params:
        cfg=stage_params("init_offsets"),
        measured=lambda w, input: f"--measured {input.measured}" if "measured" in input.keys() else "",
    log:
        "logs/init_offsets.log",
    shell:
        "{PY} -m r2s_eval.stages.init_offsets --cfg {params.cfg:q} --index {input.index}"
        " --frames {input.frames} {params.measured} --out {output} --log {log}"


rule init_estimate:
    # The calibrated sim's chain gates everything sim-side: run it before any training.
    priority: SIM_CHAIN_PRIORITY
    input:
        index="results/ingest/episodes.parquet",
        frames="results/ingest/first_frames",
        offsets="results/init/offsets.json",
    output:
        "results/init/estimates.parquet",
    params:
        cfg=stage_params("init_estimate"),
    log:
        "logs/init_estimate.log",
    shell:
        "{PY} -m r2s_eval.stages.init_estimate --cfg {params.cfg:q} --index {input.index}"
        " --frames {input.frames} --offsets {input.offsets} --out {output} --log {log}"


# The robot's joint offsets, fitted on the recordings' own states and actions: the calibrated
# sim's world parameters, which replay and every sim rollout build their simulation with.
rule calib_joints:
    priority: SIM_CHAIN_PRIORITY
    input:
        dataset=REAL_DATASET,
        index="results/ingest/episodes.parquet",
        estimates="results/init/estimates.parquet",
    output:
        "results/calib/world_params.json",
    params:
        cfg=stage_params("calib_joints"),
    log:
        "logs/calib_joints.log",
    shell:
        "{PY} -m r2s_eval.stages.calib_joints --cfg {params.cfg:q} --dataset {input.dataset}"
        " --index {input.index} --estimates {input.estimates} --out {output} --log {log}"


if TWIN:

    # Scores the estimates of the test episodes against the twin's true poses; nothing
    # downstream consumes it. (init_offsets reads the truth of the calibration episodes only.)
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
            " --table {output.table} --summary {output.summary} --log {log}"
