# Bradley-Terry fit with bootstrap CIs at every checkpoint (binomial and unit bootstrap; the
# unit of a comparison is its policy pair, task and init_id, kept in the verdicts and checked
# against the sampled pairs), then validation vs the reference with metric CIs.
rule fit:
    input:
        verdicts="results/judge/{judge}/verdicts.parquet",
        pairs="results/compare/pairs.parquet",
    output:
        fit="results/fit/{judge}.parquet",
        replicates="results/fit/{judge}.replicates.parquet",
    params:
        cfg=stage_params("fit"),
    log:
        "logs/fit/{judge}.log",
    shell:
        "{PY} -m r2s_eval.stages.fit --cfg {params.cfg:q} --verdicts {input.verdicts} --pairs {input.pairs}"
        " --out {output.fit} --replicates {output.replicates} --log {log}"


rule validate:
    input:
        fit="results/fit/{judge}.parquet",
        replicates="results/fit/{judge}.replicates.parquet",
        reference="results/reference/success.parquet",
        # stability.networks_in_twin: the checkpoints the sim ranks, rolled out in the twin
        networks=expand("results/cross/real/{policy}", policy=CROSSED if CFG["stability"]["networks_in_twin"] else []),
    output:
        "results/validate/{judge}.json",
    params:
        cfg=stage_params("validate"),
    log:
        "logs/validate/{judge}.log",
    shell:
        "{PY} -m r2s_eval.stages.validate --cfg {params.cfg:q} --fit {input.fit} --replicates {input.replicates}"
        " --reference {input.reference} --networks-in-twin {input.networks} --out {output} --log {log}"
