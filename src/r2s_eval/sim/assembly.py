"""Scene assembly from a world's robot and rig (``r2s_eval.sim.robot``) plus task objects -> MjModel.

The scene file holds the table, lights and fixed cameras; each arm's model (read by
``r2s_eval.sim.model_files``, its gripper's further fingers, coupled joints and servos and its stated
joint physics applied here) is attached at its
mount with the prefix ``<arm>_`` (its ``visual`` entry decimating its drawn meshes, its ``collision``
entry swapping collision shapes); the rig's
cameras are renamed, placed, aimed and given their intrinsics; the task objects are added as
free bodies; ``WorldParams`` perturbs the result.
The simulation settings are the scene's (``robot.timestep_s`` setting its timestep): an arm's file's
``<option>``, ``<size>`` and ``<visual>`` give way to them; its ``<compiler>`` settings still read
its own elements (angle units, autolimits, inertia from geoms).
The bundled world's files are ``assets/tabletop.xml`` and ``assets/arm.xml``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from pathlib import Path

import mujoco
import numpy as np

from r2s_eval.sim import cameras as cam_geom
from r2s_eval.sim.meshes import decimated_meshes
from r2s_eval.sim.model_files import load_model_spec, unnamed_geom_name
from r2s_eval.sim.objects import ObjectSpec, add_object
from r2s_eval.sim.params import WorldParams
from r2s_eval.sim.reading import fail
from r2s_eval.sim.render_params import apply_render_params, render_base
from r2s_eval.sim.rotations import euler_quat, matrix_from_quat, quat_from_matrix, yaw_quat
from r2s_eval.sim.robot import Arm, Collision, JointPhysics, RigCamera, Robot, world_robot
from r2s_eval.sim.tasks import sample_initial_poses, world_tasks

EE_SITE_GROUP = 5  # a site group no renderer shows by default
# MuJoCo's <size> settings: an attached model's that differ from the scene's are warned of, as its <option>'s.
SIZE_SETTINGS = ("memory", "nconmax", "njmax", "nstack", "nuserdata", "nkey", "nemax",
                 *(f"nuser_{kind}" for kind in ("actuator", "body", "cam", "geom", "jnt", "sensor", "site", "tendon")))


def ee_site(arm: str) -> str:
    """The site the world adds at an arm's grasp centre, axes (approach, jaw, third)."""
    return f"{arm}_ee"


