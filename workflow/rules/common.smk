# Compose the Hydra configuration once and expose per-rule slices as plain JSON params.
import json
import logging
import re
import sys
from pathlib import Path

# lerobot logs while it is imported, which installs a root handler that would print each of
# Snakemake's messages twice; the root keeps the handlers it had.
_ROOT_HANDLERS = list(logging.getLogger().handlers)
from r2s_eval.calib.camera_plan import camera_plan
from r2s_eval.compare.resolution import sweep_levels
from r2s_eval.config import compose_config, missing_inputs, select, stop_before_running, to_json
from r2s_eval.errors import R2SError
from r2s_eval.policy_sources import (
    check_checkpoint,
    check_server,
    checkpoint_hash,
    for_arm,
    is_external,
    is_snapshot,
    is_variant,
    result_identity,
    validate_snapshot_cfg,
    validate_source_cfg,
    validate_variant_cfg,
)
from r2s_eval.policies.checkpoint_files import snapshot_folder
from r2s_eval.judge.base import stage_defaults, transport_keys
from r2s_eval.libero import ACTION_DIM as LIBERO_ACTION_DIM
from r2s_eval.sim.robot import world_robot
from r2s_eval.stages._reads import declaration as stage_declaration

logging.getLogger().handlers[:] = _ROOT_HANDLERS

CONF_DIR = Path(workflow.basedir) / "conf"


def judge_option(judge, key):
    """A judge's stage option (mode, concurrency, ...): its entry's, else conf/judge_options.yaml's."""
    return CFG["judges"][judge].get(key, stage_defaults()[key])
EXPERIMENT = config.get("experiment", "demo")
_overrides = config.get("overrides", [])
OVERRIDES = [_overrides] if isinstance(_overrides, str) else list(_overrides)


# A fault of the user's (a config problem, a missing input) ends the plan before any job, printed
# as its message alone: one line per problem, no traceback (as the world check prints it).
try:
    CFG = compose_config(CONF_DIR, experiment=EXPERIMENT, overrides=OVERRIDES)
    missing_inputs(CFG)  # a lab's dataset or trials CSV that is not there
except R2SError as err:
    stop_before_running(err)


class _ResumingWorkflow(type(workflow)):
    """A killed run resumes with the plain command: a job cut off before Snakemake recorded its
    end is redone (outputs deleted first), as `--rerun-incomplete` asks (workflow/profiles/default
    says so; resources.smk applies it). Our stages publish by rename, so such outputs can look
    whole; they are never trusted. Snakemake hands the DAG settings over right after reading the
    Snakefile, so the switch is set at that moment."""

    @property
    def dag_settings(self):
        return self.__dict__.get("_resuming_dag_settings")

    @dag_settings.setter
    def dag_settings(self, settings):
        if settings is not None:
            settings.force_incomplete = True
        self.__dict__["_resuming_dag_settings"] = settings


# The setting: LIBERO experiments compose conf/libero (workflow/rules/libero.smk); the others
# are real-to-sim.
LIBERO = CFG.get("libero") is not None
POLICIES = sorted(CFG["policies"])
# A variant runs another candidate's weights with an execution change (planted quality): never trained.
VARIANT_CFG = {p: validate_variant_cfg(CFG["policies"][p], p) for p in POLICIES if is_variant(CFG["policies"][p])}
VARIANTS = {p: cfg["of"] for p, cfg in VARIANT_CFG.items()}
# The judges' resolution sweep (conf/resolution, workflow/rules/resolution.smk): each level a
# variant of resolution.policy, rolled out like the line-up's variants but never ranked with them.
SWEEP = [] if LIBERO else sweep_levels(CFG["resolution"])
SWEEP_CFG = {lv.policy: validate_variant_cfg(lv.variant(CFG["resolution"]["policy"]), lv.policy) for lv in SWEEP}
# Every variant's entry, the line-up's and the sweep's, and the candidate whose weights it runs.
EXECUTIONS = {**VARIANT_CFG, **SWEEP_CFG}
BASE_OF = {p: cfg["of"] for p, cfg in EXECUTIONS.items()}
# A snapshot runs the weights a training here saved on the way ({name: (its training, step)}).
SNAPSHOTS = {p: (cfg["of"], cfg["step"]) for p in POLICIES
             if is_snapshot(CFG["policies"][p]) for cfg in [validate_snapshot_cfg(CFG["policies"][p], p)]}
# Candidates trained here; checkpoint and server candidates skip training.
TRAINED = [p for p in POLICIES if not is_external(CFG["policies"][p]) and p not in VARIANTS and p not in SNAPSHOTS]
EXTERNAL = {p: validate_source_cfg(CFG["policies"][p], p) for p in POLICIES if is_external(CFG["policies"][p])}


def weights_of(policy):
    """The candidate whose training or source holds the weights `policy` runs: its own, a
    variant's base's, a snapshot's training's."""
    policy = BASE_OF.get(policy, policy)
    return SNAPSHOTS[policy][0] if policy in SNAPSHOTS else policy


# Candidates whose weights are trained here, a variant's or a snapshot's included: each crosses into
# the other world (fidelity.smk's cross_rollout; the stability report's truth of the networks ranked).
CROSSED = [p for p in POLICIES if weights_of(p) in TRAINED]


def weights_dir(policy, arm):
    """The checkpoint folder `policy` runs on `arm` when its weights are trained here: the
    training's folder, or the snapshot's in it."""
    policy = BASE_OF.get(policy, policy)
    if policy in SNAPSHOTS:
        return str(snapshot_folder(f"results/train/{arm}/{SNAPSHOTS[policy][0]}", SNAPSHOTS[policy][1]))
    return f"results/train/{arm}/{policy}"


