# Task-stratified A/B pairs at nested checkpoints, sampled once for every judge.
rule compare_pairs:
    input:
        expand("results/rollout/sim/{policy}", policy=POLICIES),
    output:
        "results/compare/pairs.parquet",
    params:
        cfg=stage_params("compare_pairs"),
    log:
        "logs/compare_pairs.log",
    shell:
        "{PY} -m r2s_eval.stages.compare_pairs --cfg {params.cfg:q} --rollouts {input}"
        " --out {output} --log {log}"
