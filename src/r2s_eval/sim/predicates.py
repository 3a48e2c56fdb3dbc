"""Task success and progress as data: documented predicates over a small scene interface.

A world (the ``world`` config group) states each task's success as a composition of predicates,
and its progress as stages towards a goal condition; this module turns those entries into
functions of a ``Scene``.
Predicates read only the scene's state queries (poses, velocities, dimensions, contacts), never
the environment class, so a rule means the same in every world that offers them.

Conditions
----------
A condition is one predicate or a combination:

    {predicate: {param: value, ...}}     e.g. {upright: {object: cup}}
    {all: [condition, ...]}              every one holds
    {any: [condition, ...]}              at least one holds
    {not: condition}                     it does not hold

Predicates (thresholds are parameters; the defaults are the bundled tasks'):

=================  ===========================================================================
predicate          holds when
=================  ===========================================================================
upright            the object's body z axis is within ``max_tilt_deg`` (15) of world up
upside_down        the object's body z axis is within ``max_tilt_deg`` (15) of world down
on_table           the object rests on the table: ``face: bottom`` its bottom face (default),
                   ``top`` its top face (a cup upside down on its rim), ``any`` whichever face
                   is down (a block, a ball), within ``tolerance_m`` (0.008)
on_top_of          the object's bottom face rests on the ``support``'s top face, inside its
                   edge: a plate (inside its rim) or a block (centre ``inset_m`` (0.005) inside
                   its top face), within ``tolerance_m``
inside             the object's centre is inside the ``container``: a cup (within its inner base
                   radius, below its rim) or a box (inside its inner walls, below its rim)
covered_by         the object is under the ``cover`` (a cup): its centre within the cup's inner
                   rim radius less its own radius plus ``margin_m`` (0.002)
over               the object is above the ``target``, within its opening or face: a plate, a
                   cup (opening up: the object above its bottom; upside down, a cup ``object``
                   over a ball ``target``), a box or a block
apart              the object's and the ``other``'s footprints do not overlap (blocks, boxes)
released           no robot geometry touches the object
at_rest            linear speed below ``max_lin_speed_m_s`` (0.03) and angular speed below
                   ``max_ang_speed_rad_s`` (0.5; null: not checked)
grasped            both jaws of one gripper touch the object
lifted             the object's centre is ``height_m`` (0.02) above where it started
=================  ===========================================================================

Progress
--------
``{objects: [...], goal: condition}``: 0.2 when a gripper's grasp centre is within
``reach_m`` (0.05) of an object's centre, 0.4 when it is grasped, 0.6 grasped and lifted
``lift_m`` (0.02), 0.8 grasped with the goal condition holding, 1.0 when the task succeeds; the
best object counts.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np

from r2s_eval.errors import ConfigError
from r2s_eval.sim.objects import height_m
from r2s_eval.sim.reading import WorldError

# Defaults of the predicates' parameters (the bundled tasks' thresholds).
MAX_TILT_DEG = 15.0
REST_MAX_LIN_SPEED_M_S = 0.03
REST_MAX_ANG_SPEED_RAD_S = 0.5
RESTING_TOLERANCE_M = 0.008  # a face vs the surface it should rest on
STACK_INSET_M = 0.005  # an object's centre this far inside the block face below it
COVER_MARGIN_M = 0.002
LIFTED_HEIGHT_M = 0.02
REACHED_DIST_M = 0.05


class Scene(Protocol):
    """What predicates read of a world's current state (``TabletopEnv`` offers it)."""

    table_top_z_m: float
    initial_centre_z_m: dict[str, float]

    def object_state(self, name: str) -> dict: ...  # pos_world_m, quat_wxyz, linvel_world_m_s, angvel_world_rad_s
    def object_dims(self, name: str) -> dict: ...
    def object_kind(self, name: str) -> str: ...
    def robot_touches(self, name: str) -> bool: ...
    def grasped(self, name: str) -> str | None: ...
    def ee_positions(self) -> dict[str, np.ndarray]: ...
    def is_success(self) -> bool: ...


Condition = Callable[[Scene], bool]


class ConditionError(WorldError):
    """A condition entry that cannot be compiled: ``path`` is the part that is wrong."""

    def __init__(self, path: str, message: str):
        super().__init__(path, message)
        self.path, self.message = path, message


# ---------------------------------------------------------------- geometry
def tilt_rad(quat_wxyz: np.ndarray) -> float:
    """Angle between the body z axis and world up."""
    w, x, y, z = quat_wxyz
    cos_tilt = 1.0 - 2.0 * (x * x + y * y)  # world z of the body's z axis
    return float(np.arccos(np.clip(cos_tilt, -1.0, 1.0)))


