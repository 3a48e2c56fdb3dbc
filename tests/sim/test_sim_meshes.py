"""Scanned objects as world data: a mesh file, its texture, and convex parts that let a concave
object hold things."""

from __future__ import annotations

import copy
import re

import numpy as np
import pytest
import trimesh

from r2s_eval.sim import TabletopEnv, world_robot
from r2s_eval.sim.reading import WorldError
from r2s_eval.sim.assembly import load_world
from r2s_eval.sim.tasks import load_tasks
from r2s_eval.twin.operator import make_operator, run_episode
from tests.helpers.worlds import bundled_world

# CoACD settings that decompose the tray in seconds (its defaults take tens of seconds).
FAST_COACD = {"threshold": 0.1, "preprocess_resolution": 20, "resolution": 500, "mcts_iterations": 30,
              "mcts_nodes": 10}


@pytest.fixture(scope="module")
def tray_file(tmp_path_factory):
    """A tray as a scan gives it: millimetres, one triangle soup of a floor and four walls."""
    L, W, H, t = 160.0, 130.0, 45.0, 6.0
    box = trimesh.creation.box
    move = trimesh.transformations.translation_matrix
    parts = [box([L, W, t], move([0, 0, t / 2]))]
    parts += [box([t, W, H], move([sx * (L - t) / 2, 0, H / 2])) for sx in (-1, 1)]
    parts += [box([L, t, H], move([0, sy * (W - t) / 2, H / 2])) for sy in (-1, 1)]
    path = tmp_path_factory.mktemp("scans") / "tray.obj"
    trimesh.util.concatenate(parts).export(path)
    return path


def _world(tray_file, collision) -> dict:
    world = copy.deepcopy(bundled_world())
    world["cameras"] = ["head_left"]
    world["objects"]["tray"] = {"kind": "mesh", "rgba": [0.1, 0.3, 0.85, 1.0], "mass_kg": 0.3,
                                "mesh": {"file": str(tray_file), "scale": 0.001}, "collision": collision,
                                "yaw_symmetry": 2}
    world["tasks"]["ball_in_tray"] = {
        "instruction": "Put the Ball in the Tray",
        "start": {"ball": {"x_range_m": [-0.05, 0.0], "y_range_m": [-0.16, -0.12]},
                  "tray": {"x_range_m": [-0.05, 0.0], "y_range_m": [0.04, 0.08]}},
        "plan": [{"pick": "ball"}, {"place_in": "tray"}], "arm": "right",
        "success": {"all": [{"inside": {"object": "ball", "container": "tray"}}, {"released": {"object": "ball"}}]},
        "progress": {"objects": ["ball"], "goal": {"over": {"object": "ball", "target": "tray"}}},
    }
    return world


def _demonstrate(world: dict) -> tuple[bool, float]:
    _, tasks = load_world(world)
    env = TabletopEnv(tasks["ball_in_tray"], cameras=(), robot=world_robot(world))
    rng = np.random.default_rng(0)
    obs = env.reset(env.sample_initial_poses(rng), seed=0)
    run_episode(env, make_operator("ball_in_tray", env, rng), 120, obs)
    above_floor = env.object_state("ball")["pos_world_m"][2] - env.object_state("tray")["pos_world_m"][2]
    success = env.is_success()
    env.close()
    return success, float(above_floor)


def test_a_concave_scan_holds_a_ball_with_its_convex_parts_not_with_its_hull(tray_file, tmp_path, monkeypatch):
    monkeypatch.setenv("R2S_EVAL_CACHE", str(tmp_path / "cache"))
    hull = _world(tray_file, "hull")
    tray = load_tasks(hull)["ball_in_tray"].object("tray")
    assert tray.dims == pytest.approx({"half_x_m": 0.08, "half_y_m": 0.065, "height_m": 0.045})
    assert tray.shape.vertices[:, 2].min() == pytest.approx(0.0) and tray.shape.parts == ()
    success, above_floor = _demonstrate(hull)
    assert not success and above_floor == pytest.approx(0.045, abs=0.005)  # the ball lies on the hull's lid

    parted = _world(tray_file, {"coacd": FAST_COACD})
    success, above_floor = _demonstrate(parted)
    assert success and above_floor < 0.02  # it dropped in, onto the floor
    cached = list((tmp_path / "cache" / "coacd").glob("*.npz"))
    assert len(cached) == 1  # decomposed once; read back since
    again = load_tasks(_world(tray_file, {"coacd": FAST_COACD}))["ball_in_tray"].object("tray").shape.parts
    assert len(again) >= 3 and all(np.array_equal(a[0], b[0]) for a, b in
                                   zip(again, load_tasks(parted)["ball_in_tray"].object("tray").shape.parts))


