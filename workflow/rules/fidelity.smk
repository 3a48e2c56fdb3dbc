# The same checkpoint in the other world, from the same initial configurations: pi^R (trained on
# the real data) in the calibrated sim, and with the twin pi^S on the real side. Splits the
# real-sim gap into its calibration and training parts (reports/fidelity_table.tex).
from r2s_eval.twin.perturb import NO_EFFECT

OTHER_ARM = {"sim": "real", "real": "sim"}
ABLATION = CFG["fidelity"]["ablation"]
# Further sims the crossing runs in (fidelity.sims), and the twin with each reality effect alone
# (fidelity.ablation.alone, measured against the twin with none).
SIMS = [] if LIBERO else CFG["fidelity"]["sims"]
ALONE = [NO_EFFECT, *ABLATION["alone"]] if ABLATION_POLICIES and ABLATION["alone"] else []


def cross_rollout_params(wildcards):
    return rollout_cfg_json(wildcards.arm, wildcards.policy, trained_on=OTHER_ARM[wildcards.arm])


def twin_ablation_params(wildcards):
    return stage_params("twin_ablation", family=wildcards.family)


def ablation_rollout_params(wildcards):
    return rollout_cfg_json("real", wildcards.policy, trained_on="sim")


def sim_variant_params(wildcards):
    return stage_params("sim_variant", sim=wildcards.sim)


def twin_alone_params(wildcards):
    return stage_params("twin_alone", effect=wildcards.effect)


def sim_variant_rollout_params(wildcards):
    # pi^S's rollouts carry no trained_on, as in the calibrated sim (rule rollout).
    trained_on = None if wildcards.trained_on == "sim" else wildcards.trained_on
    return rollout_cfg_json("sim", wildcards.policy, trained_on=trained_on)


def seed_rollout_params(wildcards):
    return rollout_cfg_json(wildcards.arm, wildcards.policy)


# A variant or a snapshot (common.smk's CROSSED) runs its training's other checkpoint, the variant
# with its execution change.
rule cross_rollout:
    wildcard_constraints:
        policy="|".join(CROSSED) or "(?!)",
    input:
        inits="results/rollout/inits.parquet",
        world=lambda w: WORLD_PARAMS[w.arm],
        policy=lambda w: f"results/train/{OTHER_ARM[w.arm]}/{weights_of(w.policy)}",
    output:
        directory("results/cross/{arm}/{policy}"),
    params:
        cfg=cross_rollout_params,
        weights=lambda w: weights_dir(w.policy, OTHER_ARM[w.arm]),
        batch_episodes=Untracked(CFG["rollout"]["batch_episodes"]),
    threads: 1
    log:
        "logs/cross/{arm}/{policy}.log",
    shell:
        "LP_NUM_THREADS=0 {PY} -m r2s_eval.stages.rollout --cfg {params.cfg:q} --policy {params.weights}"
        " --inits {input.inits} --world-params {input.world} --batch-episodes {params.batch_episodes}"
        " --threads {threads} --out {output} --log {log}"


if TWIN:

    # The twin with one perturbation family taken away (its parameters set to the calibrated sim's).
    rule twin_ablation:
        input:
            twin="results/real/twin_params.json",
            sim="results/calib/world_params.json",
        output:
            "results/fidelity/twins/{family}.json",
        params:
            cfg=twin_ablation_params,
        log:
            "logs/fidelity/twins/{family}.log",
        shell:
            "{PY} -m r2s_eval.stages.twin_ablation --cfg {params.cfg:q} --twin {input.twin} --sim {input.sim}"
            " --out {output} --log {log}"

    # The twin with one reality effect alone (none: with none of them).
    rule twin_alone:
        wildcard_constraints:
            effect="|".join(ALONE) or "(?!)",
        input:
            "results/real/twin_params.json",
        output:
            "results/fidelity/twins_alone/{effect}.json",
        params:
            cfg=twin_alone_params,
        log:
            "logs/fidelity/twins_alone/{effect}.log",
        shell:
            "{PY} -m r2s_eval.stages.twin_alone --cfg {params.cfg:q} --twin {input} --out {output} --log {log}"

    rule alone_rollout:
        wildcard_constraints:
            policy="|".join(TRAINED) or "(?!)",
            effect="|".join(ALONE) or "(?!)",
        input:
            inits="results/rollout/inits.parquet",
            world="results/fidelity/twins_alone/{effect}.json",
            policy="results/train/sim/{policy}",
        output:
            directory("results/fidelity/alone/{effect}/{policy}"),
        params:
            cfg=ablation_rollout_params,
            batch_episodes=Untracked(CFG["rollout"]["batch_episodes"]),
        threads: 1
        log:
            "logs/fidelity/alone/{effect}/{policy}.log",
        shell:
            "LP_NUM_THREADS=0 {PY} -m r2s_eval.stages.rollout --cfg {params.cfg:q} --policy {input.policy}"
            " --inits {input.inits} --world-params {input.world} --batch-episodes {params.batch_episodes}"
            " --threads {threads} --out {output} --log {log}"

    rule ablation_rollout:
        wildcard_constraints:
            policy="|".join(TRAINED) or "(?!)",
            family="|".join(ABLATION["families"]),
        input:
            inits="results/rollout/inits.parquet",
            world="results/fidelity/twins/{family}.json",
            policy="results/train/sim/{policy}",
        output:
            directory("results/fidelity/ablation/{family}/{policy}"),
        params:
            cfg=ablation_rollout_params,
            batch_episodes=Untracked(CFG["rollout"]["batch_episodes"]),
        threads: 1
        log:
            "logs/fidelity/ablation/{family}/{policy}.log",
        shell:
            "LP_NUM_THREADS=0 {PY} -m r2s_eval.stages.rollout --cfg {params.cfg:q} --policy {input.policy}"
            " --inits {input.inits} --world-params {input.world} --batch-episodes {params.batch_episodes}"
            " --threads {threads} --out {output} --log {log}"


