"""The cached parallel runner under both stage drivers, and what a stage reports it cost.

``run_cached`` asks the judge, in a thread pool, only for answers the cache lacks, and stores
each answer (with its cost) the moment it arrives (see ``cache.py``), so an interruption keeps
finished work. ``Asker`` puts comparisons through it round after round (planned, replacements,
swapped), asking each distinct question once. ``StageStats`` counts judge calls, cache hits,
model requests, retries, re-asks, tokens in/out and wall time; ``finish`` hands them over in
``df.attrs["stats"]`` and, when given, as JSON.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from r2s_eval.errors import DataError, JudgeError, R2SError
from r2s_eval.judge.cache import AnswerCache
from r2s_eval.judge.usage import Usage, metered
from r2s_eval.utils.io import write_json

log = logging.getLogger(__name__)


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


def sum_stats(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """Stats of several runs of one stage added up: every count (and the wall time) summed, the
    other fields taken from the first part that has them."""
    total: dict[str, Any] = {}
    for part in parts:
        for key, value in part.items():
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                total[key] = total.get(key, 0) + value
            else:
                total.setdefault(key, value)
    return total


def require_columns(df: pd.DataFrame, cols: tuple[str, ...], what: str) -> None:
    lacking = [c for c in cols if c not in df.columns]
    if lacking:
        raise DataError(f"{what} lacks columns {lacking}")


# One question for the judge: (label for errors, cache key inputs, the call that answers it).
Job = tuple[str, dict[str, Any], Callable[[], dict[str, Any]]]


def run_cached(jobs: dict[str, Job], cache: AnswerCache, stats: StageStats, workers: int) -> dict[str, dict[str, Any]]:
    """Answer every job (key -> (label for errors, key inputs, call)) from the cache or by calling.

    Each answer is stored, with its cost under "usage", the moment its call returns, so an
    interruption keeps finished work.
    """
    answers: dict[str, dict[str, Any]] = {}
    todo = []
    for key, (label, inputs, call) in jobs.items():
        hit = cache.get(key)
        if hit is not None:
            answers[key] = hit
        else:
            todo.append((key, label, inputs, call))
    stats.cache_hits += len(answers)
    log.info("%s with %s: %d cached, %d to ask", stats.stage, stats.judge, len(answers), len(todo))

    lock = threading.Lock()

    def one(key: str, label: str, inputs: dict[str, Any], call: Callable[[], dict[str, Any]]) -> None:
        try:
            with metered() as usage:
                answer = call()
        except R2SError as e:  # the judge could not answer (server, deadline, config): say where
            raise JudgeError(f"{stats.stage}: judge {stats.judge!r} failed on {label}: {e}") from e
        except Exception as e:  # a bug: labelled too, its traceback kept as the cause
            raise JudgeError(f"{stats.stage}: judge {stats.judge!r} failed on {label}: {e}") from e
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


# Turns (label, episode A, episode B) into the comparison's cache key and job.
Question = Callable[[str, str, str], tuple[str, dict[str, Any], Callable[[], dict[str, Any]]]]


class Asker:
    """Ask comparisons through ``run_cached``, round after round, keeping every answer of the run.

    A key already known in this run (a comparison that recurs, in a later round or swapped) is
    neither asked nor looked up again, so calls, cache hits and unique keys count each question
    once over all rounds, and ``calls + cache_hits == unique_keys``.
    """

    def __init__(self, question: Question, cache: AnswerCache, stats: StageStats, workers: int):
        self.question, self.cache, self.stats, self.workers = question, cache, stats, workers
        self.answers: dict[str, dict[str, Any]] = {}  # by cache key, everything known in this run

    def __call__(self, items: list[tuple[str, str, str]]) -> list[str]:
        """items: (label, episode A, episode B) -> their cache keys; their answers go to ``answers``."""
        jobs: dict[str, Job] = {}
        keys = []
        for label, ea, eb in items:
            key, inputs, call = self.question(label, str(ea), str(eb))
            keys.append(key)
            if key not in self.answers:
                jobs.setdefault(key, (label, inputs, call))
        self.stats.unique_keys += len(jobs)
        self.answers.update(run_cached(jobs, self.cache, self.stats, self.workers))
        return keys

    def letter(self, key: str) -> str | None:
        """The answer's letter, None when it is invalid."""
        return self.answers[key].get("letter")


def finish(stats: StageStats, t0: float, df: pd.DataFrame, stats_path: str | Path | None) -> pd.DataFrame:
    """Attach the stats (wall time since `t0`) to `df`, write them to `stats_path` if given, log them."""
    stats.wall_s = round(time.perf_counter() - t0, 3)
    df.attrs["stats"] = stats.to_dict()
    if stats_path is not None:
        write_json(stats_path, stats.to_dict(), provenance=True)
    log.info("%s", {k: v for k, v in stats.to_dict().items() if k != "exclusions"})
    return df
