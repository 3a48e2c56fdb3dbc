"""Object kinds: each kind is one class that owns its dimensions, geometry, geoms, what the task
predicates measure on it and how the scripted operator grips it; the predicates, the operator and
the video judge ask the kind instead of branching on its name."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from r2s_eval.errors import ConfigError
from r2s_eval.judge.video_judge import goal_relation
from r2s_eval.sim import WorldParams
from r2s_eval.sim.objects import KINDS, PLACEMENTS, ObjectKind, ObjectSpec, add_object
from r2s_eval.sim.predicates import SUPPORTED_KINDS, ConditionError, compile_condition, inside
from r2s_eval.twin.reality import RealityEffects
from r2s_eval.twin.scene import scene_adder, true_handle_dims
from tests.helpers.worlds import bundled_robot, bundled_tasks, bundled_world

OBJECTS = {name: ObjectSpec(name=name, kind=e["kind"], rgba=tuple(e["rgba"]), dims=e["dims"], mass_kg=e["mass_kg"])
           for name, e in bundled_world()["objects"].items()}
MUG_HANDLE = dict(handle_low_m=0.021, handle_high_m=0.068, handle_out_m=0.025, handle_thickness_m=0.009)


def test_every_kind_a_world_names_is_one_class():
    assert list(KINDS) == ["cup", "plate", "ball", "block", "box", "mesh"]
    assert all(isinstance(kind, ObjectKind) and kind.name == name for name, kind in KINDS.items())
    assert len({type(kind) for kind in KINDS.values()}) == len(KINDS)
    for obj in OBJECTS.values():  # the bundled world gives each kind its dimensions, no others
        kind = obj.kind_object
        assert set(kind.dims_keys) <= set(obj.dims) <= set(kind.dims_keys) | set(kind.optional_dims_keys)


def test_a_kind_builds_its_geoms_with_the_mass_it_is_given():
    spec = mujoco.MjSpec()
    for obj in OBJECTS.values():
        add_object(spec, obj, 1.0)
    model = spec.compile()
    for name, obj in OBJECTS.items():
        body = model.body(name)
        assert model.body_mass[body.id] == pytest.approx(obj.mass_kg)
        names = [model.geom(g).name for g in range(model.ngeom) if model.geom_bodyid[g] == body.id]
        assert all(n.startswith(f"{name}_") for n in names)
    geoms = {n: sum(model.geom_bodyid == model.body(n).id) for n in OBJECTS}
    assert geoms == {"cup": 1 + 16, "plate": 1 + 20, "ball": 1, "box": 5, "block_a": 1, "block_b": 1}


def test_each_kind_states_its_geometry():
    dims = {name: obj.dims for name, obj in OBJECTS.items()}
    cup, plate, ball, box, block = (KINDS[k] for k in ("cup", "plate", "ball", "box", "block"))
    assert [k.height_m(dims[n]) for k, n in ((cup, "cup"), (plate, "plate"), (ball, "ball"), (box, "box"),
                                             (block, "block_a"))] == pytest.approx([0.085, 0.02, 0.04, 0.035, 0.045])
    assert [k.support_top_m(dims[n]) for k, n in ((cup, "cup"), (plate, "plate"), (box, "box"), (block, "block_a"))] \
        == pytest.approx([0.008, 0.008, 0.006, 0.045])
    assert block.footprint_radius_m(dims["block_a"]) == pytest.approx(0.045 / np.sqrt(2))
    assert cup.footprint_radius_m(dims["cup"], "on_side") == pytest.approx(np.hypot(0.0425, 0.037))
    assert cup.taper_rad(dims["cup"]) > 0 and block.taper_rad(dims["block_a"]) == 0
    assert cup.placed_height_m(dims["cup"], "on_side") == pytest.approx(0.074)
    assert [cup.yaw_symmetry("upright"), cup.yaw_symmetry("on_side"), block.yaw_symmetry(), box.yaw_symmetry(),
            KINDS["mesh"].yaw_symmetry()] == [0, 1, 4, 2, 1]
    mug = {**dims["cup"], **MUG_HANDLE}  # a handle points one way; the footprint stays the body's
    assert [cup.yaw_symmetry("upright", mug), cup.yaw_symmetry("upside_down", mug)] == [1, 1]
    assert [cup.footprint_radius_m(mug, p) for p in PLACEMENTS] == [cup.footprint_radius_m(dims["cup"], p)
                                                                    for p in PLACEMENTS]


def _object_model(obj: ObjectSpec, reality: RealityEffects | None = None) -> mujoco.MjModel:
    """A model of ``obj`` alone, built as the world builds it, then as the twin of ``reality`` does."""
    spec = mujoco.MjSpec()
    add_object(spec, obj, 1.0)
    if reality is not None:
        scene_adder(reality, bundled_robot(), [obj], WorldParams())(spec)
    return spec.compile()


def test_a_cup_whose_world_states_a_handle_is_a_mug_as_the_twin_builds_its_own():
    """The world's mug (a lab's measurement) is built by the kind: three massless capsules along the
    body's -x. Stated as the twin's true handle, the calibrated sim's mug is the twin's, geom for
    geom; stated otherwise, the twin keeps its own handle (the world's never reaches its model)."""
    world = bundled_world()
    cup = world["objects"]["cup"]
    plain = ObjectSpec(name="cup", kind="cup", rgba=tuple(cup["rgba"]), dims=cup["dims"], mass_kg=cup["mass_kg"])
    true = true_handle_dims(plain.dims)
    measured = dataclasses.replace(plain, dims={**plain.dims, **true})
    wrong = dataclasses.replace(plain, dims={**plain.dims, **MUG_HANDLE, "handle_out_m": 0.04})

    def cup_geoms(obj, reality=None):
        model = _object_model(obj, reality)
        return model, [g for g in range(model.ngeom) if model.geom(g).name.startswith("cup_handle_")]

    model, geoms = cup_geoms(measured)
    assert [model.geom(g).name for g in geoms] == ["cup_handle_lower", "cup_handle_upper", "cup_handle_grip"]
    assert model.body_mass[model.body("cup").id] == pytest.approx(cup["mass_kg"])
    grip = model.geom_pos[geoms[2]]
    assert grip[0] < -cup["dims"]["radius_m"] and abs(grip[1]) < 1e-9  # off the wall, along -x
    d = cup["dims"]  # the handle's outside stands handle_out_m off the wall where its upper arm meets it
    wall = d["base_radius_m"] + (d["radius_m"] - d["base_radius_m"]) * true["handle_high_m"] / d["height_m"]
    assert grip[0] - model.geom_size[geoms[2]][0] == pytest.approx(-wall - true["handle_out_m"])
    assert not cup_geoms(plain)[1]
    twin_model, twin_geoms = cup_geoms(plain, RealityEffects(cup_handle=True))
    for obj in (measured, wrong):
        over, over_geoms = cup_geoms(obj, RealityEffects(cup_handle=True))
        assert len(over_geoms) == 3  # the twin's handle in place of the world's, not beside it
        for field in ("geom_pos", "geom_size", "geom_quat"):
            assert np.allclose(getattr(over, field)[over_geoms], getattr(twin_model, field)[twin_geoms]), field
    for field in ("geom_pos", "geom_size", "geom_quat", "geom_friction", "geom_contype", "geom_conaffinity"):
        assert np.allclose(getattr(model, field)[geoms], getattr(twin_model, field)[twin_geoms]), field
    wrong_model, wrong_geoms = cup_geoms(wrong)
    assert not np.allclose(wrong_model.geom_pos[wrong_geoms], model.geom_pos[geoms])


def test_a_block_whose_world_states_rounded_edges_is_built_as_the_twin_rounds_its_own():
    """A block's ``edge_radius_m`` (a lab's measurement) gives the kind's rounded cube: the same
    size, mass and frame; the twin's own radius replaces it in the twin's model."""
    block = bundled_world()["objects"]["block_a"]
    plain = ObjectSpec(name="block_a", kind="block", rgba=tuple(block["rgba"]), dims=block["dims"],
                       mass_kg=block["mass_kg"])

    def compiled(obj, reality=None):
        model = _object_model(obj, reality)
        return model, np.flatnonzero(model.geom_bodyid == model.body("block_a").id)

    rounded = dataclasses.replace(plain, dims={**plain.dims, "edge_radius_m": 0.004})
    model, geoms = compiled(rounded)
    cube, cube_geoms = compiled(plain)
    assert (len(geoms), len(cube_geoms)) == (15, 1)
    assert model.body_mass[model.body("block_a").id] == pytest.approx(block["mass_kg"])
    half = block["dims"]["size_m"] / 2  # the rounded cube's faces where the cube's are: its boxes reach them
    boxes = geoms[model.geom_type[geoms] == mujoco.mjtGeom.mjGEOM_BOX]
    low, high = model.geom_pos[boxes] - model.geom_size[boxes], model.geom_pos[boxes] + model.geom_size[boxes]
    assert np.allclose([low.min(0), high.max(0)], [[-half, -half, 0], [half, half, 2 * half]])
    twin, twin_geoms = compiled(plain, RealityEffects(block_edge_radius_m=0.004))
    for field in ("geom_pos", "geom_size", "geom_quat", "geom_friction", "geom_rgba", "body_mass"):
        a, b = getattr(model, field), getattr(twin, field)
        assert np.allclose(a[geoms] if field.startswith("geom") else a, b[twin_geoms] if field.startswith("geom")
                           else b), field
    other, other_geoms = compiled(rounded, RealityEffects(block_edge_radius_m=0.002))  # the twin's radius wins
    assert len(other_geoms) == 15 and model.geom_size[geoms[3], 0] == pytest.approx(0.004)
    assert other.geom_size[other_geoms[3], 0] == pytest.approx(0.002)


@pytest.mark.parametrize("name", sorted(OBJECTS))
def test_a_placed_object_gives_back_its_planar_pose(name):
    obj = OBJECTS[name]
    kind = obj.kind_object
    for placement in kind.placements:
        origin = kind.origin_m(obj.dims, placement, 0.03, -0.02, 0.7, 0.75)
        quat = kind.orientation(placement, 0.7, obj.dims)
        assert kind.planar_pose(obj.dims, placement, origin, quat) == pytest.approx((0.03, -0.02, 0.7))
    for placement in set(PLACEMENTS) - set(kind.placements):
        with pytest.raises(ConfigError, match=f"a {kind.name} starts .*, not {placement}"):
            kind.orientation(placement, 0.0, obj.dims)


def test_the_predicates_judge_the_kinds_whose_class_measures_it():
    assert SUPPORTED_KINDS == {
        "on_top_of": {"support": ("plate", "block", "mesh")},
        "inside": {"container": ("cup", "box", "mesh")},
        "covered_by": {"cover": ("cup",)},
        "over": {"target": ("cup", "plate", "ball", "block", "box", "mesh")},
        "apart": {"object": ("block", "box", "mesh"), "other": ("block", "box", "mesh")},
    }
    kinds = {name: obj.kind for name, obj in OBJECTS.items()}
    for condition, message in (
            ({"inside": {"object": "ball", "container": "plate"}},
             r"container 'plate' is a plate; inside is defined for \['cup', 'box', 'mesh'\]"),
            ({"over": {"object": "block_a", "target": "ball"}}, "over a ball is defined for a cup"),
            ({"on_table": {"object": "cup", "face": "any"}}, r"face 'any' is not defined for a cup; its faces are")):
        with pytest.raises(ConditionError, match=message):
            compile_condition(condition, "success", kinds)
    compile_condition({"on_table": {"object": "ball", "face": "any"}}, "success", kinds)  # a ball has no faces


def test_a_predicate_asked_of_a_kind_without_its_measure_names_both(nominal_env):
    with pytest.raises(ConfigError, match=r"inside: a plate \(plate\) is no container; inside is defined for "
                                          r"\['cup', 'box', 'mesh'\]"):
        inside(nominal_env, "cup", "plate")


def test_the_operator_grips_what_its_kind_says():
    dims = {name: obj.dims for name, obj in OBJECTS.items()}
    assert [k for k, kind in KINDS.items() if kind.pickable] == ["cup", "ball", "block", "mesh"]
    assert KINDS["plate"].grasp(dims["plate"], "upright") is None and KINDS["box"].grasp(dims["box"], "upright") is None
    cup = KINDS["cup"]
    assert cup.grasp(dims["cup"], "upright").half_width_m is None  # round its wall, jaws open
    assert cup.grasp(dims["cup"], "upside_down").tcp_offset_m == pytest.approx(-0.005)
    assert KINDS["block"].grasp(dims["block_a"], "upright").half_width_m == pytest.approx(0.0225)
    assert KINDS["block"].grasp_yaws(0.3, 1.0) == (0.3, np.pi / 2)  # square to its faces
    assert KINDS["ball"].grasp_yaws(0.3, 1.0) == (1.0, np.pi / 8)  # round: the arm's natural yaw


def test_the_video_judge_reads_a_stack_from_the_supports_kind():
    assert [k for k, kind in KINDS.items() if kind.stacked_on] == ["block"]
    tasks = bundled_tasks()
    assert goal_relation(tasks["stack_blocks"])[0] == "stack" and goal_relation(tasks["cup_on_plate"])[0] == "on"
