"""Stage drivers: describe every rollout, then judge every sampled pair, through the answer cache.

Both drivers ask the judge only for answers the cache lacks and store each answer as soon as it
arrives (see ``cache.py``), and both report what they cost: judge calls, cache hits, model
requests, retries, re-asks, tokens in/out and wall time (``df.attrs["stats"]``, and
``stats_path`` as JSON when given).

``judge_pairs`` also handles what a real VLM does wrong: a pair whose answer stays invalid after
one re-ask (or whose server kept sending malformed replies) is excluded and replaced in place by
the next unused comparison of the same policy pair and task from a seeded reserve
(``r2s_eval.compare.sample_reserve``), never by one already excluded, so every checkpoint still
holds its planned number of comparisons and smaller checkpoints remain prefixes of larger ones.
A configurable share of pairs is asked a second time with the sides swapped (order-swap audit).

A killed run leaves nothing a rerun trips over: scratch folders (``inputs/in-<pid>-<host>-*``)
of processes of this host that are gone, and temporary files of atomic cache writes older than
an hour, are removed when a stage driver starts; those of live processes are left alone, since
several processes may share one cache folder.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import re
import shutil
import socket
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from r2s_eval.errors import JudgeError, R2SError
from r2s_eval.judge.base import Description, InvalidAnswer, Judge, RolloutInput, Verdict
from r2s_eval.judge.cache import AnswerCache, cache_key
from r2s_eval.judge.usage import Usage, metered
from r2s_eval.utils.io import file_sha256, write_json

log = logging.getLogger(__name__)

EPISODE_COLUMNS = ("episode_id", "instruction", "video_path", "trajectory_path")
PAIR_COLUMNS = ("episode_a", "episode_b", "policy_a", "policy_b")
DESCRIPTION_COLUMNS = (
    "episode_id", "judge", "instruction", "description", "description_sha", "missing", "progress_label", "cache_key",
)
# Added to the pairs table by ``judge_pairs``.
VERDICT_COLUMNS = (
    "verdict", "winner", "rationale", "judge", "cache_key", "reasks", "source_index", "replaced",
    "swap_audited", "verdict_swapped", "swap_cache_key",
)


@dataclass
class StageStats:
    stage: str
    judge: str
    items: int = 0  # rows handled (episodes or pairs)
    unique_keys: int = 0  # distinct cache keys among them (identical content is judged once)
    calls: int = 0  # judge calls made in this run
    cache_hits: int = 0  # keys answered from the cache
    requests: int = 0  # model requests sent in this run (re-asks included, retries not)
    retries: int = 0  # requests repeated after a connection error, timeout, 408, 429, 5xx or malformed reply
    malformed: int = 0  # replies that were no chat answer (retried; an invalid answer when the last one is)
    reasks: int = 0  # invalid answers asked once more (in this run)
    tokens_in: int = 0
    tokens_out: int = 0
    wall_s: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)  # stage-specific counts

    def add_usage(self, u: Usage) -> None:
        self.requests += u.requests
        self.retries += u.retries
        self.malformed += u.malformed
        self.reasks += u.reasks
        self.tokens_in += u.tokens_in
        self.tokens_out += u.tokens_out

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.update(d.pop("extra"))
        return d


def _require(df: pd.DataFrame, cols: tuple[str, ...], what: str) -> None:
    lacking = [c for c in cols if c not in df.columns]
    if lacking:
        raise ValueError(f"{what} lacks columns {lacking}")


# Scratch folder names carry their owner, so a later run can tell a dead process's from a live one.
_SCRATCH_RE = re.compile(r"in-(\d+)-(.*)-[^-]+")
_STALE_TMP_S = 3600.0  # an atomic cache write takes milliseconds; a temporary file this old is a kill's


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, someone else's
        return True
    return True


def _clear_leftovers(cache_dir: Path, kinds: tuple[str, ...]) -> None:
    """Remove what killed runs left in `cache_dir`: scratch folders of dead processes of this host
    (pids of other hosts mean nothing here) and stale temporary files of the `kinds` caches."""
    host = socket.gethostname()
    inputs = cache_dir / "inputs"
    if inputs.is_dir():
        for folder in inputs.iterdir():
            m = _SCRATCH_RE.fullmatch(folder.name)
            if m and m.group(2) == host and not _pid_alive(int(m.group(1))):
                log.info("removing %s, left by a process that is gone", folder)
                shutil.rmtree(folder, ignore_errors=True)
    cutoff = time.time() - _STALE_TMP_S
    for kind in kinds:
        for tmp in (cache_dir / kind).glob("*/.*.tmp"):
            with contextlib.suppress(FileNotFoundError):  # another process may remove it too
                if tmp.stat().st_mtime < cutoff:
                    tmp.unlink()


@contextlib.contextmanager
def _blind_copies(files: dict[str, tuple[Path, str]], stage_root: Path) -> Iterator[dict[str, Path]]:
    """Present each file to the judge under its content hash only (hard link, else copy).

    Folder and file names of recordings may spell out the policy or the outcome; the judge
    gets `<sha256><suffix>` in a scratch folder instead, removed after the call (or, after a
    kill, by the next stage driver that starts: ``_clear_leftovers``).
    """
    stage_root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f"in-{os.getpid()}-{socket.gethostname()}-", dir=stage_root))
    try:
        out = {}
        for kind, (src, sha) in files.items():
            dst = tmp / f"{sha}{src.suffix.lower()}"
            if not dst.exists():  # the same recording on both sides
                try:
                    os.link(src, dst)
                except OSError:  # other file system, or links not allowed
                    shutil.copyfile(src, dst)
            out[kind] = dst
        yield out
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


Job = tuple[str, dict[str, Any], Callable[[], dict[str, Any]]]


def _run_cached(jobs: dict[str, Job], cache: AnswerCache, stats: StageStats, workers: int) -> dict[str, dict[str, Any]]:
    """Answer every job (key -> (label for errors, key inputs, call)) from the cache or by calling.

    Each answer is stored, with its cost under "usage", the moment its call returns, so an
    interruption keeps finished work.
    """
    answers: dict[str, dict[str, Any]] = {}
    todo = []
    hits = 0
    for key, (label, inputs, call) in jobs.items():
        hit = cache.get(key)
        if hit is not None:
            answers[key] = hit
            hits += 1
        else:
            todo.append((key, label, inputs, call))
    stats.cache_hits += hits
    log.info("%s with %s: %d cached, %d to ask", stats.stage, stats.judge, hits, len(todo))

    lock = threading.Lock()

    def one(key: str, label: str, inputs: dict[str, Any], call: Callable[[], dict[str, Any]]) -> None:
        try:
            with metered() as usage:
                answer = call()
        except R2SError as e:  # the judge could not answer (server, deadline, config): say where
            raise JudgeError(f"{stats.stage}: judge {stats.judge!r} failed on {label}: {e}") from e
        except Exception as e:  # a bug: labelled too, its traceback kept as the cause
            raise RuntimeError(f"{stats.stage}: judge {stats.judge!r} failed on {label}: {e}") from e
        answer = {**answer, "usage": usage.to_dict()}
        cache.put(key, answer, inputs)
        with lock:
            answers[key] = answer
            stats.calls += 1
            stats.add_usage(usage)

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
    df.attrs["stats"] = stats.to_dict()
    if stats_path is not None:
        write_json(stats_path, stats.to_dict())
    log.info("%s", {k: v for k, v in stats.to_dict().items() if k != "exclusions"})
    return df


def _episode_files(eid: str, row: Any, kinds: tuple[str, ...], episodes_dir: Path, judge: Judge,
                   hashes: dict[Path, str]) -> dict[str, tuple[Path, str]]:
    files: dict[str, tuple[Path, str]] = {}
    for kind in kinds:
        rel = getattr(row, f"{kind}_path")
        if rel is None or (isinstance(rel, float) and pd.isna(rel)) or str(rel) == "":
            raise ValueError(f"episode {eid}: no {kind}_path, but judge {judge.name!r} reads the {kind}")
        src = episodes_dir / str(rel)
        if not src.is_file():
            raise FileNotFoundError(f"episode {eid}: {kind} file not found: {src}")
        if src not in hashes:
            hashes[src] = file_sha256(src)
        files[kind] = (src, hashes[src])
    return files


def describe_rollouts(
    episodes_df: pd.DataFrame,
    episodes_dir: str | Path,
    judge: Judge,
    cache_dir: str | Path,
    *,
    workers: int | None = None,
    stats_path: str | Path | None = None,
) -> pd.DataFrame:
    """Describe every episode with `judge`; one row per episode, in input order.

    Only ``episode_id``, ``instruction`` and the recording paths (relative to `episodes_dir`) are
    read from the episode table; policy, outcome and every other column stay out of the judge's
    sight. Cache key = sha256 of (sha256 of each recording the judge reads, the instruction, the
    judge identity: backend, model/config hash, prompt templates and version). `workers` defaults
    to the judge's ``concurrency``.

    Returns columns ``DESCRIPTION_COLUMNS``: episode_id, judge (name), instruction, description
    (canonical JSON of a ``Description``), description_sha, missing (comma-separated missing
    sections, "" when complete), progress_label, cache_key. The stats add ``incomplete`` (rows
    with missing sections; a description whose server sent only malformed replies misses all).
    """
    t0 = time.perf_counter()
    _require(episodes_df, EPISODE_COLUMNS, "episode table")
    ids = episodes_df["episode_id"].astype(str)
    dup = ids[ids.duplicated()].unique().tolist()
    if dup:
        raise ValueError(f"episode table has duplicate episode_id values: {dup[:5]}")
    episodes_dir = Path(episodes_dir)
    _clear_leftovers(Path(cache_dir), ("describe", "requests"))
    judge.attach_cache(cache_dir)
    cache = AnswerCache(cache_dir, "describe")
    stage_root = Path(cache_dir) / "inputs"
    identity = judge.identity()
    stats = StageStats(stage="describe", judge=judge.name, items=len(episodes_df))

    jobs: dict[str, Job] = {}
    keys, instructions, hashes = [], [], {}
    for eid, row in zip(ids, episodes_df[list(EPISODE_COLUMNS[1:])].itertuples(index=False)):
        instruction = str(row.instruction)
        files = _episode_files(eid, row, judge.inputs, episodes_dir, judge, hashes)
        inputs = {"content": {k: sha for k, (_, sha) in files.items()}, "instruction": instruction, "judge": identity}
        key = cache_key(inputs)
        keys.append(key)
        instructions.append(instruction)
        if key not in jobs:
            jobs[key] = (f"episode {eid}", inputs, _describe_call(judge, files, instruction, stage_root))
    stats.unique_keys = len(jobs)

    answers = _run_cached(jobs, cache, stats, workers or judge.stage_cfg["concurrency"])
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
    out = pd.DataFrame(rows, columns=list(DESCRIPTION_COLUMNS))
    stats.extra["incomplete"] = int((out["missing"] != "").sum())
    if stats.extra["incomplete"]:
        log.warning("%d of %d descriptions miss sections (column 'missing')", stats.extra["incomplete"], len(out))
    return _finish(stats, t0, out, stats_path)


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


def swap_audited(policy_i: str, policy_j: str, pair_index: int, share: float) -> bool:
    """Whether comparison `pair_index` of a policy pair is also asked with the sides swapped.

    A hash of the position, not a random draw: the audited set only grows with `share` and is the
    same in every rerun and at every checkpoint.
    """
    if share <= 0:
        return False
    h = hashlib.sha256(f"{policy_i}\x00{policy_j}\x00{int(pair_index)}".encode()).digest()
    return int.from_bytes(h[:8], "big") / 2.0**64 < share


def judge_pairs(
    pairs_df: pd.DataFrame,
    descriptions_df: pd.DataFrame | None,
    judge: Judge,
    cache_dir: str | Path,
    *,
    workers: int | None = None,
    stats_path: str | Path | None = None,
    reserve_df: pd.DataFrame | None = None,
    episodes_df: pd.DataFrame | None = None,
    episodes_dir: str | Path | None = None,
    swap_share: float | None = None,
) -> pd.DataFrame:
    """Ask `judge` which side of every pair is better.

    `pairs_df` is ``r2s_eval.compare.sample_pairs`` output (needs episode_a, episode_b, policy_a,
    policy_b; policy_i, policy_j, task, pair_index when comparisons may be replaced or audited).

    * ``mode: two_step`` (the judge's stage option): the judge sees description A, description B
      (`descriptions_df`, ``describe_rollouts`` output) and the task instruction. Cache key =
      sha256 of (description A sha, description B sha, in that order, the instruction, the judge
      identity).
    * ``mode: one_step``: the judge sees both videos (`episodes_df` with episode_id, instruction,
      video_path relative to `episodes_dir`), under content-hash names. Cache key = sha256 of
      (video A sha, video B sha, instruction, judge identity).

    A comparison whose answer is invalid (``InvalidAnswer``) is excluded and replaced in place by
    the next unused row of `reserve_df` (``sample_reserve`` output) with the same policy pair and
    task, oriented so that the same policy is A. Rows with ``swap_audited(..., swap_share)`` are
    asked again with A and B swapped; `swap_share` and `workers` default to the judge's stage
    options.

    Returns `pairs_df` (with episode_a/episode_b/init_id of replacements) plus ``VERDICT_COLUMNS``:
    verdict ('A'/'B'), winner (the preferred policy), rationale, judge (name), cache_key, reasks
    (0/1), source_index (position in the pair's seeded sequence the comparison came from; equals
    pair_index unless replaced), replaced (how many excluded comparisons this slot went through),
    swap_audited (bool), verdict_swapped ('A'/'B' as answered with the sides swapped; "" when not
    audited or invalid), swap_cache_key. Stats add ``excluded`` (comparisons excluded from a table
    row; a row's replacement is never a comparison already excluded in its policy pair and task,
    so none is counted twice), ``replacements`` (the sum of ``replaced``: equal to ``excluded``),
    ``swap_audited``, ``swap_invalid``, ``swap_consistency`` and ``exclusions`` (one record per
    excluded comparison, with the replies). ``unique_keys`` counts each distinct question once
    over all rounds (planned, replacements, swapped), and ``calls + cache_hits == unique_keys``.
    """
    t0 = time.perf_counter()
    _require(pairs_df, PAIR_COLUMNS, "pairs table")
    mode = judge.stage_cfg["mode"]
    share = float(judge.stage_cfg["swap_share"] if swap_share is None else swap_share)
    workers = workers or judge.stage_cfg["concurrency"]
    _clear_leftovers(Path(cache_dir), ("compare", "compare_videos", "requests"))
    judge.attach_cache(cache_dir)
    identity = judge.identity()
    stats = StageStats(stage="compare", judge=judge.name, items=len(pairs_df))
    if mode == "two_step":
        if descriptions_df is None:
            raise ValueError(f"judge {judge.name!r} compares descriptions (mode two_step): give the descriptions table")
        question = _description_questions(descriptions_df, judge, identity)
        cache = AnswerCache(cache_dir, "compare")
    else:
        if episodes_df is None or episodes_dir is None:
            raise ValueError(f"judge {judge.name!r} compares videos (mode one_step): give the episode table and folder")
        question = _video_questions(episodes_df, Path(episodes_dir), judge, identity, Path(cache_dir) / "inputs")
        cache = AnswerCache(cache_dir, "compare_videos")

    rows = pairs_df.reset_index(drop=True).to_dict("records")
    labels = [f"pair row {n} ({r['policy_a']} vs {r['policy_b']}, episodes {r['episode_a']} / {r['episode_b']})"
              for n, r in enumerate(rows)]
    for r in rows:
        r["source_index"] = int(r.get("pair_index", -1))
        r["replaced"] = 0

    answers: dict[str, dict[str, Any]] = {}  # by cache key, everything known in this run

    def ask(items: list[tuple[str, str, str]]) -> list[str]:
        """items: (label, episode A, episode B) -> their cache keys; their answers go to `answers`.

        A key already known in this run (a comparison that recurs, in a later round or swapped)
        is neither asked nor looked up again, so calls, cache hits and unique keys count each
        question once."""
        jobs: dict[str, Job] = {}
        keys = []
        for label, ea, eb in items:
            key, inputs, call = question(label, str(ea), str(eb))
            keys.append(key)
            if key not in answers:
                jobs.setdefault(key, (label, inputs, call))
        stats.unique_keys += len(jobs)
        answers.update(_run_cached(jobs, cache, stats, workers))
        return keys

    keys = ask([(labels[n], r["episode_a"], r["episode_b"]) for n, r in enumerate(rows)])
    exclusions: list[dict[str, Any]] = []
    reserve = _Reserve(reserve_df)
    pending = [n for n, k in enumerate(keys) if answers[k].get("letter") is None]
    while pending:
        # Every comparison excluded in this round is marked first, so that no replacement drawn
        # in it is one of them.
        for n in pending:
            r = rows[n]
            exclusions.append({
                "policy_i": r.get("policy_i"), "policy_j": r.get("policy_j"), "pair_index": r.get("pair_index"),
                "source_index": r["source_index"], "task": r.get("task"), "episode_a": r["episode_a"],
                "episode_b": r["episode_b"], "replies": answers[keys[n]].get("replies", []),
            })
            reserve.exclude(r)
            log.warning("%s: invalid answer after a re-ask; excluded and replaced", labels[n])
        for n in pending:
            r = rows[n]
            r.update(reserve.take(r, labels[n]))
            r["replaced"] += 1
            labels[n] = (f"pair row {n} ({r['policy_a']} vs {r['policy_b']}, episodes {r['episode_a']} / "
                         f"{r['episode_b']}, replacement {r['replaced']})")
        new_keys = ask([(labels[n], rows[n]["episode_a"], rows[n]["episode_b"]) for n in pending])
        for n, k in zip(pending, new_keys):
            keys[n] = k
        pending = [n for n in pending if answers[keys[n]].get("letter") is None]

    audited = [
        share > 0 and swap_audited(str(r.get("policy_i")), str(r.get("policy_j")), int(r.get("pair_index", n)), share)
        for n, r in enumerate(rows)
    ]
    swapped = [n for n, a in enumerate(audited) if a]
    swap_keys = ask([(labels[n] + " swapped", rows[n]["episode_b"], rows[n]["episode_a"]) for n in swapped])
    swap_key_of = dict(zip(swapped, swap_keys))

    out = pd.DataFrame(rows)
    verdicts = [Verdict.from_dict(answers[k]) for k in keys]
    out["verdict"] = [v.letter for v in verdicts]
    out["winner"] = [r["policy_a"] if v.letter == "A" else r["policy_b"] for v, r in zip(verdicts, rows)]
    out["rationale"] = [v.rationale for v in verdicts]
    out["judge"] = judge.name
    out["cache_key"] = keys
    out["reasks"] = [int(answers[k].get("usage", {}).get("reasks", 0)) for k in keys]
    out["swap_audited"] = audited
    out["verdict_swapped"] = [str(answers[swap_key_of[n]].get("letter") or "") if n in swap_key_of else ""
                              for n in range(len(rows))]
    out["swap_cache_key"] = [swap_key_of.get(n, "") for n in range(len(rows))]
    out = out[[*pairs_df.columns, *VERDICT_COLUMNS]]
    out = out.astype({"source_index": "int64", "replaced": "int64", "reasks": "int64", "swap_audited": bool})

    both = out[out["swap_audited"] & (out["verdict_swapped"] != "")]
    stats.extra.update({
        "mode": mode,
        "excluded": len(exclusions),
        "replacements": int(out["replaced"].sum()),
        "reasked_answers": int(out["reasks"].sum()),
        "swap_share": share,
        "swap_audited": int(out["swap_audited"].sum()),
        "swap_invalid": int((out["swap_audited"] & (out["verdict_swapped"] == "")).sum()),
        # Consistent: the same rollout wins in both orders, i.e. the letters differ.
        "swap_consistency": float((both["verdict"] != both["verdict_swapped"]).mean()) if len(both) else None,
        "exclusions": exclusions,
    })
    return _finish(stats, t0, out, stats_path)


def _group(row: dict[str, Any]) -> tuple[str, str, str]:
    return str(row.get("policy_i")), str(row.get("policy_j")), str(row.get("task"))


def _episodes(row: dict[str, Any]) -> frozenset[str]:
    """The comparison's two episodes, whichever side each is on."""
    return frozenset((str(row["episode_a"]), str(row["episode_b"])))


class _Reserve:
    """Unused reserve comparisons per (policy_i, policy_j, task), in sequence order.

    Each reserve row is handed out once, and never when its episode pair (either order) is one
    already excluded in its group: that comparison's answer is known to be invalid, and a row
    replaced by the very comparison it held would be excluded, and counted, twice.
    """

    def __init__(self, reserve_df: pd.DataFrame | None):
        self.queues: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
        self.excluded: dict[tuple[str, str, str], set[frozenset[str]]] = {}
        if reserve_df is None:
            return
        _require(reserve_df, ("pair_index", "policy_i", "policy_j", "task", "init_id", *PAIR_COLUMNS), "reserve table")
        for r in reserve_df.sort_values("pair_index", kind="stable").to_dict("records"):
            self.queues.setdefault(_group(r), []).append(r)

    def exclude(self, row: dict[str, Any]) -> None:
        self.excluded.setdefault(_group(row), set()).add(_episodes(row))

    def take(self, row: dict[str, Any], label: str) -> dict[str, Any]:
        group = _group(row)
        queue = self.queues.get(group, [])
        excluded = self.excluded.get(group, set())
        while queue and _episodes(queue[0]) in excluded:
            queue.pop(0)  # exclusions only grow: this row can never serve
        if not queue:
            raise JudgeError(
                f"{label}: the judge's answer stayed invalid and no reserve comparison is left for policies "
                f"{group[0]} vs {group[1]} on task {group[2]!r} (none unused that was not excluded); raise the "
                "judge's 'reserve' option"
            )
        r = queue.pop(0)
        ea, eb = r["episode_a"], r["episode_b"]
        if r["policy_a"] != row["policy_a"]:  # keep the excluded comparison's sides
            ea, eb = eb, ea
        return {"episode_a": ea, "episode_b": eb, "init_id": r["init_id"], "source_index": int(r["pair_index"])}


def _description_questions(descriptions_df: pd.DataFrame, judge: Judge, identity: dict[str, Any]):
    _require(descriptions_df, ("episode_id", "instruction", "description", "description_sha"), "descriptions table")
    ids = descriptions_df["episode_id"].astype(str)
    if ids.duplicated().any():
        raise ValueError("descriptions table has duplicate episode_id values")
    by_id = {
        e: {"instruction": str(i), "description": str(d), "description_sha": str(h)}
        for e, i, d, h in zip(ids, descriptions_df["instruction"], descriptions_df["description"],
                              descriptions_df["description_sha"])
    }

    def question(label: str, ea: str, eb: str) -> Job:
        for e in (ea, eb):
            if e not in by_id:
                raise KeyError(f"{label}: episode {e} has no description")
        da, db = by_id[ea], by_id[eb]
        if da["instruction"] != db["instruction"]:
            raise ValueError(f"{label}: the two episodes have different instructions")
        instruction = da["instruction"]
        inputs = {"a": da["description_sha"], "b": db["description_sha"], "instruction": instruction, "judge": identity}
        return cache_key(inputs), inputs, _compare_call(judge, da["description"], db["description"], instruction)

    return question


def _video_questions(episodes_df: pd.DataFrame, episodes_dir: Path, judge: Judge, identity: dict[str, Any],
                     stage_root: Path):
    _require(episodes_df, ("episode_id", "instruction", "video_path"), "episode table")
    by_id = {str(r.episode_id): r for r in episodes_df.itertuples(index=False)}
    hashes: dict[Path, str] = {}

    def question(label: str, ea: str, eb: str) -> Job:
        files, instructions = {}, set()
        for side, e in (("a", ea), ("b", eb)):
            if e not in by_id:
                raise KeyError(f"{label}: episode {e} is not in the episode table")
            files[side] = _episode_files(e, by_id[e], ("video",), episodes_dir, judge, hashes)["video"]
            instructions.add(str(by_id[e].instruction))
        if len(instructions) != 1:
            raise ValueError(f"{label}: the two episodes have different instructions")
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
        with _blind_copies(files, stage_root) as blind:
            a = RolloutInput(instruction=instruction, video_path=blind["a"])
            b = RolloutInput(instruction=instruction, video_path=blind["b"])
            return _verdict_answer(lambda: judge.compare_videos(a, b, instruction))

    return call