def _attach_arm(spec: mujoco.MjSpec, arm: Arm) -> None:
    where = f"robot.arms.{arm.name}"
    if arm.mount_frame is not None:
        frame = spec.frame(arm.mount_frame)
        if frame is None:
            raise fail(f"{where}.mount.frame", f"the scene {spec.modelname!r} has no frame {arm.mount_frame!r}")
    else:
        frame = spec.worldbody.add_frame(pos=list(arm.mount_pos), quat=list(yaw_quat(np.deg2rad(arm.mount_yaw_deg))))
    model = load_model_spec(arm.model, assets=arm.model_assets, body=arm.model_body, where=f"{where}.model")
    if arm.visual_max_faces is not None:
        _decimate_visuals(model, arm)
    _give_scene_settings(spec, model)
    spec.attach(model, prefix=f"{arm.name}_", frame=frame)
    for local in arm.joints:
        if spec.joint(arm.named(local)) is None:
            raise fail(f"{where}.joints", f"{arm.model.name} has no joint {local!r}")
    if arm.servo is not None:
        for local, actuator in zip(arm.joints, arm.actuators):
            _position_servo(spec, arm, local, actuator, *arm.servo, spec.joint(arm.named(local)).range)
    for joint in arm.gripper.joints:
        if spec.joint(arm.named(joint)) is None:
            raise fail(f"{where}.gripper.joint", f"{arm.model.name} has no joint {joint!r}")
    _fit_gripper(spec, arm)
    for local in (*arm.actuators, arm.gripper.actuator):
        if spec.actuator(arm.named(local)) is None:
            raise fail(f"{where}.actuators" if local in arm.actuators else f"{where}.gripper.actuator",
                             f"{arm.model.name} has no actuator {local!r}")
    for i, finger in enumerate(arm.gripper.fingers):
        if spec.actuator(arm.named(finger.actuator)) is None:
            raise fail(f"{where}.gripper.fingers[{i}].actuator", f"{arm.model.name} has no actuator {finger.actuator!r}")
    _set_joint_physics(spec, arm, arm.joint_physics, arm.joints)
    _set_joint_physics(spec, arm, arm.finger_physics, arm.gripper.finger_joints)
    for pad in arm.gripper.pads:
        if spec.body(arm.named(pad)) is None:
            raise fail(f"{where}.gripper.pads", f"{arm.model.name} has no body {pad!r}")
    site = spec.site(arm.named(arm.ee_site))
    if site is None:
        raise fail(f"{where}.ee.site", f"{arm.model.name} has no site {arm.ee_site!r}")
    site.parent.add_site(name=ee_site(arm.name), pos=site.pos + matrix_from_quat(site.quat) @ arm.ee_pos,
                         quat=quat_from_matrix(matrix_from_quat(site.quat) @ arm.ee_rotation), group=EE_SITE_GROUP)
    if arm.collision is not None:
        _swap_collision(spec, arm, arm.collision)
    if arm.gravity_compensation:  # every body of the arm's model (attached with its prefix)
        for body in spec.bodies:
            if body.name.startswith(arm.named("")):
                body.gravcomp = 1.0


def _give_scene_settings(scene: mujoco.MjSpec, model: mujoco.MjSpec) -> None:
    """The scene's simulation settings written over the arm model's before it is attached.

    MuJoCo keeps the scene's anyway, but reports each one that differs at every compile (printed,
    as a Python warning and into MUJOCO_LOG.TXT in the working folder): keeping them is the world's
    intent, not a conflict. Compiler settings stay the file's: MuJoCo reads its elements with them."""
    for name in dir(scene.option):
        if not name.startswith("_"):
            setattr(model.option, name, getattr(scene.option, name))
    for name in SIZE_SETTINGS:
        setattr(model, name, getattr(scene, name))
    model.visual = scene.visual  # some are compared too (the near plane)


def _drop_actuators(spec: mujoco.MjSpec, joint: str) -> None:
    for actuator in [a for a in spec.actuators if a.target == joint]:
        spec.delete(actuator)


def _position_servo(spec: mujoco.MjSpec, arm: Arm, joint: str, actuator: str, kp: float, kv: float,
                    ctrlrange) -> None:
    """Replace whatever drives ``joint`` with a position servo called ``actuator``."""
    _drop_actuators(spec, arm.named(joint))
    servo = spec.add_actuator(name=arm.named(actuator), target=arm.named(joint), trntype=mujoco.mjtTrn.mjTRN_JOINT)
    servo.set_to_position(kp=kp, kv=kv)
    servo.ctrlrange = ctrlrange
    servo.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE


def _fit_gripper(spec: mujoco.MjSpec, arm: Arm) -> None:
    """A gripper's further fingers checked, its coupled joints tied to its first joint by an equality
    (their own actuators removed), and its servos, if the world gives their gains."""
    where, gripper = f"robot.arms.{arm.name}.gripper", arm.gripper
    for key, joints in (("fingers", [f.joint for f in gripper.fingers]), ("couple", [j for j, _ in gripper.couple])):
        for i, joint in enumerate(joints):
            if spec.joint(arm.named(joint)) is None:
                raise fail(f"{where}.{key}[{i}].joint", f"{arm.model.name} has no joint {joint!r}")
    for joint, ratio in gripper.couple:
        _drop_actuators(spec, arm.named(joint))
        # MuJoCo's joint equality: q1 = polycoef[0] + polycoef[1] * q2 + ...
        equality = spec.add_equality(name=arm.named(f"{joint}_couple"), type=mujoco.mjtEq.mjEQ_JOINT,
                                     name1=arm.named(joint), name2=arm.named(gripper.joints[0]))
        equality.data = np.r_[0.0, ratio, np.zeros(len(equality.data) - 2)]
    if gripper.servo is not None:
        kp, kv = gripper.servo
        for joint, actuator, ctrl in ((gripper.joints[0], gripper.actuator, (gripper.ctrl_open, gripper.ctrl_closed)),
                                      *((f.joint, f.actuator, (f.ctrl_open, f.ctrl_closed)) for f in gripper.fingers)):
            _position_servo(spec, arm, joint, actuator, kp, kv, sorted(ctrl))


