# Validate the teleop dataset and index its episodes (task, length, first frame).
rule ingest:
    # The calibrated sim's chain gates everything sim-side: run it before any training.
    priority: SIM_CHAIN_PRIORITY
    input:
        dataset=REAL_DATASET,
    output:
        index="results/ingest/episodes.parquet",
        report="results/ingest/report.json",
        frames=directory("results/ingest/first_frames"),
    params:
        cfg=stage_params("ingest", instructions=INSTRUCTIONS),
    log:
        "logs/ingest.log",
    shell:
        "{PY} -m r2s_eval.stages.ingest --cfg {params.cfg:q} --dataset {input.dataset}"
        " --index {output.index} --report {output.report} --frames {output.frames} --log {log}"
