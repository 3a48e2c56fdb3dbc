# The judge describes each sim rollout once, then picks A or B for every sampled pair.
# Answers are cached by content under results/cache/, so reruns never pay twice.
rule describe:
    input:
        expand("results/rollout/sim/{policy}", policy=POLICIES),
    output:
        "results/judge/{judge}/descriptions.parquet",
    params:
        cfg=judge_params,
    log:
        "logs/describe/{judge}.log",
    shell:
        "{PY} -m r2s_eval.stages.describe --cfg {params.cfg:q} --rollouts {input}"
        " --cache results/cache/judge/{wildcards.judge} --out {output} > {log} 2>&1"


rule judge_pairs:
    input:
        pairs="results/compare/pairs.parquet",
        descriptions="results/judge/{judge}/descriptions.parquet",
    output:
        "results/judge/{judge}/verdicts.parquet",
    params:
        cfg=judge_params,
    log:
        "logs/judge_pairs/{judge}.log",
    shell:
        "{PY} -m r2s_eval.stages.judge_pairs --cfg {params.cfg:q} --pairs {input.pairs}"
        " --descriptions {input.descriptions} --cache results/cache/judge/{wildcards.judge}"
        " --out {output} > {log} 2>&1"
