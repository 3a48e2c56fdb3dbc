"""Prompt templates (package data under ``prompts/``), rendering, and strict parsing of replies.

The templates take the task instruction and the recordings (or the two descriptions) and nothing
else: no policy, checkpoint, file name, outcome, duration, frame count or frame rate can reach a
prompt, because no template has a field for it and ``render`` refuses fields a template does not
name.

Prompt sets (the VLM judges' ``prompt_set`` key) pick the compare wording:

* ``balanced`` (default): the four criteria (motion smoothness, action continuity, task success,
  force/effort control) are weighed together, none before the others, as the method prescribes;
* ``success_first``: task success decides first, the other criteria break ties (an option, not
  the method).

The describe, system and re-ask prompts are shared. Every set's resolved texts are hashed into
the judge's cache identity (``templates_sha``), so answers of different sets, or of an edited
prompt, never mix.
"""

from __future__ import annotations

import hashlib
import re
import string
from functools import cache
from importlib import resources
from typing import Any

from r2s_eval.errors import ConfigError
from r2s_eval.judge.base import CRITERIA, CriterionNote, Description

TEMPLATES: tuple[str, ...] = ("system", "describe", "compare", "compare_videos", "reask")
DEFAULT_PROMPT_SET = "balanced"
# Template name -> file under prompts/, per prompt set (flat files: the package data is prompts/*.txt).
_SHARED = {"system": "system.txt", "describe": "describe.txt", "reask": "reask.txt"}
PROMPT_FILES: dict[str, dict[str, str]] = {
    s: {**_SHARED, "compare": f"compare.{s}.txt", "compare_videos": f"compare_videos.{s}.txt"}
    for s in ("balanced", "success_first")
}
PROMPT_SETS: tuple[str, ...] = tuple(PROMPT_FILES)

# Section headings as they appear in a description, in order; "task_progress" is asked for as
# "Task success" (the label is the explicit outcome).
HEADINGS: dict[str, str] = {
    "motion_smoothness": "Motion smoothness",
    "action_continuity": "Action continuity",
    "task_progress": "Task success",
    "force_control": "Force/effort control",
    "summary": "Summary",
}
_HEADING_PATTERNS: dict[str, str] = {
    "motion_smoothness": r"motion\s+smoothness",
    "action_continuity": r"action\s+continuity",
    "task_progress": r"task\s+(?:success|progress|completion)",
    "force_control": r"force\s*(?:/|and|&)\s*effort(?:\s+control)?|force\s+control|effort\s+control",
    "summary": r"(?:overall\s+)?summary",
}
# A heading starts a line, may be numbered or marked up (#, -, *, **bold**), and ends with a colon.
_HEADING_RE = re.compile(
    r"^[ \t>#*_\-\d.)]*(?:" + "|".join(f"(?P<{k}>{p})" for k, p in _HEADING_PATTERNS.items()) + r")"
    r"[ \t*_]*[:\uff1a][ \t*_]*",
    re.IGNORECASE | re.MULTILINE,
)
# First outcome word in the task section; "partially successful" is tried before "successful",
# and "unsuccessful" never matches "successful" (no word boundary inside it).
_LABEL_RE = re.compile(
    r"\b(partially\s+successful|partial\s+success|partially\s+succeeded|unsuccessful|successful|succeeded|"
    r"failed|failure)\b",
    re.IGNORECASE,
)
_LABELS = {
    "partially successful": "partially successful", "partial success": "partially successful",
    "partially succeeded": "partially successful", "successful": "successful", "succeeded": "successful",
    "unsuccessful": "failed", "failed": "failed", "failure": "failed",
}
_THINK_RE = re.compile(r"<think>.*?</think>", re.DOTALL | re.IGNORECASE)
# The whole reply must be one letter, optionally quoted, bracketed, bold, or after "Answer:".
_LETTER_RE = re.compile(
    r"[\s*_`\"'(\[]*(?:(?i:answer)\s*[:\uff1a]?[\s*_`\"'(\[]*)?([AB])[\s*_`\"')\].!]*"
)


def check_prompt_set(prompt_set: str) -> str:
    if prompt_set not in PROMPT_FILES:
        raise ConfigError(f"unknown prompt_set {prompt_set!r}; known: {list(PROMPT_SETS)}")
    return prompt_set


