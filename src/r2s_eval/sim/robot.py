"""The robot and the camera rig of a world, read from its config (``world.robot``, ``world.rig``).

Everything the simulation needs to know about a lab's robot is data here: which model file, where
each arm stands, which of its joints and actuators the dataset records and commands (in which units),
its grippers, the end-effector frames the scripted operator steers, and the control rate.

``world.robot``::

    type: r2s_dual_arm                # optional: the datasets' robot_type (LeRobot's info.json)
    scene: assets/tabletop.xml        # table, lights, fixed cameras (a model reference, below)
    workspace: {z_m: 0.75, geom: table_top}  # the table plane (objects rest on it, first frames
                                      #   are back-projected onto it) and the scene's table geom
    control_hz: 10                    # the dataset's fps; each action is held for one period
    timestep_s: 0.002                 # optional: the physics timestep (default: the scene's); the
                                      #   control period must be a whole number of them
    arms:                             # in the order the default dataset layout lists them
      left:
        model: assets/arm.xml         # attached with the prefix "<arm>_"
        mount: {frame: left_mount}    # a frame of the scene, or {pos: [x, y, z], yaw_deg: 0}
        joints: [j1, j2, j3, j4, j5, j6]
        actuators: [j1, ...]          # position actuators of those joints (default: same names)
        servo: {kp: 400, kv: 40}      # optional: replace the joints' actuators with position
                                      #   servos of this gain (for torque-controlled models)
        gravity_compensation: false   # optional: compensate gravity on the arm's bodies
        home: [0.0, -0.2, ...]        # joint targets at reset (model units)
        gripper:
          actuator: gripper
          ctrl: {open: 0.05, closed: 0.0}      # actuator command fully open / fully closed
          joint: finger_a                      # the joint whose position measures the opening (or a
                                               #   list: all set open at reset, the first measures)
          position: {open: 0.05, closed: 0.0}  # that joint's position fully open / closed
          jaw_open_m: 0.05            # each jaw's distance from the grasp centre when open
          pads: [finger_a, finger_b]  # the two jaws' bodies (a grasp is contact with both)
        ee: {site: tcp, approach: +x, jaw: +y}  # grasp-centre site; its axes along the approach
                                      #   direction and the jaws' closing axis; optional
                                      #   pos: [x, y, z], the grasp centre in the site's frame
                                      #   (a site that is not midway between the jaws)
        collision:                    # optional: jaw collision shapes that can hold an object
          disable: {geoms: [pad_mesh], bodies: [finger_a]}  # these geoms and every collision
                                      #   geom of these bodies stop colliding
          add:                        # primitive geoms added to bodies of the arm (collision only)
            - {body: finger_a, type: box, size: [0.01, 0.002, 0.01], pos: [0, 0, 0.04],
               euler_deg: [0, 0, 0], friction: [1.0, 0.005, 0.0001]}  # in the body's frame; euler_deg
                                      #   (x, y, z, intrinsic), friction (MuJoCo's default) optional
        visual: {max_faces: 20000}    # optional: draw the arm with at most this many mesh faces
    find: {hue: {hue_lo: 0, hue_hi: 179, sat_max: 40}}  # optional: how the robot looks in a
                                      #   frame, for the camera fit from its silhouette (an HSV
                                      #   range as objects' find, or {prompt: ...} for the
                                      #   open-vocabulary segmenter)
    features:                         # optional: the dataset's observation.state / action entries
      - {name: left_j1, arm: left, joint: j1, scale: 1.0, offset: 0.0}
      - {name: left_gripper, arm: left, gripper: true}

A model reference is a path (relative to the repository, or absolute) or
``{package: <python package>, resource: <path inside it>}`` for a model shipped in an installed
package; ``{path | package + resource, assets: ..., body: ...}`` names an include fragment with the
file(s) holding its assets, or one top body of a multi-arm file (``r2s_eval.sim.model_files``).
An arm's optional ``physics: {joints: {armature, damping, frictionloss}, fingers: {...}}`` sets
those joint properties; a gripper's optional ``fingers``, ``couple`` and ``servo`` give it further
fingers, joints that follow its first, and position servos (docs/world-models.md). A feature's value converts to model units as ``scale * value + offset`` (a joint in
degrees: ``scale: 0.017453``); a gripper feature's model unit is the closing fraction (0 open,
1 closed). Without ``features`` the layout is, arm by arm, ``<arm>_<joint>`` then ``<arm>_gripper``
in model units. Every joint and gripper of every arm is named by exactly one feature.

``collision`` is for a gripper whose jaws cannot hold an object by friction in the simulation
(jaw geoms that are convex hulls of whole printed parts meet an object on slanted faces and
squeeze it out): it swaps the jaws' collision shapes for primitives of the real jaws' faces.
The added geoms are invisible and massless and collide as their body's own collision geoms did.
It changes only what touches what; it adds no force a real gripper lacks.

``visual`` is for a model whose drawn meshes are CAD exports of hundreds of thousands of faces, which
a software renderer (EGL on llvmpipe) draws at tens of milliseconds a frame: the arm's visual geoms
(mesh geoms with ``contype`` and ``conaffinity`` 0) draw decimated copies of their mesh files
instead, the budget split over the meshes in proportion to their faces (a mesh drawn by several
geoms counts as often; none goes below 32 faces). Materials and colours stay; the collision geoms,
their meshes and the bodies' masses and inertias stay exactly as the model has them (a body whose
inertia came from its geoms keeps the one the full meshes give). Decimated meshes are cached like
scanned objects' convex parts (``r2s_eval.sim.meshes``). Geoms whose material has a texture keep
their meshes (decimation drops texture coordinates).

``world.rig`` ties each camera name (the dataset's ``observation.images.<name>``) to a camera::

    head_left: {camera: head_left, look_at: [-0.03, 0.0, 0.75]}   # a camera of the scene, re-aimed
    wrist_left: {camera: wrist, arm: left}                        # a camera of an arm's model
    front: {body: world, pos: [0.6, 0, 1.3], look_at: [0, 0, 0.75], fovy_deg: 45}  # placed here
    # any entry: intrinsics: {fx: 520, fy: 520, cx: 319.5, cy: 239.5, width: 640, height: 480}

Intrinsics follow OpenCV (pixels, principal point at the pixel-centre convention of
``r2s_eval.sim.cameras``); they scale with the rendered image size.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from r2s_eval.sim.reading import WorldError, as_mapping, check_keys, fail, file_path, finite, read_find

AXES = {"+x": 0, "+y": 1, "+z": 2, "-x": 0, "-y": 1, "-z": 2}


@dataclass(frozen=True)
class JointPhysics:
    """Joint properties a world states for a model whose own do not suit position servos."""
    armature: float | None = None  # kg m^2 (kg for a slide joint); None: the model's
    damping: float | None = None  # N m s/rad (N s/m)
    frictionloss: float | None = None  # N m (N)


@dataclass(frozen=True)
class Finger:
    """A further finger of a gripper, driven by its own actuator to the same closing fraction."""
    joint: str
    actuator: str
    ctrl_open: float
    ctrl_closed: float
    position_open: float
    position_closed: float

    def ctrl(self, closing: float) -> float:
        return self.ctrl_closed + (1.0 - np.clip(closing, 0.0, 1.0)) * (self.ctrl_open - self.ctrl_closed)

    def position(self, closing: float) -> float:
        return self.position_open + np.clip(closing, 0.0, 1.0) * (self.position_closed - self.position_open)


@dataclass(frozen=True)
class Gripper:
    actuator: str
    ctrl_open: float
    ctrl_closed: float
    joints: tuple[str, ...]  # set open at reset; the first measures the opening
    position_open: float
    position_closed: float
    jaw_open_m: float
    pads: tuple[str, str]
    fingers: tuple[Finger, ...] = ()  # further independently driven fingers
    couple: tuple[tuple[str, float], ...] = ()  # (joint, ratio): q = ratio * q of joints[0], by an equality
    servo: tuple[float, float] | None = None  # (kp, kv) of position servos for the gripper's actuators

    @property
    def finger_joints(self) -> tuple[str, ...]:
        """Every joint of the gripper's fingers: its own, the further fingers' and the coupled ones."""
        return (*self.joints, *(f.joint for f in self.fingers), *(joint for joint, _ in self.couple))

    def ctrl(self, closing: float) -> float:
        """Actuator command for a closing fraction (0 open, 1 closed)."""
        return self.ctrl_closed + (1.0 - np.clip(closing, 0.0, 1.0)) * (self.ctrl_open - self.ctrl_closed)

    def position(self, closing: float) -> float:
        """The gripper joints' position at a closing fraction (the inverse of ``closing``)."""
        return self.position_open + np.clip(closing, 0.0, 1.0) * (self.position_closed - self.position_open)

    def closing(self, position: float) -> float:
        """Closing fraction measured from the gripper joint's position."""
        return np.clip(1.0 - (position - self.position_closed) / (self.position_open - self.position_closed), 0.0, 1.0)

    def closing_rate(self, velocity: float) -> float:
        """Closing fraction per second from the gripper joint's velocity (+ = closing)."""
        return velocity / (self.position_closed - self.position_open)


