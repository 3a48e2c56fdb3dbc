# Fine-tune every candidate policy twice: on real data (pi^R) and on replayed sim data (pi^S).
def train_dataset(wildcards):
    return REAL_DATASET if wildcards.arm == "real" else "results/replay/dataset"


def train_priority(wildcards):
    # Longest jobs first, sim side first (more stages wait on it): keeps both cores busy.
    steps = int(CFG["policies"][wildcards.policy].get("steps", 0))
    return steps + (100_000 if wildcards.arm == "sim" else 0)


rule train:
    wildcard_constraints:
        policy="|".join(TRAINED) or "(?!)",  # checkpoint and server candidates are not trained
    input:
        dataset=train_dataset,
    output:
        directory("results/train/{arm}/{policy}"),
    params:
        cfg=policy_params,
    priority: train_priority
    threads: 1
    log:
        "logs/train/{arm}/{policy}.log",
    shell:
        "OMP_NUM_THREADS={threads} {PY} -m r2s_eval.stages.train --cfg {params.cfg:q}"
        " --dataset {input.dataset} --out {output} --threads {threads} > {log} 2>&1"