def test_a_texture_is_drawn_on_the_scan(tmp_path):
    """A textured scan renders its texture's colours, not its rgba."""
    cube = trimesh.creation.box([40.0, 40.0, 40.0])
    uv = np.c_[(cube.vertices[:, 0] > 0).astype(float), (cube.vertices[:, 1] > 0).astype(float)]
    lines = [f"v {x} {y} {z + 20.0}" for x, y, z in cube.vertices] + [f"vt {u} {v}" for u, v in uv]
    lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in cube.faces]
    (tmp_path / "cube.obj").write_text("\n".join(lines) + "\n")
    image = np.zeros((8, 8, 3), np.uint8)
    image[..., 0] = 230  # red everywhere
    import cv2

    cv2.imwrite(str(tmp_path / "red.png"), image[..., ::-1])
    world = copy.deepcopy(bundled_world())
    world["objects"]["scan"] = {"kind": "mesh", "rgba": [0.9, 0.9, 0.9, 1.0], "mass_kg": 0.1,
                                "mesh": {"file": str(tmp_path / "cube.obj"), "scale": 0.001,
                                         "texture": str(tmp_path / "red.png")}}
    world["tasks"]["look"] = {"instruction": "Put the Scan on the Plate",
                              "start": {"scan": {"x_range_m": [-0.05, 0.0], "y_range_m": [0.1, 0.12]},
                                        "plate": {"x_range_m": [-0.05, 0.0], "y_range_m": [-0.12, -0.1]}},
                              "plan": [{"pick": "scan"}, {"place_on": "plate"}],
                              "success": {"upright": {"object": "scan"}},
                              "progress": {"objects": ["scan"], "goal": {"upright": {"object": "scan"}}}}
    _, tasks = load_world(world)
    env = TabletopEnv(tasks["look"], cameras=("head_left",), robot=world_robot(world))
    env.reset({"scan": (-0.03, 0.0, 0.0), "plate": (-0.03, -0.15, 0.0)}, settle=False, observe=False)
    labels, names = env.render("head_left", segmentation=True)
    mask = labels == next(k for k, n in names.items() if n == "scan")
    rgb = env.render("head_left")[mask].mean(axis=0)
    assert mask.sum() > 30 and rgb[0] > 2 * rgb[1] and rgb[0] > 2 * rgb[2], rgb  # red, not the grey rgba
    env.close()


@pytest.mark.parametrize(("change", "message"), [
    ({"mesh": {"file": "/no/such/scan.obj"}}, r"world\.objects\.tray\.mesh\.file: no such mesh file: /no/such/scan\.obj"),
    ({"collision": {"vhacd": {}}}, r"world\.objects\.tray\.collision: unknown key\(s\) \['vhacd'\]"),
    ({"yaw_symmetry": -1}, r"world\.objects\.tray\.yaw_symmetry: must be in \[0, inf\], got -1"),
    ({"dims": {"size_m": 0.1}}, r"world\.objects\.tray\.dims: a mesh object's dimensions are its file's"),
])
def test_a_wrong_scan_entry_names_its_key(tray_file, change, message):
    world = _world(tray_file, "hull")
    world["objects"]["tray"].update(change)
    with pytest.raises(WorldError) as err:
        load_tasks(world)
    assert re.match(message, str(err.value)), str(err.value)


def test_a_scan_starts_upright(tray_file):
    world = _world(tray_file, "hull")
    world["tasks"]["ball_in_tray"]["start"]["tray"]["placement"] = "upside_down"
    with pytest.raises(WorldError, match=r"world\.tasks\.ball_in_tray\.start\.tray\.placement: a mesh object starts upright"):
        load_tasks(world)
