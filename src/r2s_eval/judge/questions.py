"""What the stage drivers ask the judge: each question's cache key inputs and the call answering it.

Cache keys are sha256 digests (``cache.cache_key``) of everything that determines the answer:

* a description: the sha256 of each recording the judge reads, the instruction and the judge
  identity (backend, model/config hash, prompt templates and version);
* a comparison of descriptions (mode ``two_step``): description A sha, description B sha, in that
  order, the instruction and the judge identity;
* a comparison of videos (mode ``one_step``): video A sha, video B sha, the instruction and the
  judge identity.

The judge sees recordings only under content-hash names (``scratch.blind_copies``). An invalid
comparison answer (``InvalidAnswer``) is kept like any answer, with letter None and the replies,
so a rerun does not ask again.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd

from r2s_eval.errors import DataError
from r2s_eval.judge.base import Description, InvalidAnswer, Judge, RolloutInput, Verdict
from r2s_eval.judge.cache import cache_key
from r2s_eval.judge.cached_runner import Question, require_columns
from r2s_eval.judge.scratch import blind_copies
from r2s_eval.utils.io import file_sha256


def episode_files(eid: str, row: Any, kinds: tuple[str, ...], episodes_dir: Path, judge: Judge,
                  hashes: dict[Path, str]) -> dict[str, tuple[Path, str]]:
    """kind -> (recording file, its sha256) for each of `kinds`; `hashes` memoises the digests."""
    files: dict[str, tuple[Path, str]] = {}
    for kind in kinds:
        rel = getattr(row, f"{kind}_path")
        if rel is None or (isinstance(rel, float) and pd.isna(rel)) or str(rel) == "":
            raise DataError(f"episode {eid}: no {kind}_path, but judge {judge.name!r} reads the {kind}")
        src = episodes_dir / str(rel)
        if not src.is_file():
            raise FileNotFoundError(f"episode {eid}: {kind} file not found: {src}")
        if src not in hashes:
            hashes[src] = file_sha256(src)
        files[kind] = (src, hashes[src])
    return files


def describe_call(
    judge: Judge, files: dict[str, tuple[Path, str]], instruction: str, stage_root: Path
) -> Callable[[], dict[str, Any]]:
    def call() -> dict[str, Any]:
        with blind_copies(files, stage_root) as blind:
            rollout = RolloutInput(
                instruction=instruction,
                video_path=blind.get("video"),
                trajectory_path=blind.get("trajectory"),
            )
            desc = judge.describe(rollout)
        if not isinstance(desc, Description):
            raise TypeError(f"describe returned {type(desc).__name__}, expected Description")
        return desc.to_dict()

    return call


def description_questions(descriptions_df: pd.DataFrame, judge: Judge, identity: dict[str, Any]) -> Question:
    """Comparisons of two descriptions (``describe_rollouts`` output) of the same instruction."""
    require_columns(descriptions_df, ("episode_id", "instruction", "description", "description_sha"),
                    "descriptions table")
    ids = descriptions_df["episode_id"].astype(str)
    if ids.duplicated().any():
        raise DataError("descriptions table has duplicate episode_id values")
    by_id = {
        e: {"instruction": str(i), "description": str(d), "description_sha": str(h)}
        for e, i, d, h in zip(ids, descriptions_df["instruction"], descriptions_df["description"],
                              descriptions_df["description_sha"])
    }

    def question(label: str, ea: str, eb: str):
        for e in (ea, eb):
            if e not in by_id:
                raise DataError(f"{label}: episode {e} has no description")
        da, db = by_id[ea], by_id[eb]
        if da["instruction"] != db["instruction"]:
            raise DataError(f"{label}: the two episodes have different instructions")
        instruction = da["instruction"]
        inputs = {"a": da["description_sha"], "b": db["description_sha"], "instruction": instruction, "judge": identity}
        return cache_key(inputs), inputs, _compare_call(judge, da["description"], db["description"], instruction)

    return question


def video_questions(episodes_df: pd.DataFrame, episodes_dir: Path, judge: Judge, identity: dict[str, Any],
                    stage_root: Path) -> Question:
    """Comparisons of two videos (paths relative to `episodes_dir`) of the same instruction."""
    require_columns(episodes_df, ("episode_id", "instruction", "video_path"), "episode table")
    by_id = {str(r.episode_id): r for r in episodes_df.itertuples(index=False)}
    hashes: dict[Path, str] = {}

    def question(label: str, ea: str, eb: str):
        files, instructions = {}, set()
        for side, e in (("a", ea), ("b", eb)):
            if e not in by_id:
                raise DataError(f"{label}: episode {e} is not in the episode table")
            files[side] = episode_files(e, by_id[e], ("video",), episodes_dir, judge, hashes)["video"]
            instructions.add(str(by_id[e].instruction))
        if len(instructions) != 1:
            raise DataError(f"{label}: the two episodes have different instructions")
        instruction = instructions.pop()
        inputs = {"a": files["a"][1], "b": files["b"][1], "instruction": instruction, "judge": identity}
        return cache_key(inputs), inputs, _compare_videos_call(judge, files, instruction, stage_root)

    return question


def _verdict_answer(fn: Callable[[], Verdict]) -> dict[str, Any]:
    try:
        verdict = fn()
    except InvalidAnswer as e:  # kept like any answer: a rerun does not ask again
        return {"letter": None, "rationale": "", "replies": e.replies}
    if not isinstance(verdict, Verdict):
        raise TypeError(f"compare returned {type(verdict).__name__}, expected Verdict")
    return verdict.to_dict()


def _compare_call(judge: Judge, a_json: str, b_json: str, instruction: str) -> Callable[[], dict[str, Any]]:
    def call() -> dict[str, Any]:
        return _verdict_answer(
            lambda: judge.compare(Description.from_json(a_json), Description.from_json(b_json), instruction)
        )

    return call


def _compare_videos_call(
    judge: Judge, files: dict[str, tuple[Path, str]], instruction: str, stage_root: Path
) -> Callable[[], dict[str, Any]]:
    def call() -> dict[str, Any]:
        with blind_copies(files, stage_root) as blind:
            a = RolloutInput(instruction=instruction, video_path=blind["a"])
            b = RolloutInput(instruction=instruction, video_path=blind["b"])
            return _verdict_answer(lambda: judge.compare_videos(a, b, instruction))

    return call
