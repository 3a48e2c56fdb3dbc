"""The robot and the camera rig of a world as the simulation uses them (``world.robot``,
``world.rig``): which model files, where each arm stands, which of its joints and actuators the
dataset records and commands (in which units), its grippers, the end-effector frames the scripted
operator steers, the control rate and the cameras.

The keys, their defaults and units are ``r2s_eval.sim.world_spec``'s (the reference:
``docs/world-keys.md``; how to write a world: ``docs/world-howto.md``); ``load_robot`` builds the
runtime objects below from the checked spec. Names inside the model files are checked when the
world is assembled (``r2s_eval.sim.assembly``).
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from r2s_eval.sim import world_spec as spec
from r2s_eval.sim.reading import WorldError, file_path

AXES = {"+x": 0, "+y": 1, "+z": 2, "-x": 0, "-y": 1, "-z": 2}


def ctrl_at(closing: float, opened: float, closed: float) -> float:
    """A finger's actuator command at a closing fraction (0 open, 1 closed)."""
    return closed + (1.0 - np.clip(closing, 0.0, 1.0)) * (opened - closed)


def position_at(closing: float, opened: float, closed: float) -> float:
    """A finger joint's position at a closing fraction."""
    return opened + np.clip(closing, 0.0, 1.0) * (closed - opened)


@dataclass(frozen=True)
class Finger:
    """A further finger of a gripper, driven by its own actuator to the gripper's closing fraction."""

    joint: str
    actuator: str
    ctrl_open: float
    ctrl_closed: float
    position_open: float
    position_closed: float

    def ctrl(self, closing: float) -> float:
        return ctrl_at(closing, self.ctrl_open, self.ctrl_closed)

    def position(self, closing: float) -> float:
        return position_at(closing, self.position_open, self.position_closed)


@dataclass(frozen=True)
class JointPhysics:
    """Joint properties a world states for a model whose own do not suit position servos."""

    armature: float | None = None  # kg m^2 (kg for a slide joint); None: the model's
    damping: float | None = None  # N m s/rad (N s/m)
    frictionloss: float | None = None  # N m (N)


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
    couple: tuple[tuple[str, float], ...] = ()  # (joint, ratio) that follow joints[0]
    servo: tuple[float, float] | None = None  # (kp, kv) for the gripper's actuators

    @property
    def finger_joints(self) -> tuple[str, ...]:
        """Every joint of the gripper's fingers: its own, the further fingers' and the coupled ones."""
        return (*self.joints, *(f.joint for f in self.fingers), *(joint for joint, _ in self.couple))

    def ctrl(self, closing: float) -> float:
        """Actuator command for a closing fraction (0 open, 1 closed)."""
        return ctrl_at(closing, self.ctrl_open, self.ctrl_closed)

    def position(self, closing: float) -> float:
        """The gripper joints' position at a closing fraction (the inverse of ``closing``)."""
        return position_at(closing, self.position_open, self.position_closed)

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
    model_assets: tuple[Path, ...] = ()  # files holding an include fragment's assets/defaults
    joint_physics: JointPhysics | None = None  # set on `joints`
    finger_physics: JointPhysics | None = None  # set on the gripper's finger joints

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
    scene_assets: tuple[Path, ...] = ()  # files holding the scene's assets/defaults (an include fragment)

    @property
    def control_dt_s(self) -> float:
        return 1.0 / self.control_hz

    def steps_in(self, seconds: float) -> int:
        """Control steps in ``seconds`` at this robot's rate: an episode's length is a time, so a
        30 Hz arm gets three times the steps of a 10 Hz one."""
        return max(1, round(float(seconds) * self.control_hz))

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
    """The model file a reference names (a path, ``{path}`` or ``{package, resource}``, typed in
    ``world_spec``); it must exist."""
    if isinstance(ref, spec.FileRef):
        ref = {"path": ref.path} if ref.path is not None else {"package": ref.package, "resource": ref.resource}
    elif isinstance(ref, Mapping):
        ref = {k: v for k, v in ref.items() if k not in ("body", "assets")}
    return file_path(ref, where, "model file")


def _assets(ref: Any, where: str) -> tuple[Path, ...]:
    """The files holding an include fragment's assets and defaults (a model reference's ``assets``)."""
    assets = ref.assets if isinstance(ref, spec.ModelRef) else None
    if assets is None:
        return ()
    if not isinstance(assets, tuple):
        return (model_path(assets, f"{where}.assets"),)
    return tuple(model_path(a, f"{where}.assets[{i}]") for i, a in enumerate(assets))


def _ee_rotation(ee: spec.Ee) -> np.ndarray:
    a, j = np.eye(3)[AXES[ee.approach]], np.eye(3)[AXES[ee.jaw]]
    a, j = (-a if ee.approach[0] == "-" else a), (-j if ee.jaw[0] == "-" else j)
    return np.column_stack([a, j, np.cross(a, j)])


