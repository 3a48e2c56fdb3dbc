"""Where a candidate comes from: trained here, a checkpoint folder you have, or a policy server.

Trained candidates (`type: act | diffusion | pi0 | ...`) are configured in
`r2s_eval.policies.trained_config`. The two kinds here need no training:

    type: checkpoint        a local LeRobot `pretrained_model` folder
      path: ...             for both arms, or per arm under `arms: {real: {path}, sim: {path}}`
    type: server            an openpi-protocol policy server
      host, port            per arm overridable under `arms:` like `path`
      api_key_env           name of the environment variable holding the key (never the key)
      spec                  what a foreign server consumes and returns, when its metadata
                            does not say (ours does): cameras, action_dim, max_chunk, ...
      preset, keys          the server's own request keys, sizes and dtypes (openpi's example
                            clients: preset openpi_libero | openpi_droid; `keys` entries override
                            the preset's): r2s_eval.serving.keymap. None: our own key names

Both take `action_map` (robot index per policy action dimension; default: identity).

Two more kinds have no weights of their own:

    type: variant           another candidate's checkpoint run with an execution change
      of                    that candidate (trained here, a checkpoint, a server or a snapshot;
                            not a variant)
      execution             the change: r2s_eval.policies.execution (jitter, hesitation, a late
                            gripper, a low-pass); planted quality at equal weights
    type: snapshot          a candidate trained here, as its weights were after `step` of its
      of, step              optimisation steps (saved by that training: one run gives both)

This module sits above both `r2s_eval.policies` (the in-process models) and `r2s_eval.serving`
(the client of a policy server): it picks between them, and neither imports it.
"""

from __future__ import annotations

import copy
import json
import os
from collections.abc import Mapping

from r2s_eval.errors import PolicyConfigError
from r2s_eval.policies.checkpoint_files import checkpoint_hash, resolve_checkpoint
from r2s_eval.policies.execution import complete_execution
from r2s_eval.policies.interface import ActionMap, ChunkPolicy, PolicyError
from r2s_eval.policies.types.registry import read_policy_defaults
from r2s_eval.serving.keymap import resolve_key_map

__all__ = [
    "ARMS",
    "SOURCE_TYPES",
    "SNAPSHOT",
    "VARIANT",
    "action_map",
    "check_checkpoint",
    "check_server",
    "checkpoint_hash",
    "for_arm",
    "is_external",
    "is_snapshot",
    "is_variant",
    "open_policy",
    "result_identity",
    "unwrap_variant",
    "validate_candidate_cfg",
    "validate_snapshot_cfg",
    "validate_source_cfg",
    "validate_variant_cfg",
]

SOURCE_TYPES = ("checkpoint", "server")
ARMS = ("real", "sim")

# Keys each source type allows, with their values when an entry leaves them out.
_DEFAULTS = read_policy_defaults()
_COMMON = _DEFAULTS["every_source"]
_PER_TYPE = {kind: _DEFAULTS[kind] for kind in SOURCE_TYPES}
# Where a server runs and how patiently we talk to it change no result: not part of what
# makes a rollout rerun.
# A checkpoint's content (hashed) decides its results, not the folder it lies in.
TRANSPORT_KEYS = frozenset({"path", "host", "port", "api_key_env", "connect_timeout_s", "reply_timeout_s", "connect_retries", "device"})


VARIANT = "variant"
VARIANT_KEYS = ("type", "name", "of", "execution")
SNAPSHOT = "snapshot"
SNAPSHOT_KEYS = ("type", "name", "of", "step")


def is_external(cfg: Mapping) -> bool:
    return cfg.get("type") in SOURCE_TYPES


def is_variant(cfg: Mapping) -> bool:
    return cfg.get("type") == VARIANT


def is_snapshot(cfg: Mapping) -> bool:
    return cfg.get("type") == SNAPSHOT


