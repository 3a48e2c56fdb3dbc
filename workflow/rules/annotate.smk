# The blinded A/B annotation set people answer in the annotation app
# (`python -m r2s_eval.annotate serve`; answers stay in results/annotate/answers.sqlite).
rule annotation_set:
    input:
        pairs="results/compare/pairs.parquet",
        rollouts=expand("results/rollout/sim/{policy}", policy=POLICIES),
    output:
        table="results/annotate/set.parquet",
        videos=directory("results/annotate/videos"),
        summary="results/annotate/summary.json",
    params:
        cfg=stage_params("annotation_set"),
    log:
        "logs/annotate/annotation_set.log",
    shell:
        "{PY} -m r2s_eval.stages.annotation_set --cfg {params.cfg:q} --pairs {input.pairs} --rollouts {input.rollouts}"
        " --out {output.table} --videos {output.videos} --summary {output.summary} --log {log}"