@dataclass(frozen=True)
class CollisionGeom:
    body: str
    type: str  # a MuJoCo primitive: box, sphere, capsule, cylinder, ellipsoid
    size: tuple[float, ...]
    pos: tuple[float, float, float]
    euler_deg: tuple[float, float, float]
    friction: tuple[float, float, float] | None  # None: MuJoCo's default


@dataclass(frozen=True)
class Collision:
    disable_geoms: tuple[str, ...]
    disable_bodies: tuple[str, ...]
    add: tuple[CollisionGeom, ...]


@dataclass(frozen=True)
class Arm:
    name: str
    model: Path
    mount_frame: str | None
    mount_pos: tuple[float, float, float]
    mount_yaw_deg: float
    joints: tuple[str, ...]
    actuators: tuple[str, ...]
    servo: tuple[float, float] | None  # (kp, kv)
    gravity_compensation: bool
    home: np.ndarray
    gripper: Gripper
    ee_site: str
    ee_rotation: np.ndarray  # columns: the site frame's approach, jaw and third axes
    ee_pos: tuple[float, float, float]  # the grasp centre in the site's frame
    collision: Collision | None
    visual_max_faces: int | None = None  # None: the model's meshes as they are
    model_body: str | None = None  # the body subtree to take out of a multi-arm file
    model_assets: tuple[Path, ...] = ()  # the files holding an include fragment's assets and defaults
    joint_physics: JointPhysics | None = None  # set on `joints` (physics.joints)
    finger_physics: JointPhysics | None = None  # set on the gripper's finger joints (physics.fingers)

    def named(self, local: str) -> str:
        """The model's name of one of this arm's elements (attached with the arm's prefix)."""
        return f"{self.name}_{local}"


