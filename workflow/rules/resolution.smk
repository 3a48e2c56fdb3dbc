# Each judge's resolution (conf/resolution): every level of every planted kind is a variant of
# resolution.policy, rolled out in both worlds by the `rollout` rule from the experiment's inits;
# each judge compares the clean run with every level's run from the same init.
# (SWEEP_RUNS, and the card among REPORTS: workflow/rules/report.smk.) Real rollouts need the twin;
# with a lab's own trials the card gives the sim's success alone.


# The sweep's own describe jobs (the line-up's describe rule runs only where the allocation is
# fixed); answers are cached by content, so the clean run's descriptions are never paid twice.
rule resolution_describe:
    input:
        "results/rollout/sim/{policy}",
    output:
        "results/resolution/{judge}/describe/{policy}.parquet",
        "results/resolution/{judge}/describe/{policy}.stats.json",
    params:
        cfg=judge_params("describe"),
        transport=judge_transport,
    log:
        "logs/resolution/describe/{judge}/{policy}.log",
    shell:
        "{PY} -m r2s_eval.stages.describe --cfg {params.cfg:q} --rollouts {input}"
        " --cache {JUDGE_CACHE} --transport {params.transport:q} --out {output[0]} --stats {output[1]} --log {log}"


def resolution_inputs(wildcards):
    inputs = {"sim": expand("results/rollout/sim/{policy}", policy=SWEEP_RUNS),
              "real": expand("results/rollout/real/{policy}", policy=SWEEP_RUNS) if TWIN else []}
    if judge_mode(wildcards) == "two_step":
        inputs["descriptions"] = expand("results/resolution/{judge}/describe/{policy}.parquet",
                                        judge=wildcards.judge, policy=SWEEP_RUNS)
    return inputs


rule judge_resolution:
    input:
        unpack(resolution_inputs),
    output:
        verdicts="results/resolution/{judge}/verdicts.parquet",
        stats="results/resolution/{judge}/compare_stats.json",
        card="results/resolution/{judge}.json",
    params:
        cfg=judge_params("judge_resolution"),
        transport=judge_transport,
        descriptions=lambda wc, input: f"--descriptions {' '.join(input.descriptions)}" if "descriptions" in input.keys() else "",
    log:
        "logs/resolution/{judge}.log",
    shell:
        "{PY} -m r2s_eval.stages.judge_resolution --cfg {params.cfg:q} --sim {input.sim} --real {input.real}"
        " {params.descriptions} --cache {JUDGE_CACHE} --transport {params.transport:q}"
        " --verdicts {output.verdicts} --out {output.card} --log {log}"


rule resolution_report:
    input:
        expand("results/resolution/{judge}.json", judge=JUDGES),
    output:
        table="reports/judge_resolution_table.tex",
        pdf="reports/judge_resolution.pdf",
        png="reports/judge_resolution.png",
    params:
        cfg=stage_params("resolution_report"),
    log:
        "logs/report/resolution_report.log",
    shell:
        "{PY} -m r2s_eval.stages.resolution_report --cfg {params.cfg:q} --cards {input}"
        " --table {output.table} --pdf {output.pdf} --png {output.png} --log {log}"
