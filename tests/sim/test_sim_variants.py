"""The sims a fidelity experiment crosses the checkpoints into besides the calibrated one
(``r2s_eval.sim.params.sim_variant``, the sim_variant stage), and the twin with one reality effect
alone (``r2s_eval.twin.perturb.reality_alone``, the twin_alone stage)."""

import argparse
import dataclasses
import json

import numpy as np
import pytest

from r2s_eval.errors import ConfigError, DataError
from r2s_eval.sim import WorldParams, load_world_params
from r2s_eval.sim.params import ANSWERS, SIM_VARIANTS, sim_variant
from r2s_eval.stages import sim_variant as sim_variant_stage
from r2s_eval.stages import twin_alone
from r2s_eval.twin.camera import C920_RATIONAL
from r2s_eval.twin.perturb import NO_EFFECT, REALITY_FAMILIES, reality_alone, reality_rng
from r2s_eval.twin.reality import RealityEffects, load_reality_effects
from tests.helpers.worlds import bundled_reality, bundled_twin
from tests.sim.test_sim_twin_reality import LAB

# A calibrated sim with every answer and a camera pose of its own.
CALIBRATED = WorldParams(camera_pos_offset_m={"head_left": (0.01, 0.0, -0.02)}, light_intensity_scale=0.9,
                         lens_distortion={"head_left": tuple(C920_RATIONAL[:5])}, command_latency_steps=1,
                         background_plates={"head_left": "results/calib/background/head_left.png"},
                         background_states=((0.1,) * 14, (0.2,) * 14), background_margin_px=3, shadows=True)


def test_each_variant_takes_away_exactly_its_answers():
    assert sim_variant(CALIBRATED, "nominal") == WorldParams()
    nominal = WorldParams()
    today = sim_variant(CALIBRATED, "without_answers")
    assert today == dataclasses.replace(CALIBRATED, lens_distortion={}, command_latency_steps=0, background_plates={},
                                        background_states=(), background_margin_px=2, shadows=False)
    for answer, fields in ANSWERS.items():
        variant = sim_variant(CALIBRATED, f"without_{answer}")
        changed = {f.name for f in dataclasses.fields(WorldParams) if getattr(variant, f.name) != getattr(CALIBRATED, f.name)}
        assert changed == set(fields)
        assert all(getattr(variant, f) == getattr(nominal, f) for f in fields)
    # The camera poses stay as the calibration fitted them.
    assert today.camera_pos_offset_m == CALIBRATED.camera_pos_offset_m
    assert set(SIM_VARIANTS) == {"nominal", "without_answers", *(f"without_{a}" for a in ANSWERS)}
    with pytest.raises(ValueError, match="unknown sim variant 'without_focus'"):
        sim_variant(CALIBRATED, "without_focus")


def test_the_stage_writes_a_sims_file(tmp_path):
    calibrated = tmp_path / "world_params.json"
    calibrated.write_text(json.dumps({"params": dataclasses.asdict(CALIBRATED)}))
    out = tmp_path / "without_lens.json"
    sim_variant_stage.main(argparse.Namespace(cfg={"sim": "without_lens"}, calibrated=str(calibrated), out=str(out)))
    assert load_world_params(out) == sim_variant(CALIBRATED, "without_lens")
    assert load_reality_effects(out) is None  # a sim: no reality effects
    assert json.loads(out.read_text())["sim"] == "without_lens"


def test_the_twin_with_one_effect_alone_keeps_its_parameters_and_that_effect_only(tmp_path):
    twin = bundled_twin(np.random.default_rng(3))
    reality = bundled_reality(reality_rng(3), LAB)
    assert reality_alone(reality, NO_EFFECT) == RealityEffects()
    for family, fields in REALITY_FAMILIES.items():
        alone = reality_alone(reality, family)
        for f in dataclasses.fields(RealityEffects):
            expected = getattr(reality, f.name) if f.name in fields else getattr(RealityEffects(), f.name)
            assert getattr(alone, f.name) == expected, (family, f.name)
    with pytest.raises(ConfigError, match="unknown reality effect 'joints'"):
        reality_alone(reality, "joints")  # a parameter family, not an effect

    twin_file = tmp_path / "twin_params.json"
    twin_file.write_text(json.dumps({"params": dataclasses.asdict(twin), "reality": dataclasses.asdict(reality)}))
    out = tmp_path / "latency.json"
    twin_alone.main(argparse.Namespace(cfg={"effect": "latency"}, twin=str(twin_file), out=str(out)))
    assert load_world_params(out) == twin
    assert load_reality_effects(out) == RealityEffects(latency_s=reality.latency_s)
    assert json.loads(out.read_text())["alone"] == "latency"

    # A twin without reality effects has none to take alone: one line naming its file.
    plain = tmp_path / "plain_twin.json"
    plain.write_text(json.dumps({"params": dataclasses.asdict(twin)}))
    with pytest.raises(DataError, match=r"plain_twin.json: this twin has no reality effects"):
        twin_alone.main(argparse.Namespace(cfg={"effect": "lens"}, twin=str(plain), out=str(tmp_path / "x.json")))
