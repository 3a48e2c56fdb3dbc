"""The judge's scratch folder: content-named copies of the recordings, and what killed runs left.

The judge reads each recording through a hard link (else a copy) named by its content hash in a
scratch folder ``inputs/in-<pid>-<host>-*`` of the cache folder, removed after the call. A killed
run leaves nothing a rerun trips over: scratch folders of processes of this host that are gone,
and temporary files of atomic cache writes older than an hour, are removed when a stage driver
starts; those of live processes are left alone, since several processes may share one cache
folder.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import socket
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

log = logging.getLogger(__name__)

# Scratch folder names carry their owner, so a later run can tell a dead process's from a live one.
_SCRATCH_RE = re.compile(r"in-(\d+)-(.*)-[^-]+")
_STALE_TMP_S = 3600.0  # an atomic cache write takes milliseconds; a temporary file this old is a kill's


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, someone else's
        return True
    return True


def clear_leftovers(cache_dir: Path, kinds: tuple[str, ...]) -> None:
    """Remove what killed runs left in `cache_dir`: scratch folders of dead processes of this host
    (pids of other hosts mean nothing here) and stale temporary files of the `kinds` caches."""
    host = socket.gethostname()
    inputs = cache_dir / "inputs"
    if inputs.is_dir():
        for folder in inputs.iterdir():
            m = _SCRATCH_RE.fullmatch(folder.name)
            if m and m.group(2) == host and not _pid_alive(int(m.group(1))):
                log.info("removing %s, left by a process that is gone", folder)
                shutil.rmtree(folder, ignore_errors=True)
    cutoff = time.time() - _STALE_TMP_S
    for kind in kinds:
        for tmp in (cache_dir / kind).glob("*/.*.tmp"):
            with contextlib.suppress(FileNotFoundError):  # another process may remove it too
                if tmp.stat().st_mtime < cutoff:
                    tmp.unlink()


@contextlib.contextmanager
def blind_copies(files: dict[str, tuple[Path, str]], stage_root: Path) -> Iterator[dict[str, Path]]:
    """Present each file to the judge under its content hash only (hard link, else copy).

    Folder and file names of recordings may spell out the policy or the outcome; the judge
    gets `<sha256><suffix>` in a scratch folder instead, removed after the call (or, after a
    kill, by the next stage driver that starts: ``clear_leftovers``).
    """
    stage_root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f"in-{os.getpid()}-{socket.gethostname()}-", dir=stage_root))
    try:
        out = {}
        for kind, (src, sha) in files.items():
            dst = tmp / f"{sha}{src.suffix.lower()}"
            if not dst.exists():  # the same recording on both sides
                try:
                    os.link(src, dst)
                except OSError:  # other file system, or links not allowed
                    shutil.copyfile(src, dst)
            out[kind] = dst
        yield out
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
