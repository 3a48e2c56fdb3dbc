"""The real/sim boundary: the simulation package never reaches into the reality twin."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import r2s_eval.sim

SIM_DIR = Path(r2s_eval.sim.__file__).resolve().parent


def _imported_modules(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def test_sim_source_imports_nothing_from_the_twin():
    sources = sorted(SIM_DIR.rglob("*.py"))
    assert sources
    offending = {
        str(path.relative_to(SIM_DIR)): sorted(m for m in _imported_modules(path)
                                               if m == "r2s_eval.twin" or m.startswith("r2s_eval.twin."))
        for path in sources
    }
    assert not {k: v for k, v in offending.items() if v}, offending
    texts = {str(p.relative_to(SIM_DIR)) for p in sources if "r2s_eval.twin import" in p.read_text()}
    assert not texts


def test_importing_sim_loads_no_twin_module():
    code = ("import sys, r2s_eval.sim, r2s_eval.sim.build, r2s_eval.sim.params; "
            "print(sorted(m for m in sys.modules if m.startswith('r2s_eval.twin')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
