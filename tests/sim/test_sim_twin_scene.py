"""The twin's room and its objects' true shapes (``r2s_eval.twin.scene``, built into the twin's model by
``RealityEnv``): off, the world's bytes; on, a wooden table, walls, shadows that follow an arm,
things on the table no task touches, a mug with a handle and blocks with rounded edges, which the
scripted operator still handles, while the calibrated sim keeps the world's plain scene."""

import dataclasses
import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

from r2s_eval.config import compose_config
from r2s_eval.errors import ConfigError
from r2s_eval.sim import TabletopEnv, WorldParams, get_task, load_world_params
from r2s_eval.twin import TwinMagnitudes, twin_world
from r2s_eval.twin.operator import EPISODE_S, make_operator
from r2s_eval.twin.perturb import (PERTURBATION_FAMILIES, REALITY_FAMILIES, reality_rng, reality_without_family,
                                   sample_twin_params)
from r2s_eval.twin.reality import RealityEffects, RealityEnv, load_reality_effects, make_world_env
from r2s_eval.twin.scene import DISTRACTORS, scene_adder
from tests.helpers.commands import POSES
from tests.helpers.worlds import bundled_env, bundled_reality, bundled_robot, bundled_twin_env, bundled_world

CONF = Path(__file__).resolve().parents[2] / "conf"
CAMERAS = ("head_left", "wrist_right")
IN_VIEW = (("marker", 0.26, 0.02, 0.5),)  # in the table's far strip, in the head cameras' view
ROOM = RealityEffects(table_texture=True, walls=True, shadows=True, distractors=IN_VIEW, cup_handle=True,
                      block_edge_radius_m=0.004)
SCENE_FAMILIES = {"table_texture": ("table_texture",), "walls": ("walls",), "shadows": ("shadows",),
                  "distractors": ("distractors",), "shapes": ("cup_handle", "block_edge_radius_m")}
SCENE_MAGNITUDES = dict(table_texture=True, walls=True, shadows=True, distractors=4, cup_handle=True,
                        block_edge_radius_m=0.004)


def _frames(env, poses=POSES) -> dict[str, np.ndarray]:
    env.reset(poses, seed=0, settle=False, observe=False)
    return {cam: env.render(cam) for cam in CAMERAS}


def _labels(env, camera="head_left") -> np.ndarray:
    return env.render(camera, segmentation=True)[0]


# ----------------------------------------------------------------------------- off: the world's bytes


def test_with_every_scene_effect_off_the_twin_is_the_worlds_model_and_bytes():
    world, twin = bundled_env("cup_on_plate"), bundled_twin_env("cup_on_plate", None, RealityEffects())
    try:
        assert scene_adder(RealityEffects(), bundled_robot(), world.task.objects, WorldParams()) is None
        for key in ("ngeom", "nbody", "ntex", "nmat", "nmesh"):
            assert getattr(twin.model, key) == getattr(world.model, key), key
        assert not twin.model.light_castshadow.any() and twin.model.vis.quality.shadowsize == 0
        for cam, image in _frames(twin).items():
            assert np.array_equal(image, _frames(world)[cam]), cam
    finally:
        world.close()
        twin.close()


@pytest.mark.parametrize("family", sorted(SCENE_FAMILIES))
def test_one_effect_taken_away_builds_the_twin_without_it(family):
    """The ablation's twin without a family renders the bytes of a twin that never had it."""
    without = reality_without_family(ROOM, family)
    assert all(getattr(without, f) == getattr(RealityEffects(), f) for f in SCENE_FAMILIES[family])
    built = bundled_twin_env("cup_on_plate", None, dataclasses.replace(ROOM, **{
        f: getattr(RealityEffects(), f) for f in SCENE_FAMILIES[family]}))
    ablated = bundled_twin_env("cup_on_plate", None, without)
    try:
        for cam, image in _frames(ablated).items():
            assert np.array_equal(image, _frames(built)[cam]), cam
    finally:
        built.close()
        ablated.close()


# ----------------------------------------------------------------------------- on: the room


def test_the_table_texture_grains_the_table_and_leaves_the_rest():
    plain, wooden = bundled_twin_env("cup_on_plate"), bundled_twin_env("cup_on_plate", None,
                                                                        RealityEffects(table_texture=True))
    try:
        before, after = _frames(plain)["head_left"].astype(float), _frames(wooden)["head_left"].astype(float)
        table = _labels(plain) == 1
        assert np.array_equal(table, _labels(wooden) == 1)
        assert np.array_equal(before[~table], after[~table])  # objects, arms and floor as they were
        luma_before, luma_after = before[table].mean(-1), after[table].mean(-1)
        assert luma_after.std() > 3 * luma_before.std() + 2  # the grain
        assert 0.75 * luma_before.mean() < luma_after.mean() < luma_before.mean()  # tinted, a little darker
    finally:
        plain.close()
        wooden.close()


