"""Tasks: instruction, objects, start regions, success and progress, read from the world config.

A task is data (the ``world`` config group, ``conf/world/<name>.yaml``; the bundled world is
``tabletop``, picked with ``world=<name>``): its
``success`` is a condition of documented predicates and its ``progress`` stages towards a goal
condition (``r2s_eval.sim.predicates``), both compiled here into functions of the scene:

* ``success(scene) -> bool``: the rule-based check of the current state.
* ``progress(scene) -> float`` in [0, 1]: the highest stage reached *in the current state*;
  the env also keeps the running maximum over an episode.

The keys of an object (``world.objects.<name>``) and a task entry (``world.tasks.<key>``), their
defaults and units are ``r2s_eval.sim.world_spec``'s (the reference: ``docs/world-keys.md``);
``load_tasks`` builds the runtime objects below from the checked spec. Start regions are boxes
on the table top for each object's planar pose (footprint centre, see ``objects.py``), drawn by
rejection sampling so footprints keep ``clearance_m``; a region ``relative_to`` another object is
in that object's planar frame and the object starts on its support surface (a block in a box).

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
from r2s_eval.sim import world_spec as spec
from r2s_eval.sim.reading import WorldError, fail  # noqa: F401 (WorldError: re-exported)
from r2s_eval.sim.objects import ObjectSpec
from r2s_eval.sim.meshes import load_shape
from r2s_eval.sim.plans import read_plan
from r2s_eval.sim.predicates import ConditionError, Scene, compile_condition, condition_objects, staged_progress
from r2s_eval.errors import ConfigError

WORLDS_DIR = CONF_DIR / "world"  # the `world` config group


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
    # What the scripted operator does: [{pick: X}, {<place primitive>: Y}] or [{turn_upright: X}] (plans.py).
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
        return obj.symmetry if obj.symmetry is not None else obj.kind_object.yaw_symmetry(self.placement(name), obj.dims)


# ---------------------------------------------------------------- reading a world
def _object(name: str, entry: spec.Object) -> ObjectSpec:
    where = f"objects.{name}"
    mesh_keys = {k: getattr(entry, k) for k in ("mesh", "collision") if getattr(entry, k) is not None}
    shape = load_shape(mesh_keys, where) if entry.kind == "mesh" else None
    dims = shape.dims() if shape is not None else dict(entry.dims)
    return ObjectSpec(name=name, kind=entry.kind, rgba=entry.rgba, dims=dims, mass_kg=entry.mass_kg,
                      friction=entry.friction, hue=None if entry.find is None else entry.find.hsv(),
                      prompt=None if entry.find is None else entry.find.prompt, shape=shape,
                      symmetry=entry.yaw_symmetry)


def _condition(condition: Any, objects: Mapping[str, ObjectSpec], where: str):
    names = list(objects)
    strangers = sorted(condition_objects(condition) - set(names))
    if strangers:
        raise fail(where, f"names {strangers}, which are not objects of the task {names}")
    try:
        return compile_condition(condition, where, {n: o.kind for n, o in objects.items()})
    except ConditionError as err:
        raise fail(err.path, err.message) from None


def _task(key: str, entry: spec.Task, objects: dict[str, ObjectSpec]) -> Task:
    where = f"tasks.{key}"
    names = list(entry.start)
    regions = {n: Region(x_range_m=s.x_range_m, y_range_m=s.y_range_m, yaw_range_rad=s.yaw_range_rad,
                         relative_to=s.relative_to) for n, s in entry.start.items()}
    for name, start in entry.start.items():
        kind = objects[name].kind_object
        if start.placement not in kind.placements:
            raise fail(f"{where}.start.{name}.placement", f"a {kind.name} object starts {' or '.join(kind.placements)}"
                                                          f"{kind.placement_note}, got {start.placement!r}")
    plan = read_plan(entry.plan, {n: objects[n].kind for n in names}, f"{where}.plan")
    mine = {n: objects[n] for n in names}
    success = _condition(entry.success, mine, f"{where}.success")
    stages = entry.progress
    goal = _condition(stages.goal, mine, f"{where}.progress.goal")
    thresholds = {k: getattr(stages, k) for k in ("reach_m", "lift_m") if getattr(stages, k) is not None}
    return Task(
        key=key, instruction=entry.instruction, objects=tuple(objects[n] for n in names), init_regions=regions,
        success=success, progress=staged_progress(stages.objects, goal, **thresholds), plan=plan, arm=entry.arm,
        clearance_m=entry.clearance_m,
        placements={n: s.placement for n, s in entry.start.items() if s.placement != "upright"},
        success_condition=entry.success,
        progress_stages={"objects": list(stages.objects), "goal": stages.goal, **thresholds},
    )


def load_tasks(world: Mapping) -> dict[str, Task]:
    """The tasks of a world (the ``world`` config group's ``objects`` and ``tasks``), checked
    against ``r2s_eval.sim.world_spec``, then their objects' files, plans and conditions: a
    ``WorldError`` names the wrong key, or lists every one."""
    objects_spec, tasks_spec, problems = spec.check_tasks(world)
    objects, tasks = {}, {}
    for name, entry in objects_spec.items():
        try:
            objects[name] = _object(name, entry)
        except WorldError as err:
            problems += err.problems
    for key, entry in tasks_spec.items():
        strangers = [n for n in entry.start if n not in world["objects"]]
        if strangers:
            problems.append((f"world.tasks.{key}.start",
                             f"must name objects of the world {sorted(objects_spec)}, got {list(entry.start)}"))
        elif all(n in objects for n in entry.start):  # an object that failed is reported once, above
            try:
                tasks[key] = _task(key, entry, objects)
            except WorldError as err:
                problems += err.problems
    if problems:
        raise WorldError.listing(problems)
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
