"""Where the project's own files are: the repository root and its Hydra config tree, ``conf/``,
and the one cache folder outside it.

The package is installed editable from its repository (``pip install -e .``): the config groups,
world files and assets it reads sit beside ``src/``, so every module finds them through here.
"""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
CONF_DIR = REPO_ROOT / "conf"
CACHE_NAME = "r2s_eval"  # the cache folder's name under $XDG_CACHE_HOME or ~/.cache


def cache_dir() -> Path:
    """The project's cache folder, for what is slow to make and safe to delete (LIBERO's Python
    environment, shapes computed from scanned meshes): ``$R2S_EVAL_CACHE``, else
    ``$XDG_CACHE_HOME/r2s_eval``, else ``~/.cache/r2s_eval``. Every user of a cache folder asks
    here, so there is one. Results and the judges' answer cache are not in it: they belong to a
    run's working directory."""
    if os.environ.get("R2S_EVAL_CACHE"):
        return Path(os.environ["R2S_EVAL_CACHE"]).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache").expanduser() / CACHE_NAME
