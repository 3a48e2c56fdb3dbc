"""Atomic artefact writing: a killed job never leaves a half file that looks whole."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pandas as pd


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary sibling path; rename it onto `path` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary sibling directory; it replaces `path` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        yield tmp
        if path.exists():
            shutil.rmtree(path)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def write_json(path: str | os.PathLike, data: Any, *, provenance: bool = False) -> None:
    """Write JSON atomically; with ``provenance`` a dict gains a ``provenance`` entry (the
    stage's config hash and the r2s-eval version) when a stage runner has set one."""
    if provenance and _PROVENANCE and isinstance(data, dict):
        data = {**data, "provenance": dict(_PROVENANCE)}
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, sort_keys=True, default=_json_default) + "\n")


def write_text(path: str | os.PathLike, text: str, *, comment: str | None = None) -> None:
    """Write text atomically; with ``comment`` (the format's comment marker, e.g. ``%`` for
    LaTeX) the first line records the provenance when a stage runner has set one."""
    if comment and _PROVENANCE:
        text = f"{comment} {provenance_line()}\n{text}"
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def read_json(path: str | os.PathLike) -> Any:
    return json.loads(Path(path).read_text())


# What made the artefacts this process writes: set once by the stage runner (`set_provenance`).
_PROVENANCE: dict[str, str] = {}


def set_provenance(cfg: Any) -> dict[str, str]:
    """Record the hash of the stage's config slice and the r2s-eval version; every parquet file
    written afterwards carries them in its metadata (``read_provenance``)."""
    from r2s_eval import __version__

    _PROVENANCE.clear()
    _PROVENANCE.update({"config_sha256": config_hash(cfg), "r2s_eval_version": __version__})
    return dict(_PROVENANCE)


def current_provenance() -> dict[str, str]:
    """The provenance set by the stage runner ({} outside a stage)."""
    return dict(_PROVENANCE)


def provenance_line() -> str:
    """The provenance as one line, for formats that carry free text (LaTeX comments, figure metadata)."""
    return " ".join(f"{k}={v}" for k, v in sorted(_PROVENANCE.items()))


def read_provenance(path: str | os.PathLike) -> dict[str, str]:
    """The provenance recorded in a parquet file written by `write_parquet` ({} when none)."""
    import pyarrow.parquet as pq

    raw = (pq.read_schema(path).metadata or {}).get(b"r2s_eval")
    return dict(json.loads(raw).get("provenance", {})) if raw else {}


def write_parquet(path: str | os.PathLike, df: pd.DataFrame, metadata: dict | None = None) -> None:
    """Write a parquet file atomically; `metadata` and the provenance go into the schema."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pandas(df, preserve_index=False)
    metadata = {**(metadata or {}), **({"provenance": dict(_PROVENANCE)} if _PROVENANCE else {})}
    if metadata:
        meta = dict(table.schema.metadata or {})
        meta[b"r2s_eval"] = json.dumps(metadata, sort_keys=True, default=_json_default).encode()
        table = table.replace_schema_metadata(meta)
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)


def read_parquet_metadata(path: str | os.PathLike) -> dict:
    import pyarrow.parquet as pq

    meta = pq.read_schema(path).metadata or {}
    raw = meta.get(b"r2s_eval")
    return json.loads(raw) if raw else {}


def config_hash(cfg: Any) -> str:
    """Stable short hash of a plain (JSON-able) config slice."""
    blob = json.dumps(cfg, sort_keys=True, default=_json_default).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def file_sha256(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()
