"""A small finished run with real videos and its annotation set (people.py)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from people import annotation_set, run  # noqa: E402,F401  (fixtures)
