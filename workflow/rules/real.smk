# The "real" side when the bundled reality twin stands in for the robot: sample the twin's
# perturbations, then let the scripted operator record the teleop dataset in it.
if TWIN:

    rule twin:
        output:
            "results/real/twin_params.json",
        params:
            cfg=stage_params("twin"),
        log:
            "logs/twin.log",
        shell:
            "{PY} -m r2s_eval.stages.twin --cfg {params.cfg:q} --out {output} --log {log}"

    rule teleop:
        input:
            twin="results/real/twin_params.json",
        output:
            dataset=directory("results/real/dataset"),
            truth="results/real/init_truth.parquet",
        params:
            cfg=stage_params("teleop"),
        log:
            "logs/teleop.log",
        shell:
            "{PY} -m r2s_eval.stages.teleop --cfg {params.cfg:q} --twin {input.twin}"
            " --dataset {output.dataset} --truth {output.truth} --log {log}"

    # The twin's ChArUco board take, recorded as a lab records one (the camera calibration's input).
    rule board_take:
        input:
            twin="results/real/twin_params.json",
        output:
            directory("results/real/board_take"),
        params:
            cfg=stage_params("board_take"),
        log:
            "logs/board_take.log",
        shell:
            "{PY} -m r2s_eval.stages.board_take --cfg {params.cfg:q} --twin {input.twin} --out {output} --log {log}"

