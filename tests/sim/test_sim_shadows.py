"""The calibrated sim's shadows (``WorldParams.shadows``, ``calib.appearance.shadows``): the key
light casts them in the sim's own renders, and over a background plate the sim darkens the plate
where its arm and objects shade the room (``TabletopEnv.shadow_shade``), never elsewhere."""

import dataclasses
import json

import cv2
import mujoco
import numpy as np
import pytest

from r2s_eval.calib.appearance import calibrate_appearance
from r2s_eval.calib.cameras import key_light_error_deg, score_calibration
from r2s_eval.errors import ConfigError
from r2s_eval.sim import WorldParams, load_world_params
from r2s_eval.sim.build import check_world_params
from r2s_eval.sim.render_params import SHADOW_MAP_PX, apply_shadows, key_light
from tests.helpers.commands import POSES
from tests.helpers.worlds import bundled_env, bundled_world

CAMERA = "head_left"
SIZE = (96, 96)


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    """A striped green room, unlike anything the sim draws."""
    image = np.full((*SIZE, 3), (90, 160, 90), np.uint8)
    image[::6] = (60, 120, 60)
    path = tmp_path_factory.mktemp("plates") / f"{CAMERA}.png"
    cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    return str(path), image


def _recorded(params: WorldParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The recorded image, the pinhole image and the foreground mask of CAMERA at the test poses."""
    env = bundled_env("cup_on_plate", params, image_size=SIZE)
    try:
        env.reset(POSES, seed=0, settle=False, observe=False)
        groups = env.model.geom_group.copy()
        image = env.render(CAMERA, add_noise=True)
        assert np.array_equal(env.model.geom_group, groups)  # the still scene's render put them back
        return image, env.render(CAMERA), env.foreground_mask(CAMERA, SIZE)
    finally:
        env.close()


def test_the_world_files_lights_cast_no_shadow_and_the_answer_makes_the_key_light_cast_them():
    plain, shaded = bundled_env("cup_on_plate"), bundled_env("cup_on_plate", WorldParams(shadows=True))
    try:
        assert not plain.model.light_castshadow.any() and plain.model.vis.quality.shadowsize == 0
        key = key_light(shaded.model.light_diffuse)
        assert shaded.model.light_castshadow.tolist() == [i == key for i in range(shaded.model.nlight)]
        assert shaded.model.vis.quality.shadowsize == SHADOW_MAP_PX
        for env in (plain, shaded):
            env.reset(POSES, seed=0, settle=False, observe=False)
        room = ~shaded.foreground_mask(CAMERA, SIZE)
        before, after = (e.render(CAMERA, SIZE).astype(int).sum(axis=-1) for e in (plain, shaded))
        darker = (after < before - 30) & room
        assert darker.sum() > 50  # the arms' and the objects' shadows on the table
        assert (after <= before + 3)[room].all()  # a shadow only darkens
    finally:
        plain.close()
        shaded.close()


def test_over_a_plate_the_sims_shadows_darken_the_plate_where_they_fall_and_nowhere_else(plate):
    path, image = plate
    flat, _, drawn = _recorded(WorldParams(background_plates={CAMERA: path}))
    shaded, pinhole, drawn_too = _recorded(WorldParams(background_plates={CAMERA: path}, shadows=True))
    assert np.array_equal(drawn, drawn_too)
    room = ~drawn
    assert np.array_equal(flat[room], image[room])  # without shadows the room is the plate
    dark = shaded.astype(int).sum(axis=-1) < image.astype(int).sum(axis=-1) - 30
    assert (dark & room).sum() > 50
    assert (shaded.astype(int) <= image.astype(int) + 1)[room].all()
    # The plate's own pattern is kept under a shadow: a shade, not a colour painted over it.
    stripes = np.zeros(SIZE, bool)
    stripes[::6] = True
    under = dark & room
    assert shaded[under & stripes].mean() < shaded[under & ~stripes].mean()
    # Where nothing shades the room the image is the plate, byte for byte, in most of it.
    assert np.mean(shaded[room & ~dark] == image[room & ~dark]) > 0.9


def _states(swing_rad: float) -> tuple[tuple[float, ...], ...]:
    """Recorded states of both arms at home, each first joint turned by ``swing_rad`` and by a few
    degrees more or less (a plate's frames): 0 is a robot that never left home."""
    robot = bundled_env("cup_on_plate").robot
    states = []
    for extra in (0.0, 0.05, -0.05):
        per_arm = {name: (q + np.r_[swing_rad + (extra if swing_rad else 0.0), np.zeros(len(q) - 1)], closing)
                   for name, (q, closing) in robot.home_targets().items()}
        states.append(tuple(robot.from_model(per_arm)))
    return tuple(states)


def test_a_plate_taken_while_the_arms_worked_lacks_their_shadows_at_home_and_the_sim_draws_them(plate):
    """The sim takes the median of its own room at the plate's recorded states: where the plate's
    frames show the arms at home, it holds their shadows there and the sim adds none; where they
    show the arms at work elsewhere, the arms at home cast shadows the plate lacks."""
    path, image = plate
    kept, _, drawn = _recorded(WorldParams(background_plates={CAMERA: path}, shadows=True,
                                           background_states=_states(0.0)))
    added, _, _ = _recorded(WorldParams(background_plates={CAMERA: path}, shadows=True,
                                        background_states=_states(0.8)))
    room = ~drawn
    darker = added.astype(int).sum(axis=-1) < kept.astype(int).sum(axis=-1) - 30
    assert (darker & room).sum() > 30  # the arms' shadows at home
    assert (added.astype(int) <= kept.astype(int) + 1)[room].all()  # and nothing brighter
    # States at home give what a plate without states is taken to hold: the robot at home.
    default, _, _ = _recorded(WorldParams(background_plates={CAMERA: path}, shadows=True))
    assert np.mean(np.abs(default.astype(int) - kept.astype(int))[room] <= 2) > 0.99


def _median_room(plate_path: str, margin_px: int) -> np.ndarray:
    params = WorldParams(background_plates={CAMERA: plate_path}, shadows=True, background_states=_states(0.8),
                         background_margin_px=margin_px)
    env = bundled_env("cup_on_plate", params, image_size=SIZE)
    try:
        return env.plate_shadows_image(CAMERA, SIZE)
    finally:
        env.close()


def test_the_sim_leaves_out_as_much_around_the_robot_as_the_plates_frames_did(plate, tmp_path):
    """``background_margin_px`` (calib.background.margin_px, in the plate's pixels) widens the
    robot in the sim's median of its own room as it widened it in the plate's frames: a plate
    twice the render's size counts twice the pixels for the same band."""
    path, image = plate
    large = tmp_path / f"{CAMERA}.png"
    cv2.imwrite(str(large), cv2.cvtColor(cv2.resize(image, (2 * SIZE[1], 2 * SIZE[0])), cv2.COLOR_RGB2BGR))
    same = _median_room(path, 2)
    assert np.array_equal(_median_room(str(large), 4), same)
    assert not np.array_equal(_median_room(path, 12), same)  # a wider band changes which frames count


def test_recorded_states_of_another_robot_are_refused(tmp_path):
    world = bundled_world()
    params = WorldParams(background_states=_states(0.8))
    path = tmp_path / "params.json"
    path.write_text(json.dumps({"params": dataclasses.asdict(params)}))
    assert load_world_params(path) == params  # the states come back as they went
    check_world_params(WorldParams(background_states=_states(0.8)), world, "params.json")
    with pytest.raises(ConfigError, match=r"params.json: background_states\[0\] has 3 values, a state of this "
                                          r"world has 14"):
        check_world_params(WorldParams(background_states=((0.0, 0.0, 0.0),)), world, "params.json")
    with pytest.raises(ConfigError, match=r"params.json: background_margin_px must be a whole number of pixels >= 0, "
                                          r"got -1"):
        check_world_params(WorldParams(background_margin_px=-1), world, "params.json")


def test_a_world_without_a_scene_light_cannot_have_the_answer():
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='0.1'/></worldbody></mujoco>")
    apply_shadows(model, WorldParams())  # off: nothing asked
    with pytest.raises(ConfigError, match=r"shadows: the world's model has no scene light .*calib.appearance.shadows"):
        apply_shadows(model, WorldParams(shadows=True))


def test_the_calibration_gives_the_answer_and_the_scoring_holds_it_against_the_twin():
    params, record = calibrate_appearance(None, "", None, "", bundled_world(), WorldParams(),
                                          {"fit": False, "shadows": True}, CAMERA)
    assert params.shadows and record == {"fitted": False, "shadows": True}
    world, tasks = bundled_world(), ["cup_on_plate"]
    assert key_light_error_deg(WorldParams(), WorldParams(), world, tasks) == 0.0
    moved = WorldParams(light_dir_offset=(0.1, 0.0, 0.0))
    assert 1.0 < key_light_error_deg(moved, WorldParams(), world, tasks) < 20.0
    calibrated = {"params": dataclasses.asdict(params), "appearance": record}
    scored = score_calibration({}, calibrated, moved, world, tasks, true_shadows=True)["appearance"]
    assert scored["shadows"] and scored["twin_shadows"]
    assert scored["key_light_deg"] == pytest.approx(key_light_error_deg(params, moved, world, tasks))
    assert "key_light_deg" not in score_calibration({}, calibrated, moved, world, tasks)["appearance"]