def test_the_walls_stand_round_the_table_out_of_reach_and_leave_the_cameras_near_plane():
    room = bundled_twin_env("cup_on_plate", None, RealityEffects(walls=True))
    plain = bundled_twin_env("cup_on_plate")
    try:
        walls = [room.model.geom(f"room_wall_{side}") for side in ("far", "near", "left", "right")]
        assert all(room.model.geom_contype[g.id] == 0 and room.model.geom_conaffinity[g.id] == 0 for g in walls)
        assert room.model.ntex == plain.model.ntex + 3  # plaster, floor covering, photograph
        # Their extent would push the cameras' near plane out (it scales with the model's extent).
        assert room.model.stat.extent == plain.model.stat.extent
        # Looking up from the table, a wrist camera sees a wall where the world shows empty space.
        room.reset(POSES, seed=0, settle=False, observe=False)
        plain.reset(POSES, seed=0, settle=False, observe=False)
        state = room.state()
        state[8] = -1.0  # the right arm's shoulder back: its wrist camera looks up and across the room
        for env in (room, plain):
            env.pose_robot(state)
        seen = {int(g) for g in np.unique(room.render_geoms("wrist_right")) if g >= 0}
        assert seen & {g.id for g in walls} or room.model.geom("room_poster").id in seen
        assert not np.array_equal(room.render("wrist_right"), plain.render("wrist_right"))
    finally:
        room.close()
        plain.close()


def test_the_key_light_casts_an_arms_shadow_on_the_table_that_follows_it():
    def table_pixels(env):
        env.reset(POSES, seed=0, settle=False, observe=False)
        home = env.state().copy()
        shots = []
        for turn in (0.0, 0.5):  # the right arm's base turned: its shadow moves on the table
            state = home.copy()
            state[7] += turn
            env.pose_robot(state)
            shots.append((env.render("head_left").astype(int), _labels(env) == 1))
        return shots

    plain, shaded = bundled_twin_env("cup_on_plate"), bundled_twin_env("cup_on_plate", None,
                                                                        RealityEffects(shadows=True))
    try:
        (plain_a, table_a), (plain_b, table_b) = table_pixels(plain)
        (shaded_a, _), (shaded_b, _) = table_pixels(shaded)
        table = table_a & table_b  # table in both poses: the arm covers neither
        assert np.array_equal(plain_a[table], plain_b[table])  # no shadows: the arm leaves it as it was
        for plain_image, shaded_image in ((plain_a, shaded_a), (plain_b, shaded_b)):
            darkening = (plain_image - shaded_image)[table]
            # Shadows only darken (the lit pixels within a level: the shadow pass's shader rounds).
            assert darkening.min() >= -1 and (darkening.sum(-1) > 45).sum() > 50
        moved = (shaded_b - shaded_a)[table].sum(-1)
        assert (moved < -45).sum() > 50 and (moved > 45).sum() > 50  # fallen here, lifted there
    finally:
        plain.close()
        shaded.close()


def test_a_distractor_lies_in_the_head_cameras_view_collides_as_the_table_and_keeps_out_of_start_regions():
    twin = bundled_twin_env("cup_on_plate", None, RealityEffects(distractors=IN_VIEW))
    plain = bundled_twin_env("cup_on_plate")
    try:
        geoms = [i for i in range(twin.model.ngeom) if twin.model.geom(i).name.startswith("room_distractor0_marker")]
        table = twin.model.geom(twin.robot.table_geom).id
        assert len(geoms) == 2 and all(twin.model.body_dofnum[twin.model.geom_bodyid[g]] == 0 for g in geoms)
        for g in geoms:
            assert (twin.model.geom_contype[g], twin.model.geom_conaffinity[g]) == (
                twin.model.geom_contype[table], twin.model.geom_conaffinity[table])
        twin.reset(POSES, seed=0, settle=False, observe=False)
        plain.reset(POSES, seed=0, settle=False, observe=False)
        drawn = np.isin(twin.render_geoms("head_left"), geoms)
        assert drawn.sum() > 10
        changed = np.any(twin.render("head_left") != plain.render("head_left"), axis=-1)
        assert changed[drawn].all() and not changed[~drawn].any()
        assert np.all(_labels(twin)[drawn] == 0)  # background to the segmentation, as the room is
    finally:
        twin.close()
        plain.close()
    with pytest.raises(ConfigError, match="start region of cup"):
        bundled_twin_env("cup_on_plate", None, RealityEffects(distractors=(("phone", 0.0, 0.0, 0.0),)))
    with pytest.raises(ConfigError, match="unknown distractor 'lamp'"):
        bundled_twin_env("cup_on_plate", None, RealityEffects(distractors=(("lamp", 0.3, 0.0, 0.0),)))


