"""Which installed distribution provides each importable package, read once and cheaply.

transformers and diffusers (which lerobot imports) each ask `importlib.metadata.packages_distributions()`
on import. The standard library builds that map by listing every file of every installed
distribution and checking that each one exists on disk: about 50,000 `stat` calls in a LeRobot
environment, one to two CPU-seconds per stage process, twice. `fast_package_index()` builds the
same map (top-level names from `top_level.txt`, else from the distribution's RECORD) without the
existence checks, once per process.
"""

from __future__ import annotations

import collections
import csv
import functools
import importlib.metadata

# The standard library's own, kept for comparison (tests/core/test_core_package_index.py).
STDLIB_PACKAGES_DISTRIBUTIONS = importlib.metadata.packages_distributions


@functools.cache
def packages_distributions() -> dict[str, list[str]]:
    """`importlib.metadata.packages_distributions()`, without checking that each listed file
    exists (a file that an installer listed and then lost keeps its top-level name here)."""
    found: dict[str, list[str]] = collections.defaultdict(list)
    for dist in importlib.metadata.distributions():
        names = (dist.read_text("top_level.txt") or "").split()
        if not names:
            names = {_top_level(row[0]) for row in csv.reader((dist.read_text("RECORD") or "").splitlines()) if row}
            names = {name for name in names if name and name.isidentifier()}
        for name in names:
            found[name].append(dist.metadata["Name"])
    return dict(found)


def _top_level(path: str) -> str | None:
    # As the standard library infers it: a file at the top is a module only if it is .py.
    if "/" in path:
        return path.split("/", 1)[0]
    return path[:-3] if path.endswith(".py") else None


def fast_package_index() -> None:
    """Answer `importlib.metadata.packages_distributions()` with :func:`packages_distributions`."""
    importlib.metadata.packages_distributions = packages_distributions
