"""The twin's reality effects as a record (``r2s_eval.twin.reality``): drawn from their own stream so
the world parameters of a seed are what they were, written beside them in the twin's file and read
back, taken away family by family for the fidelity ablation, and built around the environment
wherever the twin plays the robot; the calibrated sim's file never carries them."""

import argparse
import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from r2s_eval.config import compose_config
from r2s_eval.errors import ConfigError
from r2s_eval.sim import TabletopEnv, WorldParams, load_world_params
from r2s_eval.stages import twin_ablation
from r2s_eval.twin import TwinMagnitudes, twin_world
from r2s_eval.twin.camera import C920_RATIONAL
from r2s_eval.twin.perturb import (ALL_FAMILIES, PERTURBATION_FAMILIES, REALITY_FAMILIES, reality_rng,
                                   reality_without_family, without_family)
from r2s_eval.twin.reality import RealityEffects, RealityEnv, load_reality_effects, make_world_env
from tests.helpers.commands import POSES
from tests.helpers.worlds import bundled_reality, bundled_robot, bundled_twin, bundled_world

CONF = Path(__file__).resolve().parents[2] / "conf"
# A lab's hardware at the reference magnitudes (r2s_eval.twin.perturb's module docstring).
LAB = TwinMagnitudes(lens_distortion=C920_RATIONAL, lens_spread_rel=0.1, exposure_drift_rel_max=0.05,
                     white_balance_drift_rel_max=0.03, exposure_time_s_max=0.02, shot_noise_var_per_level_max=0.05,
                     latency_s_range=(0.1, 0.2), backlash_rad=float(np.deg2rad(1.0)), gripper_weakness_rel=0.5)

# sha256 of the JSON (sorted keys) of the twin stage's ``params`` for the bundled world, default
# magnitudes, as the code before the reality effects drew them (its fields: all but the two
# answers below, which it did not have).
PARAMS_BEFORE = {2: "c69831e27d1e027851cedb0597eae5b05ef44f412ccb6501116cf7bedfcbbdf7",
                 7: "ba5fbc7e1076a38a84965782a5f59b28880cb8a061c0ef42e0ed03550b96c005",
                 11: "9d4f816efcb8c9d9af401cb26bacd039c5a05a40a7aba96bd11b39b570e5a0c0"}
# The calibrated sim's answers, nominal in a twin.
ANSWER_FIELDS = ("lens_distortion", "command_latency_steps", "background_plates", "background_states",
                 "background_margin_px", "shadows")


def _twin_record(seed: int, magnitudes: dict | None = None) -> dict:
    world = bundled_world()
    return twin_world({"seed": seed, "magnitudes": magnitudes or {}}, world["objects"], bundled_robot())


def _digest(params: dict) -> str:
    return hashlib.sha256(json.dumps(params, sort_keys=True).encode()).hexdigest()


# ----------------------------------------------------------------------------- the draw


@pytest.mark.parametrize("seed", sorted(PARAMS_BEFORE))
def test_the_twins_world_parameters_are_todays_and_its_reality_is_off_by_default(seed):
    record = _twin_record(seed)
    params = dict(record["params"])
    assert {k: params.pop(k) for k in ANSWER_FIELDS} == {"lens_distortion": {}, "command_latency_steps": 0,
                                                         "background_plates": {}, "background_states": (),
                                                         "background_margin_px": 2,
                                                         "shadows": False}
    assert _digest(params) == PARAMS_BEFORE[seed]
    assert record["reality"] == dataclasses.asdict(RealityEffects())
    # Every reality magnitude at a lab's reference moves no world parameter.
    lab = _twin_record(seed, {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(LAB).items()})
    assert lab["params"] == record["params"]


