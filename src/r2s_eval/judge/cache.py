"""Persistent content-addressed cache of judge answers.

One small JSON file per answer, named by its key and written atomically the moment the answer
arrives. A killed run therefore loses at most the calls in flight, a resumed run repeats none of
the finished ones, and a rerun makes no call at all. Keys are sha256 digests of everything that
determines the answer (see ``cache_key``), so entries never need invalidating: a new judge
config or prompt version simply produces new keys.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path
from typing import Any

from r2s_eval.utils.io import write_json

log = logging.getLogger(__name__)


def cache_key(payload: Any) -> str:
    """sha256 of the canonical JSON of `payload` (a dict of content hashes, judge identity, ...)."""
    blob = json.dumps(payload, sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()


class AnswerCache:
    """``get``/``put`` JSON answers under `root`/`kind`/ab/<key>.json (ab = first two hex digits)."""

    def __init__(self, root: str | Path, kind: str):
        self.dir = Path(root) / kind

    def path(self, key: str) -> Path:
        return self.dir / key[:2] / f"{key}.json"

    def get(self, key: str) -> dict[str, Any] | None:
        p = self.path(key)
        try:
            entry = json.loads(p.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as e:
            # Writes are atomic, so this means outside damage; treat it as a miss and overwrite.
            log.warning("unreadable cache entry %s (%s); asking the judge again", p, e)
            return None
        if not isinstance(entry, dict) or entry.get("key") != key or "answer" not in entry:
            log.warning("malformed cache entry %s; asking the judge again", p)
            return None
        return entry["answer"]

    def put(self, key: str, answer: dict[str, Any], inputs: dict[str, Any]) -> None:
        """Store `answer`, with the key `inputs` alongside for auditing."""
        write_json(self.path(key), {"key": key, "inputs": inputs, "answer": answer})
