# Bradley-Terry fit with bootstrap CIs at every checkpoint, then validation vs the reference.
rule fit:
    input:
        verdicts="results/judge/{judge}/verdicts.parquet",
        pairs="results/compare/pairs.parquet",
    output:
        "results/fit/{judge}.parquet",
    params:
        cfg=params_of("stats", "compare", "seed"),
    log:
        "logs/fit/{judge}.log",
    shell:
        "{PY} -m r2s_eval.stages.fit --cfg {params.cfg:q} --verdicts {input.verdicts}"
        " --out {output} > {log} 2>&1"


rule validate:
    input:
        fit="results/fit/{judge}.parquet",
        reference="results/reference/success.parquet",
    output:
        "results/validate/{judge}.json",
    params:
        cfg=params_of("stats"),
    log:
        "logs/validate/{judge}.log",
    shell:
        "{PY} -m r2s_eval.stages.validate --cfg {params.cfg:q} --fit {input.fit}"
        " --reference {input.reference} --out {output} > {log} 2>&1"
