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
from typing import Any

import numpy as np

from r2s_eval.sim.objects import KINDS, Scene, centre_m, kind_in, tilt_rad
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

Condition = Callable[[Scene], bool]


class ConditionError(WorldError):
    """A condition entry that cannot be compiled: ``path`` is the part that is wrong."""

    def __init__(self, path: str, message: str):
        super().__init__(path, message)
        self.path, self.message = path, message


# ---------------------------------------------------------------- predicates
def upright(scene: Scene, object: str, max_tilt_deg: float = MAX_TILT_DEG) -> bool:
    return tilt_rad(scene.object_state(object)["quat_wxyz"]) < np.deg2rad(max_tilt_deg)


def upside_down(scene: Scene, object: str, max_tilt_deg: float = MAX_TILT_DEG) -> bool:
    return tilt_rad(scene.object_state(object)["quat_wxyz"]) > np.pi - np.deg2rad(max_tilt_deg)


def on_table(scene: Scene, object: str, face: str = "bottom", tolerance_m: float = RESTING_TOLERANCE_M) -> bool:
    return kind_in(scene, object).rests_on_table(scene, object, face, tolerance_m)


def on_top_of(scene: Scene, object: str, support: str, tolerance_m: float = RESTING_TOLERANCE_M,
              inset_m: float = STACK_INSET_M) -> bool:
    return kind_in(scene, support).holds_on_top(scene, object, support, tolerance_m, inset_m)


def inside(scene: Scene, object: str, container: str) -> bool:
    return kind_in(scene, container).holds_inside(scene, object, container)


def covered_by(scene: Scene, object: str, cover: str, margin_m: float = COVER_MARGIN_M) -> bool:
    return kind_in(scene, cover).covers(scene, object, cover, margin_m)


def over(scene: Scene, object: str, target: str, tolerance_m: float = RESTING_TOLERANCE_M) -> bool:
    return kind_in(scene, target).has_above(scene, object, target, tolerance_m)


def _separated_xy(points_a: np.ndarray, points_b: np.ndarray, axes: list[np.ndarray]) -> bool:
    """Separating-axis test of the convex hulls of two planar point sets."""
    for axis in axes:
        pa, pb = points_a @ axis, points_b @ axis
        if pa.max() <= pb.min() or pb.max() <= pa.min():
            return True
    return False


def apart(scene: Scene, object: str, other: str) -> bool:
    points_a, axes_a = kind_in(scene, object).footprint(scene, object)
    points_b, axes_b = kind_in(scene, other).footprint(scene, other)
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
# The measure of an object kind (an ``ObjectKind`` method) each predicate's parameter needs; the
# kinds that define it are the ones the predicate judges (checked when a world is read).
KIND_MEASURES: dict[str, dict[str, str]] = {
    "on_top_of": {"support": "holds_on_top"},
    "inside": {"container": "holds_inside"},
    "covered_by": {"cover": "covers"},
    "over": {"target": "has_above"},
    "apart": {"object": "footprint", "other": "footprint"},
}
SUPPORTED_KINDS: dict[str, dict[str, tuple[str, ...]]] = {
    predicate: {param: tuple(k for k, kind in KINDS.items() if kind.defines(measure))
                for param, measure in measures.items()}
    for predicate, measures in KIND_MEASURES.items()
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
    if name == "over" and (target := kinds.get(params.get("target"))) is not None:
        return KINDS[target].over_problem(kinds.get(params.get("object")))
    if name == "on_table" and "face" in params and (kind := kinds.get(params.get("object"))) is not None:
        faces = KINDS[kind].table_faces
        if params["face"] not in faces:
            return f"face {params['face']!r} is not defined for a {kind}; its faces are {list(faces)}"
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