rule sim_variant:
    wildcard_constraints:
        sim="|".join(SIMS) or "(?!)",
    input:
        "results/calib/world_params.json",
    output:
        "results/fidelity/sims/{sim}.json",
    params:
        cfg=sim_variant_params,
    log:
        "logs/fidelity/sims/{sim}.log",
    shell:
        "{PY} -m r2s_eval.stages.sim_variant --cfg {params.cfg:q} --calibrated {input} --out {output} --log {log}"


# Each checkpoint trained here (on the real data, on the sim's: trained_on) in a further sim.
rule sim_variant_rollout:
    wildcard_constraints:
        sim="|".join(SIMS) or "(?!)",
        policy="|".join(TRAINED) or "(?!)",
        trained_on="real|sim",
    input:
        inits="results/rollout/inits.parquet",
        world="results/fidelity/sims/{sim}.json",
        policy="results/train/{trained_on}/{policy}",
    output:
        directory("results/fidelity/in_sims/{sim}/{trained_on}/{policy}"),
    params:
        cfg=sim_variant_rollout_params,
        batch_episodes=Untracked(CFG["rollout"]["batch_episodes"]),
    threads: 1
    log:
        "logs/fidelity/in_sims/{sim}/{trained_on}/{policy}.log",
    shell:
        "LP_NUM_THREADS=0 {PY} -m r2s_eval.stages.rollout --cfg {params.cfg:q} --policy {input.policy}"
        " --inits {input.inits} --world-params {input.world} --batch-episodes {params.batch_episodes}"
        " --threads {threads} --out {output} --log {log}"


# Further training seeds (policies.<name>.seeds): each rolled out in its own world (pi^R on the
# real side, where it can be rerun: the twin; pi^S in the sim), for the spread over trainings.
# With the twin each also crosses into the other world (pi^R in the calibrated sim, pi^S on the
# twin), so that the crossing's parts average over every training of a recipe, not one.
SEED_ARMS = {"real": "R_real", "sim": "S_sim"} if TWIN else {"sim": "S_sim"}
SEED_CROSS_ARMS = {"sim": "R_sim", "real": "S_real"} if TWIN else {}
SEED_ROLLOUTS = [f"results/seeds/rollout/{arm}/{p}/{k}" for p in TRAINED for k in range(1, seeds_of(p))
                 for arm in SEED_ARMS]
SEED_CROSS_ROLLOUTS = [f"results/seeds/cross/{arm}/{p}/{k}" for p in TRAINED for k in range(1, seeds_of(p))
                       for arm in SEED_CROSS_ARMS]


rule seed_rollout:
    wildcard_constraints:
        policy="|".join(TRAINED) or "(?!)",
        replicate=r"[1-9]\d*",
    input:
        inits="results/rollout/inits.parquet",
        world=lambda w: WORLD_PARAMS[w.arm],
        policy="results/seeds/train/{arm}/{policy}/{replicate}",
    output:
        directory("results/seeds/rollout/{arm}/{policy}/{replicate}"),
    params:
        cfg=seed_rollout_params,
        batch_episodes=Untracked(CFG["rollout"]["batch_episodes"]),
    threads: 1
    log:
        "logs/seeds/rollout/{arm}/{policy}/{replicate}.log",
    shell:
        "LP_NUM_THREADS=0 {PY} -m r2s_eval.stages.rollout --cfg {params.cfg:q} --policy {input.policy}"
        " --inits {input.inits} --world-params {input.world} --batch-episodes {params.batch_episodes}"
        " --threads {threads} --out {output} --log {log}"


