# The calibrated sim from what a lab has: the cameras (a board take, or the robot's silhouette in
# the recordings), initial object poses from each episode's first frame through those cameras
# (per-task offsets fitted once on held-out calibration episodes, init_offsets, then frozen and
# added to every estimate, init_estimate), the robot's joint offsets (calib_joints), and the
# light and colours (calib_appearance, which writes the calibrated sim's world parameters).
CAMERAS = CFG["calib"]["cameras"]
BOARD_TAKE = "results/real/board_take" if TWIN else CAMERAS["board_take"]
# The camera estimates made (the one the calibrated sim uses, and the others a run compares it with).
USED_ESTIMATE, MADE_ESTIMATES = camera_plan(CAMERAS, world_robot(CFG["world"]), bool(BOARD_TAKE),
                                            CFG["calib"]["segmenter"]["type"])
CAMERA_ESTIMATES = {method: "results/calib/cameras_" + method + ".json" for method in MADE_ESTIMATES}
USED_CAMERAS = {"cameras": CAMERA_ESTIMATES[USED_ESTIMATE]} if USED_ESTIMATE != "none" else {}
ESTIMATES_ARG = " ".join(method + "=" + path for method, path in CAMERA_ESTIMATES.items())


def cameras_arg(wildcards, input):
    return "--cameras " + input.cameras if "cameras" in input.keys() else ""


rule calib_board:
    priority: SIM_CHAIN_PRIORITY
    input:
        take=BOARD_TAKE or [],
    output:
        "results/calib/cameras_board.json",
    params:
        cfg=stage_params("calib_board"),
    log:
        "logs/calib_board.log",
    shell:
        "{PY} -m r2s_eval.stages.calib_board --cfg {params.cfg:q} --take {input.take} --out {output} --log {log}"


# The board's lenses, where it fits them, let the silhouette fit compare undistorted frames.
BOARD_LENSES = ({"lenses": CAMERA_ESTIMATES["board"]}
                if "board" in CAMERA_ESTIMATES and CAMERAS["board"]["intrinsics"] else {})


rule calib_silhouette:
    priority: SIM_CHAIN_PRIORITY
    input:
        **BOARD_LENSES,
        dataset=REAL_DATASET,
        index="results/ingest/episodes.parquet",
    output:
        "results/calib/cameras_silhouette.json",
    params:
        cfg=stage_params("calib_silhouette"),
        lenses=lambda w, input: f"--lenses {input.lenses}" if "lenses" in input.keys() else "",
    log:
        "logs/calib_silhouette.log",
    shell:
        "{PY} -m r2s_eval.stages.calib_silhouette --cfg {params.cfg:q} {params.lenses} --dataset {input.dataset}"
        " --index {input.index} --out {output} --log {log}"


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
        **USED_CAMERAS,
        index="results/ingest/episodes.parquet",
        frames="results/ingest/first_frames",
    output:
        "results/init/offsets.json",
    params:
        cfg=stage_params("init_offsets"),
        measured=lambda w, input: f"--measured {input.measured}" if "measured" in input.keys() else "",
        cameras=cameras_arg,
    log:
        "logs/init_offsets.log",
    shell:
        "{PY} -m r2s_eval.stages.init_offsets --cfg {params.cfg:q} --index {input.index}"
        " --frames {input.frames} {params.measured} {params.cameras} --out {output} --log {log}"


rule init_estimate:
    # The calibrated sim's chain gates everything sim-side: run it before any training.
    priority: SIM_CHAIN_PRIORITY
    input:
        **USED_CAMERAS,
        index="results/ingest/episodes.parquet",
        frames="results/ingest/first_frames",
        offsets="results/init/offsets.json",
    output:
        "results/init/estimates.parquet",
    params:
        cfg=stage_params("init_estimate"),
        cameras=cameras_arg,
    log:
        "logs/init_estimate.log",
    shell:
        "{PY} -m r2s_eval.stages.init_estimate --cfg {params.cfg:q} --index {input.index}"
        " --frames {input.frames} --offsets {input.offsets} {params.cameras} --out {output} --log {log}"


# The robot's joint offsets, fitted on the recordings' own states and actions.
rule calib_joints:
    priority: SIM_CHAIN_PRIORITY
    input:
        dataset=REAL_DATASET,
        index="results/ingest/episodes.parquet",
        estimates="results/init/estimates.parquet",
    output:
        "results/calib/joints.json",
    params:
        cfg=stage_params("calib_joints"),
    log:
        "logs/calib_joints.log",
    shell:
        "{PY} -m r2s_eval.stages.calib_joints --cfg {params.cfg:q} --dataset {input.dataset}"
        " --index {input.index} --estimates {input.estimates} --out {output} --log {log}"


# The room behind the robot: a background plate per fixed camera from the recordings, seen through
# the calibrated cameras (calib.background.fit).
BACKGROUND = {"background": "results/calib/background"} if CFG["calib"]["background"]["fit"] else {}


rule calib_background:
    priority: SIM_CHAIN_PRIORITY
    input:
        **USED_CAMERAS,
        dataset=REAL_DATASET,
        index="results/ingest/episodes.parquet",
        estimates="results/init/estimates.parquet",
    output:
        directory("results/calib/background"),
    params:
        cfg=stage_params("calib_background"),
        cameras=cameras_arg,
    log:
        "logs/calib_background.log",
    shell:
        "{PY} -m r2s_eval.stages.calib_background --cfg {params.cfg:q} {params.cameras} --dataset {input.dataset}"
        " --index {input.index} --estimates {input.estimates} --out {output} --log {log}"


# Light and colours from first frames, and the calibrated sim's world parameters (cameras, joints,
# background plates, appearance), which replay and every sim rollout build their simulation with.
rule calib_appearance:
    priority: SIM_CHAIN_PRIORITY
    input:
        **USED_CAMERAS,
        **BACKGROUND,
        joints="results/calib/joints.json",
        dataset=REAL_DATASET,
        index="results/ingest/episodes.parquet",
        frames="results/ingest/first_frames",
        estimates="results/init/estimates.parquet",
    output:
        "results/calib/world_params.json",
    params:
        cfg=stage_params("calib_appearance"),
        cameras=cameras_arg,
        background=lambda w, input: f"--background {input.background}" if "background" in input.keys() else "",
    log:
        "logs/calib_appearance.log",
    shell:
        "{PY} -m r2s_eval.stages.calib_appearance --cfg {params.cfg:q} {params.cameras} {params.background}"
        " --joints {input.joints}"
        " --dataset {input.dataset} --index {input.index} --frames {input.frames} --estimates {input.estimates}"
        " --out {output} --log {log}"


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

    # Each camera estimate (and the model's poses) against the twin's true cameras, and the
    # appearance fit's colour error: the world report's calibration section.
    rule calib_error:
        input:
            twin="results/real/twin_params.json",
            estimates=list(CAMERA_ESTIMATES.values()),
            world="results/calib/world_params.json",
        output:
            "results/calib/error.json",
        params:
            cfg=stage_params("calib_error"),
            cameras=ESTIMATES_ARG,
        log:
            "logs/calib_error.log",
        shell:
            "{PY} -m r2s_eval.stages.calib_error --cfg {params.cfg:q} --twin {input.twin}"
            " --cameras {params.cameras} --world-params {input.world} --out {output} --log {log}"