@dataclass(frozen=True)
class Feature:
    name: str
    arm: str
    joint: str | None  # None: the arm's gripper
    scale: float
    offset: float


@dataclass(frozen=True)
class RigCamera:
    name: str
    camera: str | None  # a camera of the scene or, with `arm`, of that arm's model
    arm: str | None
    body: str | None  # where a camera placed by the world hangs
    pos: tuple[float, float, float] | None
    look_at: tuple[float, float, float] | None
    fovy_deg: float | None
    intrinsics: dict[str, float] | None  # fx, fy, cx, cy at width x height (OpenCV, pixels)


@dataclass(frozen=True)
class Robot:
    type: str
    scene: Path
    workspace_z_m: float
    table_geom: str
    control_hz: float
    timestep_s: float | None  # None: the scene's
    arms: dict[str, Arm]
    features: tuple[Feature, ...]
    rig: dict[str, RigCamera]
    find_hue: dict | None = None  # how the robot looks in a frame (its silhouette): an HSV range
    find_prompt: str | None = None  # or the open-vocabulary segmenter's prompt
    scene_assets: tuple[Path, ...] = ()  # the files holding a fragment scene's assets and defaults

    @property
    def control_dt_s(self) -> float:
        return 1.0 / self.control_hz

    @property
    def feature_names(self) -> list[str]:
        return [f.name for f in self.features]

    @property
    def action_dim(self) -> int:
        return len(self.features)

    @property
    def camera_names(self) -> tuple[str, ...]:
        return tuple(self.rig)

    def home_targets(self) -> dict[str, tuple[np.ndarray, float]]:
        """Per arm, the joint targets and the (open) gripper closing at reset."""
        return {name: (arm.home.copy(), 0.0) for name, arm in self.arms.items()}

    @functools.cached_property
    def _slots(self) -> tuple[tuple[str, int | None], ...]:
        """Per feature, its arm and its joint's index in that arm (None: the gripper), looked up
        once: the conversions below run every control step."""
        return tuple((f.arm, None if f.joint is None else self.arms[f.arm].joints.index(f.joint)) for f in self.features)

    def to_model(self, vector) -> dict[str, tuple[np.ndarray, float]]:
        """A dataset-layout vector -> per arm (joint values, gripper closing), model units."""
        values = np.asarray(vector, dtype=float).reshape(self.action_dim)
        joints = {name: np.zeros(len(arm.joints)) for name, arm in self.arms.items()}
        grips = dict.fromkeys(self.arms, 0.0)
        for value, f, (arm, index) in zip(values, self.features, self._slots):
            model_value = f.scale * value + f.offset
            if index is None:
                grips[arm] = model_value
            else:
                joints[arm][index] = model_value
        return {name: (joints[name], grips[name]) for name in self.arms}

    def from_model(self, per_arm: Mapping[str, tuple[np.ndarray, float]], offsets: bool = True) -> np.ndarray:
        """Per arm (joint values, gripper closing) in model units -> a dataset-layout vector
        (``offsets=False``: rates, which scale but do not shift)."""
        out = np.empty(self.action_dim)
        for i, (f, (arm, index)) in enumerate(zip(self.features, self._slots)):
            q, grip = per_arm[arm]
            model_value = grip if index is None else q[index]
            out[i] = (model_value - (f.offset if offsets else 0.0)) / f.scale
        return out

    def slices(self, arm: str) -> tuple[list[int], int]:
        """Indices of ``arm``'s joints (in its joint order) and of its gripper in the dataset layout."""
        joints = sorted((index, i) for i, (a, index) in enumerate(self._slots) if a == arm and index is not None)
        return [i for _, i in joints], next(i for i, (a, index) in enumerate(self._slots) if a == arm and index is None)


