# Closed-loop rollouts from the same seeded initial configurations for every policy:
# pi^S in the calibrated sim, pi^R on the real side (the twin) for the reference.
rule rollout_inits:
    output:
        "results/rollout/inits.parquet",
    params:
        cfg=stage_params("rollout_inits"),
    log:
        "logs/rollout_inits.log",
    shell:
        "{PY} -m r2s_eval.stages.rollout_inits --cfg {params.cfg:q} --out {output} --log {log}"


# Each arm's world: the calibrated sim's parameters (calib_joints), or the twin's.
WORLD_PARAMS = {"sim": "results/calib/world_params.json", "real": "results/real/twin_params.json"}


def rollout_inputs(wildcards):
    inputs = {"inits": "results/rollout/inits.parquet", "world": WORLD_PARAMS[wildcards.arm]}
    if weights_of(wildcards.policy) in TRAINED:  # a variant runs its base's weights, a snapshot its training's
        inputs["policy"] = f"results/train/{wildcards.arm}/{weights_of(wildcards.policy)}"
    return inputs


def rollout_trained_arg(wildcards, input):
    return f"--policy {weights_dir(wildcards.policy, wildcards.arm)}" if "policy" in input.keys() else ""


# How many episodes run side by side changes no result: passed apart from --cfg, so a change
# reruns nothing (nor does the job's thread count, set in the profile).
ROLLOUT_UNTRACKED = ("batch_episodes",)


def rollout_params(wildcards):
    return rollout_cfg_json(wildcards.arm, wildcards.policy)


def rollout_cfg_json(arm, policy, trained_on=None):
    """The rollout stage's --cfg for `policy` on `arm`; `trained_on`: the arm whose data trained
    the checkpoint, where it is the other one (fidelity.smk's cross-evaluations)."""
    provided = {} if trained_on is None else {"trained_on": trained_on}
    if policy in SWEEP_CFG and CFG["resolution"]["tasks"] is not None:  # the sweep's levels run on its tasks
        provided["tasks"] = CFG["resolution"]["tasks"]
    cfg = stage_cfg("rollout", arm=arm, policy=policy, policy_cfg=candidate_identity(policy, arm), **provided)
    # real_inits_per_task and real_video_size are read by the real arm only, video_size by the
    # sim arm only: a change must not rerun the other arm's rollouts.
    by_arm = {"sim": ("real_inits_per_task", "real_video_size"), "real": ("video_size",)}
    untracked = ROLLOUT_UNTRACKED + by_arm[arm]
    cfg["rollout"] = {k: v for k, v in cfg["rollout"].items() if k not in untracked}
    return to_json(cfg)


rule rollout:
    input:
        unpack(rollout_inputs),
    priority: lambda w: 1 if w.arm == "sim" else 0
    output:
        directory("results/rollout/{arm}/{policy}"),
    params:
        cfg=rollout_params,
        trained=rollout_trained_arg,
        transport=rollout_transport,
        batch_episodes=Untracked(CFG["rollout"]["batch_episodes"]),
    # Model calls on one thread (the stage pins torch's); physics, rendering (llvmpipe
    # rasterises in the thread that renders: LP_NUM_THREADS=0) and video on `threads` workers.
    threads: 1
    log:
        "logs/rollout/{arm}/{policy}.log",
    shell:
        "LP_NUM_THREADS=0 {PY} -m r2s_eval.stages.rollout --cfg {params.cfg:q}"
        " {params.trained} --inits {input.inits} --world-params {input.world} --transport {params.transport:q}"
        " --batch-episodes {params.batch_episodes} --threads {threads} --out {output} --log {log}"


if TWIN:

    rule reference:
        input:
            expand("results/rollout/real/{policy}", policy=POLICIES),
        output:
            "results/reference/success.parquet",
        log:
            "logs/reference.log",
        shell:
            "{PY} -m r2s_eval.stages.reference --rollouts {input} --out {output} --log {log}"

else:

    rule reference:
        input:
            CFG["real"]["reference_csv"],
        output:
            "results/reference/success.parquet",
        log:
            "logs/reference.log",
        shell:
            "{PY} -m r2s_eval.stages.reference --csv {input} --out {output} --log {log}"
