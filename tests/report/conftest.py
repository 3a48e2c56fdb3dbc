"""Small constructed artefacts shared by the report tests."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
import yaml

REPORT_CONF = Path(__file__).resolve().parents[2] / "conf" / "report" / "default.yaml"


def figure_opts(name: str, **changes) -> dict:
    """A figure's options as conf/report (their one owner) sets them, with ``changes``."""
    return {**yaml.safe_load(REPORT_CONF.read_text())[name], **changes}


def _verdicts(rows):
    """Verdict rows from (policy_i, policy_j, pair_index, episode_a, policy_a, episode_b, policy_b, verdict)."""
    out = []
    for pi, pj, k, ea, pa, eb, pb, v in rows:
        out.append({"pair_index": k, "policy_i": pi, "policy_j": pj, "task": "cup_on_plate", "init_id": k,
                    "episode_a": ea, "episode_b": eb, "policy_a": pa, "policy_b": pb, "first_checkpoint": 2,
                    "verdict": v, "winner": pa if v == "A" else pb, "rationale": f"reason {k}"})
    return pd.DataFrame(out)


@pytest.fixture
def verdicts():
    # a beats b 2-0, a beats c 1-1, b beats c 2-0. Episodes: a1, a2 succeed, b1 succeeds, b2, c1, c2 fail.
    return _verdicts([
        ("a", "b", 0, "a1", "a", "b1", "b", "A"),
        ("a", "b", 1, "b2", "b", "a2", "a", "B"),
        ("a", "c", 0, "c1", "c", "a1", "a", "A"),
        ("a", "c", 1, "a2", "a", "c2", "c", "A"),
        ("b", "c", 0, "b1", "b", "c1", "c", "A"),
        ("b", "c", 1, "c2", "c", "b2", "b", "B"),
    ])


@pytest.fixture
def sim_episodes():
    ids = ["a1", "a2", "b1", "b2", "c1", "c2"]
    return pd.DataFrame({
        "episode_id": ids, "policy": [e[0] for e in ids], "task": "cup_on_plate",
        "success": [True, True, True, False, False, False], "video_path": [f"videos/{e}.mp4" for e in ids],
        "trajectory_path": [f"trajectories/{e}.parquet" for e in ids],
    })


@pytest.fixture
def make_verdicts():
    return _verdicts


def _fit_table(scores_by_checkpoint):
    """Fit rows from {checkpoint: {policy: (score, ci_low, ci_high)}}."""
    rows = [{"checkpoint": n, "policy": p, "score": s, "ci_low": lo, "ci_high": hi, "strength": s / 100}
            for n, by_policy in scores_by_checkpoint.items() for p, (s, lo, hi) in by_policy.items()]
    return pd.DataFrame(rows)


@pytest.fixture
def make_fit():
    return _fit_table
