"""What configuration each stage reads, as the stage itself declares it.

Every stage module starts with ``READS``: the config paths (a group, ``"seed"``, or a dotted path
such as ``"calib.camera"``) its ``--cfg`` slice holds, and, where the rule adds values of its own
(the policy or judge of the job), ``PROVIDED``: those keys. The workflow builds each rule's
``--cfg`` from ``READS``, so a rule reruns when, and only when, something the stage reads
changed; a test compares each declaration with the keys the stage's code reads.

A stage reads each value by the path it declares, ``cfg["stats.n_boot"]``, never
``cfg["stats"]["n_boot"]``: it declares the settings it uses, so a change elsewhere in their
group never reruns it. A group is declared only where the stage hands it whole to a library call
(``world``, ``rollout``, ``teleop``) or where it is the stage's own options (``report.<name>``).

The declarations are read from the source (``ast``), not imported: planning a workflow must not
import torch.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

STAGES_DIR = Path(__file__).resolve().parent


@cache
def declaration(stage: str) -> dict[str, tuple[str, ...]]:
    """``{"READS": (...), "PROVIDED": (...)}`` of `stage` (``PROVIDED`` empty when absent)."""
    path = STAGES_DIR / f"{stage}.py"
    found: dict[str, tuple[str, ...]] = {"READS": (), "PROVIDED": ()}
    for node in ast.parse(path.read_text(), str(path)).body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            name = node.targets[0].id
            if name in found:
                found[name] = tuple(ast.literal_eval(node.value))
    return found
