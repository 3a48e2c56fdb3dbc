"""Pieces shared by the offline heuristic judges (`kinematic`, `video`): config merging, evidence
rounding, reference-ratio scores, the four-criterion description and the rule between failures."""

from __future__ import annotations

import copy
import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from r2s_eval.errors import ConfigError
from r2s_eval.judge.base import CriterionNote, Description, Verdict, tie_break

# How a built-in judge compares two runs that both failed (its `failures` key): "tie", neither
# completed the task, so neither is preferred (the letter comes from tie_break, no position
# wins); "progress", the one that got further, as the success_first prompt asks of a VLM judge.
FAILURE_RULES = ("tie", "progress")


def merge_config(judge: str, defaults: dict[str, Any], cfg: Mapping[str, Any], nested: Iterable[str]) -> dict[str, Any]:
    """`defaults` updated by `cfg`; the `nested` dict keys are merged key by key. Unknown keys
    at either level are an error naming them."""
    unknown = set(cfg) - set(defaults)
    if unknown:
        raise ConfigError(f"{judge} judge: unknown config keys {sorted(unknown)}; known: {sorted(defaults)}")
    nested = set(nested)
    out = copy.deepcopy(defaults)
    for k, v in cfg.items():
        if k in nested:
            bad = set(v) - set(defaults[k])
            if bad:
                raise ConfigError(f"{judge} judge: unknown {k} keys {sorted(bad)}; known: {sorted(defaults[k])}")
            out[k].update(v)
        else:
            out[k] = v
    return out


def round_evidence(x: Any) -> Any:
    """Evidence as plain numbers rounded to 6 significant digits: readable and stable across platforms."""
    if isinstance(x, (float, np.floating)):
        return float(f"{float(x):.6g}")
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def fmt(x: float) -> str:
    return f"{x:.3g}"


def ratio_score(evidence: Mapping[str, Any], keys: Iterable[str], ref: Mapping[str, float]) -> float | None:
    """Geometric mean of 1 / (1 + x / ref) over `keys`: one bad number (a long stall, say) is not
    averaged away by two good ones. None when a number is absent."""
    vals = []
    for key in keys:
        x = evidence.get(key)
        if not isinstance(x, (int, float)) or isinstance(x, bool):
            return None
        vals.append(1.0 / (1.0 + max(float(x), 0.0) / float(ref[key])))
    return math.prod(vals) ** (1.0 / len(vals))


def description(texts: Mapping[str, str], evidence: Mapping[str, Mapping[str, Any]], label: str,
                summary: str, judge: str) -> Description:
    """The four criteria (texts and rounded evidence; the task label on task progress)."""
    criteria = {
        name: CriterionNote(text=texts[name], evidence={k: round_evidence(v) for k, v in evidence[name].items()},
                            label=label if name == "task_progress" else None)
        for name in ("motion_smoothness", "action_continuity", "task_progress", "force_control")
    }
    return Description(criteria=criteria, summary=summary, judge=judge)


def check_failure_rule(judge: str, rule: Any) -> None:
    if rule not in FAILURE_RULES:
        raise ConfigError(f"{judge} judge: failures must be one of {list(FAILURE_RULES)}, got {rule!r}")


def failures_tie(a: Description, b: Description, instruction: str) -> Verdict:
    """Two failures under the `tie` rule: tie_break's letter, with the reason in the rationale."""
    return Verdict(tie_break(a, b, instruction).letter,
                   f"neither successful (A {a.progress_label}, B {b.progress_label}): a tie, the letter from the description hashes")