def snapshot_steps_of(policy):
    """The steps of `policy`'s training that the line-up's snapshots run."""
    return sorted(step for of, step in SNAPSHOTS.values() if of == policy)
ARMS = ["sim"] if LIBERO else ["real", "sim"]


def workflow_made(path):
    """A checkpoint this workflow builds (under results/): checked when it is loaded, and its
    rule's outputs, not its bytes at planning time, decide what reruns."""
    return Path(str(path)).parts[:1] == ("results",)


# A wrong folder, or a candidate that reads what the world does not record, fails now, before any
# rollout (LIBERO's cameras and state are checked by its own stage).
_WORLD = None if LIBERO else (CFG["world"]["cameras"], world_robot(CFG["world"]).action_dim)
for _name, _source in EXTERNAL.items():
    for _arm in ARMS:
        _entry = for_arm(_source, _arm)
        try:
            if _source["type"] == "checkpoint" and not workflow_made(_entry["path"]):
                check_checkpoint(_entry, _name, LIBERO_ACTION_DIM if LIBERO else _WORLD[1],
                                 *(_WORLD or (None, None)))
            elif _source["type"] == "server" and _WORLD:
                check_server(_entry, _name, _WORLD[1], *_WORLD)
        except R2SError as err:
            stop_before_running(err)
JUDGES = sorted(CFG["judges"])
# What ingest matches a dataset's task strings against: the instructions of the tasks evaluated.
INSTRUCTIONS = {key: CFG["world"]["tasks"][key]["instruction"] for key in CFG["tasks"]}
TWIN = not LIBERO and CFG["real"]["source"] == "twin"
PY = sys.executable
# Scheduling: ingest -> init_offsets -> init_estimate -> replay ahead of trains (train.smk ranks those).
SIM_CHAIN_PRIORITY = 1_000_000
ASSETS = str(Path(workflow.basedir) / "assets")


wildcard_constraints:
    policy="|".join(re.escape(p) for p in [*POLICIES, *SWEEP_CFG]),
    judge="|".join(JUDGES),
    arm="real|sim",


def stage_cfg(stage, **provided):
    """The --cfg of a stage: the config paths it declares in READS, plus the values the rule
    provides (its PROVIDED keys)."""
    declared = stage_declaration(stage)
    undeclared = set(provided) - set(declared["PROVIDED"])
    if undeclared:
        raise ValueError(f"stage {stage}: {sorted(undeclared)} are not in its PROVIDED declaration")
    return {**select(CFG, *declared["READS"]), **provided}


def stage_params(stage, **provided):
    """`stage_cfg` as one sorted JSON string, which Snakemake compares on rerun."""
    return to_json(stage_cfg(stage, **provided))


def policy_params(wildcards):
    replicate = int(getattr(wildcards, "replicate", 0))
    # How many seeds are trained changes no single training.
    policy = {k: v for k, v in CFG["policies"][wildcards.policy].items() if k != "seeds"}
    provided = {"replicate": replicate} if replicate else {}
    if not replicate and snapshot_steps_of(wildcards.policy):  # a further seed runs no snapshot
        provided["snapshot_steps"] = snapshot_steps_of(wildcards.policy)
    return stage_params("train", policy=policy, name=wildcards.policy, **provided)


def seeds_of(policy):
    """How many trainings per arm `policy` gets (its `seeds`; 1 unless set)."""
    return int(CFG["policies"][policy].get("seeds", 1))


class Untracked:
    """A rule param handed to the job but left out of Snakemake's rerun comparison (it compares
    plain values only): where a checkpoint or server lies changes no result."""

    def __init__(self, value):
        self.value = value

    def __str__(self):
        return to_json(self.value)


CHECKPOINT_HASH_MEMO = "results/.cache/checkpoint_hashes.json"


def candidate_identity(policy, arm):
    """What decides a candidate's rollouts: its type, or a checkpoint's content, or a server's
    config without its address; a variant's: its base's and its execution change."""
    if policy in BASE_OF:
        return {"type": "variant", "of": BASE_OF[policy], "weights": candidate_identity(BASE_OF[policy], arm),
                "execution": EXECUTIONS[policy]["execution"]}
    if policy in SNAPSHOTS:
        of, step = SNAPSHOTS[policy]
        return {"type": "snapshot", "of": of, "step": step, "weights": candidate_identity(of, arm)}
    if policy in TRAINED:
        return {"type": CFG["policies"][policy]["type"]}
    source = for_arm(EXTERNAL[policy], arm)
    identity = result_identity(source)
    if source["type"] == "checkpoint" and not workflow_made(source["path"]):
        identity["content_sha256"] = checkpoint_hash(source["path"], CHECKPOINT_HASH_MEMO)
    return identity


def candidate_transport(policy, arm):
    policy = weights_of(policy)
    if policy in TRAINED:
        return Untracked({})
    source = for_arm(EXTERNAL[policy], arm)
    return Untracked({k: v for k, v in source.items() if k not in result_identity(source)})


def rollout_transport(wildcards):
    return candidate_transport(wildcards.policy, wildcards.arm)


REAL_DATASET = "results/real/dataset" if TWIN else CFG["real"]["dataset_root"]

# Threads, memory, run time and GPUs of every job (workflow/profiles/default and the config);
# it also switches the resuming workflow above on, as that profile's rerun-incomplete asks.
include: "resources.smk"


onsuccess:
    ranking = Path("reports/ranking.txt")
    if ranking.exists():
        print(ranking.read_text())