def _set_joint_physics(spec: mujoco.MjSpec, arm: Arm, physics: JointPhysics | None, joints) -> None:
    """The armature, damping and friction loss the world states for these joints (the rest the model's)."""
    if physics is None:
        return
    for local in joints:
        joint = spec.joint(arm.named(local))
        if physics.armature is not None:
            joint.armature = physics.armature
        if physics.damping is not None:
            joint.damping = [physics.damping, *joint.damping[1:]]  # the linear term (MuJoCo's `damping`)
        if physics.frictionloss is not None:
            joint.frictionloss = physics.frictionloss


def _textured(spec: mujoco.MjSpec, geom: mujoco.MjsGeom) -> bool:
    material = spec.material(geom.material) if geom.material else None
    return material is not None and any(material.textures)


def _decimate_visuals(model: mujoco.MjSpec, arm: Arm) -> None:
    """Point the arm's visual mesh geoms (not colliding: contype = conaffinity = 0) at decimated
    copies of their meshes (``robot.arms.<arm>.visual``), in the arm's own model before it is
    attached. Collision geoms and their meshes are untouched; a mesh no geom names any more is
    dropped; a body whose inertia came from its geoms is given the one the full meshes gave it."""
    where = f"robot.arms.{arm.name}.visual"
    drawn: dict[str, list[mujoco.MjsGeom]] = {}
    for geom in model.geoms:
        if (geom.type == mujoco.mjtGeom.mjGEOM_MESH and geom.contype == 0 and geom.conaffinity == 0
                and not _textured(model, geom)):
            drawn.setdefault(geom.meshname, []).append(geom)
    meshes = [mesh for mesh in map(model.mesh, drawn) if mesh is not None and mesh.file]
    files = []
    for mesh in meshes:
        # A mesh file is found as MuJoCo finds it: under the meshdir of the model that declared it.
        path = Path(mesh.file)
        meshdir = mesh.compiler.meshdir if hasattr(mesh, "compiler") else model.meshdir
        path = path if path.is_absolute() else arm.model.parent / meshdir / path
        if not path.is_file():
            raise fail(where, f"{arm.model.name}'s mesh {mesh.name!r} has no file {path}")
        files.append((path, len(drawn[mesh.name])))
    derived = set()  # bodies whose inertia comes from geoms that get a new mesh
    for mesh, decimated in zip(meshes, decimated_meshes(files, arm.visual_max_faces, where)):
        if decimated is None:
            continue
        vertices, faces = decimated
        name = f"{mesh.name}_visual"
        while model.mesh(name) is not None:
            name += "_"
        coarse = model.add_mesh(name=name, uservert=vertices.flatten().tolist(), userface=faces.flatten().tolist())
        for attribute in ("scale", "refpos", "refquat", "smoothnormal", "material"):  # as the file was read
            if hasattr(mesh, attribute):
                setattr(coarse, attribute, getattr(mesh, attribute))
        # No geom's mass comes from it (see below), and a shell's inertia never fails on an open surface.
        coarse.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
        for geom in drawn[mesh.name]:
            geom.meshname = name
            if _inertia_from(geom, where):
                derived.add(geom.parent.name)
        if not any(g.meshname == mesh.name for g in model.geoms):
            model.delete(mesh)
    if derived:
        inertials = _model_inertials(arm.model, arm.model.stat().st_mtime_ns, arm.model_assets, arm.model_body,
                                     f"robot.arms.{arm.name}.model")
        for body in map(model.body, sorted(derived)):
            body.explicitinertial = True
            body.mass, body.ipos, body.iquat, body.inertia = inertials[body.name]
            body.fullinertia = [np.nan] * 6