def rotation(quat_wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(quat_wxyz, float) / np.linalg.norm(quat_wxyz)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def local(scene: Scene, frame_obj: str, point_world_m: np.ndarray) -> np.ndarray:
    """``point_world_m`` in the body frame of ``frame_obj``."""
    s = scene.object_state(frame_obj)
    return rotation(s["quat_wxyz"]).T @ (np.asarray(point_world_m) - s["pos_world_m"])


def centre_m(scene: Scene, name: str) -> np.ndarray:
    """World position of the object's geometric centre (half its height along body z)."""
    s = scene.object_state(name)
    half = height_m(scene.object_kind(name), scene.object_dims(name)) / 2
    return s["pos_world_m"] + rotation(s["quat_wxyz"])[:, 2] * half


def _block_corners_world(scene: Scene, name: str) -> tuple[np.ndarray, np.ndarray]:
    s = scene.object_state(name)
    R = rotation(s["quat_wxyz"])
    half = scene.object_dims(name)["size_m"] / 2
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (0, 2)], float)
    return s["pos_world_m"] + (signs * half) @ R.T, R


def _separated_xy(points_a: np.ndarray, points_b: np.ndarray, axes: list[np.ndarray]) -> bool:
    """Separating-axis test of the convex hulls of two planar point sets."""
    for axis in axes:
        pa, pb = points_a @ axis, points_b @ axis
        if pa.max() <= pb.min() or pb.max() <= pa.min():
            return True
    return False


def _footprint(scene: Scene, name: str) -> tuple[np.ndarray, list[np.ndarray]]:
    """An object's footprint corners on the table and its edge normals (blocks and boxes)."""
    kind = scene.object_kind(name)
    if kind == "block":
        corners, R = _block_corners_world(scene, name)
        axes = [R[:2, k] / np.linalg.norm(R[:2, k]) for k in range(3) if np.linalg.norm(R[:2, k]) > 0.3]
        return corners[:, :2], axes  # a flat block has two horizontal face normals
    if kind in ("box", "mesh"):
        s = scene.object_state(name)
        R = rotation(s["quat_wxyz"])
        axes = [R[:2, 0] / np.linalg.norm(R[:2, 0]), R[:2, 1] / np.linalg.norm(R[:2, 1])]
        signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], float)
        return s["pos_world_m"][:2] + (signs * _half_extent(scene, name)) @ np.array(axes), axes
    raise ConfigError(f"apart: no footprint for a {kind} ({name}); blocks, boxes and meshes have one")


def _half_extent(scene: Scene, name: str) -> np.ndarray:
    """Half the footprint's sides along the body x and y axes (a box, a mesh's bounding box)."""
    dims = scene.object_dims(name)
    if "half_x_m" in dims:
        return np.array([dims["half_x_m"], dims["half_y_m"]])
    return np.array([dims["length_m"], dims["width_m"]]) / 2


def _in_bounds(scene: Scene, point_world_m: np.ndarray, mesh: str, inset_m: float = 0.0) -> tuple[np.ndarray, bool]:
    """A point in a mesh object's frame, and whether it lies within its footprint (less ``inset_m``)."""
    p = local(scene, mesh, point_world_m)
    return p, bool(np.all(np.abs(p[:2]) < _half_extent(scene, mesh) - inset_m))


def _in_cup(scene: Scene, name: str, cup: str) -> dict:
    """Where object ``name``'s centre lies in the cup's frame, and the cup's inner sizes."""
    dims = scene.object_dims(cup)
    p = local(scene, cup, centre_m(scene, name))
    return dict(offset_m=float(np.hypot(*p[:2])), z_m=float(p[2]), inner_r=dims["radius_m"] - dims["wall_m"],
                inner_base_r=dims["base_radius_m"] - dims["wall_m"], height_m=dims["height_m"])


def _in_box(scene: Scene, name: str, box: str) -> tuple[np.ndarray, bool]:
    """Object ``name``'s centre in the box's frame, and whether it is within the inner walls."""
    d = scene.object_dims(box)
    p = local(scene, box, centre_m(scene, name))
    return p, bool(abs(p[0]) < d["length_m"] / 2 - d["wall_m"] and abs(p[1]) < d["width_m"] / 2 - d["wall_m"])


