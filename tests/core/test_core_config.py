"""Hydra composition, config slices and atomic artefact writes."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from r2s_eval.artifacts import record_mtimes, restore_mtimes
from r2s_eval.config import candidate_config, candidate_configs, compose_config, select, to_json
from r2s_eval.errors import ConfigError
from r2s_eval.utils.io import atomic_dir, atomic_path, read_json, write_json

CONF = Path(__file__).resolve().parents[2] / "conf"


def test_experiments_compose():
    smoke = compose_config(CONF, "smoke")
    demo = compose_config(CONF, "demo")
    assert smoke["teleop"]["episodes_per_task"] < demo["teleop"]["episodes_per_task"]
    # The smoke's line-up adds a planted-quality variant of act (act's weights, stops and restarts).
    assert set(smoke["policies"]) == {"act", "act_subset", "act_weak", "act_hesitant"}
    assert smoke["policies"]["act_hesitant"]["of"] == "act" and smoke["stability"]["repetitions"] == 2
    # The demo's weaker policies are act's own weights earlier in its training; each line-up's
    # planted order names its own.
    assert set(demo["policies"]) == {"act", "act_short", "act_weak"}
    assert demo["report"]["judge_audit"]["planted_order"] == ["act", "act_short", "act_weak"]
    assert {demo["policies"][p]["of"] for p in ("act_short", "act_weak")} == {"act"}
    assert demo["policies"]["act_weak"]["step"] < demo["policies"]["act_short"]["step"] < demo["policies"]["act"]["steps"]
    # The seven-task demo keeps its three trainings, as they were measured.
    seven = compose_config(CONF, "demo_seven")["policies"]
    assert {p["type"] for p in seven.values()} == {"act"}
    assert seven["act_weak"]["steps"] < seven["act_short"]["steps"] < seven["act"]["steps"]
    assert set(compose_config(CONF, "paper")["policies"]) == {"pi0", "pi05", "smolvla", "xvla"}
    assert smoke["policies"]["act_weak"]["steps"] < smoke["policies"]["act"]["steps"]
    assert "experiment" not in smoke
    # Both offline judges in smoke and demo; the demo audits order swaps on a share of pairs.
    assert set(smoke["judges"]) == set(demo["judges"]) == {"kinematic", "video"}
    assert all(0 < j["swap_share"] < 1 for j in demo["judges"].values())


@pytest.mark.parametrize("entry, where, says", [
    ("{type:snapshot,of:act,step:700}", "policies.late.step", "must be below act's steps (700)"),
    ("{type:snapshot,of:act_short,step:10}", "policies.late.of", "must name a candidate of this line-up trained here ['act']"),
    ("{type:snapshot,of:act,step:0}", "policies.late.step", "must be in [1, inf], got 0"),
    ("{type:snapshot,of:act,step:10,steps:20}", "policies.late", "unknown key(s) ['steps']"),
])
def test_a_snapshot_outside_its_training_is_refused_naming_the_key(entry, where, says):
    with pytest.raises(ConfigError) as err:
        compose_config(CONF, "demo", [f"+policies.late={entry}"])
    assert where in str(err.value) and says in str(err.value), str(err.value)


def test_overrides_and_slices():
    cfg = compose_config(CONF, "smoke", ["stats.n_boot=17"])
    assert select(cfg, "stats")["stats"]["n_boot"] == 17
    assert list(select(cfg, "stats", "seed")) == ["seed", "stats"]
    with pytest.raises(ConfigError, match="no field 'stats.nope'"):
        select(cfg, "stats.nope")
    assert to_json({"b": 1, "a": {"d": 2, "c": 3}}) == '{"a":{"c":3,"d":2},"b":1}'


def test_atomic_writes_leave_nothing_on_failure(tmp_path):
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "x.json") as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    with pytest.raises(RuntimeError):
        with atomic_dir(tmp_path / "d") as tmp:
            (tmp / "f").write_text("half")
            raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []
    write_json(tmp_path / "y.json", {"a": 1})
    assert read_json(tmp_path / "y.json") == {"a": 1}


def test_mtimes_round_trip(tmp_path):
    folder = tmp_path / "results" / "train"
    (folder / "m").mkdir(parents=True)
    (folder / "m" / "w.bin").write_bytes(b"1")
    recorded = record_mtimes(tmp_path, [folder])
    for path in [folder, folder / "m", folder / "m" / "w.bin"]:
        os.utime(path, ns=(1, 1))
    assert restore_mtimes(tmp_path, recorded) == 3
    assert record_mtimes(tmp_path, [folder]) == recorded


def test_candidates_take_their_types_defaults_and_name_unknown_ones():
    # conf/policies writes only what differs from a type's defaults; validation fills in the rest.
    demo = candidate_configs("demo")
    assert {cfg["chunk_size"] for cfg in demo.values() if cfg["type"] != "snapshot"} == {25}
    assert candidate_config("act", "demo", batch_size=8)["batch_size"] == 8
    paper = candidate_configs("paper")
    assert {cfg["scheduler"] for cfg in paper.values()} == {"cosine"}
    with pytest.raises(ConfigError, match="unknown candidate policy 'nope'"):
        candidate_config("nope", "demo")
    with pytest.raises(ConfigError, match="'act_short' of experiment 'demo' is a snapshot"):
        candidate_config("act_short", "demo")

