"""The one judge interface every backend implements, and the records it exchanges.

A judge works in two steps, the way a person would:

1. ``describe(rollout)``: watch one rollout and write a structured description along
   four criteria (motion smoothness, action continuity, task progress, force/effort control);
2. ``compare(a, b, instruction)``: read two descriptions and answer 'A' or 'B'.

``RolloutInput`` is everything a judge may see. It deliberately has no field for the policy,
checkpoint, episode outcome or anything else that would let a judge rank by identity instead
of behaviour; the stage drivers also hand it content-named copies of the files, so even file
and folder names carry no meaning.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from r2s_eval.errors import ConfigError, DataError
from r2s_eval.paths import CONF_DIR
from r2s_eval.utils.io import config_hash

CRITERIA: tuple[str, ...] = (
    "motion_smoothness",
    "action_continuity",
    "task_progress",
    "force_control",
)
PROGRESS_LABELS: tuple[str, ...] = ("successful", "partially successful", "failed")
INPUT_KINDS: tuple[str, ...] = ("video", "trajectory")


@dataclass(frozen=True)
class RolloutInput:
    """What a judge may see of one rollout: the recording and the task instruction, nothing else."""

    instruction: str
    video_path: Path | None = None
    trajectory_path: Path | None = None


@dataclass(frozen=True)
class CriterionNote:
    """One criterion of a description: a short text, the numbers behind it, and (task progress) a label."""

    text: str
    evidence: dict[str, Any] = field(default_factory=dict)
    label: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"text": self.text, "evidence": dict(self.evidence), "label": self.label}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> CriterionNote:
        return cls(text=str(d.get("text") or ""), evidence=dict(d.get("evidence") or {}), label=d.get("label"))


def _section_missing(name: str, note: CriterionNote | None) -> bool:
    if note is None or not note.text.strip():
        return True
    # Task progress without an explicit outcome label is incomplete: the ranking leans on it.
    return name == "task_progress" and note.label not in PROGRESS_LABELS


@dataclass(frozen=True)
class Description:
    """Structured four-criterion description of one rollout.

    ``missing`` is derived, never supplied: it lists the criteria (and ``summary``) that are absent
    or empty, so a backend that parses free text into this record gets the flag for free.
    """

    criteria: Mapping[str, CriterionNote]
    summary: str
    judge: str
    # The model's reply as written, kept when the sections were parsed out of free text.
    raw_text: str = ""
    missing: tuple[str, ...] = field(init=False)

    def __post_init__(self) -> None:
        unknown = set(self.criteria) - set(CRITERIA)
        if unknown:
            raise DataError(f"unknown description criteria {sorted(unknown)}; expected {list(CRITERIA)}")
        object.__setattr__(self, "criteria", {k: self.criteria[k] for k in CRITERIA if k in self.criteria})
        missing = [c for c in CRITERIA if _section_missing(c, self.criteria.get(c))]
        if not self.summary.strip():
            missing.append("summary")
        object.__setattr__(self, "missing", tuple(missing))

    @property
    def progress_label(self) -> str | None:
        note = self.criteria.get("task_progress")
        return note.label if note is not None and note.label in PROGRESS_LABELS else None

    def to_dict(self) -> dict[str, Any]:
        out = {
            "judge": self.judge,
            "summary": self.summary,
            "criteria": {k: v.to_dict() for k, v in self.criteria.items()},
            "missing": list(self.missing),
        }
        if self.raw_text:  # only when present, so structured descriptions keep their bytes
            out["raw_text"] = self.raw_text
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Description:
        crit = d.get("criteria") or {}
        return cls(
            criteria={k: CriterionNote.from_dict(v) for k, v in crit.items() if k in CRITERIA},
            summary=str(d.get("summary") or ""),
            judge=str(d.get("judge") or ""),
            raw_text=str(d.get("raw_text") or ""),
        )

    def to_json(self) -> str:
        """Canonical JSON (sorted keys, no NaN): equal descriptions give equal bytes."""
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"), allow_nan=False)

    @classmethod
    def from_json(cls, s: str) -> Description:
        return cls.from_dict(json.loads(s))

    def sha256(self) -> str:
        return hashlib.sha256(self.to_json().encode()).hexdigest()


@dataclass(frozen=True)
class Verdict:
    """A judge's answer to one A/B comparison."""

    letter: str
    rationale: str = ""

    def __post_init__(self) -> None:
        if self.letter not in ("A", "B"):
            raise DataError(f"verdict letter must be 'A' or 'B', got {self.letter!r}")

    def to_dict(self) -> dict[str, str]:
        return {"letter": self.letter, "rationale": self.rationale}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Verdict:
        return cls(letter=str(d["letter"]), rationale=str(d.get("rationale") or ""))


