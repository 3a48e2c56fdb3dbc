# Fine-tune every candidate policy twice: on real data (pi^R) and on replayed sim data (pi^S).
def train_dataset(wildcards):
    return REAL_DATASET if wildcards.arm == "real" else "results/replay/dataset"


rule train:
    input:
        dataset=train_dataset,
    output:
        directory("results/train/{arm}/{policy}"),
    params:
        cfg=policy_params,
    threads: 1
    log:
        "logs/train/{arm}/{policy}.log",
    shell:
        "OMP_NUM_THREADS={threads} {PY} -m r2s_eval.stages.train --cfg {params.cfg:q}"
        " --dataset {input.dataset} --out {output} --threads {threads} > {log} 2>&1"
