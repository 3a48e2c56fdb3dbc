# Fine-tune every candidate policy twice: on real data (pi^R) and on replayed sim data (pi^S).
def train_inputs(wildcards):
    # The real arm reads ingest's index (only the episodes it kept), so it cannot start before
    # ingest passed; the replayed sim dataset is made from those episodes only.
    if wildcards.arm == "real":
        return {"dataset": REAL_DATASET, "index": "results/ingest/episodes.parquet"}
    return {"dataset": "results/replay/dataset"}


def train_index_arg(wildcards, input):
    return f"--episodes-index {input.index}" if wildcards.arm == "real" else ""


def train_priority(wildcards):
    # Longest jobs first, sim side first (more stages wait on it): keeps both cores busy.
    steps = int(CFG["policies"][wildcards.policy].get("steps", 0))
    return steps + (100_000 if wildcards.arm == "sim" else 0)


rule train:
    wildcard_constraints:
        policy="|".join(TRAINED) or "(?!)",  # checkpoint and server candidates are not trained
    input:
        unpack(train_inputs),
    output:
        directory("results/train/{arm}/{policy}"),
    params:
        cfg=policy_params,
        index=train_index_arg,
    priority: train_priority
    threads: 1
    log:
        "logs/train/{arm}/{policy}.log",
    shell:
        "OMP_NUM_THREADS={threads} {PY} -m r2s_eval.stages.train --cfg {params.cfg:q}"
        " --dataset {input.dataset} {params.index} --out {output} --threads {threads} --log {log}"


# A candidate's further training seeds (policies.<name>.seeds > 1), for the fidelity report's
# spread of success over trainings; replicate 0 is the candidate itself (results/train/).
rule train_replicate:
    wildcard_constraints:
        policy="|".join(TRAINED) or "(?!)",
        replicate=r"[1-9]\d*",
    input:
        unpack(train_inputs),
    output:
        directory("results/seeds/train/{arm}/{policy}/{replicate}"),
    params:
        cfg=policy_params,
        index=train_index_arg,
    priority: train_priority
    threads: 1
    log:
        "logs/seeds/train/{arm}/{policy}/{replicate}.log",
    shell:
        "OMP_NUM_THREADS={threads} {PY} -m r2s_eval.stages.train --cfg {params.cfg:q}"
        " --dataset {input.dataset} {params.index} --out {output} --threads {threads} --log {log}"