def _on_plate(scene: Scene, name: str, plate: str) -> tuple[float, float, float]:
    """(offset from the plate's centre, the largest offset inside its rim, height above its top)."""
    obj, s = scene.object_state(name), scene.object_state(plate)
    dims, plate_dims = scene.object_dims(name), scene.object_dims(plate)
    offset = float(np.linalg.norm(obj["pos_world_m"][:2] - s["pos_world_m"][:2]))
    bottom_r = dims.get("base_radius_m", dims.get("radius_m", 0.0))
    above = float(obj["pos_world_m"][2] - (s["pos_world_m"][2] + plate_dims["thickness_m"]))
    return offset, plate_dims["radius_m"] - bottom_r, above


def _on_block(scene: Scene, name: str, block: str) -> tuple[np.ndarray, float]:
    """The object's bottom centre in the block's frame, and the block's edge."""
    return local(scene, block, scene.object_state(name)["pos_world_m"]), scene.object_dims(block)["size_m"]


# ---------------------------------------------------------------- predicates
def upright(scene: Scene, object: str, max_tilt_deg: float = MAX_TILT_DEG) -> bool:
    return tilt_rad(scene.object_state(object)["quat_wxyz"]) < np.deg2rad(max_tilt_deg)


def upside_down(scene: Scene, object: str, max_tilt_deg: float = MAX_TILT_DEG) -> bool:
    return tilt_rad(scene.object_state(object)["quat_wxyz"]) > np.pi - np.deg2rad(max_tilt_deg)


def on_table(scene: Scene, object: str, face: str = "bottom", tolerance_m: float = RESTING_TOLERANCE_M) -> bool:
    table = scene.table_top_z_m
    kind = scene.object_kind(object)
    if kind == "ball":  # no faces: its lowest point
        return bool(abs(centre_m(scene, object)[2] - scene.object_dims(object)["radius_m"] - table) < tolerance_m)
    pos = scene.object_state(object)["pos_world_m"]
    if face == "bottom":
        return bool(abs(pos[2] - table) < tolerance_m)
    if face == "top":
        return bool(abs(pos[2] - height_m(kind, scene.object_dims(object)) - table) < tolerance_m)
    if face == "any" and kind == "block":
        size = scene.object_dims(object)["size_m"]
        lowest = _block_corners_world(scene, object)[0][:, 2].min()
        return bool(abs(lowest - table) < tolerance_m
                    and abs(centre_m(scene, object)[2] - table - size / 2) < tolerance_m)
    raise ConfigError(f"on_table: face {face!r} is not defined for a {kind} ({object}); bottom, top, or any for a block")


def on_top_of(scene: Scene, object: str, support: str, tolerance_m: float = RESTING_TOLERANCE_M,
              inset_m: float = STACK_INSET_M) -> bool:
    kind = scene.object_kind(support)
    if kind == "plate":
        offset, max_offset, above = _on_plate(scene, object, support)
        return bool(offset < max_offset and abs(above) < tolerance_m)
    if kind == "block":
        p, size = _on_block(scene, object, support)
        return bool(max(abs(p[0]), abs(p[1])) < size / 2 - inset_m and abs(p[2] - size) < tolerance_m)
    if kind == "mesh":  # on the top of its bounding box
        p, within = _in_bounds(scene, scene.object_state(object)["pos_world_m"], support, inset_m)
        return bool(within and abs(p[2] - scene.object_dims(support)["height_m"]) < tolerance_m)
    raise ConfigError(f"on_top_of: a {kind} ({support}) has no top face defined; plates, blocks and meshes have")


def inside(scene: Scene, object: str, container: str) -> bool:
    kind = scene.object_kind(container)
    if kind == "cup":
        g = _in_cup(scene, object, container)
        return bool(g["offset_m"] < g["inner_base_r"] and g["z_m"] < g["height_m"])
    if kind == "box":
        p, within = _in_box(scene, object, container)
        return bool(within and 0 < p[2] < scene.object_dims(container)["height_m"])
    if kind == "mesh":  # a concave scan (a bowl): the centre within its bounding box
        p, within = _in_bounds(scene, centre_m(scene, object), container)
        return bool(within and 0 < p[2] < scene.object_dims(container)["height_m"])
    raise ConfigError(f"inside: a {kind} ({container}) is not a container; cups, boxes and meshes are")


def covered_by(scene: Scene, object: str, cover: str, margin_m: float = COVER_MARGIN_M) -> bool:
    if scene.object_kind(cover) != "cup":
        raise ConfigError(f"covered_by: a {scene.object_kind(cover)} ({cover}) cannot cover; a cup can")
    g = _in_cup(scene, object, cover)
    return bool(g["offset_m"] < g["inner_r"] - scene.object_dims(object)["radius_m"] + margin_m)