def validate_variant_cfg(cfg: Mapping, name: str | None = None) -> dict:
    """Completed copy of a variant entry: `of` names a candidate, `execution` changes something.
    Whether `of` is in the line-up is the configuration check's (it sees every entry)."""
    who = f"policies.{name or cfg.get('name') or '?'}"
    unknown = sorted(set(cfg) - set(VARIANT_KEYS))
    if unknown:
        raise PolicyConfigError(f"{who} (variant): unknown key(s) {unknown}; allowed: {list(VARIANT_KEYS)}")
    if not isinstance(cfg.get("of"), str) or not cfg["of"]:
        raise PolicyConfigError(f"{who}.of: name the candidate whose checkpoint the variant runs, got {cfg.get('of')!r}")
    return {"type": VARIANT, "name": cfg.get("name"), "of": cfg["of"],
            "execution": complete_execution(cfg.get("execution"), who)}


def validate_snapshot_cfg(cfg: Mapping, name: str | None = None) -> dict:
    """Completed copy of a snapshot entry: `of` names a candidate, `step` a step of its training.
    That `of` is trained here and `step` falls inside its training is the configuration check's."""
    who = f"policies.{name or cfg.get('name') or '?'}"
    unknown = sorted(set(cfg) - set(SNAPSHOT_KEYS))
    if unknown:
        raise PolicyConfigError(f"{who} (snapshot): unknown key(s) {unknown}; allowed: {list(SNAPSHOT_KEYS)}")
    if not isinstance(cfg.get("of"), str) or not cfg["of"]:
        raise PolicyConfigError(f"{who}.of: name the candidate whose training the snapshot is taken from, "
                                f"got {cfg.get('of')!r}")
    step = cfg.get("step")
    if isinstance(step, bool) or not isinstance(step, int) or step < 1:
        raise PolicyConfigError(f"{who}.step: the optimisation step whose weights it runs, a whole number "
                                f">= 1, got {step!r}")
    return {"type": SNAPSHOT, "name": cfg.get("name"), "of": cfg["of"], "step": step}


def validate_candidate_cfg(cfg: Mapping, name: str) -> dict:
    """Completed copy of any candidate entry, by its kind: trained here, a checkpoint, a server, a
    variant or a snapshot (the one dispatch the config check and the line-up readers share)."""
    from r2s_eval.policies.trained_config import validate_policy_cfg

    if is_external(cfg):
        return validate_source_cfg(cfg, name)
    if is_variant(cfg):
        return validate_variant_cfg(cfg, name)
    if is_snapshot(cfg):
        return validate_snapshot_cfg(cfg, name)
    return validate_policy_cfg(dict(cfg, name=name))


def unwrap_variant(policy_cfg: Mapping) -> tuple[dict, dict | None]:
    """A rollout's policy config as (what opens the weights, the execution change or None): a
    variant's or a snapshot's rollout config holds its base's under `weights` (the workflow's
    candidate identity, ``{"type": "variant", "of": name, "weights": <the base's>, "execution":
    ...}``, ``{"type": "snapshot", "of": name, "step": n, "weights": <the training's>}``)."""
    execution = dict(policy_cfg["execution"]) if is_variant(policy_cfg) else None
    while is_variant(policy_cfg) or is_snapshot(policy_cfg):
        policy_cfg = policy_cfg["weights"]
    return dict(policy_cfg), execution


