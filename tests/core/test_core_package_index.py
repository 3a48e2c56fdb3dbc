"""The package-to-distribution map r2s-eval answers lerobot's imports with is the standard library's."""

from __future__ import annotations

import importlib.metadata

from r2s_eval.utils import package_index


def test_the_map_is_the_standard_librarys():
    ours = package_index.packages_distributions()
    stdlib = package_index.STDLIB_PACKAGES_DISTRIBUTIONS()
    assert {k: sorted(v) for k, v in ours.items()} == {k: sorted(v) for k, v in stdlib.items()}
    assert "r2s_eval" in ours and "torch" in ours


def test_importing_r2s_eval_answers_with_it():
    assert importlib.metadata.packages_distributions is package_index.packages_distributions
