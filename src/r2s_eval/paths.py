"""Where the project's own files are: the repository root and its Hydra config tree, ``conf/``.

The package is installed editable from its repository (``pip install -e .``): the config groups,
world files and assets it reads sit beside ``src/``, so every module finds them through here.
"""

from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
CONF_DIR = REPO_ROOT / "conf"
