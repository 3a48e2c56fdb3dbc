"""Fixtures shared by more than one test folder: a small finished run with real videos and its
annotation set (tests/helpers/people.py builds them), for the annotation app's tests in
tests/annotate and the browser tests in tests/browser."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from tests.helpers.people import build_run

    root = tmp_path_factory.mktemp("run")
    return {"root": root, **build_run(root)}


@pytest.fixture(scope="module")
def annotation_set(run):
    """The run's annotation set (9 pairs, 3 per outcome category) under results/annotate."""
    import pandas as pd

    from r2s_eval.annotate import draw_annotation_set, write_annotation_set

    pairs = pd.read_parquet(run["root"] / "results" / "compare" / "pairs.parquet")
    items, summary = draw_annotation_set(pairs, run["sim"], n_pairs=9, seed=0)
    folder = run["root"] / "results" / "annotate"
    items = write_annotation_set(items, summary, run["sim"], set_path=folder / "set.parquet",
                                 videos_dir=folder / "videos", summary_path=folder / "summary.json")
    return {"dir": folder, "items": items, "summary": summary}


@pytest.fixture
def bundled_world():
    """The bundled world's config (``conf/world/tabletop.yaml``), a copy the test may change."""
    from tests.helpers.worlds import bundled_world

    return bundled_world()