# ---------------------------------------------------------------- reading
def model_path(ref: Any, where: str) -> Path:
    """The model file a reference names (a path, or ``{package, resource}``); it must exist."""
    return file_path(ref, where, "model file")


def model_reference(ref: Any, where: str) -> tuple[Path, tuple[Path, ...], str | None]:
    """(file, assets files, body) of a model reference: a path or ``{package, resource}`` as
    ``model_path`` reads it, or ``{path | package + resource, assets, body}``: an include fragment
    with the file(s) holding its assets and defaults, or one top body of a multi-arm file."""
    if not isinstance(ref, Mapping) or not {"path", "assets", "body"} & set(ref):
        return model_path(ref, where), (), None
    entry = as_mapping(ref, where)
    check_keys(entry, {"path", "package", "resource", "assets", "body"}, set(), where)
    if ("path" in entry) == ("package" in entry or "resource" in entry):
        raise fail(where, "must name its file by path or by package and resource (one of the two)")
    path = model_path(entry["path"] if "path" in entry else {k: entry.get(k) for k in ("package", "resource")}, where)
    assets = entry.get("assets", [])
    assets = assets if isinstance(assets, list) else [assets]
    body = entry.get("body")
    if body is not None and (not isinstance(body, str) or not body):
        raise fail(f"{where}.body", f"must be the name of a body of {path.name}, got {body!r}")
    return path, tuple(model_path(a, f"{where}.assets[{i}]") for i, a in enumerate(assets)), body


def _joint_physics(value: Any, where: str) -> JointPhysics:
    entry = as_mapping(value, where)
    check_keys(entry, {"armature", "damping", "frictionloss"}, set(), where)
    for key, v in entry.items():
        if finite(v, f"{where}.{key}") < 0:
            raise fail(f"{where}.{key}", f"must not be negative, got {v!r}")
    return JointPhysics(**{k: float(v) for k, v in entry.items()})


def _physics(value: Any, where: str) -> tuple[JointPhysics | None, JointPhysics | None]:
    entry = as_mapping(value, where)
    check_keys(entry, {"joints", "fingers"}, set(), where)
    return tuple(_joint_physics(entry[k], f"{where}.{k}") if entry.get(k) is not None else None
                 for k in ("joints", "fingers"))


def _vector(value: Any, where: str, length: int | None = None) -> tuple[float, ...]:
    if not isinstance(value, list | tuple) or (length is not None and len(value) != length):
        raise fail(where, f"must be a list of {length or 'some'} numbers, got {value!r}")
    return tuple(float(finite(v, where)) for v in value)


def _names(value: Any, where: str) -> tuple[str, ...]:
    if not isinstance(value, list | tuple) or not value or not all(isinstance(v, str) and v for v in value):
        raise fail(where, f"must be a non-empty list of names, got {value!r}")
    if len(set(value)) != len(value):
        raise fail(where, f"names something twice: {list(value)}")
    return tuple(value)