def test_the_reality_effects_are_seeded_bounded_and_near_their_references():
    reality = bundled_reality(reality_rng(7), LAB)
    assert reality == bundled_reality(reality_rng(7), LAB) and reality != bundled_reality(reality_rng(8), LAB)
    assert set(reality.lens_distortion) == set(bundled_robot().camera_names)
    for coefficients in reality.lens_distortion.values():
        assert len(coefficients) == 8
        for c, reference in zip(coefficients, C920_RATIONAL):
            assert abs(c - reference) <= 0.1 * abs(reference) + 1e-12
    assert len(set(reality.lens_distortion.values())) == len(reality.lens_distortion)  # each unit its own lens
    assert 0 < reality.exposure_drift_rel <= 0.05 and 0 < reality.white_balance_drift_rel <= 0.03
    assert 0 < reality.exposure_time_s <= 0.02 and 0 < reality.shot_noise_var_per_level <= 0.05
    assert 0.1 <= reality.latency_s <= 0.2 and 0 < reality.backlash_rad <= np.deg2rad(1.0)
    assert 0.5 <= reality.gripper_strength_scale <= 1.0
    # One magnitude moves only its own effect's draw.
    no_blur = bundled_reality(reality_rng(7), dataclasses.replace(LAB, exposure_time_s_max=0.0))
    assert dataclasses.replace(no_blur, exposure_time_s=reality.exposure_time_s) == reality
    assert bundled_reality(reality_rng(7), LAB.scaled(0.0)) == RealityEffects()


def test_the_magnitudes_scale_entry_by_entry_and_refuse_a_wrong_lens_or_latency_range():
    half = LAB.scaled(0.5)
    assert half.lens_distortion == pytest.approx(tuple(0.5 * c for c in C920_RATIONAL))
    assert half.latency_s_range == pytest.approx((0.05, 0.1)) and half.exposure_time_s_max == pytest.approx(0.01)
    with pytest.raises(ConfigError, match="eight coefficients"):
        TwinMagnitudes(lens_distortion=(0.1, 0.2, 0.0, 0.0, 0.1))
    with pytest.raises(ConfigError, match="latency_s_range"):
        TwinMagnitudes(latency_s_range=(0.2, 0.1))
    # The config takes them as lists (real.twin.magnitudes, schema from the dataclass's fields).
    cfg = compose_config(CONF, "smoke", ["+real.twin.magnitudes.latency_s_range=[0.1,0.2]",
                                         "+real.twin.magnitudes.backlash_rad=0.017"])
    assert TwinMagnitudes(**cfg["real"]["twin"]["magnitudes"]).latency_s_range == (0.1, 0.2)


# ----------------------------------------------------------------------------- the file


def test_the_twins_file_round_trips_its_parameters_and_reality(tmp_path):
    record = _twin_record(2, {"latency_s_range": [0.1, 0.2], "lens_distortion": list(C920_RATIONAL),
                              "lens_spread_rel": 0.1, "exposure_time_s_max": 0.02})
    path = tmp_path / "twin_params.json"
    path.write_text(json.dumps(record))
    params, reality = load_world_params(path), load_reality_effects(path)
    assert dataclasses.asdict(params) == record["params"]
    assert reality == bundled_reality(reality_rng(2), TwinMagnitudes(
        latency_s_range=(0.1, 0.2), lens_distortion=C920_RATIONAL, lens_spread_rel=0.1, exposure_time_s_max=0.02))
    assert all(isinstance(c, tuple) for c in reality.lens_distortion.values())
    assert 0.1 <= reality.latency_s <= 0.2
    # The calibrated sim's file holds no reality record.
    sim = tmp_path / "world_params.json"
    sim.write_text(json.dumps({"params": dataclasses.asdict(WorldParams(command_latency_steps=1))}))
    assert load_reality_effects(sim) is None


# ----------------------------------------------------------------------------- families


