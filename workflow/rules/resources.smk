# Threads, memory, run time and GPUs of every job. The numbers live in profiles, never in rules:
# workflow/profiles/default is the base of every run, local or on a cluster, and a cluster
# profile (workflow/profiles/slurm, or a lab's own) or the command line changes what it names.
#
# Snakemake looks for a workflow profile in profiles/default beside the Snakefile only, and ours
# stays inside workflow/, so the workflow applies workflow/profiles/default itself, read with
# Snakemake's own profile parser: underneath whatever the command line and other profiles set,
# which win rule by rule and resource by resource (`--set-threads train=4` changes train's
# threads and nothing else). The jobs of a cluster run get the merged values on their command
# line, so they run with what was scheduled.
#
# GPUs follow the config, not a profile: a job asks for one exactly when its config puts a model
# on a CUDA device (`_gpu_jobs` below), and goes to the profile's `gpu_partition` if it names one;
# a profile may still set `gpu` or `slurm_partition` for a rule.
import yaml
from snakemake.cli import get_argument_parser, parse_set_resources
from snakemake.exceptions import WorkflowError
from snakemake.resources import Resources

DEFAULT_PROFILE = Path(workflow.basedir) / "workflow" / "profiles" / "default"
# What the workflow applies from the default profile; anything else there would silently do nothing.
APPLIED_PROFILE_KEYS = {"set-threads", "set-resources", "default-resources", "rerun-incomplete"}


def read_default_profile(folder):
    keys = set(yaml.safe_load((folder / "config.yaml").read_text()) or {})
    if keys - APPLIED_PROFILE_KEYS:
        raise WorkflowError(f"{folder / 'config.yaml'}: {sorted(keys - APPLIED_PROFILE_KEYS)} would not take effect; "
                            f"the workflow applies only {sorted(APPLIED_PROFILE_KEYS)} from it (put the rest in a --profile)")
    return get_argument_parser(profiles=[str(folder)]).parse_args([])


def _on_gpu(device):
    return str(device or "cpu").startswith("cuda")


def _gpu_jobs():
    """{rule: (wildcard names, [wildcard values of the jobs whose model runs on a GPU])}."""
    jobs = {
        "train": (("policy",), [(p,) for p in TRAINED if _on_gpu(CFG["policies"][p].get("device"))]),
        # In-process candidates run on rollout.device (a checkpoint entry's own device wins);
        # a policy server's model runs wherever the server does.
        "rollout": (("arm", "policy"), [
            (arm, p) for arm in ARMS for p in POLICIES  # a variant's model is its base's
            if weights_of(p) in TRAINED and _on_gpu(CFG["rollout"]["device"])
            or weights_of(p) in EXTERNAL and EXTERNAL[weights_of(p)]["type"] == "checkpoint"
            and _on_gpu(for_arm(EXTERNAL[weights_of(p)], arm).get("device") or CFG["rollout"]["device"])
        ]),
    }
    # The fidelity checks roll out trained candidates only (workflow/rules/fidelity.smk).
    trained_on_gpu = _on_gpu(CFG["rollout"]["device"])
    jobs["cross_rollout"] = (("arm", "policy"), [(arm, p) for arm in ARMS for p in TRAINED if trained_on_gpu])
    jobs["ablation_rollout"] = (("policy",), [(p,) for p in TRAINED if trained_on_gpu])
    jobs["seed_rollout"] = jobs["seed_cross_rollout"] = jobs["cross_rollout"]
    jobs["train_replicate"] = (("policy",), [(p,) for p in TRAINED if _on_gpu(CFG["policies"][p].get("device"))])
    # A LIBERO checkpoint candidate runs where rollout.device (or its own device) says.
    jobs["libero_rollout"] = (("policy",), [
        (p,) for p in POLICIES
        if LIBERO and p in EXTERNAL and EXTERNAL[p]["type"] == "checkpoint"
        and _on_gpu(for_arm(EXTERNAL[p], "sim").get("device") or CFG["rollout"]["device"])
    ])
    local_judges = [(j,) for j in JUDGES
                    if CFG["judges"][j].get("backend") == "transformers" and _on_gpu(CFG["judges"][j].get("device"))]
    jobs["describe"] = jobs["judge_pairs"] = (("judge",), local_judges)
    jobs["judge_adaptive"] = jobs["judge_adaptive_described"] = jobs["judge_pairs"]
    segmenter = CFG["calib"]["segmenter"]
    on_gpu = segmenter.get("type") == "grounded_sam" and _on_gpu(segmenter.get("device"))
    jobs["init_offsets"] = jobs["init_estimate"] = jobs["calib_silhouette"] = ((), [()] if on_gpu else [])
    return jobs


def _raw(resources, name):
    """A resource's value as written in a profile or on the command line (None if unset)."""
    resource = resources.get(name) if resources is not None else None
    return None if resource is None else resource.raw


def gpu_resources(settings):
    """`gpu` per rule, as resource expressions Snakemake evaluates per job (and hands on to the
    jobs of a cluster run): 1 for the jobs listed by `_gpu_jobs`, 0 for the rule's other jobs.
    Where the run names a `gpu_partition` (a cluster profile's default-resources), those jobs
    go there and the rule's other jobs to the default `slurm_partition`."""
    defaults = Resources.from_mapping(settings.default_resources or {})
    gpu_partition, partition = _raw(defaults, "gpu_partition"), _raw(defaults, "slurm_partition")
    entries = []
    for rule, (names, combos) in _gpu_jobs().items():
        if not combos:
            continue
        key = "(" + "".join(f"wildcards.{n}, " for n in names) + ")"
        on_gpu = f"{key} in {sorted(set(combos))!r}" if names else "True"
        entries.append(f"{rule}:gpu=int({on_gpu})")
        if gpu_partition is not None:
            entries.append(f"{rule}:slurm_partition=({str(gpu_partition)!r} if {on_gpu} else {partition!r})")
    return parse_set_resources(entries)


def _merge_resources(base, over):
    merged = {}
    for rule in set(base) | set(over):
        resources = Resources.from_mapping(base.get(rule, {})).copy()
        resources.update(over.get(rule, {}))
        merged[rule] = resources
    return merged


def _given(resources):
    """Default resources as written: parsing `--default-resources` (or a profile's) adds
    Snakemake's own guesses (memory and disk from the input size) for every name not given,
    which must not hide the default profile's values."""
    implied = Resources.default("full")
    return Resources({name: r for name, r in Resources.from_mapping(resources or {}).items()
                      if name not in implied or r.raw != implied[name].raw})


def apply_default_profile(settings, defaults, gpu):
    """The default profile and the GPU requests underneath what the run was given."""
    settings.overwrite_threads = {**defaults.set_threads, **settings.overwrite_threads}
    settings.overwrite_resources = _merge_resources(_merge_resources(defaults.set_resources, gpu),
                                                    settings.overwrite_resources)
    base = Resources.default("bare")
    base.update(_given(defaults.default_resources))
    base.update(_given(settings.default_resources))
    settings.default_resources = base
    for cached in ("_parsed_overwrite_threads", "_parsed_overwrite_resources", "_parsed_default_resources"):
        settings.__dict__.pop(cached, None)  # computed from the fields above on first use


DEFAULTS = read_default_profile(DEFAULT_PROFILE)
apply_default_profile(workflow.resource_settings, DEFAULTS, gpu_resources(workflow.resource_settings))
if DEFAULTS.rerun_incomplete:
    workflow.__class__ = _ResumingWorkflow
