"""What a task's ``plan`` may say: the plan primitives, their arguments, and the plan's shape.

A task's plan (``world.tasks.<key>.plan``) is what the twin's scripted operator does: a pick of
one object followed by one place primitive, or a primitive that is the whole plan alone::

    plan: [{pick: cup}, {place_on: plate}]
    plan: [{turn_upright: cup}]

Each step names one object of the task. The table below is the one list of primitives: the task
check reads it here, and the operator's implementations (``r2s_eval.twin.primitives``) register
against it, so a name the check accepts is one the operator can do.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from r2s_eval.sim.reading import fail


@dataclass(frozen=True)
class PlanPrimitive:
    name: str
    role: str  # "pick": the first step of a pick-and-place; "place": its second; "alone": the whole plan
    argument: str  # what the object the step names is
    doc: str  # what the operator does
    kinds: tuple[str, ...] | None = None  # the kinds of object its argument may be (None: any)
    held_kinds: tuple[str, ...] | None = None  # a place step: the kinds the picked object may be


PLAN_PRIMITIVES: dict[str, PlanPrimitive] = {p.name: p for p in (
    PlanPrimitive("pick", "pick", "the object to grasp",
                  "grasps it from above (a cup round its wall near the table, a ball, block or mesh with the "
                  "jaws pre-shaped just wider than it)"),
    PlanPrimitive("place_on", "place", "the support",
                  "releases the held object with its bottom 6 mm above the support's top face, over its centre"),
    PlanPrimitive("place_in", "place", "the container",
                  "releases the held object 2 cm above the container's rim, over its centre: it drops in"),
    PlanPrimitive("place_over", "place", "the object to cover",
                  "releases the upside-down held object with its rim 6 mm above the table, centred on it"),
    PlanPrimitive("put_down_beside", "place", "the box",
                  "puts the held block on the table beside the box, towards the table's centre line",
                  kinds=("box",), held_kinds=("block",)),
    PlanPrimitive("turn_upright", "alone", "the lying cup", "stands the lying cup up", kinds=("cup",)),
)}
PLACE_PRIMITIVES = tuple(name for name, p in PLAN_PRIMITIVES.items() if p.role == "place")
ALONE_PRIMITIVES = tuple(name for name, p in PLAN_PRIMITIVES.items() if p.role == "alone")


def read_plan(value: Any, kinds: Mapping[str, str], where: str) -> tuple[dict[str, str], ...]:
    """The plan entry ``value`` of a task whose objects are ``kinds`` (name -> kind), checked: a
    wrong step is a ``WorldError`` naming it (``where``: the plan's key)."""
    names = list(kinds)
    steps = value if isinstance(value, list) else []
    if not steps or not all(isinstance(s, Mapping) and len(s) == 1 for s in steps):
        raise fail(where, f"must be a list of one-key steps, e.g. [{{pick: cup}}, {{place_on: plate}}], got {value!r}")
    for i, step in enumerate(steps):
        (name, obj), = step.items()
        if name not in PLAN_PRIMITIVES:
            raise fail(f"{where}[{i}]", f"unknown primitive {name!r}; primitives are {list(PLAN_PRIMITIVES)}")
        if obj not in names:
            raise fail(f"{where}[{i}].{name}", f"must name an object of the task {names}, got {obj!r}")
    roles = [PLAN_PRIMITIVES[next(iter(s))].role for s in steps]
    if roles not in (["alone"], ["pick", "place"]):
        raise fail(where, f"must be a pick and one of {list(PLACE_PRIMITIVES)}, or one of {list(ALONE_PRIMITIVES)} "
                          f"alone; got {[next(iter(s)) for s in steps]}")
    held = next(iter(steps[0].values()))
    for i, step in enumerate(steps):
        (name, obj), = step.items()
        primitive = PLAN_PRIMITIVES[name]
        if primitive.kinds is not None and kinds[obj] not in primitive.kinds:
            raise fail(f"{where}[{i}].{name}", f"{obj!r} is a {kinds[obj]}; {name} is defined for {list(primitive.kinds)}")
        if primitive.role == "place" and obj == held:
            raise fail(f"{where}[{i}].{name}", f"must name another object than the one picked, got {obj!r}")
        if primitive.held_kinds is not None and kinds[held] not in primitive.held_kinds:
            raise fail(f"{where}[{i}].{name}", f"the picked {held!r} is a {kinds[held]}; {name} puts down "
                                               f"{list(primitive.held_kinds)}")
    return tuple(dict(s) for s in steps)
