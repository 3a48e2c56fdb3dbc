"""The keys of a world (a file of the ``world`` config group), as typed dataclasses: the one place
that states each key's type, default, unit and meaning.

A world is checked against ``WorldSpec`` with the rest of the configuration (``r2s_eval.schema``),
so every problem is listed at once with its key and the file that set it; ``check_robot`` and
``check_tasks`` do the same for a world slice read outside a composed configuration (a test, a
tool) and raise one ``WorldError`` listing them. ``r2s_eval.sim.robot`` and ``r2s_eval.sim.tasks``
build their runtime objects from the checked spec. What needs the model files (a joint the model
lacks) is checked when the world is assembled (``r2s_eval.sim.assembly.load_world``); success and
progress conditions by ``r2s_eval.sim.predicates``, plans by the operator's primitives.

``python -m r2s_eval.sim.world_spec --markdown`` prints the key reference (``docs/world-keys.md``,
which a test keeps equal to it).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import MISSING, dataclass, field
from typing import Annotated, Any, Literal, Union

from r2s_eval.sim.reading import WorldError
from r2s_eval.typed import Finite, Increasing, NonEmpty, OneOf, Problem, Range, _split, build, check

# ----------------------------------------------------------------------------- value types


@dataclass(frozen=True)
class Distinct:
    def problem(self, v: Sequence) -> str | None:
        return f"names something twice: {list(v)}" if len(set(v)) != len(v) else None


@dataclass(frozen=True)
class NonBlank:
    def problem(self, v: str) -> str | None:
        return "must be a non-empty text" if not v.strip() else None


Number = Annotated[float, Finite()]
PositiveNumber = Annotated[float, Finite(), Range(min=0, open_min=True)]
NonNegativeNumber = Annotated[float, Finite(), Range(min=0)]
Vec3 = tuple[Number, Number, Number]
Dimension = Annotated[int | float, Finite(), Range(min=0, open_min=True)]  # kept as written (n_walls: 16)
Names = Annotated[list[str], NonEmpty(), Distinct()]
Text = Annotated[str, NonBlank()]
Interval = Annotated[tuple[Number, Number], Increasing()]
Axis = Literal["+x", "+y", "+z", "-x", "-y", "-z"]
Hue = Annotated[int, Range(0, 179)]  # OpenCV's 8-bit HSV
Byte = Annotated[int, Range(0, 255)]
GEOM_SIZES = {"box": 3, "sphere": 1, "capsule": 2, "cylinder": 2, "ellipsoid": 3}  # size entries per primitive


def _kinds() -> Sequence[str]:
    from r2s_eval.sim.objects import KINDS

    return KINDS


def _kind(name: str):
    from r2s_eval.sim.objects import KINDS

    return KINDS[name]


def _placements() -> Sequence[str]:
    from r2s_eval.sim.objects import PLACEMENTS

    return PLACEMENTS


def key(doc: str, default: Any = MISSING, unit: str = "") -> Any:
    """A world key: its meaning (one line), its unit and its default (none: the world must set it)."""
    return field(default=default, metadata={"doc": doc, "unit": unit})


# ----------------------------------------------------------------------------- model files


@dataclass(frozen=True)
class FileRef:
    """A file: `path` (relative to the repository, or absolute) or `package` + `resource`."""

    path: str | None = key("the file: relative to the repository, or absolute", None)
    package: str | None = key("an installed Python package that ships the file (read without importing it)", None)
    resource: str | None = key("the file's path inside `package`", None)

    def problems(self) -> list[tuple[str, str]]:
        if (self.path is None) == (self.package is None) or (self.package is None) != (self.resource is None):
            return [("", "must give path, or package and resource")]
        return []


@dataclass(frozen=True)
class ModelRef(FileRef):
    """A model file (MJCF, an include fragment or URDF), with what to take from it."""

    body: str | None = key("take only this body's subtree out of a multi-arm file (with the actuators, tendons, "
                           "equalities, contact excludes and sensors that refer only to it)", None)
    assets: str | FileRef | list[str | FileRef] | None = key(
        "the file(s) holding an include fragment's <asset>, <default> and <compiler>", None)


ModelFile = str | ModelRef  # a path, or a reference with more to say

# ----------------------------------------------------------------------------- robot


@dataclass(frozen=True)
class Workspace:
    z_m: Number = key("height of the table top: objects rest on it, first frames are back-projected onto it",
                      unit="m")
    geom: str = key("the scene's table-top geom (an unnamed one is <body>_geom<i>)")


@dataclass(frozen=True)
class Mount:
    frame: str | None = key("a frame of the scene the arm's model is attached at (or give pos)", None)
    pos: Vec3 | None = key("where the model's world frame goes, in the scene's world frame (or give frame)", None,
                           "m")
    yaw_deg: Number = key("the model's turn about the vertical, with pos", 0.0, "deg")

    def problems(self) -> list[tuple[str, str]]:
        if (self.frame is None) == (self.pos is None):
            return [("", "must give frame, or pos (and yaw_deg)")]
        if self.frame is not None and self.yaw_deg != 0.0:
            return [("yaw_deg", "goes with pos: a frame brings its own orientation")]
        return []


@dataclass(frozen=True)
class Servo:
    kp: PositiveNumber = key("position gain", unit="N m/rad (N/m)")
    kv: Number = key("velocity gain (damping of the servo)", unit="N m s/rad (N s/m)")


@dataclass(frozen=True)
class OpenClosed:
    open: Number = key("the value fully open")
    closed: Number = key("the value fully closed")

    def problems(self) -> list[tuple[str, str]]:
        return [("", f"open and closed must differ, got {self.open} for both")] if self.open == self.closed else []


@dataclass(frozen=True)
class Finger:
    joint: str = key("the finger's joint")
    actuator: str = key("its actuator (an unnamed one is named after the joint it drives)")
    ctrl: OpenClosed = key("the actuator's command fully open / fully closed", unit="model units")
    position: OpenClosed = key("the joint's position fully open / fully closed", unit="model units")


@dataclass(frozen=True)
class Couple:
    joint: str = key("a joint that follows the gripper's first joint (its own actuator is removed)")
    ratio: Number = key("its position per unit of the first joint's (an equality the world adds)")

    def problems(self) -> list[tuple[str, str]]:
        return [("ratio", "must not be 0")] if self.ratio == 0 else []


@dataclass(frozen=True)
class Gripper:
    actuator: str = key("the (first finger's) actuator, commanded by the closing fraction")
    ctrl: OpenClosed = key("the actuator's command fully open / fully closed", unit="model units")
    joint: str | Names = key("the joint whose position measures the opening, or a list: all set open at reset, the "
                             "first measures")
    position: OpenClosed = key("that joint's position fully open / fully closed", unit="model units")
    jaw_open_m: PositiveNumber = key("each jaw's distance from the grasp centre when open (one fixed jaw: the moving "
                                     "jaw's)", unit="m")
    pads: tuple[str, str] = key("the two jaws' bodies (a grasp is contact with both)")
    fingers: tuple[Finger, ...] = key("further fingers, each driven by its own actuator to the same closing "
                                      "fraction", ())
    couple: tuple[Couple, ...] = key("joints that follow the first joint through an equality (instead of fingers)",
                                     ())
    servo: Servo | None = key("position servos of this gain for the gripper's actuator(s); null: the model's", None)

    @property
    def joints(self) -> tuple[str, ...]:
        return (self.joint,) if isinstance(self.joint, str) else tuple(self.joint)

    def problems(self) -> list[tuple[str, str]]:
        problems = []
        if len(set(self.pads)) != 2:
            problems.append(("pads", f"must name the two jaws' bodies, got {list(self.pads)}"))
        if self.fingers and self.couple:
            problems.append(("", "give fingers (each with its actuator) or couple (joints that follow), not both"))
        more = [f.joint for f in self.fingers] + [c.joint for c in self.couple]
        twice = sorted({j for j in more if j in self.joints or more.count(j) > 1})
        if twice:
            problems.append(("fingers" if self.fingers else "couple", f"names joints {twice} twice"))
        return problems


@dataclass(frozen=True)
class Ee:
    site: str = key("a site of the arm's model at (or near) the grasp centre")
    approach: Axis = key("the site's axis along which the hand approaches an object", "+x")
    jaw: Axis = key("the site's axis along which the jaws close", "+y")
    pos: Vec3 = key("the grasp centre in the site's frame (a site that is not midway between the jaws; one fixed "
                    "jaw: where a held object's centre sits)", (0.0, 0.0, 0.0), "m")

    def problems(self) -> list[tuple[str, str]]:
        if self.approach[1] == self.jaw[1]:
            return [("", f"approach and jaw must be different axes, got {self.approach} and {self.jaw}")]
        return []


@dataclass(frozen=True)
class CollisionAdd:
    body: str = key("a body of the arm's model the primitive is added to (collision only, massless)")
    type: Literal["box", "sphere", "capsule", "cylinder", "ellipsoid"] = key("a MuJoCo primitive")
    size: Annotated[tuple[PositiveNumber, ...], NonEmpty()] = key(
        "MuJoCo's size of the primitive (box 3, sphere 1, capsule 2, cylinder 2, ellipsoid 3 numbers)", unit="m")
    pos: Vec3 = key("its centre in the body's frame", (0.0, 0.0, 0.0), "m")
    euler_deg: Vec3 = key("its orientation in the body's frame (x, y, z, intrinsic)", (0.0, 0.0, 0.0), "deg")
    friction: Vec3 | None = key("sliding, torsional, rolling friction; null: MuJoCo's default", None)

    def problems(self) -> list[tuple[str, str]]:
        n = GEOM_SIZES[self.type]
        return [("size", f"must be a list of {n} numbers, got {list(self.size)}")] if len(self.size) != n else []


@dataclass(frozen=True)
class CollisionDisable:
    geoms: Annotated[tuple[str, ...], Distinct()] = key(
        "geoms of the arm's model that stop colliding (an unnamed one is <body>_geom<i>)", ())
    bodies: Annotated[tuple[str, ...], Distinct()] = key("bodies of the arm's model whose collision geoms all stop colliding", ())


@dataclass(frozen=True)
class Collision:
    disable: CollisionDisable = key("the jaws' collision shapes switched off", CollisionDisable())
    add: tuple[CollisionAdd, ...] = key("primitives added in their place", ())


@dataclass(frozen=True)
class Visual:
    max_faces: Annotated[int, Range(min=1)] = key("the arm's drawn meshes decimated to at most this many faces in all")


@dataclass(frozen=True)
class JointPhysics:
    armature: NonNegativeNumber | None = key("added rotor inertia; null: the model's", None, "kg m^2 (kg)")
    damping: NonNegativeNumber | None = key("joint damping; null: the model's", None, "N m s/rad (N s/m)")
    frictionloss: NonNegativeNumber | None = key("dry friction; null: the model's", None, "N m (N)")


@dataclass(frozen=True)
class Physics:
    joints: JointPhysics | None = key("set on the arm's `joints`", None)
    fingers: JointPhysics | None = key("set on the gripper's finger joints", None)


@dataclass(frozen=True)
class Arm:
    model: ModelFile = key("the arm's model file: a path, or {path | package + resource, body, assets}")
    mount: Mount = key("where the arm stands")
    joints: Names = key("the joints the dataset records and commands, in order")
    home: tuple[Number, ...] = key("joint targets at reset, one per joint", unit="model units (rad, m)")
    gripper: Gripper = key("the arm's gripper")
    ee: Ee = key("the grasp centre the scripted operator steers")
    actuators: Names | None = key("their position actuators, one per joint; null: the joint names", None)
    servo: Servo | None = key("replace the joints' actuators with position servos of this gain (a torque-driven "
                              "model); null: the model's actuators", None)
    gravity_compensation: bool = key("compensate gravity on every body of the arm", False)
    collision: Collision | None = key("jaw collision shapes that can hold an object; null: the model's", None)
    visual: Visual | None = key("draw the arm with fewer mesh faces; null: the model's meshes as they are", None)
    physics: Physics | None = key("joint armature, damping and friction the world states; null: the model's", None)

    def problems(self) -> list[tuple[str, str]]:
        problems = []
        if self.actuators is not None and len(self.actuators) != len(self.joints):
            problems.append(("actuators", f"must name one actuator per joint ({len(self.joints)}), "
                                          f"got {list(self.actuators)}"))
        if len(self.home) != len(self.joints):
            problems.append(("home", f"must be a list of {len(self.joints)} numbers (one per joint), "
                                     f"got {list(self.home)}"))
        return problems


@dataclass(frozen=True)
class HueRange:
    hue_lo: Hue = key("lowest hue (wrapping past 179 when hue_lo > hue_hi)", unit="OpenCV hue, 0-179")
    hue_hi: Hue = key("highest hue", unit="OpenCV hue, 0-179")
    sat_min: Byte | None = key("lowest saturation; null: the segmenter's", None, "0-255")
    sat_max: Byte | None = key("highest saturation; null: the segmenter's", None, "0-255")
    val_min: Byte | None = key("lowest value; null: the segmenter's", None, "0-255")
    val_max: Byte | None = key("highest value; null: the segmenter's", None, "0-255")


@dataclass(frozen=True)
class Find:
    hue: HueRange | None = key("the colour segmenter's HSV range; null: around the colour (objects)", None)
    prompt: Text | None = key("the open-vocabulary segmenter's text; null: `a <name>` (objects)", None)

    def hsv(self) -> dict | None:
        """The HSV range as the segmenter takes it: the keys the world gives."""
        return None if self.hue is None else {k: v for k, v in dataclasses.asdict(self.hue).items() if v is not None}


@dataclass(frozen=True)
class Feature:
    name: str = key("the dataset's name of the entry (observation.state and action)")
    arm: str = key("the arm it belongs to")
    joint: str | None = key("the arm's joint it records (or say gripper: true)", None)
    gripper: bool = key("it records the arm's gripper (model unit: the closing fraction, 0 open .. 1 closed)", False)
    scale: Number = key("model value = scale * dataset value + offset", 1.0)
    offset: Number = key("see scale", 0.0, "model units")

    def problems(self) -> list[tuple[str, str]]:
        problems = []
        if (self.joint is not None) == self.gripper:
            problems.append(("", "must name a joint or say gripper: true (one of the two)"))
        if self.scale == 0:
            problems.append(("scale", "must not be 0"))
        return problems


@dataclass(frozen=True)
class Robot:
    scene: ModelFile = key("the scene's model file: table, lights, fixed cameras (a path or {path | package + "
                           "resource, assets})")
    workspace: Workspace = key("the table plane")
    control_hz: PositiveNumber = key("the control rate, the dataset's fps: each action is held for one period",
                                     unit="Hz")
    arms: Annotated[dict[str, Arm], NonEmpty()] = key("the arms by name, in the order of the default dataset layout")
    type: str = key("the datasets' robot_type (LeRobot's info.json)", "robot")
    timestep_s: PositiveNumber | None = key("the physics timestep; null: the scene's (never an arm's model file's). "
                                            "The control period must be whole timesteps", None, "s")
    features: Annotated[tuple[Feature, ...], NonEmpty()] | None = key(
        "the dataset's observation.state / action entries; null: per arm <arm>_<joint> then <arm>_gripper in "
        "model units", None)
    find: Find | None = key("how the robot looks in a frame (the camera fit from its silhouette)", None)

    def problems(self) -> list[tuple[str, str]]:
        if self.features is None:
            return []
        problems, seen = [], {}
        for i, feature in enumerate(self.features):
            where = f"features[{i}]"
            arm = self.arms.get(feature.arm)
            if arm is None:
                problems.append((f"{where}.arm", f"must be an arm of the robot {list(self.arms)}, got {feature.arm!r}"))
                continue
            if feature.joint is not None and feature.joint not in arm.joints:
                problems.append((f"{where}.joint", f"must be a joint of arm {feature.arm} {list(arm.joints)}, "
                                                   f"got {feature.joint!r}"))
                continue
            target = (feature.arm, feature.joint)
            if target in seen:
                problems.append((where, f"maps to {feature.arm} {feature.joint or 'gripper'}, which {seen[target]} "
                                        f"maps to already"))
            seen[target] = where
        names = [f.name for f in self.features]
        if len(set(names)) != len(names):
            problems.append(("features", f"names a feature twice: {names}"))
        uncovered = [f"{a} {j or 'gripper'}" for a, arm in self.arms.items() for j in (*arm.joints, None)
                     if (a, j) not in seen]
        if uncovered and not problems:
            problems.append(("features", f"no feature maps to {uncovered}: every joint and gripper needs one"))
        return problems


# ----------------------------------------------------------------------------- rig


@dataclass(frozen=True)
class Intrinsics:
    fx: PositiveNumber = key("focal length along x", unit="px")
    fy: PositiveNumber = key("focal length along y", unit="px")
    cx: NonNegativeNumber = key("principal point, x (OpenCV: 0 is the first pixel's centre)", unit="px")
    cy: NonNegativeNumber = key("principal point, y", unit="px")
    width: Annotated[int, Range(min=1)] = key("the image width these hold at (they scale with the rendered size)",
                                              unit="px")
    height: Annotated[int, Range(min=1)] = key("the image height these hold at", unit="px")

    def problems(self) -> list[tuple[str, str]]:
        return [(centre, f"must lie inside the {self.width}x{self.height} image (0..{size - 1:g}), got {value!r}")
                for centre, value, size in (("cx", self.cx, self.width), ("cy", self.cy, self.height))
                if value > size - 1]


@dataclass(frozen=True)
class RigCamera:
    camera: str | None = key("a camera of the scene or, with arm, of that arm's model", None)
    arm: str | None = key("the arm whose model holds `camera`", None)
    body: str | None = key("a body the world places a camera on (`world` for the world frame), with pos", None)
    pos: Vec3 | None = key("the placed camera's position in its body's frame", None, "m")
    look_at: Vec3 | None = key("a world point the camera is aimed at; null: as the model has it", None, "m")
    fovy_deg: Annotated[float, Range(0, 180, open_min=True, open_max=True)] | None = key(
        "vertical field of view (MuJoCo's fovy); null: the model's, for a placed camera give it or intrinsics",
        None, "deg")
    intrinsics: Intrinsics | None = key("a lab's calibrated OpenCV intrinsics (instead of fovy_deg)", None)

    def problems(self) -> list[tuple[str, str]]:
        problems = []
        if (self.camera is None) == (self.body is None):
            problems.append(("", "must name a model's camera (camera, with arm for an arm's) or place one (body, pos)"))
        if self.arm is not None and self.camera is None:
            problems.append(("arm", "goes with camera (a camera of that arm's model)"))
        if self.body is not None:
            missing = [k for k in ("pos", "look_at") if getattr(self, k) is None]
            if self.fovy_deg is None and self.intrinsics is None:
                missing.append("fovy_deg or intrinsics")
            if missing:
                problems.append(("", f"a camera placed on a body needs {' and '.join(missing)}"))
        if self.intrinsics is not None and self.fovy_deg is not None:
            problems.append(("", "give intrinsics or fovy_deg, not both"))
        return problems


# ----------------------------------------------------------------------------- objects and tasks


@dataclass(frozen=True)
class Object:
    kind: Annotated[str, OneOf(_kinds)] = key("the object's kind: its builder and geometry (r2s_eval.sim.objects)")
    rgba: tuple[Annotated[float, Range(0, 1)], ...] = key("its colour (the colour segmenter looks for it)",
                                                          unit="0-1 each")
    mass_kg: PositiveNumber = key("its mass", unit="kg")
    dims: dict[str, Dimension] | None = key("the kind's dimensions (kind mesh: its file's)", None, "m")
    friction: PositiveNumber = key("sliding friction coefficient", 1.0)
    find: Find | None = key("how it is found in a camera frame", None)
    mesh: dict | None = key("kind mesh: {file, scale, texture} (r2s_eval.sim.meshes)", None)
    collision: Any = key("kind mesh: hull, or {coacd: {...}} for convex parts (r2s_eval.sim.meshes)", None)
    yaw_symmetry: Annotated[int, Range(min=0)] | None = key("kind mesh: looks the same after 2 pi / n of yaw (0: "
                                                            "round); null: none", None)

    def problems(self) -> list[tuple[str, str]]:
        problems = []
        if len(self.rgba) != 4:
            problems.append(("rgba", f"must be four numbers in [0, 1], got {list(self.rgba)}"))
        if self.kind == "mesh":
            if self.mesh is None:
                problems.append(("mesh", "is missing (a mesh object is read from its file)"))
            if self.dims is not None:
                problems.append(("dims", "a mesh object's dimensions are its file's"))
        else:
            if self.dims is None:
                problems.append(("dims", "is missing"))
            else:  # the kind's own dimensions, no more (a key nothing reads is a mistake)
                kind = _kind(self.kind)
                known = (*kind.dims_keys, *kind.optional_dims_keys)
                problems += [(f"dims.{k}", f"is not a dimension of a {self.kind} {list(known)}")
                             for k in self.dims if k not in known]
                problems += [(f"dims.{k}", "is missing") for k in kind.dims_keys if k not in self.dims]
                if all(k in self.dims for k in kind.dims_keys):
                    problems += kind.dims_problems(dict(self.dims))
            problems += [(k, f"is for kind mesh, not {self.kind}") for k in ("mesh", "collision", "yaw_symmetry")
                         if getattr(self, k) is not None]
        return problems


@dataclass(frozen=True)
class Start:
    x_range_m: Interval = key("the start region along x (world frame, or relative_to's planar frame)", unit="m")
    y_range_m: Interval = key("the start region along y", unit="m")
    yaw_range_rad: Interval = key("yaw drawn uniformly in it", (-math.pi, math.pi), "rad")
    relative_to: str | None = key("another object of the task: the region is in its planar frame, on its support "
                                  "surface", None)
    placement: Annotated[str, OneOf(_placements)] = key("how it starts: upright, upside_down or on_side", "upright")


@dataclass(frozen=True)
class Progress:
    objects: Names = key("the objects whose reach, grasp and lift are stages")
    goal: Any = key("the goal condition (predicates)")
    reach_m: PositiveNumber | None = key("a hand this close has reached the object; null: r2s_eval.sim.predicates'",
                                         None, "m")
    lift_m: PositiveNumber | None = key("an object this much higher is lifted; null: r2s_eval.sim.predicates'", None,
                                        "m")


@dataclass(frozen=True)
class Task:
    instruction: Text = key("the task's text (matched against a dataset's task strings)")
    start: Annotated[dict[str, Start], NonEmpty()] = key("the task's objects (of the world's objects), in order, "
                                                         "with their start regions")
    plan: Any = key("what the twin's scripted operator does: [{pick: X}, {<place>: Y}] or [{turn_upright: X}] "
                    "(Plan primitives, below)")
    success: Any = key("the success condition (predicates)")
    progress: Progress = key("the progress stages towards a goal")
    arm: Text = key("an arm of the robot, nearest (to the objects) or behind_axis (an on_side object)", "nearest")
    clearance_m: PositiveNumber = key("objects' footprints kept this far apart at the start", 0.03, "m")

    def problems(self) -> list[tuple[str, str]]:
        names = list(self.start)
        problems = [(f"start.{n}.relative_to", f"must name another object of the task {names}, got {s.relative_to!r}")
                    for n, s in self.start.items() if s.relative_to is not None and (s.relative_to not in names
                                                                                    or s.relative_to == n)]
        strangers = [m for m in self.progress.objects if m not in names]
        if strangers:
            problems.append(("progress.objects", f"must list objects of the task {names}, "
                                                 f"got {list(self.progress.objects)}"))
        return problems


# ----------------------------------------------------------------------------- the world


@dataclass(frozen=True)
class WorldSpec:
    image_height: Annotated[int, Range(min=1)] = key("height of the recorded images", unit="px")
    image_width: Annotated[int, Range(min=1)] = key("width of the recorded images", unit="px")
    cameras: Annotated[tuple[str, ...], NonEmpty(), Distinct()] = key("the rig's cameras a run records "
                                                                      "(observation.images.<name>)")
    robot: Robot = key("the robot: scene, arms, dataset layout")
    rig: Annotated[dict[str, RigCamera], NonEmpty()] = key("each camera name tied to a camera of a model or "
                                                           "placed by the world")
    objects: Annotated[dict[str, Object], NonEmpty()] = key("the objects tasks use, by name")
    tasks: Annotated[dict[str, Task], NonEmpty()] = key("the tasks, by key")

    def problems(self) -> list[tuple[str, str]]:
        problems = rig_problems(list(self.robot.arms), self.rig, self.cameras)
        for task_key, task in self.tasks.items():
            strangers = [n for n in task.start if n not in self.objects]
            if strangers:
                problems.append((f"tasks.{task_key}.start", f"must name objects of the world {sorted(self.objects)}, "
                                                            f"got {list(task.start)}"))
            if task.arm not in (*self.robot.arms, "nearest", "behind_axis"):
                problems.append((f"tasks.{task_key}.arm", f"must be an arm of the robot {list(self.robot.arms)}, "
                                                          f"nearest or behind_axis, got {task.arm!r}"))
        return problems


def rig_problems(arms: Sequence[str], rig: Mapping[str, RigCamera], cameras: Sequence[str]) -> list[tuple[str, str]]:
    """The rig against the robot's arms (an arm's camera) and the recorded cameras against the rig."""
    problems = [(f"rig.{name}.arm", f"must be an arm of the robot {list(arms)}, got {cam.arm!r}")
                for name, cam in rig.items() if cam.arm is not None and cam.arm not in arms]
    missing = [c for c in cameras if c not in rig]
    if missing:
        problems.append(("cameras", f"records {missing}, which the rig {sorted(rig)} does not place"))
    return problems


# ----------------------------------------------------------------------------- checking a world slice


def _raise(problems: list[Problem]) -> None:
    if problems:
        raise WorldError.listing([(p.path, p.message) for p in problems])


def check_robot(world: Mapping) -> tuple[Robot, dict[str, RigCamera]]:
    """The robot and rig of a world slice (``robot``, ``rig``, optionally ``cameras``), checked: a
    ``WorldError`` lists every problem."""
    cameras = world.get("cameras") or ()
    problems = check(world.get("robot"), Robot, "world.robot")
    rig_problems_ = check(world.get("rig"), dict[str, RigCamera], "world.rig")
    problems += rig_problems_ + check(list(cameras), list[str], "world.cameras")
    arms = world["robot"].get("arms") if isinstance(world.get("robot"), Mapping) else None
    if not rig_problems_ and isinstance(arms, Mapping):  # the rig against the arms named, even with other problems
        problems += [Problem(f"world.{k}", m) for k, m in rig_problems(list(arms), build(dict[str, RigCamera],
                                                                                         world["rig"]), cameras)]
    _raise(problems)
    return build(Robot, world["robot"]), build(dict[str, RigCamera], world["rig"])


def check_tasks(world: Mapping) -> tuple[dict[str, Object], dict[str, Task], list[tuple[str, str]]]:
    """The objects and tasks of a world slice (``objects``, ``tasks``) that pass their own check,
    and the problems of those that do not (a mapping that is not one raises a ``WorldError``)."""
    problems = check(world.get("objects"), dict, "world.objects") + check(world.get("tasks"), Annotated[
        dict, NonEmpty()], "world.tasks")
    _raise(problems)
    sound = {}
    for section, cls in (("objects", Object), ("tasks", Task)):
        sound[section] = {}
        for name, entry in world[section].items():
            found = check(entry, cls, f"world.{section}.{name}")
            problems += found
            if not found:
                sound[section][str(name)] = build(cls, entry)
    return sound["objects"], sound["tasks"], [(p.path, p.message) for p in problems]


# ----------------------------------------------------------------------------- the key reference

RULES = """\
## Rules