def validate_source_cfg(cfg: Mapping, name: str | None = None) -> dict:
    """Completed copy of a checkpoint/server entry; unknown keys are errors naming them."""
    who = f"policy {name or cfg.get('name') or '?'!r}"
    kind = cfg.get("type")
    if kind not in SOURCE_TYPES:
        raise PolicyConfigError(f"{who}: type must be one of {SOURCE_TYPES}, got {kind!r}")
    allowed = {**_COMMON, **_PER_TYPE[kind]}
    unknown = sorted(set(cfg) - set(allowed))
    if unknown:
        raise PolicyConfigError(f"{who} ({kind}): unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    out = {**copy.deepcopy(allowed), **copy.deepcopy(dict(cfg))}
    out["arms"] = dict(out["arms"] or {})
    for arm, over in out["arms"].items():
        if arm not in ARMS:
            raise PolicyConfigError(f"{who}: arms has {arm!r}; arms are {ARMS}")
        bad = sorted(set(over or {}) - (set(_PER_TYPE[kind]) | {"action_map"}))
        if bad:
            raise PolicyConfigError(f"{who}: arms.{arm} cannot set {bad}")
    for arm in ARMS:
        arm_cfg = for_arm(out, arm)
        if kind == "checkpoint" and not arm_cfg["path"]:
            raise PolicyConfigError(f"{who}: no checkpoint path for the {arm} arm (set path, or arms.{arm}.path)")
        if kind == "server" and arm_cfg["port"] is None:
            raise PolicyConfigError(f"{who}: no server port for the {arm} arm (set port, or arms.{arm}.port)")
        if kind == "server":
            _check_server_streams(arm_cfg, who)
    if out["action_map"] is not None:
        out["action_map"] = [int(i) for i in out["action_map"]]
    return out


SPEC_FIELDS = ("cameras", "action_dim", "max_chunk", "uses_state", "uses_task", "state_dim")
KEY_MAP_SPEC_FIELDS = ("cameras", "uses_state", "uses_task")  # a key map decides these


def _check_server_streams(cfg: Mapping, who: str) -> None:
    """A server entry's `spec`, `preset` and `keys` (for one arm): unknown spec fields, a key map
    that leaves a key unfilled, a spec field the key map decides."""
    spec = cfg.get("spec")
    if spec is not None and not isinstance(spec, Mapping):
        raise PolicyConfigError(f"{who}: 'spec' must be a mapping of {list(SPEC_FIELDS)}, got {spec!r}")
    unknown = sorted(set(spec or {}) - set(SPEC_FIELDS))
    if unknown:
        raise PolicyConfigError(f"{who}: 'spec' has unknown field(s) {unknown}; allowed: {list(SPEC_FIELDS)}")
    try:
        key_map = resolve_key_map(cfg.get("preset"), cfg.get("keys"), who)
    except PolicyError as exc:
        raise PolicyConfigError(str(exc)) from exc
    clash = [k for k in KEY_MAP_SPEC_FIELDS if (spec or {}).get(k) is not None]
    if key_map is not None and clash:
        raise PolicyConfigError(f"{who}: 'spec' sets {clash}, which its key map ('keys' / 'preset') decides; "
                                f"leave them out")


def for_arm(cfg: Mapping, arm: str) -> dict:
    """The entry with the arm's overrides applied (`arms` removed)."""
    merged = {k: v for k, v in cfg.items() if k != "arms"}
    merged.update((cfg.get("arms") or {}).get(arm) or {})
    return merged


def result_identity(cfg: Mapping) -> dict:
    """The part of an external entry that decides what its rollouts are (not where it runs)."""
    return {k: v for k, v in cfg.items() if k not in TRANSPORT_KEYS}


def action_map(cfg: Mapping, robot_dim: int) -> ActionMap:
    indices = cfg.get("action_map")
    return ActionMap(robot_dim, tuple(indices) if indices is not None else None)


def _action_map_problem(indices, action_dim: int, robot_action_dim: int, what: str) -> str | None:
    if indices is None and action_dim != robot_action_dim:
        return (f"{what} returns {action_dim}-D actions, the robot takes {robot_action_dim}-D; set action_map "
                f"(the robot index of each action dimension)")
    if indices is not None and (len(indices) != action_dim or len(set(indices)) != len(indices)
                                or min(indices) < 0 or max(indices) >= robot_action_dim):
        return f"action_map {list(indices)} must list {action_dim} distinct robot indices below {robot_action_dim} for {what}"
    return None


def _stream_problems(cameras_used, state_dim_used, cameras, state_dim: int | None) -> list[str]:
    """What a policy reads that the world does not record: cameras, or a state of another width."""
    out = []
    if cameras is not None:
        missing = sorted(set(cameras_used) - set(cameras))
        if missing:
            out.append(f"reads cameras {missing}, which world.cameras {list(cameras)} does not record")
    if state_dim is not None and state_dim_used is not None and int(state_dim_used) != state_dim:
        out.append(f"reads a {state_dim_used}-D state, the world's robot records {state_dim}-D (robot.features)")
    return out


def check_server(cfg: Mapping, name: str, robot_action_dim: int, cameras, state_dim: int) -> None:
    """A server entry (one arm's) against the world, before any episode: what its key map or its
    spec reads (cameras, state width) and the actions its spec returns. What the server itself
    announces is checked when it is reached."""
    who = f"policy {name!r}"
    spec = dict(cfg.get("spec") or {})
    key_map = resolve_key_map(cfg.get("preset"), cfg.get("keys"), who)
    if key_map is not None:
        key_map.check_streams(cameras, state_dim, who, offerer="world.cameras")
        action_dim = spec.get("action_dim", key_map.action_dim)
        problems = []
    else:
        used = [str(c).removeprefix("observation.images.") for c in spec.get("cameras") or ()]
        problems = _stream_problems(used, spec.get("state_dim"), cameras, state_dim)
        action_dim = spec.get("action_dim")
    if action_dim is not None:
        problem = _action_map_problem(cfg.get("action_map"), int(action_dim), robot_action_dim, "its spec")
        problems += [problem] if problem else []
    if problems:
        raise PolicyError(f"{who} (server {cfg.get('host')}:{cfg.get('port')}): " + "; ".join(problems))


def check_checkpoint(cfg: Mapping, name: str, robot_action_dim: int, cameras=None, state_dim: int | None = None) -> dict:
    """Read a checkpoint's config (no model load) and check it can drive the robot: its action
    width (or action_map), and with ``cameras`` / ``state_dim`` the world's, the cameras and the
    state width it reads.

    Runs when the workflow is planned, so a wrong folder fails before any rollout starts.
    """
    try:
        folder = resolve_checkpoint(cfg["path"])
    except PolicyError as exc:
        raise PolicyError(f"policy {name!r}: {exc}") from exc
    try:
        config = json.loads((folder / "config.json").read_text())
        action_dim = int(config["output_features"]["action"]["shape"][0])
        policy_type = str(config["type"])
    except (OSError, ValueError, KeyError, IndexError, TypeError) as exc:
        raise PolicyError(f"policy {name!r}: {folder}/config.json is not a LeRobot policy config ({exc!r})") from exc
    inputs = config.get("input_features") or {}
    used = [k.removeprefix("observation.images.") for k in inputs if k.startswith("observation.images.")]
    state_shape = (inputs.get("observation.state") or {}).get("shape") or [None]
    problems = _stream_problems(used, state_shape[0], cameras, state_dim)
    problem = _action_map_problem(cfg.get("action_map"), action_dim, robot_action_dim, f"checkpoint {folder}")
    if problem or problems:
        raise PolicyError(f"policy {name!r}: " + "; ".join([*([problem] if problem else []),
                                                          *(f"checkpoint {folder} {p}" for p in problems)]))
    return {"folder": str(folder), "type": policy_type, "action_dim": action_dim}


def open_policy(cfg: Mapping, name: str, trained_dir: str | os.PathLike | None = None, device: str = "cpu",
                call_batch: int | None = None) -> ChunkPolicy:
    """The candidate as a ChunkPolicy: a trained folder, a checkpoint, or a server connection.

    In-process models run on `device` (a checkpoint entry's own `device` wins), every call with
    `call_batch` rows (`LeRobotPolicy`; a server computes what it computes)."""
    from r2s_eval.policies.lerobot_policy import load_lerobot_policy

    if not is_external(cfg):
        if trained_dir is None:
            raise PolicyError(f"policy {name!r} is trained here, but no trained folder was given")
        return load_lerobot_policy(trained_dir, device=device, name=name, call_batch=call_batch)
    if cfg["type"] == "checkpoint":
        return load_lerobot_policy(cfg["path"], device=cfg.get("device") or device, name=name, call_batch=call_batch)
    from r2s_eval.serving.client import ServerPolicy

    spec = dict(cfg.get("spec") or {})
    return ServerPolicy(
        name, cfg["host"], int(cfg["port"]), api_key_env=cfg.get("api_key_env"),
        connect_timeout_s=float(cfg["connect_timeout_s"]), reply_timeout_s=float(cfg["reply_timeout_s"]),
        connect_retries=int(cfg["connect_retries"]), preset=cfg.get("preset"), keys=cfg.get("keys"), **spec,
    )
