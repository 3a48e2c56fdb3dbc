"""Shared argument parsing, logging and error reporting for stage entry points.

Every stage takes ``--log PATH`` (the workflow passes the rule's log file) and ``--debug``. With
``--log``, everything the stage and its libraries print goes to that file, tracebacks included;
the terminal gets only the error paragraph of a failed stage. An expected failure (an
``R2SError``: a damaged dataset, a wrong config, a server that will not answer) is shown as that
paragraph and exits with status 1; its traceback is written to the log file, or to the terminal
with ``--debug``. Anything else is a bug and keeps its traceback. Every stage keeps its thread
pools within the threads its job was given (``r2s_eval.utils.numerics.limit_threads``).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import resource
import sys
import time
import traceback
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TypeVar

from r2s_eval.errors import DataError, R2SError
from r2s_eval.utils.io import set_provenance
from r2s_eval.utils.numerics import limit_threads

T = TypeVar("T")
EXIT_EXPECTED = 1


def parser(description: str, cfg: bool = True) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=description)
    if cfg:
        p.add_argument("--cfg", type=json.loads, required=True, help="the stage's config slice as JSON")
    p.add_argument("--log", default=None, help="write all output (tracebacks included) to this file")
    p.add_argument("--debug", action="store_true", help="show the traceback of an expected error too")
    return p


def _redirect_output(log_path: str) -> int:
    """Point fd 1 and 2 (and so every library's prints) at the log file; return a copy of the
    terminal's stderr for the final message."""
    Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    terminal = os.dup(2)
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    sys.stdout.flush()
    sys.stderr.flush()
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    return terminal


def _say(fd: int | None, text: str) -> None:
    if fd is not None:
        os.write(fd, text.encode())


def error_paragraph(stage: str, err: BaseException) -> str:
    """Which stage failed and why: the message as written (its list lines stay one per line)."""
    return f"{stage} failed: {str(err).strip()}\n"


def run(main: Callable[[argparse.Namespace], None], p: argparse.ArgumentParser, argv=None) -> None:
    """Parse, set up logging, run `main`, and log the wall time; report failures as above."""
    args = p.parse_args(argv)
    limit_threads()  # no more threads than the job was given (Snakemake sets OMP_NUM_THREADS)
    log_path = getattr(args, "log", None)
    terminal = _redirect_output(log_path) if log_path else None
    logging.basicConfig(
        level=logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
        force=True,
    )
    log = logging.getLogger("r2s_eval")
    stage = _stage_name(main)
    set_provenance(getattr(args, "cfg", None) or {})
    start = time.perf_counter()
    try:
        main(args)
    except R2SError as err:
        message, trace = error_paragraph(stage, err), traceback.format_exc()
        if log_path:  # stderr is the log file now: it keeps the whole story
            sys.stderr.write(trace + message)
            sys.stderr.flush()
            _say(terminal, (trace if args.debug else "") + message + f"  (details: {log_path})\n")
        else:
            sys.stderr.write((trace if args.debug else "") + message)
        raise SystemExit(EXIT_EXPECTED) from None
    except Exception:
        # A bug: the traceback goes to the log (Python prints it on the way out) and the terminal.
        _say(terminal, f"{stage} failed with an unexpected error (a bug in r2s-eval):\n"
                       f"{traceback.format_exc()}  (log: {log_path})\n")
        raise
    log.info("stage done in %.1f s wall, %.1f CPU-s (user + system since the process started, "
             "its child processes included)", time.perf_counter() - start, cpu_seconds())


def cpu_seconds() -> float:
    """CPU time (user + system) of this process since it started, imports included, and of its
    finished child processes: what the job cost, whatever else shared the machine."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _stage_name(main: Callable) -> str:
    module = main.__module__
    if module == "__main__":  # run with `python -m r2s_eval.stages.<stage>`
        spec = getattr(sys.modules["__main__"], "__spec__", None)
        module = spec.name if spec is not None else Path(sys.argv[0]).stem
    parts = module.split(".")
    return parts[-2] if parts[-1] == "__main__" and len(parts) > 1 else parts[-1]  # `python -m r2s_eval.world`


def add_validation_table_inputs(p: argparse.ArgumentParser) -> None:
    """The arguments of the stages that write a validation table and the printed ranking."""
    p.add_argument("--validation", nargs="+", required=True)
    p.add_argument("--audits", nargs="*", default=[], help="judge-audit JSON per judge")
    p.add_argument("--fits", nargs="+", required=True)
    p.add_argument("--reference", required=True)
    p.add_argument("--table", required=True)
    p.add_argument("--ranking", required=True)


def by_judge(paths: Iterable[str], read: Callable[[str], T]) -> dict[str, T]:
    """Per-judge artefacts (`.../<judge>.parquet`, `.../<judge>.json`) read into {judge: content}."""
    return {Path(p).stem: read(p) for p in paths}


def keyed(values: Iterable[str], read: Callable[[list[str]], T], option: str) -> dict[str, T]:
    """``KEY=PATH`` arguments of ``--option`` read into {KEY: read([PATH, ...])} (a key given
    more than once gets all its paths)."""
    paths: dict[str, list[str]] = {}
    for value in values:
        key, sep, path = value.partition("=")
        if not sep:
            raise DataError(f"--{option} {value!r}: expected KEY=PATH")
        paths.setdefault(key, []).append(path)
    return {key: read(group) for key, group in paths.items()}
