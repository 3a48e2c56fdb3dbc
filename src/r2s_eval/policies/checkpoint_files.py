"""A LeRobot checkpoint folder on disk: its file names, where its config is, its content hash.

The lowest floor of `policies`: no torch, no lerobot, so the workflow can find and hash a
checkpoint when it plans a run, and both the in-process loader and the policy sources use it.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from r2s_eval.policies.interface import PolicyError

CHECKPOINT_SUBDIR = "pretrained_model"
RUNNER_CONFIG = "runner_config.json"  # our settings next to lerobot's files (cameras used)
WEIGHTS_FILE = "model.safetensors"
SNAPSHOTS_SUBDIR = "snapshots"


def snapshot_folder(train_dir: str | Path, step: int) -> Path:
    """Where a training's folder keeps its weights after `step` optimisation steps (a `snapshot`
    candidate, r2s_eval.policy_sources): a checkpoint folder like the training's own."""
    return Path(train_dir) / SNAPSHOTS_SUBDIR / str(int(step))


def resolve_checkpoint(checkpoint_dir: str | Path) -> Path:
    """Accept either a training `out_dir` or its `pretrained_model/` folder."""
    path = Path(checkpoint_dir)
    if (path / CHECKPOINT_SUBDIR / "config.json").is_file():
        path = path / CHECKPOINT_SUBDIR
    if not (path / "config.json").is_file():
        # Checked here: lerobot would treat a missing folder as a hub id and try to download it.
        raise PolicyError(f"no LeRobot policy at {checkpoint_dir} (no config.json; expected a pretrained_model folder)")
    return path


def checkpoint_hash(path: str | os.PathLike, memo_file: str | os.PathLike | None = None) -> str:
    """SHA-256 over a checkpoint folder's file names and contents.

    Hashing a multi-GB VLA checkpoint takes seconds, and the workflow asks on every plan, so
    digests are remembered per file by (size, mtime_ns, inode) in `memo_file`.
    """
    root = Path(path)
    if not root.exists():
        raise PolicyError(f"checkpoint {root} does not exist")
    files = sorted(p for p in root.rglob("*") if p.is_file()) if root.is_dir() else [root]
    memo: dict[str, Any] = {}
    if memo_file and Path(memo_file).is_file():
        try:
            memo = json.loads(Path(memo_file).read_text())
        except (OSError, ValueError):
            memo = {}
    digest = hashlib.sha256()
    changed = False
    for f in files:
        st = f.stat()
        stamp = [st.st_size, st.st_mtime_ns, st.st_ino]
        key = str(f.resolve())
        entry = memo.get(key)
        if not entry or entry["stamp"] != stamp:
            h = hashlib.sha256()
            with open(f, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    h.update(block)
            entry = memo[key] = {"stamp": stamp, "sha256": h.hexdigest()}
            changed = True
        digest.update(f.relative_to(root).as_posix().encode() if root.is_dir() else b"")
        digest.update(entry["sha256"].encode())
    if memo_file and changed:
        Path(memo_file).parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(memo_file).with_suffix(".tmp")
        tmp.write_text(json.dumps(memo))
        tmp.replace(memo_file)
    return digest.hexdigest()
