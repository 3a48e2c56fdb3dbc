"""DVC-tracked artefacts: the teleop dataset, trained policies and the final reports.

Snakemake stays the only DAG; DVC is the content-addressed store with a remote.

    python -m r2s_eval.artifacts push   # dvc add + record mtimes + dvc push
    python -m r2s_eval.artifacts pull   # dvc pull + restore mtimes

`dvc pull`/`checkout` stamp files with the current time, which would make Snakemake rerun
every job downstream of a pulled file. The content is byte-identical (DVC checks hashes), so
`push` records each tracked file's and folder's mtime in `artifacts.mtimes.json` and `pull`
puts them back; then `snakemake -n` plans nothing.

DVC finds the `.dvc` pointers only where git does not ignore them: the repository's
`.gitignore` ignores every artefact under `results/` and `reports/` but never a folder, a
pointer or a `.gitignore` there. A DVC command that fails is reported as one paragraph
naming the command and DVC's own message.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from r2s_eval.errors import DataError, StoreError
from r2s_eval.stages import _cli

MANIFEST = "artifacts.mtimes.json"


def tracked_paths(root: Path) -> list[Path]:
    """What DVC tracks: the real dataset, every trained policy folder, every report file and folder
    (the results browser keeps its videos in reports/browser/)."""
    paths = []
    dataset = root / "results" / "real" / "dataset"
    if dataset.exists():
        paths.append(dataset)
    paths += sorted(p for p in (root / "results" / "train").glob("*/*") if p.is_dir())
    paths += sorted(p for p in (root / "reports").glob("*") if (p.is_file() or p.is_dir()) and not p.name.startswith(".")
                    and p.suffix != ".dvc")
    return paths


def _walk(path: Path):
    yield path
    if path.is_dir():
        for dirpath, dirnames, filenames in os.walk(path):
            for name in dirnames + filenames:
                yield Path(dirpath) / name


def record_mtimes(root: Path, paths: list[Path]) -> dict[str, int]:
    return {str(p.relative_to(root)): p.stat().st_mtime_ns for path in paths for p in _walk(path)}


def restore_mtimes(root: Path, mtimes: dict[str, int]) -> int:
    """Set recorded mtimes, deepest paths first so a folder's own time is not bumped afterwards."""
    restored = 0
    for rel in sorted(mtimes, key=lambda r: r.count("/"), reverse=True):
        path = root / rel
        if path.exists():
            os.utime(path, ns=(mtimes[rel], mtimes[rel]))
            restored += 1
    return restored


def _dvc(root: Path, *args: str) -> None:
    # DVC of this interpreter's environment, whether or not that environment is on PATH.
    proc = subprocess.run([sys.executable, "-m", "dvc", *args], cwd=root, capture_output=True, text=True)
    if proc.returncode != 0:
        words = [a for a in args if a.startswith("-") or not (root / a).exists()]  # the command, not its paths
        paths = len(args) - len(words)
        command = " ".join(["dvc", *words, *([f"<{paths} paths>"] if paths else [])])
        said = " ".join((proc.stderr.strip() or proc.stdout.strip() or "no message").split())
        raise StoreError(f"`{command}` failed in {root} (exit status {proc.returncode}): {said}")


def push(root: Path, remote: str | None = None) -> list[Path]:
    paths = tracked_paths(root)
    if not paths:
        raise DataError(f"nothing to track under {root}: run the pipeline first")
    rel = [str(p.relative_to(root)) for p in paths]
    _dvc(root, "add", *rel)
    (root / MANIFEST).write_text(json.dumps(record_mtimes(root, paths), indent=1, sort_keys=True) + "\n")
    _dvc(root, "push", *(["--remote", remote] if remote else []), *rel)
    return paths


def pull(root: Path, remote: str | None = None) -> int:
    _dvc(root, "pull", *(["--remote", remote] if remote else []))
    manifest = root / MANIFEST
    if not manifest.exists():
        raise DataError(f"{manifest} is missing: it is written by `push` and committed beside the .dvc files")
    return restore_mtimes(root, json.loads(manifest.read_text()))


def parser() -> argparse.ArgumentParser:
    p = _cli.parser(__doc__.split("\n")[0], cfg=False)
    p.add_argument("action", choices=["push", "pull"])
    p.add_argument("--root", default=".", help="the pipeline's working directory (a DVC repo)")
    p.add_argument("--remote", help="DVC remote (default: the repo's default remote)")
    return p


def main(args: argparse.Namespace) -> None:
    root = Path(args.root).resolve()
    if args.action == "push":
        for path in push(root, args.remote):
            print(f"tracked {path.relative_to(root)}")
    else:
        print(f"pulled; restored {pull(root, args.remote)} mtimes")


if __name__ == "__main__":
    _cli.run(main, parser())