def test_drawn_distractors_lie_in_the_far_strip_apart_and_clear_of_every_tasks_start_region():
    world = bundled_world()
    for seed in range(5):
        reality = bundled_reality(reality_rng(seed), TwinMagnitudes(distractors=len(DISTRACTORS)))
        assert [kind for kind, *_ in reality.distractors] == list(DISTRACTORS)
        for kind, x, y, _ in reality.distractors:
            assert 0.19 <= x - DISTRACTORS[kind].footprint_radius_m and x + DISTRACTORS[kind].footprint_radius_m <= 0.45
        for i, (a, xa, ya, _) in enumerate(reality.distractors):
            for b, xb, yb, _ in reality.distractors[i + 1:]:
                apart = DISTRACTORS[a].footprint_radius_m + DISTRACTORS[b].footprint_radius_m
                assert np.hypot(xa - xb, ya - yb) > apart
        for task in world["tasks"]:  # every task's twin builds with them (none in a start region)
            RealityEnv(get_task(task, world), None, reality, cameras=(), robot=bundled_robot()).close()


# ----------------------------------------------------------------------------- on: the true shapes


def test_the_twins_cup_is_a_mug_and_its_blocks_are_rounded_with_the_worlds_masses_and_frames():
    params = dataclasses.replace(WorldParams(), object_rgb_offset={"cup": (0.05, 0.0, 0.0)},
                                 object_mass_scale={"block_a": 1.1}, object_size_scale={"block_a": 1.02})
    for task, names in (("cup_on_plate", ("cup",)), ("stack_blocks", ("block_a", "block_b"))):
        world = bundled_env(task, params, cameras=())
        twin = bundled_twin_env(task, params, ROOM, cameras=())
        try:
            for name in names:
                body_w, body_t = world.model.body(name).id, twin.model.body(name).id
                assert twin.model.body_mass[body_t] == pytest.approx(world.model.body_mass[body_w], rel=1e-9)
                geoms_t = np.flatnonzero(twin.model.geom_bodyid == body_t)
                # Every geom in the object's (offset) colour: the calibration's colours and the
                # segmentation treat them as the object.
                assert np.allclose(twin.model.geom_rgba[geoms_t], world.model.geom_rgba[world.model.geom_bodyid
                                                                                         == body_w][0])
            twin.reset(seed=3)
            world.reset(seed=3)
            for name in names:  # the same frames: the same reset poses
                assert np.allclose(twin.object_poses()[name]["planar"], world.object_poses()[name]["planar"],
                                   atol=2e-3)
        finally:
            world.close()
            twin.close()
    mug = bundled_twin_env("cup_on_plate", None, ROOM, cameras=())
    plain = bundled_env("cup_on_plate", cameras=())
    try:
        assert {f"cup_handle_{p}" for p in ("lower", "upper", "grip")} <= {mug.model.geom(i).name
                                                                          for i in range(mug.model.ngeom)}
        with pytest.raises(KeyError):
            plain.model.geom("cup_handle_grip")
    finally:
        mug.close()
        plain.close()
    blocks = bundled_twin_env("stack_blocks", None, ROOM, cameras=())
    try:
        # A cube of the world's size: its geoms' outer faces at +-half the edge, its top at the edge.
        model, body = blocks.model, blocks.model.body("block_a").id
        mujoco.mj_forward(model, blocks.data)
        spec = blocks.task.object("block_a")
        half = spec.dims["size_m"] / 2
        geoms = np.flatnonzero(model.geom_bodyid == body)
        assert len(geoms) == 15
        boxes = [g for g in geoms if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX]
        assert sorted(np.round(np.max(model.geom_size[boxes], axis=1), 6)) == [round(half, 6)] * 3
        assert np.allclose(model.geom_pos[geoms][:, 2].mean(), half)
    finally:
        blocks.close()
    with pytest.raises(ConfigError, match="block_edge_radius_m"):
        bundled_twin_env("stack_blocks", None, RealityEffects(block_edge_radius_m=0.03), cameras=())