- **Names inside a model.** Each arm's model is attached with the prefix `<arm>_`: the arm `left`'s
  joint `j1` is `left_j1` in the assembled model. The world names everything as the model file
  does (`joints: [j1]`, `gripper.pads`, `ee.site`, a rig camera's `camera` with `arm`); the
  prefix appears only where the assembled model is read (a dataset's default feature names,
  `<arm>_<joint>` and `<arm>_gripper`, and the site the world adds at each grasp centre, `<arm>_ee`).
- **Unnamed actuators.** An actuator the model leaves unnamed that drives a joint is named after
  that joint (its name in the model file), so `actuators` and `gripper.actuator` can name it by
  its joint. Two actuators of one joint make the name ambiguous: an error.
- **Unnamed geoms.** A geom the model leaves unnamed in a named body is named `<body>_geom<i>`,
  `i` its place among that body's geoms in the model file, from 0 and counting the named ones:
  the second geom of body `right_follower` is `right_follower_geom1` (`<arm>_right_follower_geom1`
  in the assembled model), so `collision.disable.geoms` (and the scene's `workspace.geom`) can
  name it. A geom name the model lacks stops the run with the arm's colliding geoms listed; a
  derived name that another geom of the file already has is an error.
- **Actuators' default.** `actuators` left out means the joints' names: a model whose position
  actuators are named as their joints (or unnamed) needs no list. `servo` replaces the joints'
  actuators with position servos of its gain (ranged as the joints), for a torque-driven model.
- **Mount.** `mount` moves the arm model's world frame, not its root body: the model's own
  offsets stay, so a root body the file puts 0.15 m from its origin stands 0.15 m from the mount.
  `frame` attaches at a frame of the scene; `pos` with `yaw_deg` places a new frame there.
- **Gripper.** The dataset's gripper value is the closing fraction, 0 fully open .. 1 fully
  closed (a feature's scale and offset convert a recording's unit, e.g. 0..100). It maps
  linearly to the actuator's command between `ctrl.open` and `ctrl.closed` and is measured from
  the first joint's position between `position.open` and `position.closed`. `joint` as a list
  names joints that are set open at reset (a model's own coupled fingers); the first measures.
  `fingers` adds fingers driven by their own actuators to the same closing fraction; `couple`
  makes joints follow the first through an equality the world adds (their own actuators removed).
- **One fixed jaw.** A gripper with one fixed jaw (the SO-101's) closes with the other alone, but
  the scripted operator still puts the grasp centre (`ee.site` moved by `ee.pos`) over an object's
  centre and pre-shapes to the object's half width plus a margin from it. So the grasp centre is
  where a held object's centre sits: off the fixed jaw's inner face by about half the width of the
  objects the tasks pick, plus a few millimetres for the fixed jaw to clear an object's side as the
  hand comes down (the SO-101's 2 cm, for a 2.8 cm block and a 3.2 cm ball). `jaw_open_m` is the
  moving jaw's distance from that centre when fully open (a hinged jaw: a linear fit over the
  openings used), and `pads` still names both jaws' bodies (the fixed jaw's is the hand's). A
  narrower object is pushed against the fixed jaw, off the centre by the difference; a wider one
  meets the fixed jaw on the way down. The recorded end-effector position (`ee_pos_<arm>`, the
  judges' and the success checks' hand) is this point too.
- **Cameras.** A rig entry either names a camera of a model (`camera`, with `arm` for a camera of
  that arm's model, re-aimed with `look_at`) or places one (`body`, `pos`, `look_at`, and
  `fovy_deg` or `intrinsics`). `fovy_deg` is MuJoCo's vertical field of view in degrees;
  `intrinsics` are OpenCV's (pixels, at `width` x `height`; they scale with the rendered size).
- **Model files.** A model reference is a path (relative to the repository, or absolute) or a
  mapping: `path`, or `package` and `resource` (a file shipped in an installed Python package,
  read without importing it), plus `body` (one body subtree of a multi-arm file) and `assets`
  (the files holding an include fragment's assets and defaults). `robot.scene` is a model
  reference too, so a scene may be a package resource. A file may be MJCF (`<mujoco>`), an
  include fragment (`<mujocoinclude>`) or URDF.
- **Simulation settings.** The scene's: its `<option>` (with `robot.timestep_s` for the step),
  `<size>` and `<visual>`. An arm's model file's own (its timestep, solver, tolerance, iterations,
  Jacobian, integrator, cone, impratio, gravity, flags, memory, near plane, ...) give way to them
  without a warning; its `<compiler>` settings still read its own elements (angle units,
  autolimits, inertia from geoms, mesh folder).
- **Units.** SI throughout (m, kg, s, rad) unless a key's name says otherwise (`_deg`, `_hz`);
  joint values are the model's units (rad for a hinge, m for a slide).
"""


def _type_words(tp: Any) -> str:
    tp, markers = _split(tp)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (Union, types.UnionType):
        words = [_type_words(a) for a in args if a is not type(None)]
        return " or ".join(words) + (" or null" if type(None) in args else "")
    one_of = next((m for m in markers if isinstance(m, OneOf)), None)
    if one_of is not None:
        return "one of " + ", ".join(one_of.values())
    if origin is Literal:
        return "one of " + ", ".join(str(a) for a in args)
    if dataclasses.is_dataclass(tp):
        return "mapping" if tp is not ModelRef else "model reference"
    if origin in (list, tuple):
        if origin is tuple and args and Ellipsis not in args:
            return f"list of {len(args)} {_type_words(args[0])}s" if len(set(args)) == 1 else "list"
        return f"list of {_type_words(args[0])}s" if args else "list"
    if origin is dict or tp is dict:
        return f"mapping of name to {_type_words(args[1])}" if args else "mapping"
    bounds = next((m for m in markers if isinstance(m, Range)), None)
    base = {int: "integer", float: "number", str: "text", bool: "true/false"}.get(tp, "any")
    if bounds is not None:
        low = "-inf" if bounds.min is None else f"{bounds.min:g}"
        high = "inf" if bounds.max is None else f"{bounds.max:g}"
        base += f" in {'(' if bounds.open_min else '['}{low}, {high}{')' if bounds.open_max else ']'}"
    return base


def _default_words(f: dataclasses.Field) -> str:
    if f.default is MISSING:
        return "required"
    value = f.default
    if dataclasses.is_dataclass(value):
        return "(see below)"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, tuple):
        return "[" + ", ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in value) + "]"
    return f"{value:.4g}" if isinstance(value, float) else str(value)


SECTIONS = ((WorldSpec, "world", "The world"), (Robot, "world.robot", "robot"),
            (Workspace, "world.robot.workspace", "robot.workspace"),
            (Arm, "world.robot.arms.<arm>", "An arm"), (ModelRef, "model", "A model reference"),
            (Mount, "world.robot.arms.<arm>.mount", "mount"), (Servo, "servo", "servo (an arm's, a gripper's)"),
            (Gripper, "world.robot.arms.<arm>.gripper", "gripper"), (OpenClosed, "ctrl / position", "open and closed"),
            (Finger, "world.robot.arms.<arm>.gripper.fingers[]", "gripper.fingers"),
            (Couple, "world.robot.arms.<arm>.gripper.couple[]", "gripper.couple"),
            (Ee, "world.robot.arms.<arm>.ee", "ee"), (Collision, "world.robot.arms.<arm>.collision", "collision"),
            (CollisionDisable, "world.robot.arms.<arm>.collision.disable", "collision.disable"),
            (CollisionAdd, "world.robot.arms.<arm>.collision.add[]", "collision.add"),
            (Visual, "world.robot.arms.<arm>.visual", "visual"),
            (Physics, "world.robot.arms.<arm>.physics", "physics"),
            (JointPhysics, "physics.joints / physics.fingers", "physics.joints and physics.fingers"),
            (Feature, "world.robot.features[]", "robot.features"), (Find, "find", "find (the robot's, an object's)"),
            (HueRange, "find.hue", "find.hue"), (RigCamera, "world.rig.<camera>", "A rig camera"),
            (Intrinsics, "world.rig.<camera>.intrinsics", "intrinsics"),
            (Object, "world.objects.<object>", "An object"), (Task, "world.tasks.<task>", "A task"),
            (Start, "world.tasks.<task>.start.<object>", "A start region"),
            (Progress, "world.tasks.<task>.progress", "progress"))


def markdown() -> str:
    """The key reference page: every key of every section, its type, default, unit and meaning."""
    out = ["# World keys", "",
           "Every key of a world file (`conf/world/<name>.yaml`), generated from `r2s_eval.sim.world_spec` "
           "(`python -m r2s_eval.sim.world_spec --markdown > docs/world-keys.md`; a test keeps this page equal "
           "to it). How to write a world: [Writing a world](world-howto.md).", ""]
    for cls, prefix, title in SECTIONS:
        hints = typing.get_type_hints(cls, include_extras=True)
        out += [f"## {title}", "", f"`{prefix}`" + (f": {cls.__doc__.strip()}" if cls.__doc__ and not
                                                    cls.__doc__.startswith(cls.__name__ + "(") else ""), "",
                "| key | type | default | unit | meaning |", "|---|---|---|---|---|"]
        for f in dataclasses.fields(cls):
            cells = (f"`{f.name}`", _type_words(hints[f.name]), _default_words(f), f.metadata.get("unit", ""),
                     f.metadata["doc"])
            out.append("| " + " | ".join(c.replace("|", "\\|").replace("<", "&lt;") for c in cells) + " |")
        out.append("")
    return "\n".join(out + _object_kinds() + _plan_primitives()) + "\n" + RULES


def _object_kinds() -> list[str]:
    """The kinds an object may be and the dimensions each takes (``r2s_eval.sim.objects``)."""
    from r2s_eval.sim.objects import KINDS

    out = ["## Object kinds", "", "`world.objects.<name>.kind` and the `dims` each kind takes (metres; `n_` keys "
           "are counts).", "", "| kind | dims | optional dims | starts |", "|---|---|---|---|"]
    for kind in KINDS.values():
        dims = "read off its mesh file" if kind.name == "mesh" else ", ".join(f"`{k}`" for k in kind.dims_keys)
        optional = ", ".join(f"`{k}`" for k in kind.optional_dims_keys)
        out.append(f"| `{kind.name}` | {dims} | {optional} | {', '.join(kind.placements)} |")
    return [*out, ""]


def _plan_primitives() -> list[str]:
    """The steps a task's ``plan`` may take (``r2s_eval.sim.plans``, which the task check reads)."""
    from r2s_eval.sim.plans import PLAN_PRIMITIVES

    roles = {"pick": "first step", "place": "second step, after a pick", "alone": "the whole plan"}
    out = ["## Plan primitives", "",
           "`world.tasks.<key>.plan`: a `pick` then one place step, or one step that is the whole plan.", "",
           "| primitive | step | names | the scripted operator |", "|---|---|---|---|"]
    for p in PLAN_PRIMITIVES.values():
        names = p.argument + (f" (a {' or '.join(p.kinds)})" if p.kinds else "")
        out.append(f"| `{p.name}` | {roles[p.role]} | {names} | {p.doc} |")
    return [*out, ""]


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--markdown", action="store_true", help="print the key reference (docs/world-keys.md)")
    args = parser.parse_args(argv)
    if args.markdown:
        print(markdown(), end="")


if __name__ == "__main__":
    main()