rule seed_cross_rollout:
    wildcard_constraints:
        policy="|".join(TRAINED) or "(?!)",
        replicate=r"[1-9]\d*",
        arm="|".join(SEED_CROSS_ARMS) or "(?!)",
    input:
        inits="results/rollout/inits.parquet",
        world=lambda w: WORLD_PARAMS[w.arm],
        policy=lambda w: f"results/seeds/train/{OTHER_ARM[w.arm]}/{w.policy}/{w.replicate}",
    output:
        directory("results/seeds/cross/{arm}/{policy}/{replicate}"),
    params:
        cfg=cross_rollout_params,
        batch_episodes=Untracked(CFG["rollout"]["batch_episodes"]),
    threads: 1
    log:
        "logs/seeds/cross/{arm}/{policy}/{replicate}.log",
    shell:
        "LP_NUM_THREADS=0 {PY} -m r2s_eval.stages.rollout --cfg {params.cfg:q} --policy {input.policy}"
        " --inits {input.inits} --world-params {input.world} --batch-episodes {params.batch_episodes}"
        " --threads {threads} --out {output} --log {log}"


def fidelity_inputs(wildcards):
    inputs = {
        "reference": "results/reference/success.parquet",
        "sim": expand("results/rollout/sim/{policy}", policy=TRAINED),
        "cross_sim": expand("results/cross/sim/{policy}", policy=TRAINED),
        "world": "results/calib/world_params.json",
        "seeds": SEED_ROLLOUTS + SEED_CROSS_ROLLOUTS,
        "sims": expand("results/fidelity/in_sims/{sim}/{trained_on}/{policy}", sim=SIMS, trained_on=["real", "sim"],
                       policy=TRAINED),
    }
    if TWIN:
        # pi^R's real-side episodes (the reference's own), for intervals paired over the shared inits
        inputs["real"] = expand("results/rollout/real/{policy}", policy=TRAINED)
        inputs["cross_real"] = expand("results/cross/real/{policy}", policy=TRAINED)
        inputs["twin"] = "results/real/twin_params.json"
        inputs["ablation"] = expand("results/fidelity/ablation/{family}/{policy}", family=ABLATION["families"],
                                    policy=ABLATION_POLICIES)
        inputs["alone"] = expand("results/fidelity/alone/{effect}/{policy}", effect=ALONE, policy=ABLATION_POLICIES)
    return inputs


def fidelity_args(wildcards, input):
    # results/seeds/rollout/<arm>/<policy>/<k> -> WORLD:k=FOLDER
    # results/seeds/cross/<arm>/<policy>/<k> likewise, the world being the cross's (R_sim, S_real)
    worlds = {"rollout": SEED_ARMS, "cross": SEED_CROSS_ARMS}
    args = [f"--seed-rollouts"] + [f"{worlds[Path(d).parts[-4]][Path(d).parts[-3]]}:{Path(d).name}={d}"
                                   for d in input.seeds]
    if not input.seeds:
        args = []
    if TWIN:
        args += ["--real", *input.real, "--cross-real", *input.cross_real, "--twin", input.twin]
        if ABLATION_POLICIES:
            args += ["--ablation", *[f"{Path(d).parent.name}={d}" for d in input.ablation]]
        if ALONE:
            args += ["--alone", *[f"{Path(d).parent.name}={d}" for d in input.alone]]
    if input.sims:  # results/fidelity/in_sims/<sim>/<trained_on>/<policy> -> SIM:TRAINED_ON=FOLDER
        args += ["--sims", *[f"{Path(d).parts[-3]}:{Path(d).parts[-2]}={d}" for d in input.sims]]
    return " ".join(args)


rule fidelity:
    input:
        unpack(fidelity_inputs),
    output:
        report="results/fidelity/report.json",
        table="reports/fidelity_table.tex",
        ablation=FIDELITY_ABLATION,
        more=FIDELITY_MORE_TABLES,
    params:
        cfg=stage_params("fidelity"),
        args=fidelity_args,
        ablation=("--ablation-table reports/fidelity_ablation_table.tex --pdf reports/fidelity_ablation.pdf"
                  " --png reports/fidelity_ablation.png") if FIDELITY_ABLATION else "",
        # reports/fidelity_sims_table.tex -> --sims-table reports/fidelity_sims_table.tex, alone likewise
        more=" ".join(f"--{Path(t).stem.removeprefix('fidelity_').replace('_', '-')} {t}" for t in FIDELITY_MORE_TABLES),
    log:
        "logs/fidelity.log",
    shell:
        "{PY} -m r2s_eval.stages.fidelity --cfg {params.cfg:q} --reference {input.reference} --sim {input.sim}"
        " --cross-sim {input.cross_sim} --world-params {input.world} {params.args} --out {output.report}"
        " --table {output.table} {params.ablation} {params.more} --log {log}"