def _inertia_from(geom: mujoco.MjsGeom, where: str) -> bool:
    """Whether ``geom`` adds to its body's mass and inertia."""
    compiler = geom.compiler if hasattr(geom, "compiler") else geom.parent.compiler
    low, high = compiler.inertiagrouprange
    if not low <= geom.group <= high:
        return False
    if compiler.inertiafromgeom == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE:
        raise fail(where, f"the model takes every body's inertia from its geoms (inertiafromgeom=true): "
                          f"decimating {geom.parent.name!r}'s visual geoms would change its mass")
    return (compiler.inertiafromgeom == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO
            and not geom.parent.explicitinertial)


@functools.cache
def _model_inertials(path: Path, mtime_ns: int, assets: tuple[Path, ...], body: str | None,
                     where: str) -> dict[str, tuple]:
    """Per body of the model file, (mass, ipos, iquat, diagonal inertia) as compiled (once per file)."""
    model = load_model_spec(path, assets=assets, body=body, where=where).compile()
    return {model.body(i).name: (float(model.body_mass[i]), model.body_ipos[i].copy(), model.body_iquat[i].copy(),
                                 model.body_inertia[i].copy()) for i in range(1, model.nbody)}


def _collision_bits(body: mujoco.MjsBody) -> tuple[int, int]:
    """(contype, conaffinity) of the body's first collision geom; MuJoCo's default without one."""
    return next(((g.contype, g.conaffinity) for g in body.geoms if g.contype or g.conaffinity), (1, 1))


def _colliding_geoms(spec: mujoco.MjSpec, arm: Arm) -> list[str]:
    """The arm's colliding geoms, by the names the world gives them (the model file's)."""
    prefix = arm.named("")
    return [g.name[len(prefix):] for g in spec.geoms
            if g.name.startswith(prefix) and (g.contype or g.conaffinity)]


def _swap_collision(spec: mujoco.MjSpec, arm: Arm, collision: Collision) -> None:
    """Switch the arm's named collision geoms off and add its primitives (invisible, massless),
    which collide as their body's own collision geoms did."""
    where = f"robot.arms.{arm.name}.collision"

    def body_of(local: str, key: str) -> mujoco.MjsBody:
        body = spec.body(arm.named(local))
        if body is None:
            raise fail(f"{where}.{key}", f"{arm.model.name} has no body {local!r}")
        return body

    added = [(entry, body_of(entry.body, f"add[{i}].body")) for i, entry in enumerate(collision.add)]
    bits = [_collision_bits(body) for _, body in added]  # before any is switched off
    off = []
    for local in collision.disable_geoms:
        geom = spec.geom(arm.named(local))
        if geom is None:
            raise fail(f"{where}.disable.geoms", f"{arm.model.name} has no geom {local!r}; its colliding geoms "
                                                 f"(an unnamed one is {unnamed_geom_name('<body>', '<i>')}): "
                                                 f"{_colliding_geoms(spec, arm)}")
        off.append(geom)
    for local in collision.disable_bodies:
        geoms = [g for g in body_of(local, "disable.bodies").geoms if g.contype or g.conaffinity]
        if not geoms:
            raise fail(f"{where}.disable.bodies", f"body {local!r} of {arm.model.name} has no collision geom")
        off += geoms
    for geom in off:
        geom.contype = geom.conaffinity = 0
    for i, ((entry, body), (contype, conaffinity)) in enumerate(zip(added, bits)):
        quat = euler_quat(np.deg2rad(entry.euler_deg))
        kind = getattr(mujoco.mjtGeom, f"mjGEOM_{entry.type.upper()}")
        geom = body.add_geom(name=arm.named(f"collision_{i}"), type=kind,
                             size=[*entry.size, *[0.0] * (3 - len(entry.size))], pos=list(entry.pos), quat=quat,
                             group=3, density=0.0, contype=contype, conaffinity=conaffinity)
        if entry.friction is not None:
            geom.friction = list(entry.friction)