def test_every_field_belongs_to_one_family_and_the_new_families_take_the_twins_effects_away(tmp_path):
    reality_fields = [f for names in REALITY_FAMILIES.values() for f in names]
    assert sorted(reality_fields) == sorted(f.name for f in dataclasses.fields(RealityEffects))
    assert set(REALITY_FAMILIES) <= set(PERTURBATION_FAMILIES)
    assert {"lens", "exposure", "blur", "sensor_noise", "latency", "backlash", "gripper"} <= set(REALITY_FAMILIES)

    twin = bundled_twin(np.random.default_rng(3))
    reality = bundled_reality(reality_rng(3), LAB)
    sim = WorldParams(lens_distortion={"head_left": C920_RATIONAL[:5]}, command_latency_steps=1)
    for family, fields in REALITY_FAMILIES.items():
        without = reality_without_family(reality, family)
        assert all(getattr(without, f) == getattr(RealityEffects(), f) for f in fields)
        assert dataclasses.replace(without, **{f: getattr(reality, f) for f in fields}) == reality
    # Taken away, the twin runs on the calibrated sim's answer where it has one.
    assert without_family(twin, sim, "lens").lens_distortion == sim.lens_distortion
    assert without_family(twin, sim, "latency").command_latency_steps == 1
    assert without_family(twin, sim, "blur") == twin
    assert reality_without_family(reality, ALL_FAMILIES) == RealityEffects()
    assert reality_without_family(reality, "joints") == reality
    with pytest.raises(ConfigError, match="unknown perturbation family 'focus'"):
        reality_without_family(reality, "focus")

    # The ablation stage carries the reality record through to the file the rollouts read.
    twin_file, sim_file = tmp_path / "twin_params.json", tmp_path / "world_params.json"
    twin_file.write_text(json.dumps({"params": dataclasses.asdict(twin), "reality": dataclasses.asdict(reality)}))
    sim_file.write_text(json.dumps({"params": dataclasses.asdict(sim)}))
    for family in ("latency", "camera"):
        out = tmp_path / f"{family}.json"
        twin_ablation.main(argparse.Namespace(cfg={"family": family}, twin=str(twin_file), sim=str(sim_file),
                                              out=str(out)))
        assert load_world_params(out) == without_family(twin, sim, family)
        assert load_reality_effects(out) == reality_without_family(reality, family)
        assert json.loads(out.read_text())["without"] == family


# ----------------------------------------------------------------------------- the environment


def test_a_file_with_reality_builds_the_twins_environment_and_the_sims_file_a_plain_one(tmp_path):
    world = {**bundled_world(), "cameras": []}
    late = RealityEffects(latency_s=0.2)
    twin_env = make_world_env("cup_on_plate", world, WorldParams(), late)
    sim_env = make_world_env("cup_on_plate", world, WorldParams(), None)
    assert isinstance(twin_env, RealityEnv) and twin_env.reality == late
    assert type(sim_env) is TabletopEnv
    for env in (twin_env, sim_env):
        env.reset(POSES, seed=0, observe=False)
    at_reset = twin_env.data.ctrl.copy()
    command = twin_env.state() + 0.1
    for env in (twin_env, sim_env):
        env.step(command, images=False)
        env.step(command, images=False)
    assert np.array_equal(twin_env.data.ctrl, at_reset)  # two steps late: nothing has arrived
    assert not np.array_equal(sim_env.data.ctrl, at_reset)
    for env in (twin_env, sim_env):
        env.close()


def test_the_teleop_recording_and_the_board_take_run_in_the_twins_environment(tmp_path, monkeypatch):
    from r2s_eval.twin import board_take, record

    built = []

    def spying(make):
        def build(*args, **kwargs):
            env = make(*args, **kwargs)
            built.append(env)
            return env
        return build

    reality = RealityEffects(latency_s=0.1, lens_distortion={"head_left": C920_RATIONAL})
    cfg = compose_config(CONF, "smoke")
    world = dict(cfg["world"], cameras=["head_left"], image_height=32, image_width=32)
    monkeypatch.setattr(record, "make_reality_env", spying(record.make_reality_env))
    record.record_teleop(str(tmp_path / "teleop"), WorldParams(), teleop=dict(cfg["teleop"], episodes_per_task=1),
                         world=world, tasks=["cup_on_plate"], suite=cfg["suite"], seed=0, reality=reality)
    monkeypatch.setattr(board_take, "RealityEnv", spying(board_take.RealityEnv))
    board = {"squares": [9, 7], "square_m": 0.04, "marker_m": 0.03, "dictionary": "DICT_5X5_100",
             "thickness_m": 0.003, "mount": "table", "pose": {"x_m": -0.03, "y_m": 0.0, "yaw_rad": 0.0}}
    take = {"frames": 2, "image_size": [48, 64], "joint_spread_rad": 0.3,
            "video": {"vcodec": "h264", "preset": "ultrafast", "crf": 12}}
    board_take.record_board_take(str(tmp_path / "take"), WorldParams(), take=take, board_cfg=board, world=world,
                                 tasks=["cup_on_plate"], seed=0, reality=reality)
    assert len(built) == 2 and all(isinstance(env, RealityEnv) and env.reality == reality for env in built)