@cache
def _read(filename: str) -> str:
    return resources.files("r2s_eval.judge").joinpath("prompts", filename).read_text(encoding="utf-8")


def template(name: str, prompt_set: str = DEFAULT_PROMPT_SET) -> str:
    if name not in TEMPLATES:
        raise KeyError(f"unknown prompt template {name!r}; known: {TEMPLATES}")
    return _read(PROMPT_FILES[check_prompt_set(prompt_set)][name])


def templates_sha(prompt_set: str = DEFAULT_PROMPT_SET) -> str:
    """sha256 over the set's name and every template text it uses: part of every VLM cache key, so
    an edited prompt is asked anew and answers of different prompt sets never mix."""
    h = hashlib.sha256(b"prompt_set\0" + check_prompt_set(prompt_set).encode() + b"\0")
    for name in TEMPLATES:
        h.update(name.encode() + b"\0" + template(name, prompt_set).encode() + b"\0")
    return h.hexdigest()


def fields(name: str, prompt_set: str = DEFAULT_PROMPT_SET) -> set[str]:
    return {f for _, f, _, _ in string.Formatter().parse(template(name, prompt_set)) if f}


def render(name: str, *, prompt_set: str = DEFAULT_PROMPT_SET, **values: Any) -> str:
    """Fill template `name` of `prompt_set`; every field must be given and no other value is accepted."""
    need = fields(name, prompt_set)
    if set(values) != need:
        raise ValueError(f"prompt {name!r} takes fields {sorted(need)}, got {sorted(values)}")
    return template(name, prompt_set).format(**values).strip()


def split_on(text: str, *markers: str) -> list[str]:
    """Split rendered text around placeholder markers, each of which must occur exactly once."""
    for m in markers:
        if text.count(m) != 1:
            raise ValueError(f"marker {m!r} must occur exactly once in the prompt")
    parts = [text]
    for m in markers:
        out = []
        for p in parts:
            if p in markers or m not in p:
                out.append(p)
                continue
            before, after = p.split(m)
            out += [before, m, after]
        parts = out
    return [p for p in parts if p in markers or p.strip()]


def description_text(desc: Description) -> str:
    """The description as the compare prompt shows it: the five sections, nothing about its source."""
    lines = []
    for key in CRITERIA:
        note = desc.criteria.get(key)
        text = note.text.strip() if note is not None and note.text.strip() else "(not described)"
        if key == "task_progress" and note is not None and note.label and not text.lower().startswith(note.label):
            text = f"{note.label}. {text}"
        lines.append(f"{HEADINGS[key]}: {text}")
    lines.append(f"{HEADINGS['summary']}: {desc.summary.strip() or '(not described)'}")
    return "\n".join(lines)


def strip_thinking(text: str) -> str:
    return _THINK_RE.sub("", text or "").strip()


def parse_description(text: str, judge: str) -> Description:
    """Cut a free-text reply into the four criteria and the summary by their headings.

    Sections that are absent or empty, and a task section without an outcome label, end up in
    ``Description.missing``; the full reply is kept as ``raw_text``.
    """
    body = strip_thinking(text)
    hits = []
    for m in _HEADING_RE.finditer(body):
        key = next(k for k, v in m.groupdict().items() if v)
        hits.append((m.start(), m.end(), key))
    sections: dict[str, str] = {}
    for n, (_, end, key) in enumerate(hits):
        stop = hits[n + 1][0] if n + 1 < len(hits) else len(body)
        if key not in sections:  # the first heading of a kind wins
            sections[key] = body[end:stop].strip().strip("*_ ").strip()
    criteria = {}
    for key in CRITERIA:
        if key not in sections:
            continue
        label = None
        if key == "task_progress":
            m = _LABEL_RE.search(sections[key])
            label = _LABELS[re.sub(r"\s+", " ", m.group(1).lower())] if m else None
        criteria[key] = CriterionNote(text=sections[key], label=label)
    return Description(criteria=criteria, summary=sections.get("summary", ""), judge=judge, raw_text=text or "")


def parse_letter(text: str) -> str | None:
    """'A' or 'B' when the whole reply is that one letter (see ``_LETTER_RE``), else None."""
    m = _LETTER_RE.fullmatch(strip_thinking(text))
    return m.group(1) if m else None