def tie_break(a: Description, b: Description, instruction: str) -> Verdict:
    """The built-in judges' answer when their scores tie: the smaller description hash, and for
    identical descriptions a letter from the hash's parity with the instruction (deterministic, and
    not always A, so a tie carries no position bias)."""
    ha, hb = a.sha256(), b.sha256()
    if ha != hb:
        return Verdict("A" if ha < hb else "B", "exact tie; broken by the smaller description hash")
    parity = int(hashlib.sha256((ha + "\n" + instruction).encode()).hexdigest(), 16) % 2
    return Verdict("A" if parity == 0 else "B", "identical descriptions; letter from a hash parity")


class InvalidAnswer(Exception):
    """The judge did not answer with a valid letter, even when asked once more.

    The stage driver records it (the pair is excluded and replaced) instead of failing the run.
    """

    def __init__(self, message: str, replies: Sequence[str] = ()):
        super().__init__(message)
        self.replies = list(replies)


# Options of the stage drivers, not of the judge: they decide which questions are asked and how
# fast, never how one is answered, so they stay out of the judge identity and its cache keys.
STAGE_OPTIONS: tuple[str, ...] = ("mode", "concurrency", "swap_share", "reserve")
# Their defaults live in conf/ only, beside the judge configs that may set them.
STAGE_DEFAULTS_FILE = CONF_DIR / "judge_options.yaml"


@functools.cache
def stage_defaults() -> dict[str, Any]:
    """The stage options a judge entry leaves out (conf/judge_options.yaml)."""
    import yaml

    with open(STAGE_DEFAULTS_FILE) as f:
        values = yaml.safe_load(f) or {}
    if sorted(values) != sorted(STAGE_OPTIONS):
        raise ConfigError(f"{STAGE_DEFAULTS_FILE} must set exactly {list(STAGE_OPTIONS)}, got {sorted(values)}")
    return values


MODES: tuple[str, ...] = ("two_step", "one_step")


def plain_config(cfg: Any) -> Any:
    """Turn a (possibly OmegaConf) config into plain JSON-able dicts/lists for hashing and storage."""
    if isinstance(cfg, Mapping):
        return {str(k): plain_config(v) for k, v in cfg.items()}
    if isinstance(cfg, (list, tuple)):
        return [plain_config(v) for v in cfg]
    if isinstance(cfg, float) and not math.isfinite(cfg):
        raise ConfigError(f"judge config values must be finite numbers, got {cfg}")
    return cfg


