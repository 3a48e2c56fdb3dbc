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

import hashlib
import json
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

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
    missing: tuple[str, ...] = field(init=False)

    def __post_init__(self) -> None:
        unknown = set(self.criteria) - set(CRITERIA)
        if unknown:
            raise ValueError(f"unknown description criteria {sorted(unknown)}; expected {list(CRITERIA)}")
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
        return {
            "judge": self.judge,
            "summary": self.summary,
            "criteria": {k: v.to_dict() for k, v in self.criteria.items()},
            "missing": list(self.missing),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Description:
        crit = d.get("criteria") or {}
        return cls(
            criteria={k: CriterionNote.from_dict(v) for k, v in crit.items() if k in CRITERIA},
            summary=str(d.get("summary") or ""),
            judge=str(d.get("judge") or ""),
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
            raise ValueError(f"verdict letter must be 'A' or 'B', got {self.letter!r}")

    def to_dict(self) -> dict[str, str]:
        return {"letter": self.letter, "rationale": self.rationale}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Verdict:
        return cls(letter=str(d["letter"]), rationale=str(d.get("rationale") or ""))


def plain_config(cfg: Any) -> Any:
    """Turn a (possibly OmegaConf) config into plain JSON-able dicts/lists for hashing and storage."""
    if isinstance(cfg, Mapping):
        return {str(k): plain_config(v) for k, v in cfg.items()}
    if isinstance(cfg, (list, tuple)):
        return [plain_config(v) for v in cfg]
    if isinstance(cfg, float) and not math.isfinite(cfg):
        raise ValueError(f"judge config values must be finite numbers, got {cfg}")
    return cfg


class Judge(ABC):
    """Base class of every judge backend.

    Subclasses set ``backend`` (the registry key), ``prompt_version`` (bump it whenever the
    prompt/template or the describing logic changes, so cached answers are not reused) and
    ``inputs`` (which recordings the judge reads: "video", "trajectory" or both; the cache key
    covers exactly these bytes and the other paths are withheld).
    """

    backend: ClassVar[str] = ""
    prompt_version: ClassVar[str] = "v1"
    inputs: ClassVar[tuple[str, ...]] = ("video",)

    def __init__(self, cfg: Mapping[str, Any] | None = None):
        self.cfg: dict[str, Any] = plain_config(cfg or {})
        bad = set(self.inputs) - set(INPUT_KINDS)
        if not self.inputs or bad:
            raise ValueError(f"{type(self).__name__}.inputs must be a non-empty subset of {INPUT_KINDS}")

    @property
    def name(self) -> str:
        return str(self.cfg.get("name") or self.backend)

    def identity(self) -> dict[str, str]:
        """Everything that changes a judge's answers; part of every cache key."""
        return {
            "name": self.name,
            "backend": self.backend,
            "config_hash": config_hash(self.cfg),
            "prompt_version": self.prompt_version,
        }

    @abstractmethod
    def describe(self, rollout: RolloutInput) -> Description:
        """Describe one rollout along the four criteria."""

    @abstractmethod
    def compare(self, a: Description, b: Description, instruction: str) -> Verdict:
        """Say which of two described rollouts better carries out `instruction`: 'A' or 'B'."""


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
        raise ValueError(f"judge config needs a 'backend' key (one of {available_backends()})")
    if backend not in _BACKENDS:
        raise ValueError(f"unknown judge backend {backend!r}; available: {available_backends()}")
    return _BACKENDS[backend](cfg)