def _pair(value: Any, where: str) -> tuple[float, float]:
    entry = as_mapping(value, where)
    check_keys(entry, {"open", "closed"}, {"open", "closed"}, where)
    opened, closed = float(finite(entry["open"], f"{where}.open")), float(finite(entry["closed"], f"{where}.closed"))
    if opened == closed:
        raise fail(where, f"open and closed must differ, got {opened} for both")
    return opened, closed


def _ee_rotation(entry: dict, where: str) -> np.ndarray:
    approach, jaw = entry.get("approach", "+x"), entry.get("jaw", "+y")
    for key, axis in (("approach", approach), ("jaw", jaw)):
        if axis not in AXES:
            raise fail(f"{where}.{key}", f"must be one of {sorted(AXES)}, got {axis!r}")
    if AXES[approach] == AXES[jaw]:
        raise fail(where, f"approach and jaw must be different axes, got {approach} and {jaw}")
    a, j = np.eye(3)[AXES[approach]], np.eye(3)[AXES[jaw]]
    a, j = (-a if approach[0] == "-" else a), (-j if jaw[0] == "-" else j)
    return np.column_stack([a, j, np.cross(a, j)])


GEOM_SIZES = {"box": 3, "sphere": 1, "capsule": 2, "cylinder": 2, "ellipsoid": 3}


def _collision_geom(value: Any, where: str) -> CollisionGeom:
    entry = as_mapping(value, where)
    check_keys(entry, {"body", "type", "size", "pos", "euler_deg", "friction"}, {"body", "type", "size"}, where)
    if not isinstance(entry["type"], str) or entry["type"] not in GEOM_SIZES:
        raise fail(f"{where}.type", f"must be one of {sorted(GEOM_SIZES)}, got {entry['type']!r}")
    size = _vector(entry["size"], f"{where}.size", GEOM_SIZES[entry["type"]])
    if min(size) <= 0:
        raise fail(f"{where}.size", f"must be positive, got {list(size)}")
    return CollisionGeom(
        body=str(entry["body"]), type=entry["type"], size=size,
        pos=_vector(entry.get("pos", (0.0, 0.0, 0.0)), f"{where}.pos", 3),
        euler_deg=_vector(entry.get("euler_deg", (0.0, 0.0, 0.0)), f"{where}.euler_deg", 3),
        friction=_vector(entry["friction"], f"{where}.friction", 3) if "friction" in entry else None,
    )


def _collision(value: Any, where: str) -> Collision:
    entry = as_mapping(value, where)
    check_keys(entry, {"disable", "add"}, set(), where)
    disable = as_mapping(entry.get("disable", {}), f"{where}.disable")
    check_keys(disable, {"geoms", "bodies"}, set(), f"{where}.disable")
    add = entry.get("add", [])
    if not isinstance(add, list):
        raise fail(f"{where}.add", f"must be a list of geoms, got {add!r}")
    return Collision(
        disable_geoms=_names(disable["geoms"], f"{where}.disable.geoms") if "geoms" in disable else (),
        disable_bodies=_names(disable["bodies"], f"{where}.disable.bodies") if "bodies" in disable else (),
        add=tuple(_collision_geom(g, f"{where}.add[{i}]") for i, g in enumerate(add)),
    )


def _visual(value: Any, where: str) -> int:
    entry = as_mapping(value, where)
    check_keys(entry, {"max_faces"}, {"max_faces"}, where)
    faces = entry["max_faces"]
    if isinstance(faces, bool) or not isinstance(faces, int) or faces < 1:
        raise fail(f"{where}.max_faces", f"must be a whole number of faces (>= 1), got {faces!r}")
    return faces


def _finger(value: Any, where: str) -> Finger:
    entry = as_mapping(value, where)
    check_keys(entry, {"joint", "actuator", "ctrl", "position"}, {"joint", "actuator", "ctrl", "position"}, where)
    for key in ("joint", "actuator"):
        if not isinstance(entry[key], str) or not entry[key]:
            raise fail(f"{where}.{key}", f"must be a name, got {entry[key]!r}")
    ctrl_open, ctrl_closed = _pair(entry["ctrl"], f"{where}.ctrl")
    position_open, position_closed = _pair(entry["position"], f"{where}.position")
    return Finger(entry["joint"], entry["actuator"], ctrl_open, ctrl_closed, position_open, position_closed)