class Judge(ABC):
    """Base class of every judge backend.

    Subclasses set ``backend`` (the registry key), ``prompt_version`` (bump it whenever the
    prompt/template or the describing logic changes, so cached answers are not reused) and
    ``inputs`` (which recordings the judge reads: "video", "trajectory" or both; the cache key
    covers exactly these bytes and the other paths are withheld).

    The stage options (``STAGE_OPTIONS``: mode, concurrency, swap_share, reserve) are taken out of
    the config into ``stage_cfg`` before a backend sees it; those it leaves out come from
    :func:`stage_defaults`.
    """

    backend: ClassVar[str] = ""
    prompt_version: ClassVar[str] = "v1"
    # Bump it when only how two descriptions are compared changes: the compare cache keys change
    # and the descriptions (for the video judge, minutes of optical flow per policy) are kept.
    compare_version: ClassVar[str] = ""
    # Config keys that change only how two descriptions are compared: out of ``identity`` (the
    # descriptions are kept when they change), in ``compare_identity``.
    compare_keys: ClassVar[tuple[str, ...]] = ()
    inputs: ClassVar[tuple[str, ...]] = ("video",)

    def __init__(self, cfg: Mapping[str, Any] | None = None):
        self.cfg: dict[str, Any] = plain_config(cfg or {})
        defaults = stage_defaults()
        self.stage_cfg: dict[str, Any] = {k: self.cfg.pop(k, defaults[k]) for k in STAGE_OPTIONS}
        bad = set(self.inputs) - set(INPUT_KINDS)
        if not self.inputs or bad:
            raise ValueError(f"{type(self).__name__}.inputs must be a non-empty subset of {INPUT_KINDS}")
        sc = self.stage_cfg
        if sc["mode"] not in MODES:
            raise ConfigError(f"judge mode must be one of {MODES}, got {sc['mode']!r}")
        if not (isinstance(sc["concurrency"], int) and sc["concurrency"] >= 1):
            raise ConfigError(f"judge concurrency must be an integer >= 1, got {sc['concurrency']!r}")
        if not 0.0 <= float(sc["swap_share"]) <= 1.0:
            raise ConfigError(f"judge swap_share must be within [0, 1], got {sc['swap_share']!r}")
        if not (isinstance(sc["reserve"], int) and sc["reserve"] >= 0):
            raise ConfigError(f"judge reserve must be an integer >= 0, got {sc['reserve']!r}")

    @property
    def name(self) -> str:
        return str(self.cfg.get("name") or self.backend)

    def know_tasks(self, tasks: Mapping[str, Any]) -> None:
        """The world's tasks ({key: Task}), for a judge that reads more of a task than its
        instruction (the offline video judge); the others ignore them."""

    def know_robot(self, robot: Any) -> None:
        """The world's robot (``r2s_eval.sim.robot.Robot``), for a judge that reads the recorded
        joint values (the kinematic judge: their units); the others ignore it."""

    def identity(self) -> dict[str, str]:
        """Everything that changes a judge's answers; part of every cache key."""
        return {
            "name": self.name,
            "backend": self.backend,
            "config_hash": config_hash({k: v for k, v in self.cfg.items() if k not in self.compare_keys}),
            "prompt_version": self.prompt_version,
        }

    def compare_identity(self) -> dict[str, str]:
        """The identity behind every compare cache key: ``identity``, the compare version and the
        compare keys' values."""
        out = self.identity()
        if self.compare_version:
            out["compare_version"] = self.compare_version
        if self.compare_keys:
            out["compare_config_hash"] = config_hash({k: self.cfg.get(k) for k in self.compare_keys})
        return out

    @abstractmethod
    def describe(self, rollout: RolloutInput) -> Description:
        """Describe one rollout along the four criteria."""

    @abstractmethod
    def compare(self, a: Description, b: Description, instruction: str) -> Verdict:
        """Say which of two described rollouts better carries out `instruction`: 'A' or 'B'.

        Raise ``InvalidAnswer`` when no valid letter came back (after asking once more).
        """

    def compare_videos(self, a: RolloutInput, b: RolloutInput, instruction: str) -> Verdict:
        """One-step mode: watch both rollouts and answer 'A' or 'B' (as the human annotators do)."""
        raise NotImplementedError(f"judge backend {self.backend!r} has no one-step mode; use mode: two_step")

    def attach_cache(self, cache_dir: str | Path) -> None:
        """Called by the stage drivers with their cache folder; backends that send several
        requests per answer use it to keep each request, so a killed run never repeats one."""


_BACKENDS: dict[str, type[Judge]] = {}


def register_judge(backend: str) -> Callable[[type[Judge]], type[Judge]]:
    """Class decorator: make a Judge subclass available to ``make_judge`` under `backend`."""

    def deco(cls: type[Judge]) -> type[Judge]:
        if backend in _BACKENDS and _BACKENDS[backend] is not cls:
            raise ValueError(f"judge backend {backend!r} is already registered by {_BACKENDS[backend].__name__}")
        cls.backend = backend
        _BACKENDS[backend] = cls
        return cls

    return deco


def available_backends() -> list[str]:
    return sorted(_BACKENDS)


def make_judge(cfg: Mapping[str, Any]) -> Judge:
    """Build the judge named by ``cfg["backend"]``; the whole dict is its configuration."""
    backend = cfg.get("backend") if isinstance(cfg, Mapping) else None
    if not backend:
        raise ConfigError(f"judge config needs a 'backend' key (one of {available_backends()})")
    if backend not in _BACKENDS:
        raise ConfigError(f"unknown judge backend {backend!r}; available: {available_backends()}")
    return _BACKENDS[backend](cfg)


def transport_keys(cfg: Mapping[str, Any]) -> frozenset[str]:
    """Keys of a judge config that say where or how fast to ask, never what is answered (server
    address, timeouts, retries, parallel calls): a change to them must not rerun judging."""
    cls = _BACKENDS.get(str(cfg.get("backend")))
    own = getattr(cls, "TRANSPORT_KEYS", frozenset())
    return frozenset((set(own) - {"name"}) | {"concurrency"})
