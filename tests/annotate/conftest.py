"""A small finished run with real videos and its annotation set (tests/browser/people.py)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "browser"))
from people import annotation_set, run  # noqa: E402,F401  (fixtures)