def _coupled(value: Any, where: str) -> tuple[str, float]:
    entry = as_mapping(value, where)
    check_keys(entry, {"joint", "ratio"}, {"joint", "ratio"}, where)
    if not isinstance(entry["joint"], str) or not entry["joint"]:
        raise fail(f"{where}.joint", f"must be a name, got {entry['joint']!r}")
    ratio = float(finite(entry["ratio"], f"{where}.ratio"))
    if ratio == 0:
        raise fail(f"{where}.ratio", "must not be 0")
    return entry["joint"], ratio


def _gripper(value: Any, where: str) -> Gripper:
    entry = as_mapping(value, where)
    check_keys(entry, {"actuator", "ctrl", "joint", "position", "jaw_open_m", "pads", "fingers", "couple", "servo"},
               {"actuator", "ctrl", "joint", "position", "jaw_open_m", "pads"}, where)
    more = {}
    for key, read in (("fingers", _finger), ("couple", _coupled)):
        if entry.get(key) is not None:
            if not isinstance(entry[key], list) or not entry[key]:
                raise fail(f"{where}.{key}", f"must be a non-empty list, got {entry[key]!r}")
            more[key] = tuple(read(v, f"{where}.{key}[{i}]") for i, v in enumerate(entry[key]))
    if entry.get("servo") is not None:
        more["servo"] = _servo(entry["servo"], f"{where}.servo")
    pads = _names(entry["pads"], f"{where}.pads")
    if len(pads) != 2:
        raise fail(f"{where}.pads", f"must name the two jaws' bodies, got {list(pads)}")
    ctrl_open, ctrl_closed = _pair(entry["ctrl"], f"{where}.ctrl")
    position_open, position_closed = _pair(entry["position"], f"{where}.position")
    joints = [entry["joint"]] if isinstance(entry["joint"], str) else entry["joint"]
    return Gripper(actuator=str(entry["actuator"]), ctrl_open=ctrl_open, ctrl_closed=ctrl_closed,
                   joints=_names(joints, f"{where}.joint"), position_open=position_open,
                   position_closed=position_closed,
                   jaw_open_m=float(finite(entry["jaw_open_m"], f"{where}.jaw_open_m", positive=True)), pads=pads,
                   **more)


def _servo(value: Any, where: str) -> tuple[float, float]:
    gains = as_mapping(value, where)
    check_keys(gains, {"kp", "kv"}, {"kp", "kv"}, where)
    return float(finite(gains["kp"], f"{where}.kp", positive=True)), float(finite(gains["kv"], f"{where}.kv"))


def _arm(name: str, value: Any) -> Arm:
    where = f"robot.arms.{name}"
    entry = as_mapping(value, where)
    check_keys(entry, {"model", "mount", "joints", "actuators", "servo", "gravity_compensation", "home", "gripper", "ee",
                       "collision", "visual", "physics"}, {"model", "mount", "joints", "home", "gripper", "ee"}, where)
    joints = _names(entry["joints"], f"{where}.joints")
    actuators = _names(entry.get("actuators", list(joints)), f"{where}.actuators")
    if len(actuators) != len(joints):
        raise fail(f"{where}.actuators", f"must name one actuator per joint ({len(joints)}), got {list(actuators)}")
    mount = as_mapping(entry["mount"], f"{where}.mount")
    if "frame" in mount:
        check_keys(mount, {"frame"}, {"frame"}, f"{where}.mount")
    else:
        check_keys(mount, {"pos", "yaw_deg"}, {"pos"}, f"{where}.mount")
    servo = _servo(entry["servo"], f"{where}.servo") if entry.get("servo") is not None else None
    ee = as_mapping(entry["ee"], f"{where}.ee")
    check_keys(ee, {"site", "approach", "jaw", "pos"}, {"site"}, f"{where}.ee")
    model, model_assets, model_body = model_reference(entry["model"], f"{where}.model")
    joint_physics, finger_physics = (_physics(entry["physics"], f"{where}.physics")
                                     if entry.get("physics") is not None else (None, None))
    return Arm(
        name=name, model=model, model_body=model_body, model_assets=model_assets, joint_physics=joint_physics,
        finger_physics=finger_physics, mount_frame=mount.get("frame"),
        mount_pos=_vector(mount.get("pos", (0.0, 0.0, 0.0)), f"{where}.mount.pos", 3),
        mount_yaw_deg=float(finite(mount.get("yaw_deg", 0.0), f"{where}.mount.yaw_deg")), joints=joints,
        actuators=actuators, servo=servo, gravity_compensation=bool(entry.get("gravity_compensation", False)),
        home=np.array(_vector(entry["home"], f"{where}.home", len(joints))),
        gripper=_gripper(entry["gripper"], f"{where}.gripper"), ee_site=str(ee["site"]),
        ee_rotation=_ee_rotation(ee, f"{where}.ee"),
        ee_pos=_vector(ee.get("pos", (0.0, 0.0, 0.0)), f"{where}.ee.pos", 3),
        collision=_collision(entry["collision"], f"{where}.collision") if entry.get("collision") is not None else None,
        visual_max_faces=_visual(entry["visual"], f"{where}.visual") if entry.get("visual") is not None else None,
    )


