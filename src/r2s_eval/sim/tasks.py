"""Tasks: instruction, objects, start regions, success and progress, read from the world config.

A task is data (the ``world`` config group, ``conf/world/<name>.yaml``; the bundled world is
``tabletop``, picked with ``world=<name>``): its
``success`` is a condition of documented predicates and its ``progress`` stages towards a goal
condition (``r2s_eval.sim.predicates``), both compiled here into functions of the scene:

* ``success(scene) -> bool``: the rule-based check of the current state.
* ``progress(scene) -> float`` in [0, 1]: the highest stage reached *in the current state*;
  the env also keeps the running maximum over an episode.

An object (``world.objects.<name>``): ``kind`` (cup, plate, ball, block, box: the builders and
geometry of ``objects.py``; or mesh, a scanned object read from its file, ``meshes.py``), ``rgba`` (its colour, which the colour segmenter looks for), ``dims``
(the kind's dimensions, metres), ``mass_kg``, optionally ``friction`` (1.0) and ``find``, how it is
found in a camera frame: ``hue`` (an explicit HSV range ``{hue_lo, hue_hi, sat_min, val_min}``,
OpenCV units; default: around ``rgba``) and ``prompt`` (the open-vocabulary segmenter's text,
default ``"a <name>"``).

A task entry (``world.tasks.<key>``)::

    instruction: Pick the Cup and Place it on the Plate   # matched against a dataset's task strings
    start:                                   # the task's objects (of the world's `objects`), in order
      cup: {x_range_m: [-0.12, 0.06], y_range_m: [-0.16, 0.16]}   # + yaw_range_rad (default any yaw),
      plate: {x_range_m: [...], y_range_m: [...]}                 #   placement, relative_to
    plan: [{pick: cup}, {place_on: plate}]   # what the twin's scripted operator does (r2s_eval.twin.operator)
    arm: nearest                             # an arm of the robot | nearest | behind_axis (default nearest)
    clearance_m: 0.03                        # footprints kept this far apart at the start (default)
    success: {all: [{upright: {object: cup}}, {on_top_of: {object: cup, support: plate}}, ...]}
    progress: {objects: [cup], goal: {over: {object: cup, target: plate}}}

Start regions are axis-aligned boxes on the table top (world frame, metres) for each object's
planar pose (footprint centre, see ``objects.py``), with yaw uniform in ``yaw_range_rad``; poses
are drawn by rejection sampling so footprints keep ``clearance_m``. A region ``relative_to``
another object is expressed in that object's planar frame (its x, y rotated by its yaw) and the
object starts on the other's support surface (a block inside a box). Each object starts in a
placement (``upright`` by default, ``upside_down``, ``on_side``).

The bundled world's seven tasks (``conf/world/tabletop.yaml`` states them in full):

================  ==========================================  ==========================
key               instruction                                 objects (start placement)
================  ==========================================  ==========================
cover_ball        Cover the Ball with the Cup                 cup (upside down), ball
ball_in_box       Pick the Ball and Place it in the Box       ball, box
ball_in_cup       Pick the Ball and Place it in the Cup       ball, cup
cup_on_plate      Pick the Cup and Place it on the Plate      cup, plate
stack_blocks      Stack the Two Blocks                        block_a, block_b
block_from_box    Take the Block out of the Box               box, block_a (in the box)
upright_cup       Upright the Fallen Cup                      cup (on its side)
================  ==========================================  ==========================
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from r2s_eval.paths import CONF_DIR
from r2s_eval.sim.reading import WorldError, as_mapping, check_keys, fail, finite, interval, read_find  # noqa: F401 (WorldError: re-exported)
from r2s_eval.sim.objects import KINDS, PLACEMENTS, ObjectSpec
from r2s_eval.sim.meshes import MESH_KEYS, load_shape, yaw_symmetry_of
from r2s_eval.sim.predicates import ConditionError, Scene, compile_condition, condition_objects, staged_progress
from r2s_eval.errors import ConfigError

WORLDS_DIR = CONF_DIR / "world"  # the `world` config group
# The scripted operator's plan primitives (r2s_eval.twin.operator): a pick and one place, or a turn.
PLACE_PRIMITIVES = ("place_on", "place_in", "place_over", "put_down_beside")
PLAN_PRIMITIVES = ("pick", *PLACE_PRIMITIVES, "turn_upright")


@dataclass(frozen=True)
class Region:
    x_range_m: tuple[float, float]
    y_range_m: tuple[float, float]
    yaw_range_rad: tuple[float, float] = (-np.pi, np.pi)
    relative_to: str | None = None  # x/y ranges in this object's planar frame


@dataclass(frozen=True)
class Task:
    key: str
    instruction: str
    objects: tuple[ObjectSpec, ...]
    init_regions: dict[str, Region]
    success: Callable[[Scene], bool]
    progress: Callable[[Scene], float]
    # What the scripted operator does: [{pick: X}, {<place primitive>: Y}] or [{turn_upright: X}].
    plan: tuple[dict[str, str], ...] = ()
    # "left", "right", "nearest" (the arm whose base is nearest to the midpoint of the
    # objects), or "behind_axis" (on_side objects: the arm on the side the object's axis
    # points away from, so the gripper ends pointing along it).
    arm: str = "nearest"
    clearance_m: float = 0.03
    placements: dict[str, str] = field(default_factory=dict)  # missing -> "upright"
    success_condition: Any = None  # the world's entries the two functions were compiled from
    progress_stages: Any = None

    def placement(self, name: str) -> str:
        return self.placements.get(name, "upright")

    @property
    def manipulated(self) -> str:
        """The object the operator grasps and moves (the first of its plan)."""
        return next(iter(self.plan[0].values()))

    @property
    def object_names(self) -> tuple[str, ...]:
        return tuple(o.name for o in self.objects)

    def object(self, name: str) -> ObjectSpec:
        return next(o for o in self.objects if o.name == name)

    def yaw_symmetry(self, name: str) -> int:
        """Yaw symmetry of the object in its start placement (its kind's, ``ObjectKind.yaw_symmetry``)."""
        obj = self.object(name)
        return obj.symmetry if obj.symmetry is not None else obj.kind_object.yaw_symmetry(self.placement(name))


# ---------------------------------------------------------------- reading a world
def _object(name: str, entry: Any) -> ObjectSpec:
    where = f"objects.{name}"
    entry = as_mapping(entry, where)
    if entry.get("kind") not in KINDS:
        raise fail(f"{where}.kind", f"must be one of {sorted(KINDS)}, got {entry.get('kind')!r}")
    common = {"kind", "rgba", "mass_kg", "friction", "find"}
    if entry["kind"] == "mesh":  # a scanned object: its dimensions are its mesh's
        check_keys(entry, common | MESH_KEYS, {"kind", "rgba", "mass_kg", "mesh"}, where)
    else:
        check_keys(entry, common | {"dims"}, {"kind", "rgba", "dims", "mass_kg"}, where)
    rgba = entry["rgba"]
    if not isinstance(rgba, list) or len(rgba) != 4 or not all(0 <= finite(c, f"{where}.rgba") <= 1 for c in rgba):
        raise fail(f"{where}.rgba", f"must be four numbers in [0, 1], got {rgba!r}")
    shape = load_shape(entry, where) if entry["kind"] == "mesh" else None
    dims = shape.dims() if shape is not None else as_mapping(entry["dims"], f"{where}.dims")
    for key, value in dims.items():
        finite(value, f"{where}.dims.{key}", positive=True)
    hue, prompt = read_find(entry.get("find"), f"{where}.find")
    return ObjectSpec(name=name, kind=entry["kind"], rgba=tuple(rgba), dims=dims,
                      mass_kg=finite(entry["mass_kg"], f"{where}.mass_kg", positive=True),
                      friction=finite(entry.get("friction", 1.0), f"{where}.friction", positive=True),
                      hue=hue, prompt=prompt, shape=shape, symmetry=yaw_symmetry_of(entry, where))


def _region(entry: Any, names: list[str], name: str, where: str) -> tuple[Region, str]:
    entry = as_mapping(entry, where)
    check_keys(entry, {"x_range_m", "y_range_m", "yaw_range_rad", "relative_to", "placement"}, {"x_range_m", "y_range_m"},
          where)
    placement = entry.get("placement", "upright")
    if placement not in PLACEMENTS:
        raise fail(f"{where}.placement", f"must be one of {list(PLACEMENTS)}, got {placement!r}")
    parent = entry.get("relative_to")
    if parent is not None and (parent not in names or parent == name):
        raise fail(f"{where}.relative_to", f"must name another object of the task {names}, got {parent!r}")
    yaw = interval(entry["yaw_range_rad"], f"{where}.yaw_range_rad") if "yaw_range_rad" in entry else (-np.pi, np.pi)
    region = Region(x_range_m=interval(entry["x_range_m"], f"{where}.x_range_m"),
                    y_range_m=interval(entry["y_range_m"], f"{where}.y_range_m"), yaw_range_rad=yaw,
                    relative_to=parent)
    return region, placement


def _condition(spec: Any, objects: Mapping[str, ObjectSpec], where: str):
    names = list(objects)
    strangers = sorted(condition_objects(spec) - set(names))
    if strangers:
        raise fail(where, f"names {strangers}, which are not objects of the task {names}")
    try:
        return compile_condition(spec, where, {n: o.kind for n, o in objects.items()})
    except ConditionError as err:
        raise fail(err.path, err.message) from None


def _plan(value: Any, names: list[str], where: str) -> tuple[dict[str, str], ...]:
    steps = value if isinstance(value, list) else []
    if not all(isinstance(s, Mapping) and len(s) == 1 for s in steps):
        raise fail(where, f"must be a list of one-key steps, e.g. [{{pick: cup}}, {{place_on: plate}}], got {value!r}")
    kinds = [next(iter(s)) for s in steps]
    for i, step in enumerate(steps):
        (primitive, obj), = step.items()
        if primitive not in PLAN_PRIMITIVES:
            raise fail(f"{where}[{i}]", f"unknown primitive {primitive!r}; primitives are {list(PLAN_PRIMITIVES)}")
        if obj not in names:
            raise fail(f"{where}[{i}].{primitive}", f"must name an object of the task {names}, got {obj!r}")
    if not (kinds == ["turn_upright"] or (len(kinds) == 2 and kinds[0] == "pick" and kinds[1] in PLACE_PRIMITIVES)):
        raise fail(where, f"must be a pick and one of {list(PLACE_PRIMITIVES)}, or a turn_upright alone; got {kinds}")
    return tuple(dict(s) for s in steps)


def _task(key: str, entry: Any, objects: dict[str, ObjectSpec]) -> Task:
    where = f"tasks.{key}"
    entry = as_mapping(entry, where)
    check_keys(entry, {"instruction", "start", "plan", "arm", "clearance_m", "success", "progress"},
          {"instruction", "start", "plan", "success", "progress"}, where)
    if not isinstance(entry["instruction"], str) or not entry["instruction"].strip():
        raise fail(f"{where}.instruction", "must be a non-empty text")
    start = as_mapping(entry["start"], f"{where}.start")
    names = list(start)
    unknown = [n for n in names if n not in objects]
    if not names or unknown:
        raise fail(f"{where}.start", f"must name objects of the world {sorted(objects)}, got {names}")
    regions, placements = {}, {}
    for name in names:
        regions[name], placement = _region(start[name], names, name, f"{where}.start.{name}")
        kind = objects[name].kind_object
        if placement not in kind.placements:
            raise fail(f"{where}.start.{name}.placement", f"a {kind.name} object starts {' or '.join(kind.placements)}"
                                                          f"{kind.placement_note}, got {placement!r}")
        if placement != "upright":
            placements[name] = placement
    plan = _plan(entry["plan"], names, f"{where}.plan")
    arm = entry.get("arm", "nearest")
    if not isinstance(arm, str) or not arm:  # an arm of the world's robot: checked with the robot
        raise fail(f"{where}.arm", f"must name an arm of the robot, nearest or behind_axis, got {arm!r}")
    mine = {n: objects[n] for n in names}
    success = _condition(entry["success"], mine, f"{where}.success")
    stages = as_mapping(entry["progress"], f"{where}.progress")
    check_keys(stages, {"objects", "goal", "reach_m", "lift_m"}, {"objects", "goal"}, f"{where}.progress")
    movers = stages["objects"]
    if not isinstance(movers, list) or not movers or any(m not in names for m in movers):
        raise fail(f"{where}.progress.objects", f"must list objects of the task {names}, got {movers!r}")
    goal = _condition(stages["goal"], mine, f"{where}.progress.goal")
    thresholds = {k: finite(stages[k], f"{where}.progress.{k}", positive=True)
                  for k in ("reach_m", "lift_m") if k in stages}
    return Task(
        key=key, instruction=entry["instruction"], objects=tuple(objects[n] for n in names), init_regions=regions,
        success=success, progress=staged_progress(tuple(movers), goal, **thresholds), plan=plan, arm=arm,
        clearance_m=finite(entry.get("clearance_m", 0.03), f"{where}.clearance_m", positive=True),
        placements=placements, success_condition=entry["success"], progress_stages=stages,
    )


def load_tasks(world: Mapping) -> dict[str, Task]:
    """The tasks of a world (the ``world`` config group's ``objects`` and ``tasks``), checked: a
    wrong entry is a ``WorldError`` naming its key."""
    objects = {str(n): _object(str(n), e) for n, e in as_mapping(world.get("objects"), "objects").items()}
    tasks = {str(k): _task(str(k), e, objects) for k, e in as_mapping(world.get("tasks"), "tasks").items()}
    if not tasks:
        raise fail("tasks", "must list at least one task")
    return tasks


_LOADED: dict[str, dict[str, Task]] = {}


def world_tasks(world: Mapping) -> dict[str, Task]:
    """The tasks of ``world`` (a ``world`` config slice), compiled once per content."""
    key = json.dumps({"objects": world.get("objects"), "tasks": world.get("tasks")}, sort_keys=True)
    if key not in _LOADED:
        _LOADED[key] = load_tasks(world)
    return _LOADED[key]


def world_names() -> list[str]:
    """The worlds of the ``world`` config group."""
    return sorted(p.stem for p in WORLDS_DIR.glob("*.yaml"))


def world_config(world: str | Path) -> dict:
    """The config of ``world``, a world of the ``world`` config group (``conf/world/<name>.yaml``)
    or a world file (``.yaml``), as the file states it: for callers without a composed config (a
    command line, the Gymnasium environment, tests)."""
    path = Path(world)
    if path.suffix not in (".yaml", ".yml"):
        path = WORLDS_DIR / f"{world}.yaml"
        if not path.is_file():
            raise ConfigError(f"unknown world {str(world)!r}: the worlds are {world_names()}, or give a world file (.yaml)")
    elif not path.is_file():
        raise ConfigError(f"world file {str(world)!r} does not exist")
    config = yaml.safe_load(path.read_text())
    if not isinstance(config, dict) or "robot" not in config:
        raise ConfigError(f"{path}: not a world file (no 'robot' entry)")
    return config


def get_task(key: str, world: Mapping) -> Task:
    """Task ``key`` of ``world`` (a ``world`` config slice)."""
    tasks = world_tasks(world)
    try:
        return tasks[key]
    except KeyError:
        raise ConfigError(f"unknown task {key!r}; the world's tasks are {sorted(tasks)}") from None


def sample_initial_poses(
    task: Task, rng: np.random.Generator, size_scales: dict[str, float] | None = None, max_tries: int = 1000
) -> dict[str, tuple[float, float, float]]:
    """Planar poses {name: (x_m, y_m, yaw_rad)} inside the task regions, footprints apart.

    Objects placed relative to another (a block in a box) are exempt from the clearance
    check against that object.
    """
    size_scales = size_scales or {}
    radii = {
        o.name: o.kind_object.footprint_radius_m(o.scaled_dims(size_scales.get(o.name, 1.0)), task.placement(o.name))
        for o in task.objects
    }
    # Objects in a parent's frame are drawn after their parent.
    order = sorted(task.objects, key=lambda o: task.init_regions[o.name].relative_to is not None)
    for _ in range(max_tries):
        poses: dict[str, tuple[float, float, float]] = {}
        for obj in order:
            region = task.init_regions[obj.name]
            u, v = float(rng.uniform(*region.x_range_m)), float(rng.uniform(*region.y_range_m))
            yaw = float(rng.uniform(*region.yaw_range_rad))
            if region.relative_to is not None:
                px, py, pyaw = poses[region.relative_to]
                c, s = np.cos(pyaw), np.sin(pyaw)
                u, v = px + c * u - s * v, py + s * u + c * v
            poses[obj.name] = (u, v, yaw)
        names = list(poses)
        ok = all(
            np.hypot(poses[a][0] - poses[b][0], poses[a][1] - poses[b][1]) > radii[a] + radii[b] + task.clearance_m
            for i, a in enumerate(names)
            for b in names[i + 1 :]
            if b != task.init_regions[a].relative_to and a != task.init_regions[b].relative_to
        )
        if ok:
            return poses
    raise fail(f"tasks.{task.key}.start", f"leaves no room: no draw of {max_tries} keeps the objects' footprints "
                     f"{task.clearance_m:g} m apart (regions overlap too much)")
