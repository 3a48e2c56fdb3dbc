"""The judges' resolution card: a row per kind and judge naming the smallest magnitude it sees (or
that it sees none, with its best share), and a panel per kind of share against magnitude."""

from __future__ import annotations

import pandas as pd
from matplotlib.image import imread

from r2s_eval.compare.resolution import sweep_levels, sweep_pairs
from r2s_eval.report import resolution_figure, resolution_table, save_figure
from r2s_eval.stats.resolution import kind_summaries, level_rows
from tests.report.conftest import figure_opts

RESOLUTION = {"policy": "act", "kinds": ["jitter", "fumbling"], "detect_share": 0.8,
              "sweeps": {"jitter": {"key": "action_noise_std", "levels": [0.01, 0.04]},
                         "fumbling": {"execution": {"fumble": {"after_steps": 3, "open_steps": 1}},
                                      "key": "fumble.open_steps", "levels": [2, 8]}}}


def _card(sees) -> dict:
    """A judge's card on 20 inits where every run succeeds; `sees(level)`: it prefers the clean run."""
    levels = sweep_levels(RESOLUTION)
    sim = pd.DataFrame([{"episode_id": f"{p}-{i}", "policy": p, "task": "t", "init_id": i, "success": True}
                        for p in ["act", *(lv.policy for lv in levels)] for i in range(20)])
    pairs = sweep_pairs(sim, "act", levels, seed=0)
    pairs["winner"] = [r.policy_i if sees(r) else r.policy_j for r in pairs.itertuples()]
    rows = level_rows(pairs, sim, sim, "act", levels, detect_share=0.8, n_boot=100, ci_level=0.95, seed=0)
    return {"judge": "j", "policy": "act", "detect_share": 0.8, "comparisons": len(pairs), "levels": rows,
            "kinds": kind_summaries(rows)}


def test_table_names_the_smallest_magnitude_seen_or_says_none_is(tmp_path):
    cards = {"kinematic": _card(lambda r: True),
             "video": _card(lambda r: r.kind == "fumbling" and r.level == 2 or r.init_id % 2 == 0)}
    table = resolution_table(cards)
    rows = [line for line in table.splitlines() if line.startswith(("jitter", "fumbling"))]
    assert [row.split(" & ")[:2] for row in rows] == [["jitter", "kinematic"], ["jitter", "video"],
                                                      ["fumbling", "kinematic"], ["fumbling", "video"]]
    assert rows[0].split(" & ")[3] == "0.01" and "100.0" in rows[0]
    assert rows[1].split(" & ")[3].startswith("not seen") and "50.0" in rows[1]
    assert rows[3].split(" & ")[3] == "8"
    assert r"100.0/100.0; 100.0/100.0" in rows[0]  # success: changed/clean, sim; real
    fig = resolution_figure(cards, figure_opts("judge_resolution"))
    assert [ax.get_title() for ax in fig.axes[:2]] == ["jitter", "fumbling"]
    save_figure(fig, tmp_path / "r.pdf", tmp_path / "r.png")
    assert imread(tmp_path / "r.png").shape[1] > 400