def _episode(task: str, i: int, reality: RealityEffects) -> tuple[bool, bool]:
    """A scripted episode in a perturbed twin; (success, whether the gripper touched a handle)."""
    world, robot = bundled_world(), bundled_robot()
    spec = get_task(task, world)
    params = sample_twin_params(np.random.default_rng([0, i, 1]), object_names=spec.object_names, robot=robot)
    env = RealityEnv(spec, params, reality, cameras=(), robot=robot)
    try:
        obs = env.reset(seed=i)
        handle = {i for i in range(env.model.ngeom) if "_handle_" in env.model.geom(i).name}
        robot_geoms = set(np.flatnonzero(env.geom_is_robot))
        operator = make_operator(spec, env, np.random.default_rng([0, i, 2]))
        touched = False
        for _ in range(round(EPISODE_S * robot.control_hz)):
            action = operator.act(obs)
            if operator.done:
                break
            obs = env.step(action, images=False)
            touched |= any({c.geom1, c.geom2} & handle and {c.geom1, c.geom2} & robot_geoms
                           for c in env.data.contact[:env.data.ncon])
        return operator.failure() is None, touched
    finally:
        env.close()


def test_the_operator_turns_its_jaws_from_the_mugs_handle_and_places_the_mug_and_stacks_rounded_blocks(monkeypatch):
    mug = RealityEffects(cup_handle=True)
    # Episodes whose cup stands with its handle across the arm's natural jaws.
    for i in (1, 2):
        assert _episode("cup_on_plate", i, mug) == (True, False)
    for i in (0, 1):
        assert _episode("stack_blocks", i, RealityEffects(block_edge_radius_m=0.004))[0]
    # An operator blind to the handle closes its jaws on it there.
    from r2s_eval.twin.operator import ScriptedOperator

    monkeypatch.setattr(ScriptedOperator, "_protrusion", lambda self, name, xy: [])
    assert _episode("cup_on_plate", 1, mug)[1]


# ----------------------------------------------------------------------------- the record


def test_the_scene_magnitudes_draw_the_room_round_trip_the_record_and_the_sim_never_has_it(tmp_path):
    cfg = compose_config(CONF, "smoke", ["+real.twin.magnitudes.walls=true", "+real.twin.magnitudes.distractors=3",
                                         "+real.twin.magnitudes.block_edge_radius_m=0.004"])
    magnitudes = TwinMagnitudes(**cfg["real"]["twin"]["magnitudes"])
    assert magnitudes.walls is True and magnitudes.distractors == 3
    record = twin_world({"seed": 2, "magnitudes": SCENE_MAGNITUDES}, bundled_world()["objects"], bundled_robot())
    assert record["params"] == twin_world({"seed": 2}, bundled_world()["objects"], bundled_robot())["params"]
    path = tmp_path / "twin_params.json"
    path.write_text(json.dumps(record))
    reality = load_reality_effects(path)
    assert reality == bundled_reality(reality_rng(2), TwinMagnitudes(**SCENE_MAGNITUDES))
    assert reality.table_texture and reality.walls and reality.shadows and reality.cup_handle
    assert 0 < reality.block_edge_radius_m <= 0.004 and len(reality.distractors) == 4
    assert all(isinstance(d, tuple) for d in reality.distractors)
    # One magnitude moves only its own effect; scaled to nothing, the room is gone.
    fewer = bundled_reality(reality_rng(2), TwinMagnitudes(**{**SCENE_MAGNITUDES, "distractors": 2}))
    assert fewer == dataclasses.replace(reality, distractors=reality.distractors[:2])
    assert bundled_reality(reality_rng(2), TwinMagnitudes(**SCENE_MAGNITUDES).scaled(0.0)) == RealityEffects()
    for family, fields in SCENE_FAMILIES.items():
        # Taken away, the twin's shadows are the sim's answer's (WorldParams.shadows); the rest has none.
        assert REALITY_FAMILIES[family] == fields and PERTURBATION_FAMILIES[family] == (
            ("shadows",) if family == "shadows" else ())
        assert reality_without_family(reality, family) == dataclasses.replace(
            reality, **{f: getattr(RealityEffects(), f) for f in fields})
    # The calibrated sim is built from world parameters alone: none of the room's textures or geoms.
    world = {**bundled_world(), "cameras": []}
    sim = make_world_env("cup_on_plate", world, load_world_params(path), None)
    twin = make_world_env("cup_on_plate", world, load_world_params(path), reality)
    try:
        assert type(sim) is TabletopEnv and isinstance(twin, RealityEnv)
        assert sim.model.ntex == 0 and twin.model.ntex == 4
        assert not any(sim.model.geom(i).name.startswith("room_") for i in range(sim.model.ngeom))
    finally:
        sim.close()
        twin.close()