def _physics(value: spec.JointPhysics | None) -> JointPhysics | None:
    return None if value is None else JointPhysics(value.armature, value.damping, value.frictionloss)


def _gripper(g: spec.Gripper) -> Gripper:
    return Gripper(
        actuator=g.actuator, ctrl_open=g.ctrl.open, ctrl_closed=g.ctrl.closed, joints=g.joints,
        position_open=g.position.open, position_closed=g.position.closed, jaw_open_m=g.jaw_open_m, pads=g.pads,
        fingers=tuple(Finger(f.joint, f.actuator, f.ctrl.open, f.ctrl.closed, f.position.open, f.position.closed)
                      for f in g.fingers),
        couple=tuple((c.joint, c.ratio) for c in g.couple),
        servo=None if g.servo is None else (g.servo.kp, g.servo.kv))


def _collision(c: spec.Collision) -> Collision:
    return Collision(disable_geoms=c.disable.geoms, disable_bodies=c.disable.bodies,
                     add=tuple(CollisionGeom(body=g.body, type=g.type, size=g.size, pos=g.pos, euler_deg=g.euler_deg,
                                             friction=g.friction) for g in c.add))


def _arm(name: str, a: spec.Arm) -> Arm:
    where = f"robot.arms.{name}.model"
    physics = a.physics or spec.Physics()
    return Arm(
        name=name, model=model_path(a.model, where), mount_frame=a.mount.frame,
        mount_pos=a.mount.pos if a.mount.pos is not None else (0.0, 0.0, 0.0), mount_yaw_deg=a.mount.yaw_deg,
        joints=a.joints, actuators=a.actuators if a.actuators is not None else a.joints,
        servo=None if a.servo is None else (a.servo.kp, a.servo.kv), gravity_compensation=a.gravity_compensation,
        home=np.array(a.home), gripper=_gripper(a.gripper), ee_site=a.ee.site, ee_rotation=_ee_rotation(a.ee),
        ee_pos=a.ee.pos, collision=None if a.collision is None else _collision(a.collision),
        visual_max_faces=None if a.visual is None else a.visual.max_faces,
        model_body=a.model.body if isinstance(a.model, spec.ModelRef) else None, model_assets=_assets(a.model, where),
        joint_physics=_physics(physics.joints), finger_physics=_physics(physics.fingers),
    )


def _features(features: tuple[spec.Feature, ...] | None, arms: dict[str, Arm]) -> tuple[Feature, ...]:
    if features is None:  # the default layout: per arm its joints, then its gripper, in model units
        return tuple(Feature(f"{a}_{j or 'gripper'}", a, j, 1.0, 0.0) for a, arm in arms.items()
                     for j in (*arm.joints, None))
    return tuple(Feature(f.name, f.arm, f.joint, f.scale, f.offset) for f in features)


def _rig_camera(name: str, c: spec.RigCamera) -> RigCamera:
    intrinsics = None if c.intrinsics is None else {
        k: float(getattr(c.intrinsics, k)) for k in sorted(("fx", "fy", "cx", "cy", "width", "height"))}
    return RigCamera(name=name, camera=c.camera, arm=c.arm, body=c.body, pos=c.pos, look_at=c.look_at,
                     fovy_deg=c.fovy_deg, intrinsics=intrinsics)


def load_robot(world: Mapping) -> Robot:
    """The robot and camera rig of ``world`` (a ``world`` config slice), checked against
    ``r2s_eval.sim.world_spec``: a ``WorldError`` names the wrong key, or lists every one. Names
    inside the model files are checked when it is compiled (``r2s_eval.sim.assembly.load_world``)."""
    robot, rig = spec.check_robot(world)
    arms = {name: _arm(name, a) for name, a in robot.arms.items()}
    return Robot(
        type=robot.type, scene=model_path(robot.scene, "robot.scene"), workspace_z_m=robot.workspace.z_m,
        table_geom=robot.workspace.geom, control_hz=robot.control_hz, timestep_s=robot.timestep_s, arms=arms,
        features=_features(robot.features, arms), rig={name: _rig_camera(name, c) for name, c in rig.items()},
        find_hue=None if robot.find is None else robot.find.hsv(), find_prompt=None if robot.find is None else robot.find.prompt,
        scene_assets=_assets(robot.scene, "robot.scene"),
    )


_LOADED: dict[str, Robot] = {}


def world_robot(world: Mapping) -> Robot:
    """The robot of ``world`` (a ``world`` config slice), read once per content."""
    key = json.dumps({k: world.get(k) for k in ("robot", "rig", "cameras")}, sort_keys=True, default=str)
    if key not in _LOADED:
        _LOADED[key] = load_robot(world)
    return _LOADED[key]


__all__ = ["Arm", "Collision", "CollisionGeom", "Feature", "Finger", "Gripper", "JointPhysics", "RigCamera", "Robot",
           "WorldError", "load_robot", "model_path", "world_robot"]

