"""What one judge answer cost: model requests, transient-error retries, malformed replies, re-asks
and tokens.

Backends report through ``record_usage`` from inside a call; the runner (``runner.run_cached``)
wraps each call in ``metered()`` and so learns the cost of exactly that answer, even with calls
running in parallel threads (the meter is thread-local).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator
from dataclasses import asdict, dataclass

_local = threading.local()


@dataclass
class Usage:
    requests: int = 0  # model requests that got an answer (re-asks included)
    retries: int = 0  # attempts repeated after a connection error, timeout, 408, 429, 5xx or malformed reply
    malformed: int = 0  # replies that were not a chat answer (not JSON, no choices, empty content)
    reasks: int = 0  # invalid answers asked once more
    request_cache_hits: int = 0  # requests answered from the request cache (resumed answers)
    tokens_in: int = 0
    tokens_out: int = 0

    def add(self, other: Usage) -> None:
        for k, v in asdict(other).items():
            setattr(self, k, getattr(self, k) + v)

    def to_dict(self) -> dict[str, int]:
        return asdict(self)


@contextlib.contextmanager
def metered() -> Iterator[Usage]:
    """Collect everything ``record_usage`` reports in this thread until the block ends."""
    prev = getattr(_local, "usage", None)
    usage = Usage()
    _local.usage = usage
    try:
        yield usage
    finally:
        _local.usage = prev


def record_usage(**counts: int) -> None:
    """Add counts (fields of ``Usage``) to the meter of the current thread, if any."""
    usage = getattr(_local, "usage", None)
    if usage is None:
        return
    for k, v in counts.items():
        setattr(usage, k, getattr(usage, k) + int(v))