def over(scene: Scene, object: str, target: str, tolerance_m: float = RESTING_TOLERANCE_M) -> bool:
    kind = scene.object_kind(target)
    if kind == "plate":
        offset, max_offset, above = _on_plate(scene, object, target)
        return bool(offset < max_offset and above > -tolerance_m)
    if kind == "cup":  # the object above the opening of an upright cup
        g = _in_cup(scene, object, target)
        return bool(g["offset_m"] < g["inner_r"] - scene.object_dims(object)["radius_m"] / 2 and g["z_m"] > 0)
    if kind == "ball" and scene.object_kind(object) == "cup":  # an upside-down cup over the ball
        g = _in_cup(scene, target, object)
        return bool(g["offset_m"] < g["inner_r"])
    if kind == "box":
        p, within = _in_box(scene, object, target)
        return bool(within and p[2] > 0)
    if kind == "block":
        p, size = _on_block(scene, object, target)
        return bool(max(abs(p[0]), abs(p[1])) < size / 2 and p[2] > size - tolerance_m)
    if kind == "mesh":  # above its bottom, within its footprint (over a bowl's opening, or its top)
        p, within = _in_bounds(scene, centre_m(scene, object), target)
        return bool(within and p[2] > 0)
    raise ConfigError(f"over: 'over a {kind}' ({target}) is not defined; plates, cups, boxes, blocks, meshes, "
                     f"and a cup over a ball")


def apart(scene: Scene, object: str, other: str) -> bool:
    points_a, axes_a = _footprint(scene, object)
    points_b, axes_b = _footprint(scene, other)
    return _separated_xy(points_a, points_b, [*axes_b, *axes_a])


def released(scene: Scene, object: str) -> bool:
    return not scene.robot_touches(object)


def at_rest(scene: Scene, object: str, max_lin_speed_m_s: float = REST_MAX_LIN_SPEED_M_S,
            max_ang_speed_rad_s: float | None = REST_MAX_ANG_SPEED_RAD_S) -> bool:
    s = scene.object_state(object)
    slow = np.linalg.norm(s["linvel_world_m_s"]) < max_lin_speed_m_s
    if max_ang_speed_rad_s is None:
        return bool(slow)
    return bool(slow and np.linalg.norm(s["angvel_world_rad_s"]) < max_ang_speed_rad_s)


def grasped(scene: Scene, object: str) -> bool:
    return scene.grasped(object) is not None


def lifted(scene: Scene, object: str, height_m: float = LIFTED_HEIGHT_M) -> bool:
    return bool(centre_m(scene, object)[2] > scene.initial_centre_z_m[object] + height_m)


PREDICATES: dict[str, Callable[..., bool]] = {
    "upright": upright, "upside_down": upside_down, "on_table": on_table, "on_top_of": on_top_of,
    "inside": inside, "covered_by": covered_by, "over": over, "apart": apart, "released": released,
    "at_rest": at_rest, "grasped": grasped, "lifted": lifted,
}
COMBINATORS = ("all", "any", "not")
# The object kinds a predicate's geometry is defined for, per parameter (checked when a world is read).
SUPPORTED_KINDS: dict[str, dict[str, tuple[str, ...]]] = {
    "on_top_of": {"support": ("plate", "block", "mesh")},
    "inside": {"container": ("cup", "box", "mesh")},
    "covered_by": {"cover": ("cup",)},
    "over": {"target": ("plate", "cup", "box", "block", "ball", "mesh")},
    "apart": {"object": ("block", "box", "mesh"), "other": ("block", "box", "mesh")},
}
# The parameters that name objects (a task's condition may name only its own objects).
OBJECT_PARAMS = ("object", "support", "container", "cover", "target", "other")


# ---------------------------------------------------------------- compiling conditions
def condition_objects(spec: Any) -> set[str]:
    """The objects a condition names."""
    if isinstance(spec, list):
        return set().union(*(condition_objects(s) for s in spec)) if spec else set()
    if not isinstance(spec, Mapping) or len(spec) != 1:
        return set()
    (name, params), = spec.items()
    if name in COMBINATORS:
        return condition_objects(params)
    return {v for k, v in (params or {}).items() if k in OBJECT_PARAMS}


def _kind_problem(name: str, params: Mapping, kinds: Mapping[str, str]) -> str | None:
    """Why predicate ``name`` cannot judge these objects (``kinds``: object -> kind), if it cannot."""
    for param, supported in SUPPORTED_KINDS.get(name, {}).items():
        kind = kinds.get(params.get(param))
        if kind is not None and kind not in supported:
            return f"{param} {params[param]!r} is a {kind}; {name} is defined for {list(supported)}"
    if name == "over" and kinds.get(params.get("target")) == "ball" and kinds.get(params.get("object")) != "cup":
        return "over a ball is defined for a cup (upside down, covering it) only"
    if name == "on_table" and params.get("face") == "any" and kinds.get(params.get("object")) not in ("block", "ball"):
        return "face 'any' is defined for blocks (and balls, which have no faces)"
    return None


