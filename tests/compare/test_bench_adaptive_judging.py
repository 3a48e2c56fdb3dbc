"""benchmarks/bench_adaptive_judging.py on a tiny setting: it runs and its numbers are sane."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_adaptive_judging.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_adaptive_judging", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is made
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop(spec.name, None)


@pytest.fixture(scope="module")
def demo(bench):
    return bench.main(["--runs", "20", "--worlds", "demo", "--workers", "1", "--n-boot", "200", "--designs", "2"])


def test_fields_and_ranges(demo):
    s = demo["demo"]
    assert s["runs"] == 20
    for key in ("fixed_requests", "adaptive_stop_median", "adaptive_stop_p90", "fixed_describes"):
        assert s[key] > 0
    for key in ("adaptive_wrong", "fixed_wrong", "reached"):
        assert 0.0 <= s[key] <= 1.0
    for key in ("adaptive_width_stop", "fixed_width_equal"):
        assert 0.0 < s[key] <= 1.0
    assert s["fixed_describes"] == 3 * 7 * 18  # every episode is described up front
    assert s["adaptive_wrong"] <= s["alpha"]
    assert 0 <= s["adaptive_decided"] <= 3 and 0 <= s["fixed_decided"] <= 3


def test_adaptive_asks_less_than_fixed_on_demo(demo):
    s = demo["demo"]
    assert s["adaptive_stop_p90"] <= s["fixed_requests"]
    if s["reached"] > 0:
        assert s["adaptive_match_median"] <= s["adaptive_stop_p90"]
        assert math.isfinite(s["ratio_match"]) and s["ratio_match"] > 0


def test_seeded(bench, demo):
    again = bench.main(["--runs", "20", "--worlds", "demo", "--workers", "1", "--n-boot", "200", "--designs", "2"])
    assert again["demo"] == demo["demo"] or all(
        (a == b) or (isinstance(a, float) and math.isnan(a) and math.isnan(b))
        for a, b in zip(again["demo"].values(), demo["demo"].values())
    )