def _features(value: Any, arms: dict[str, Arm]) -> tuple[Feature, ...]:
    if value is None:
        return tuple(Feature(f"{a}_{j or 'gripper'}", a, j, 1.0, 0.0) for a, arm in arms.items()
                     for j in (*arm.joints, None))
    if not isinstance(value, list) or not value:
        raise fail("robot.features", f"must be a list of {{name, arm, joint | gripper}} entries, got {value!r}")
    features, seen = [], {}
    for i, raw in enumerate(value):
        where = f"robot.features[{i}]"
        entry = as_mapping(raw, where)
        check_keys(entry, {"name", "arm", "joint", "gripper", "scale", "offset"}, {"name", "arm"}, where)
        if entry["arm"] not in arms:
            raise fail(f"{where}.arm", f"must be an arm of the robot {list(arms)}, got {entry['arm']!r}")
        arm = arms[entry["arm"]]
        if ("joint" in entry) == bool(entry.get("gripper")):
            raise fail(where, "must name a joint or say gripper: true (one of the two)")
        joint = entry.get("joint")
        if joint is not None and joint not in arm.joints:
            raise fail(f"{where}.joint", f"must be a joint of arm {arm.name} {list(arm.joints)}, got {joint!r}")
        target = (arm.name, joint)
        if target in seen:
            raise fail(where, f"maps to {arm.name} {joint or 'gripper'}, which {seen[target]} maps to already")
        seen[target] = f"robot.features[{i}]"
        scale = float(finite(entry.get("scale", 1.0), f"{where}.scale"))
        if scale == 0:
            raise fail(f"{where}.scale", "must not be 0")
        features.append(Feature(str(entry["name"]), arm.name, joint, scale, float(finite(entry.get("offset", 0.0), f"{where}.offset"))))
    names = [f.name for f in features]
    if len(set(names)) != len(names):
        raise fail("robot.features", f"names a feature twice: {names}")
    uncovered = [f"{a} {j or 'gripper'}" for a, arm in arms.items() for j in (*arm.joints, None) if (a, j) not in seen]
    if uncovered:
        raise fail("robot.features", f"no feature maps to {uncovered}: every joint and gripper needs one")
    return tuple(features)


def _rig_camera(name: str, value: Any, arms: dict[str, Arm]) -> RigCamera:
    where = f"rig.{name}"
    entry = as_mapping(value, where)
    check_keys(entry, {"camera", "arm", "body", "pos", "look_at", "fovy_deg", "intrinsics"}, set(), where)
    if ("camera" in entry) == ("body" in entry):
        raise fail(where, "must name a model's camera (camera, with arm for an arm's) or place one (body, pos)")
    if "arm" in entry and entry["arm"] not in arms:
        raise fail(f"{where}.arm", f"must be an arm of the robot {list(arms)}, got {entry['arm']!r}")
    if "body" in entry and "pos" not in entry:
        raise fail(where, "a camera placed on a body needs its pos")
    if "body" in entry and "look_at" not in entry:
        raise fail(where, "a camera placed on a body needs look_at (where it points)")
    intrinsics = None
    if entry.get("intrinsics") is not None:
        intrinsics = _intrinsics(entry["intrinsics"], f"{where}.intrinsics")
        if "fovy_deg" in entry:
            raise fail(where, "give intrinsics or fovy_deg, not both")
    fovy = entry.get("fovy_deg")
    if fovy is not None and not 0 < finite(fovy, f"{where}.fovy_deg") < 180:
        raise fail(f"{where}.fovy_deg", f"must be in (0, 180), got {fovy!r}")
    if "body" in entry and fovy is None and intrinsics is None:
        raise fail(where, "a camera placed on a body needs fovy_deg or intrinsics")
    return RigCamera(
        name=name, camera=entry.get("camera"), arm=entry.get("arm"), body=entry.get("body"),
        pos=_vector(entry["pos"], f"{where}.pos", 3) if "pos" in entry else None,
        look_at=_vector(entry["look_at"], f"{where}.look_at", 3) if "look_at" in entry else None,
        fovy_deg=None if fovy is None else float(fovy), intrinsics=intrinsics,
    )


