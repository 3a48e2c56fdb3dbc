# The judge describes each sim rollout once, then picks A or B for every sampled pair (two-step
# judges compare the descriptions; one-step judges, `mode: one_step`, watch both videos).
# Answers are cached by content in one folder shared by all judges (keys hold the model, the
# prompts and the generation settings), so reruns and repeated judge entries never pay twice.
JUDGE_CACHE = "results/cache/judge"


def judge_mode(wildcards):
    return judge_option(wildcards.judge, "mode")


def judge_answer_cfg(wildcards):
    cfg = CFG["judges"][wildcards.judge]
    return {k: v for k, v in cfg.items() if k not in transport_keys(cfg)}


def judge_transport(wildcards):
    cfg = CFG["judges"][wildcards.judge]
    return Untracked({k: v for k, v in cfg.items() if k in transport_keys(cfg)})


def judge_params(stage):
    def params(wildcards):
        return stage_params(stage, judge=judge_answer_cfg(wildcards), name=wildcards.judge)

    return params


def judge_pair_inputs(wildcards):
    inputs = {
        "pairs": "results/compare/pairs.parquet",
        "rollouts": expand("results/rollout/sim/{policy}", policy=POLICIES),
    }
    if judge_mode(wildcards) == "two_step":
        inputs["descriptions"] = f"results/judge/{wildcards.judge}/descriptions.parquet"
    return inputs


ADAPTIVE = CFG["compare"]["allocation"] == "adaptive"
TWO_STEP_JUDGES = [j for j in JUDGES if judge_option(j, "mode") == "two_step"]
ONE_STEP_JUDGES = [j for j in JUDGES if j not in TWO_STEP_JUDGES]

if not ADAPTIVE:
    # One describe job per judge and policy, started as soon as that policy's sim rollouts exist, so
    # judging overlaps the rollouts still running (and spreads over a cluster); `descriptions`
    # gathers a judge's parts into one table.
    rule describe:
        input:
            "results/rollout/sim/{policy}",
        output:
            "results/judge/{judge}/describe/{policy}.parquet",
            "results/judge/{judge}/describe/{policy}.stats.json",
        # Before the real side's rollouts: only the reference waits on those.
        priority: 1
        params:
            cfg=judge_params("describe"),
            transport=judge_transport,
        log:
            "logs/describe/{judge}/{policy}.log",
        shell:
            "{PY} -m r2s_eval.stages.describe --cfg {params.cfg:q} --rollouts {input}"
            " --cache {JUDGE_CACHE} --transport {params.transport:q} --out {output[0]} --stats {output[1]} --log {log}"


    rule descriptions:
        input:
            expand("results/judge/{{judge}}/describe/{policy}.parquet", policy=POLICIES),
        output:
            "results/judge/{judge}/descriptions.parquet",
            "results/judge/{judge}/describe_stats.json",
        log:
            "logs/descriptions/{judge}.log",
        shell:
            "{PY} -m r2s_eval.stages.descriptions --parts {input} --out {output[0]} --log {log}"


    rule judge_pairs:
        input:
            unpack(judge_pair_inputs),
        output:
            "results/judge/{judge}/verdicts.parquet",
            "results/judge/{judge}/compare_stats.json",
        params:
            cfg=judge_params("judge_pairs"),
            transport=judge_transport,
            descriptions=lambda wc, input: f"--descriptions {input.descriptions}" if "descriptions" in input.keys() else "",
        log:
            "logs/judge_pairs/{judge}.log",
        shell:
            "{PY} -m r2s_eval.stages.judge_pairs --cfg {params.cfg:q} --pairs {input.pairs}"
            " --rollouts {input.rollouts} {params.descriptions} --cache {JUDGE_CACHE}"
            " --transport {params.transport:q} --out {output[0]} --log {log}"


# compare.allocation: adaptive. One job per judge asks block after block of comparisons for the
# pairs still open; two-step judges describe a rollout when a chosen comparison first needs it,
# so the describe jobs above do not run and this job writes the descriptions it made.
def adaptive_inputs(wildcards):
    return {"pairs": "results/compare/pairs.parquet",
            "rollouts": expand("results/rollout/sim/{policy}", policy=POLICIES)}


ADAPTIVE_SHELL = (
    "{PY} -m r2s_eval.stages.judge_adaptive --cfg {params.cfg:q} --pairs {input.pairs}"
    " --rollouts {input.rollouts} --cache {JUDGE_CACHE} --transport {params.transport:q}"
    " --out {output.verdicts} {params.descriptions} --log {log}"
)

if ADAPTIVE and TWO_STEP_JUDGES:

    rule judge_adaptive_described:
        input:
            unpack(adaptive_inputs),
        output:
            verdicts="results/judge/{judge}/verdicts.parquet",
            stats="results/judge/{judge}/compare_stats.json",
            descriptions="results/judge/{judge}/descriptions.parquet",
            describe_stats="results/judge/{judge}/describe_stats.json",
        wildcard_constraints:
            judge="|".join(TWO_STEP_JUDGES),
        params:
            cfg=judge_params("judge_adaptive"),
            transport=judge_transport,
            descriptions=lambda wc, output: f"--descriptions-out {output.descriptions}",
        log:
            "logs/judge_pairs/{judge}.log",
        shell:
            ADAPTIVE_SHELL

if ADAPTIVE and ONE_STEP_JUDGES:

    rule judge_adaptive:
        input:
            unpack(adaptive_inputs),
        output:
            verdicts="results/judge/{judge}/verdicts.parquet",
            stats="results/judge/{judge}/compare_stats.json",
        wildcard_constraints:
            judge="|".join(ONE_STEP_JUDGES),
        params:
            cfg=judge_params("judge_adaptive"),
            transport=judge_transport,
            descriptions="",
        log:
            "logs/judge_pairs/{judge}.log",
        shell:
            ADAPTIVE_SHELL
