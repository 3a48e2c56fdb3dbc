"""Shared argument parsing and logging for stage entry points."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TypeVar

T = TypeVar("T")


def parser(description: str, cfg: bool = True) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=description)
    if cfg:
        p.add_argument("--cfg", type=json.loads, required=True, help="the stage's config slice as JSON")
    return p


def run(main: Callable[[argparse.Namespace], None], p: argparse.ArgumentParser, argv=None) -> None:
    """Parse, set up logging, run `main`, and log the wall time."""
    args = p.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
        force=True,
    )
    start = time.perf_counter()
    main(args)
    logging.getLogger("r2s_eval").info("stage done in %.1f s", time.perf_counter() - start)


def by_judge(paths: Iterable[str], read: Callable[[str], T]) -> dict[str, T]:
    """Per-judge artefacts (`.../<judge>.parquet`, `.../<judge>.json`) read into {judge: content}."""
    return {Path(p).stem: read(p) for p in paths}