def _intrinsics(value: Any, where: str) -> dict[str, float]:
    entry = as_mapping(value, where)
    keys = {"fx", "fy", "cx", "cy", "width", "height"}
    check_keys(entry, keys, keys, where)
    out = {k: float(finite(entry[k], f"{where}.{k}", positive=True)) for k in sorted(keys)}
    for size, centre in (("width", "cx"), ("height", "cy")):
        if out[size] != int(out[size]):
            raise fail(f"{where}.{size}", f"must be a whole number of pixels, got {entry[size]!r}")
        if not 0 <= out[centre] <= out[size] - 1:
            raise fail(f"{where}.{centre}", f"must lie inside the {int(out['width'])}x{int(out['height'])} image "
                                            f"(0..{out[size] - 1:g}), got {entry[centre]!r}")
    return out


def load_robot(world: Mapping) -> Robot:
    """The robot and camera rig of ``world`` (a ``world`` config slice), checked: a wrong entry is a
    ``WorldError`` naming its key. Names inside the model files are checked when it is compiled
    (``r2s_eval.sim.assembly.load_world``)."""
    entry = as_mapping(world.get("robot"), "robot")
    check_keys(entry, {"type", "scene", "workspace", "control_hz", "timestep_s", "arms", "features", "find"},
               {"scene", "workspace", "control_hz", "arms"}, "robot")
    find_hue, find_prompt = read_find(entry.get("find"), "robot.find")
    workspace = as_mapping(entry["workspace"], "robot.workspace")
    check_keys(workspace, {"z_m", "geom"}, {"z_m", "geom"}, "robot.workspace")
    arms_entry = as_mapping(entry["arms"], "robot.arms")
    if not arms_entry:
        raise fail("robot.arms", "must list at least one arm")
    arms = {str(n): _arm(str(n), v) for n, v in arms_entry.items()}
    rig = {str(n): _rig_camera(str(n), v, arms) for n, v in as_mapping(world.get("rig"), "rig").items()}
    missing = [c for c in world.get("cameras") or () if c not in rig]
    if missing:
        raise fail("cameras", f"records {missing}, which the rig {sorted(rig)} does not place")
    scene, scene_assets, scene_body = model_reference(entry["scene"], "robot.scene")
    if scene_body is not None:
        raise fail("robot.scene.body", "a scene is a whole file or a fragment: it takes no body")
    return Robot(
        type=str(entry.get("type", "robot")), scene=scene, scene_assets=scene_assets,
        workspace_z_m=float(finite(workspace["z_m"], "robot.workspace.z_m")), table_geom=str(workspace["geom"]),
        control_hz=float(finite(entry["control_hz"], "robot.control_hz", positive=True)),
        timestep_s=(float(finite(entry["timestep_s"], "robot.timestep_s", positive=True))
                    if entry.get("timestep_s") is not None else None),
        arms=arms, features=_features(entry.get("features"), arms), rig=rig, find_hue=find_hue,
        find_prompt=find_prompt,
    )


_LOADED: dict[str, Robot] = {}


def world_robot(world: Mapping) -> Robot:
    """The robot of ``world`` (a ``world`` config slice), read once per content."""
    key = json.dumps({k: world.get(k) for k in ("robot", "rig", "cameras")}, sort_keys=True, default=str)
    if key not in _LOADED:
        _LOADED[key] = load_robot(world)
    return _LOADED[key]


@functools.cache
def bundled_robot() -> Robot:
    from r2s_eval.sim.tasks import bundled_world

    return world_robot(bundled_world())


__all__ = ["Arm", "Collision", "CollisionGeom", "Feature", "Finger", "Gripper", "JointPhysics", "RigCamera", "Robot", "WorldError", "bundled_robot",
           "load_robot", "model_path", "model_reference", "world_robot"]

