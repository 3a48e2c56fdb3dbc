"""The world's docs: the key reference (docs/world-keys.md) is what the world spec generates, and
every YAML block of the how-to (docs/world-howto.md) passes the world check as written."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from r2s_eval.sim.assembly import load_world
from r2s_eval.sim.world_spec import markdown

REPO = Path(__file__).resolve().parents[2]
HOWTO = (REPO / "docs" / "world-howto.md").read_text()
BLOCKS = re.findall(r"```yaml\n(.*?)```", HOWTO, re.S)


def test_the_key_reference_is_the_one_the_spec_generates():
    page = (REPO / "docs" / "world-keys.md").read_text()
    assert page == markdown(), "docs/world-keys.md is stale: python -m r2s_eval.sim.world_spec --markdown > docs/world-keys.md"


def _laid_over(base: dict, fragment: dict) -> dict:
    """`fragment` over `base` key by key (a mapping merged, anything else replaced)."""
    out = dict(base)
    for k, v in fragment.items():
        out[k] = _laid_over(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


@pytest.mark.parametrize("block", BLOCKS, ids=[b.splitlines()[0] for b in BLOCKS])
def test_every_world_snippet_of_the_howto_passes_the_world_check(block):
    # A block is a whole world, or says in its first line which world it is laid over.
    world = yaml.safe_load(block)
    over = re.match(r"# Over (conf/world/\w+\.yaml)", block)
    if over:
        world = _laid_over(yaml.safe_load((REPO / over.group(1)).read_text()), world)
    robot, tasks = load_world(world)
    assert robot.arms and tasks


def test_the_howto_has_snippets():
    assert len(BLOCKS) >= 2