def compile_condition(spec: Any, where: str = "condition", kinds: Mapping[str, str] | None = None) -> Condition:
    """A condition entry (see the module docstring) as a function of a scene; raises
    ConditionError naming the part of ``where`` that is wrong. With ``kinds`` (object -> kind),
    a predicate asked of objects its geometry does not cover is wrong too."""
    if not isinstance(spec, Mapping) or len(spec) != 1:
        raise ConditionError(where, f"a condition is one mapping {{predicate or all/any/not: ...}}, got {spec!r}")
    (name, params), = spec.items()
    if name in ("all", "any"):
        if not isinstance(params, list) or not params:
            raise ConditionError(f"{where}.{name}", f"must be a non-empty list of conditions, got {params!r}")
        parts = [compile_condition(p, f"{where}.{name}[{i}]", kinds) for i, p in enumerate(params)]
        combine = all if name == "all" else any
        return lambda scene: combine(part(scene) for part in parts)
    if name == "not":
        part = compile_condition(params, f"{where}.not", kinds)
        return lambda scene: not part(scene)
    if name not in PREDICATES:
        raise ConditionError(where, f"unknown predicate {name!r}; predicates are {sorted(PREDICATES)}, "
                         f"combined with {list(COMBINATORS)}")
    if not isinstance(params, Mapping):
        raise ConditionError(f"{where}.{name}", f"its parameters are a mapping, e.g. {{object: cup}}, got {params!r}")
    predicate, kwargs = PREDICATES[name], dict(params)
    _check_params(predicate, kwargs, f"{where}.{name}")
    if kinds is not None and (problem := _kind_problem(name, kwargs, kinds)):
        raise ConditionError(f"{where}.{name}", problem)
    return lambda scene: bool(predicate(scene, **kwargs))


def _check_params(predicate: Callable, kwargs: dict, where: str) -> None:
    import inspect

    signature = inspect.signature(predicate)
    accepted = [p for p in signature.parameters if p != "scene"]
    unknown = sorted(set(kwargs) - set(accepted))
    missing = [p for p, v in signature.parameters.items()
               if p != "scene" and v.default is inspect.Parameter.empty and p not in kwargs]
    if unknown or missing:
        raise ConditionError(where, "; ".join(
            ([f"unknown parameter(s) {unknown}"] if unknown else []) + ([f"missing {missing}"] if missing else []))
            + f" (it takes {accepted})")


def staged_progress(objects: tuple[str, ...], goal: Condition, reach_m: float = REACHED_DIST_M,
                    lift_m: float = LIFTED_HEIGHT_M) -> Callable[[Scene], float]:
    """Progress stages (see the module docstring) over ``objects`` towards ``goal``."""

    def progress(scene: Scene) -> float:
        if scene.is_success():  # the task's own rule (computed once per state by the env)
            return 1.0
        best = 0.0
        for name in objects:
            held = scene.grasped(name) is not None
            up = centre_m(scene, name)[2] > scene.initial_centre_z_m[name] + lift_m
            if held and goal(scene):
                best = max(best, 0.8)
            elif held and up:
                best = max(best, 0.6)
            elif held:
                best = max(best, 0.4)
            else:
                tcp_dist_m = min(np.linalg.norm(p - centre_m(scene, name)) for p in scene.ee_positions().values())
                if tcp_dist_m < reach_m:
                    best = max(best, 0.2)
        return best

    return progress


def false_parts(spec: Any, scene: Scene, where: str = "condition") -> list[str]:
    """Why condition ``spec`` is false in ``scene``: its false predicates, each as its key under
    ``where`` and its parameters (``where.all[1].on_top_of {object: cup, support: plate}``); a
    negation that fails is named as ``where.not``. Empty when the condition holds."""
    if compile_condition(spec, where)(scene):
        return []
    (name, params), = spec.items()
    if name in ("all", "any"):  # all: the false ones; any: every one is false
        return [part for i, p in enumerate(params) for part in false_parts(p, scene, f"{where}.{name}[{i}]")]
    if name == "not":
        return [f"{where}.not {params}"]
    shown = ", ".join(f"{k}: {v}" for k, v in params.items())
    return [f"{where}.{name} {{{shown}}}"]