def _rest_frame(body: mujoco.MjsBody) -> tuple[np.ndarray, np.ndarray]:
    """(rotation, position) of ``body`` in the world at the model's rest pose (no joints moved)."""
    R, p = np.eye(3), np.zeros(3)
    while body is not None and body.name != "world":
        R_body = matrix_from_quat(body.quat)
        R, p = R_body @ R, np.asarray(body.pos, float) + R_body @ p
        body = body.parent
    return R, p


def _place_camera(spec: mujoco.MjSpec, robot: Robot, cam: RigCamera) -> None:
    where = f"rig.{cam.name}"
    if cam.camera is not None:
        model_name = robot.arms[cam.arm].named(cam.camera) if cam.arm else cam.camera
        mj_cam = spec.camera(model_name)
        if mj_cam is None:
            known = sorted(c.name for c in spec.cameras)
            raise fail(f"{where}.camera", f"the model has no camera {model_name!r}; its cameras: {known}")
        if spec.camera(cam.name) is not None and model_name != cam.name:
            raise fail(where, f"the model already has a camera called {cam.name!r}")
        mj_cam.name = cam.name
    else:
        body = spec.worldbody if cam.body == "world" else spec.body(cam.body)
        if body is None:
            raise fail(f"{where}.body", f"the model has no body {cam.body!r}")
        mj_cam = body.add_camera(name=cam.name, pos=list(cam.pos))
    if cam.look_at is not None:
        R_parent, p_parent = _rest_frame(mj_cam.parent)
        quat = cam_geom.look_at_quat_wxyz(p_parent + R_parent @ np.asarray(mj_cam.pos), np.asarray(cam.look_at))
        mj_cam.quat = quat if np.array_equal(R_parent, np.eye(3)) else quat_from_matrix(R_parent.T @ matrix_from_quat(quat))
    if cam.fovy_deg is not None:
        mj_cam.fovy = cam.fovy_deg
    if cam.intrinsics is not None:
        k = cam.intrinsics
        size = [k["width"], k["height"]]
        mj_cam.resolution = [int(k["width"]), int(k["height"])]
        mj_cam.sensor_size = size  # one length unit per pixel
        mj_cam.focal_pixel = [k["fx"], k["fy"]]
        # MuJoCo's principal point is an offset from the sensor centre, positive left and up.
        mj_cam.principal_pixel = [(k["width"] - 1) / 2 - k["cx"], (k["height"] - 1) / 2 - k["cy"]]


def build_robot_spec(robot: Robot) -> mujoco.MjSpec:
    """Scene, arms and camera rig (no task objects)."""
    spec = load_model_spec(robot.scene, assets=robot.scene_assets, where="robot.scene")
    if robot.timestep_s is not None:
        spec.option.timestep = robot.timestep_s
    if spec.geom(robot.table_geom) is None:
        raise fail("robot.workspace.geom", f"{robot.scene.name} has no geom {robot.table_geom!r}; its geoms (an "
                                           f"unnamed one is {unnamed_geom_name('<body>', '<i>')}): "
                                           f"{[g.name for g in spec.geoms if g.name]}")
    for arm in robot.arms.values():
        _attach_arm(spec, arm)
    for cam in robot.rig.values():
        _place_camera(spec, robot, cam)
    return spec


