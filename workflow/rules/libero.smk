# The method's LIBERO setting: LIBERO's own Python environment (made from pinned requirements,
# remade when deleted), each candidate's LIBERO rollouts into results/rollout/sim/{policy} (the
# folder the judges, pairs, fit and reports read in either setting), and the reference: LIBERO's
# own success rate over the same episodes.
import zlib

from r2s_eval.libero import ACTION_DIM as _LIBERO_ACTION_DIM, STATE_DIM as _LIBERO_STATE_DIM
from r2s_eval.libero import environment as libero_environment

LIBERO_ENV = libero_environment.env_dir(CFG["libero"]["env_dir"])
LIBERO_READY = str(LIBERO_ENV / libero_environment.READY)
LIBERO_PYTHON = str(libero_environment.python_of(LIBERO_ENV))
TINY_CAMERAS = ["observation.images.image", "observation.images.wrist_image"]


rule libero_env:
    output:
        LIBERO_READY,
    log:
        "logs/libero_env.log",
    shell:
        "{PY} -m r2s_eval.libero.environment --dir {LIBERO_ENV:q} > {log} 2>&1"


# Tiny randomly initialised VLA checkpoints for smoke runs (policies/libero_tiny.yaml points at them).
rule tiny_checkpoint:
    output:
        directory("results/libero/tiny/{name}"),
    wildcard_constraints:
        name="[^/]+",
    params:
        seed=lambda w: zlib.crc32(w.name.encode()) % 2**31,
    log:
        "logs/libero/tiny_checkpoint/{name}.log",
    shell:
        "{PY} -m r2s_eval.stages.tiny_checkpoint --cameras {TINY_CAMERAS} --state-dim {_LIBERO_STATE_DIM}"
        " --action-dim {_LIBERO_ACTION_DIM} --seed {params.seed} --chunk-size {CFG[rollout][horizon][chunk]}"
        " --out {output} --log {log}"


def libero_rollout_inputs(wildcards):
    # The environment must exist; remaking it (same pins) reruns no rollout.
    inputs = {"env": ancient(LIBERO_READY)}
    source = for_arm(EXTERNAL[wildcards.policy], "sim")
    if source["type"] == "checkpoint" and workflow_made(source["path"]):
        inputs["checkpoint"] = source["path"]
    return inputs


def libero_rollout_params(wildcards):
    return stage_params("libero_rollout", policy=wildcards.policy,
                        policy_cfg=candidate_identity(wildcards.policy, "sim"))


rule libero_rollout:
    input:
        unpack(libero_rollout_inputs),
    output:
        directory("results/rollout/sim/{policy}"),
    params:
        cfg=libero_rollout_params,
        transport=lambda w: candidate_transport(w.policy, "sim"),
    # LIBERO processes side by side (set-threads: libero_rollout); the model serves them on one thread.
    threads: 1
    log:
        "logs/rollout/sim/{policy}.log",
    shell:
        "{PY} -m r2s_eval.stages.libero_rollout --cfg {params.cfg:q} --python {LIBERO_PYTHON:q}"
        " --transport {params.transport:q} --threads {threads} --out {output} --log {log}"


rule reference:
    input:
        expand("results/rollout/sim/{policy}", policy=POLICIES),
    output:
        "results/reference/success.parquet",
    log:
        "logs/reference.log",
    shell:
        "{PY} -m r2s_eval.stages.reference --rollouts {input} --out {output} --log {log}"
