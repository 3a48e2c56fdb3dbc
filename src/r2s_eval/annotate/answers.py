"""Answers of the annotators, in SQLite, committed one by one.

Each answer is its own transaction in a write-ahead-logged database with full syncs, so an
answer the server has acknowledged survives the server being killed, the machine losing power
or the browser tab being closed. The database remembers which annotation set it belongs to (the
hash of the set's key table) and refuses another set, so answers never attach to other pairs.

Every annotator sees the items in an order of their own (a permutation seeded by the set and the
annotator's name), so the order in which pairs are met does not line up across annotators, and a
returning annotator gets the same order back and resumes at the first item left unanswered.
"""

from __future__ import annotations

import hashlib
import re
import sqlite3
import threading
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd

from r2s_eval.errors import DataError

ANNOTATOR_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,39}$")
EXPORT_COLUMNS = ("episode_a", "episode_b", "choice", "annotator", "item_id", "answered_at", "seconds", "watched_full")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS answers (
    annotator TEXT NOT NULL,
    item_id TEXT NOT NULL,
    episode_a TEXT NOT NULL,
    episode_b TEXT NOT NULL,
    choice TEXT NOT NULL CHECK (choice IN ('A', 'B')),
    answered_at TEXT NOT NULL,
    seconds REAL,
    watched_full INTEGER NOT NULL DEFAULT 0,
    revisions INTEGER NOT NULL DEFAULT 1,
    PRIMARY KEY (annotator, item_id)
);
"""


class AnnotationError(DataError):
    """An answer or annotator the store cannot take (unknown item, bad letter, bad name)."""


def set_fingerprint(items: pd.DataFrame) -> str:
    """Hash of what the answers refer to: the items and the two videos each shows, in order."""
    rows = items[["item_id", "episode_a", "episode_b"]].astype(str).itertuples(index=False)
    return hashlib.sha256("\n".join("\t".join(r) for r in rows).encode()).hexdigest()


def check_annotator(name: str) -> str:
    name = str(name).strip()
    if not ANNOTATOR_PATTERN.match(name):
        raise AnnotationError(f"annotator name {name!r}: use 1-40 letters, digits, '.', '_' or '-', "
                              "starting with a letter or digit")
    return name


class AnswerStore:
    """The answers of one annotation set (``items``: its key table) in the SQLite file ``path``."""

    def __init__(self, path: str | Path, items: pd.DataFrame):
        self.path = Path(path)
        self.items = items.reset_index(drop=True)
        self._by_id = {str(i): n for n, i in enumerate(self.items["item_id"])}
        self.fingerprint = set_fingerprint(self.items)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")  # a committed answer is on disk before we reply
        with self._lock:
            self._db.executescript(_SCHEMA)
            self._db.execute("BEGIN IMMEDIATE")
            row = self._db.execute("SELECT value FROM meta WHERE key = 'set_fingerprint'").fetchone()
            if row is None:
                self._db.execute("INSERT INTO meta VALUES ('set_fingerprint', ?)", (self.fingerprint,))
            self._db.execute("COMMIT")
        if row is not None and row[0] != self.fingerprint:
            self._db.close()
            raise AnnotationError(f"{self.path} holds answers for another annotation set; give this set its own "
                                  "database (or export and move the old one away)")

    def close(self) -> None:
        self._db.close()

    # ------------------------------------------------------------------ order

    def order(self, annotator: str) -> list[int]:
        """The annotator's own order of the items (row numbers of ``items``)."""
        digest = hashlib.sha256(f"{self.fingerprint}\x00{check_annotator(annotator)}".encode()).digest()
        rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
        return [int(k) for k in rng.permutation(len(self.items))]

    def item_at(self, annotator: str, position: int) -> pd.Series:
        order = self.order(annotator)
        if not 0 <= int(position) < len(order):
            raise AnnotationError(f"position {position} is outside 0..{len(order) - 1}")
        return self.items.iloc[order[int(position)]]

    # ---------------------------------------------------------------- answers

    def record(self, annotator: str, item_id: str, choice: str, seconds: float | None = None,
               watched_full: bool = False) -> None:
        """Store (or replace) one answer and commit it before returning."""
        annotator = check_annotator(annotator)
        choice = str(choice).strip().upper()
        if choice not in ("A", "B"):
            raise AnnotationError(f"choice must be A or B, got {choice!r}")
        if str(item_id) not in self._by_id:
            raise AnnotationError(f"no item {item_id!r} in this annotation set")
        row = self.items.iloc[self._by_id[str(item_id)]]
        seconds = None if seconds is None else max(0.0, float(seconds))
        now = datetime.now(timezone.utc).isoformat(timespec="milliseconds")
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                self._db.execute(
                    "INSERT INTO answers (annotator, item_id, episode_a, episode_b, choice, answered_at, seconds,"
                    " watched_full) VALUES (?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (annotator, item_id) DO UPDATE SET"
                    " choice = excluded.choice, answered_at = excluded.answered_at, seconds = excluded.seconds,"
                    " watched_full = excluded.watched_full, revisions = revisions + 1",
                    (annotator, str(item_id), str(row["episode_a"]), str(row["episode_b"]), choice, now, seconds,
                     int(bool(watched_full))),
                )
                self._db.execute("COMMIT")
            except BaseException:
                self._db.execute("ROLLBACK")
                raise

    def answers(self, annotator: str | None = None) -> pd.DataFrame:
        """All answers (or one annotator's), one row per (annotator, item)."""
        query = "SELECT annotator, item_id, episode_a, episode_b, choice, answered_at, seconds, watched_full," \
                " revisions FROM answers"
        args: tuple = ()
        if annotator is not None:
            query, args = query + " WHERE annotator = ?", (check_annotator(annotator),)
        with self._lock:
            rows = self._db.execute(query + " ORDER BY item_id, annotator", args).fetchall()
        cols = ["annotator", "item_id", "episode_a", "episode_b", "choice", "answered_at", "seconds", "watched_full",
                "revisions"]
        out = pd.DataFrame(rows, columns=cols)
        return out.astype({"watched_full": bool}) if len(out) else out

    def progress(self, annotator: str) -> dict:
        """How far the annotator is: answered count, total, and the first unanswered position
        in their order (``total`` when all are answered)."""
        done = set(self.answers(annotator)["item_id"].astype(str))
        order = self.order(annotator)
        ids = self.items["item_id"].astype(str).to_numpy()
        first = next((p for p, k in enumerate(order) if ids[k] not in done), len(order))
        return {"annotator": annotator, "answered": len(done), "total": len(order), "position": first}

    def export(self) -> pd.DataFrame:
        """The answers as the CSV the judge audit reads (``EXPORT_COLUMNS``), videos in the order
        the annotator saw them."""
        out = self.answers()
        if not len(out):
            return pd.DataFrame(columns=list(EXPORT_COLUMNS))
        return out[list(EXPORT_COLUMNS)]