def substeps(robot: Robot, timestep_s: float) -> int:
    """Physics steps per control period; the control period must be whole timesteps."""
    n = robot.control_dt_s / timestep_s
    if abs(n - round(n)) > 1e-6 or round(n) < 1:
        raise fail("robot.timestep_s" if robot.timestep_s is not None else "robot.control_hz",
                   f"{robot.control_hz:g} Hz is not a whole number of {timestep_s:g} s physics steps")
    return int(round(n))


def _offscreen_size(spec: mujoco.MjSpec, max_size_hw) -> None:
    spec.visual.global_.offheight = max(spec.visual.global_.offheight, int(max_size_hw[0]))
    spec.visual.global_.offwidth = max(spec.visual.global_.offwidth, int(max_size_hw[1]))


def _apply_physics_params(model: mujoco.MjModel, robot: Robot, params: WorldParams, objects) -> None:
    model.geom_friction[:, 0] *= params.friction_scale
    model.actuator_gainprm[:, 0] *= params.actuator_kp_scale
    model.actuator_biasprm[:, 1] *= params.actuator_kp_scale
    for name, offsets in params.joint_offset_rad.items():
        arm = robot.arms[name]
        for actuator, offset in zip(arm.actuators, offsets, strict=True):
            # A position servo's force is kp * (ctrl - q) + bias0: bias0 = kp * offset holds the
            # joint at ctrl + offset.
            act = model.actuator(arm.named(actuator)).id
            model.actuator_biasprm[act, 0] = model.actuator_gainprm[act, 0] * float(offset)
    for obj in objects:
        body_id = model.body(obj.name).id
        model.body_mass[body_id] *= params.mass_scale(obj.name)
        model.body_inertia[body_id] *= params.mass_scale(obj.name)
    # Quantities derived from masses at compile time (subtree masses, the inverse weights
    # that scale soft contacts) must follow, or a heavier light object's contacts go unstable.
    mujoco.mj_setConst(model, mujoco.MjData(model))


def build_model(
    robot: Robot, objects: tuple[ObjectSpec, ...], params: WorldParams, max_size_hw=(480, 640),
    add_to_spec: Callable[[mujoco.MjSpec], None] | None = None,
) -> mujoco.MjModel:
    """Compile the full scene for ``objects`` under ``params``; ``add_to_spec`` may add bodies
    that are in no task (a calibration board) before it compiles."""
    spec = build_robot_spec(robot)
    _offscreen_size(spec, max_size_hw)
    for obj in objects:
        add_object(spec, obj, params.size_scale(obj.name))
    if add_to_spec is not None:
        add_to_spec(spec)
    substeps(robot, spec.option.timestep)
    model = spec.compile()
    # Compiled with the nominal look; the world's cameras, light and colours written over it.
    apply_render_params(model, render_base(model, robot.table_geom, objects), params)
    _apply_physics_params(model, robot, params, objects)
    return model


def build_robot_model(robot: Robot) -> mujoco.MjModel:
    """Robot-only model (no free objects), used for inverse kinematics."""
    return build_robot_spec(robot).compile()


def load_world(world: Mapping) -> tuple[Robot, dict]:
    """The robot and the tasks of ``world`` (a ``world`` config slice), checked against each other
    and against the model files: the joints, actuators, sites, bodies and cameras the robot and rig
    name are the model's, a task's arm is one of the robot's, and its start regions leave room for
    its objects."""
    robot, tasks = world_robot(world), world_tasks(world)
    substeps(robot, build_robot_spec(robot).option.timestep)  # the names given are the model's
    for key, task in tasks.items():
        if task.arm not in (*robot.arms, "nearest", "behind_axis"):
            raise fail(f"tasks.{key}.arm", f"must be an arm of the robot {list(robot.arms)}, nearest or behind_axis, "
                                           f"got {task.arm!r}")
        sample_initial_poses(task, np.random.default_rng(0))  # a start region that leaves no room raises
    return robot, tasks
