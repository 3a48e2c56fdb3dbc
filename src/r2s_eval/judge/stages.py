"""Stage drivers: describe every rollout, then judge every sampled pair, through the answer cache.

Both drivers ask the judge only for answers the cache lacks and store each answer as soon as it
arrives (see ``cache.py``), and both report how many calls they made, how many answers came from
the cache, and the wall time (``df.attrs["stats"]``, and ``stats_path`` as JSON when given).
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from r2s_eval.judge.base import Description, Judge, RolloutInput, Verdict
from r2s_eval.judge.cache import AnswerCache, cache_key
from r2s_eval.utils.io import file_sha256, write_json

log = logging.getLogger(__name__)

EPISODE_COLUMNS = ("episode_id", "instruction", "video_path", "trajectory_path")
PAIR_COLUMNS = ("episode_a", "episode_b", "policy_a", "policy_b")
DESCRIPTION_COLUMNS = (
    "episode_id", "judge", "instruction", "description", "description_sha", "missing", "progress_label", "cache_key",
)


@dataclass
class StageStats:
    stage: str
    judge: str
    items: int = 0  # rows handled (episodes or pairs)
    unique_keys: int = 0  # distinct cache keys among them (identical content is judged once)
    calls: int = 0  # judge calls made in this run
    cache_hits: int = 0  # keys answered from the cache
    wall_s: float = 0.0


def _require(df: pd.DataFrame, cols: tuple[str, ...], what: str) -> None:
    lacking = [c for c in cols if c not in df.columns]
    if lacking:
        raise ValueError(f"{what} lacks columns {lacking}")


@contextlib.contextmanager
def _blind_copies(files: dict[str, tuple[Path, str]], stage_root: Path) -> Iterator[dict[str, Path]]:
    """Present each file to the judge under its content hash only (hard link, else copy).

    Folder and file names of recordings may spell out the policy or the outcome; the judge
    gets `<sha256><suffix>` in a scratch folder instead, removed after the call.
    """
    stage_root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="in-", dir=stage_root))
    try:
        out = {}
        for kind, (src, sha) in files.items():
            dst = tmp / f"{sha}{src.suffix.lower()}"
            try:
                os.link(src, dst)
            except OSError:  # other file system, or links not allowed
                shutil.copyfile(src, dst)
            out[kind] = dst
        yield out
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _run_cached(
    jobs: dict[str, tuple[str, dict[str, Any], Callable[[], dict[str, Any]]]],
    cache: AnswerCache,
    stats: StageStats,
    workers: int,
) -> dict[str, dict[str, Any]]:
    """Answer every job (key -> (label for errors, key inputs, call)) from the cache or by calling.

    Each answer is stored the moment its call returns, so an interruption keeps finished work.
    """
    answers: dict[str, dict[str, Any]] = {}
    todo = []
    for key, (label, inputs, call) in jobs.items():
        hit = cache.get(key)
        if hit is not None:
            answers[key] = hit
            stats.cache_hits += 1
        else:
            todo.append((key, label, inputs, call))
    log.info("%s with %s: %d cached, %d to ask", stats.stage, stats.judge, stats.cache_hits, len(todo))

    lock = threading.Lock()

    def one(key: str, label: str, inputs: dict[str, Any], call: Callable[[], dict[str, Any]]) -> None:
        try:
            answer = call()
        except Exception as e:
            raise RuntimeError(f"{stats.stage}: judge {stats.judge!r} failed on {label}: {e}") from e
        cache.put(key, answer, inputs)
        with lock:
            answers[key] = answer
            stats.calls += 1

    if workers <= 1:
        for job in todo:
            one(*job)
        return answers
    with ThreadPoolExecutor(max_workers=workers) as ex:
        futures = [ex.submit(one, *job) for job in todo]
        done, pending = wait(futures, return_when=FIRST_EXCEPTION)
        for f in pending:
            f.cancel()
        for f in done:
            f.result()  # re-raises the first failure; finished answers are already stored
    return answers


def _finish(stats: StageStats, t0: float, df: pd.DataFrame, stats_path: str | Path | None) -> pd.DataFrame:
    stats.wall_s = round(time.perf_counter() - t0, 3)
    df.attrs["stats"] = asdict(stats)
    if stats_path is not None:
        write_json(stats_path, asdict(stats))
    log.info("%s", asdict(stats))
    return df


def describe_rollouts(
    episodes_df: pd.DataFrame,
    episodes_dir: str | Path,
    judge: Judge,
    cache_dir: str | Path,
    *,
    workers: int = 1,
    stats_path: str | Path | None = None,
) -> pd.DataFrame:
    """Describe every episode with `judge`; one row per episode, in input order.

    Only ``episode_id``, ``instruction`` and the recording paths (relative to `episodes_dir`) are
    read from the episode table; policy, outcome and every other column stay out of the judge's
    sight. Cache key = sha256 of (sha256 of each recording the judge reads, the instruction, the
    judge identity: name, backend, config hash, prompt version).

    Returns columns ``DESCRIPTION_COLUMNS``: episode_id, judge (name), instruction, description
    (canonical JSON of a ``Description``), description_sha, missing (comma-separated missing
    sections, "" when complete), progress_label, cache_key.
    """
    t0 = time.perf_counter()
    _require(episodes_df, EPISODE_COLUMNS, "episode table")
    ids = episodes_df["episode_id"].astype(str)
    dup = ids[ids.duplicated()].unique().tolist()
    if dup:
        raise ValueError(f"episode table has duplicate episode_id values: {dup[:5]}")
    episodes_dir = Path(episodes_dir)
    cache = AnswerCache(cache_dir, "describe")
    stage_root = Path(cache_dir) / "inputs"
    identity = judge.identity()
    stats = StageStats(stage="describe", judge=judge.name, items=len(episodes_df))

    jobs: dict[str, tuple[str, dict[str, Any], Callable[[], dict[str, Any]]]] = {}
    keys, instructions = [], []
    for eid, row in zip(ids, episodes_df[list(EPISODE_COLUMNS[1:])].itertuples(index=False)):
        instruction = str(row.instruction)
        files: dict[str, tuple[Path, str]] = {}
        for kind in judge.inputs:
            rel = getattr(row, f"{kind}_path")
            if rel is None or (isinstance(rel, float) and pd.isna(rel)) or str(rel) == "":
                raise ValueError(f"episode {eid}: no {kind}_path, but judge {judge.name!r} reads the {kind}")
            src = episodes_dir / str(rel)
            if not src.is_file():
                raise FileNotFoundError(f"episode {eid}: {kind} file not found: {src}")
            files[kind] = (src, file_sha256(src))
        inputs = {"content": {k: sha for k, (_, sha) in files.items()}, "instruction": instruction, "judge": identity}
        key = cache_key(inputs)
        keys.append(key)
        instructions.append(instruction)
        if key not in jobs:
            jobs[key] = (f"episode {eid}", inputs, _describe_call(judge, files, instruction, stage_root))
    stats.unique_keys = len(jobs)

    answers = _run_cached(jobs, cache, stats, workers)
    rows = []
    for eid, key, instruction in zip(ids, keys, instructions):
        desc = Description.from_dict(answers[key])
        rows.append({
            "episode_id": eid,
            "judge": judge.name,
            "instruction": instruction,
            "description": desc.to_json(),
            "description_sha": desc.sha256(),
            "missing": ",".join(desc.missing),
            "progress_label": desc.progress_label or "",
            "cache_key": key,
        })
    return _finish(stats, t0, pd.DataFrame(rows, columns=list(DESCRIPTION_COLUMNS)), stats_path)


def _describe_call(
    judge: Judge, files: dict[str, tuple[Path, str]], instruction: str, stage_root: Path
) -> Callable[[], dict[str, Any]]:
    def call() -> dict[str, Any]:
        with _blind_copies(files, stage_root) as blind:
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


def judge_pairs(
    pairs_df: pd.DataFrame,
    descriptions_df: pd.DataFrame,
    judge: Judge,
    cache_dir: str | Path,
    *,
    workers: int = 1,
    stats_path: str | Path | None = None,
) -> pd.DataFrame:
    """Ask `judge` which side of every pair is better, from the two descriptions alone.

    `pairs_df` is ``r2s_eval.compare.sample_pairs`` output (needs episode_a, episode_b, policy_a,
    policy_b); `descriptions_df` is ``describe_rollouts`` output. The judge sees description A,
    description B and the task instruction. Cache key = sha256 of (description A sha,
    description B sha, in that order, the instruction, the judge identity).

    Returns `pairs_df` with added columns: verdict ('A'/'B'), winner (the preferred policy),
    rationale, judge (name), cache_key.
    """
    t0 = time.perf_counter()
    _require(pairs_df, PAIR_COLUMNS, "pairs table")
    _require(descriptions_df, ("episode_id", "instruction", "description", "description_sha"), "descriptions table")
    ids = descriptions_df["episode_id"].astype(str)
    if ids.duplicated().any():
        raise ValueError("descriptions table has duplicate episode_id values")
    by_id = {
        e: {"instruction": str(i), "description": str(d), "description_sha": str(h)}
        for e, i, d, h in zip(ids, descriptions_df["instruction"], descriptions_df["description"],
                              descriptions_df["description_sha"])
    }
    cache = AnswerCache(cache_dir, "compare")
    identity = judge.identity()
    stats = StageStats(stage="compare", judge=judge.name, items=len(pairs_df))

    jobs: dict[str, tuple[str, dict[str, Any], Callable[[], dict[str, Any]]]] = {}
    keys = []
    for n, row in enumerate(pairs_df[list(PAIR_COLUMNS)].itertuples(index=False)):
        ea, eb = str(row.episode_a), str(row.episode_b)
        label = f"pair row {n} ({row.policy_a} vs {row.policy_b}, episodes {ea} / {eb})"
        for e in (ea, eb):
            if e not in by_id:
                raise KeyError(f"{label}: episode {e} has no description")
        da, db = by_id[ea], by_id[eb]
        if da["instruction"] != db["instruction"]:
            raise ValueError(f"{label}: the two episodes have different instructions")
        instruction = da["instruction"]
        inputs = {"a": da["description_sha"], "b": db["description_sha"], "instruction": instruction, "judge": identity}
        key = cache_key(inputs)
        keys.append(key)
        if key not in jobs:
            jobs[key] = (label, inputs, _compare_call(judge, da["description"], db["description"], instruction))
    stats.unique_keys = len(jobs)

    answers = _run_cached(jobs, cache, stats, workers)
    verdicts = [Verdict.from_dict(answers[k]) for k in keys]
    out = pairs_df.copy()
    out["verdict"] = [v.letter for v in verdicts]
    out["winner"] = [a if v.letter == "A" else b for v, a, b in zip(verdicts, pairs_df["policy_a"], pairs_df["policy_b"])]
    out["rationale"] = [v.rationale for v in verdicts]
    out["judge"] = judge.name
    out["cache_key"] = keys
    return _finish(stats, t0, out, stats_path)


def _compare_call(judge: Judge, a_json: str, b_json: str, instruction: str) -> Callable[[], dict[str, Any]]:
    def call() -> dict[str, Any]:
        verdict = judge.compare(Description.from_json(a_json), Description.from_json(b_json), instruction)
        if not isinstance(verdict, Verdict):
            raise TypeError(f"compare returned {type(verdict).__name__}, expected Verdict")
        return verdict.to_dict()

    return call
