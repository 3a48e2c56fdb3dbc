"""Scene assembly: table + two arms + head cameras + task objects -> MjModel.

The MJCF lives in ``assets/`` (``tabletop.xml`` and ``arm.xml``); this module
attaches the arm twice, adds the task objects and applies ``WorldParams``.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from r2s_eval.sim import cameras as cam_geom
from r2s_eval.sim.objects import ObjectSpec, add_object
from r2s_eval.sim.params import WorldParams

ASSETS_DIR = Path(__file__).resolve().parents[3] / "assets"

TABLE_TOP_Z_M = 0.75
PHYSICS_DT_S = 0.002
CONTROL_DT_S = 0.1  # 10 Hz control; each action is held for 50 physics steps
N_SUBSTEPS = int(round(CONTROL_DT_S / PHYSICS_DT_S))
GRIPPER_OPEN_M = 0.05  # per-jaw opening at command 0 (fully open)

ARMS = ("left", "right")
ARM_JOINTS = ("j1", "j2", "j3", "j4", "j5", "j6")
# The cameras both head cameras are aimed at (centre of the workspace, on the table).
HEAD_TARGET_WORLD_M = np.array([-0.03, 0.0, TABLE_TOP_Z_M])

# Home pose of the left arm (rad): gripper pointing down above the table near
# its own side. The right arm mirrors it across the x-z plane, which flips the
# sign of the joints that turn about z (j1) or x (j4, j6).
HOME_LEFT_Q_RAD = np.array([0.0, -0.2, 0.8, 0.0, 0.97, 0.0])
_MIRROR_SIGNS = np.array([-1.0, 1.0, 1.0, -1.0, 1.0, -1.0])


def home_arm_q(arm: str) -> np.ndarray:
    return HOME_LEFT_Q_RAD.copy() if arm == "left" else HOME_LEFT_Q_RAD * _MIRROR_SIGNS


def build_robot_spec() -> mujoco.MjSpec:
    """Table, head, lights and both arms (no task objects)."""
    spec = mujoco.MjSpec.from_file(str(ASSETS_DIR / "tabletop.xml"))
    for arm in ARMS:
        arm_spec = mujoco.MjSpec.from_file(str(ASSETS_DIR / "arm.xml"))
        spec.attach(arm_spec, prefix=f"{arm}_", frame=spec.frame(f"{arm}_mount"))
        spec.camera(f"{arm}_wrist").name = f"wrist_{arm}"
    for name in ("head_left", "head_right"):
        cam = spec.camera(name)
        head_pos_world_m = np.asarray(spec.body("head").pos) + np.asarray(cam.pos)
        cam.quat = cam_geom.look_at_quat_wxyz(head_pos_world_m, HEAD_TARGET_WORLD_M)
    return spec


def _apply_render_params(spec: mujoco.MjSpec, params: WorldParams, max_size_hw) -> None:
    spec.visual.global_.offheight = max(spec.visual.global_.offheight, int(max_size_hw[0]))
    spec.visual.global_.offwidth = max(spec.visual.global_.offwidth, int(max_size_hw[1]))
    for light in spec.lights:
        light.diffuse = np.clip(np.asarray(light.diffuse) * params.light_intensity_scale, 0, 1)
        direction = np.asarray(light.dir) + np.asarray(params.light_dir_offset)
        light.dir = direction / np.linalg.norm(direction)
    table = spec.geom("table_top")
    table.rgba = np.clip(np.r_[np.asarray(table.rgba[:3]) + params.table_rgb_offset, 1.0], 0, 1)
    for cam in spec.cameras:
        # Offsets are expressed in the camera's own frame (mount error).
        dpos = np.asarray(params.camera_pos_offset_m.get(cam.name, (0.0, 0.0, 0.0)))
        drot = params.camera_rot_offset_rad.get(cam.name, (0.0, 0.0, 0.0))
        quat = np.asarray(cam.quat, float)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, quat)
        cam.pos = np.asarray(cam.pos) + R.reshape(3, 3) @ dpos
        new_quat = np.zeros(4)
        mujoco.mju_mulQuat(new_quat, quat, cam_geom.small_rotation_quat_wxyz(drot))
        cam.quat = new_quat


def _apply_physics_params(model: mujoco.MjModel, params: WorldParams, objects) -> None:
    model.geom_friction[:, 0] *= params.friction_scale
    model.actuator_gainprm[:, 0] *= params.actuator_kp_scale
    model.actuator_biasprm[:, 1] *= params.actuator_kp_scale
    for arm, offsets in params.joint_offset_rad.items():
        for joint, offset in zip(ARM_JOINTS, offsets, strict=True):
            # A position servo's force is kp * (ctrl - q) + bias0: bias0 = kp * offset holds the
            # joint at ctrl + offset.
            act = model.actuator(f"{arm}_{joint}").id
            model.actuator_biasprm[act, 0] = model.actuator_gainprm[act, 0] * float(offset)
    for obj in objects:
        body_id = model.body(obj.name).id
        model.body_mass[body_id] *= params.mass_scale(obj.name)
        model.body_inertia[body_id] *= params.mass_scale(obj.name)
    # Quantities derived from masses at compile time (subtree masses, the inverse weights
    # that scale soft contacts) must follow, or a heavier light object's contacts go unstable.
    mujoco.mj_setConst(model, mujoco.MjData(model))


def build_model(
    objects: tuple[ObjectSpec, ...], params: WorldParams, max_size_hw=(480, 640)
) -> mujoco.MjModel:
    """Compile the full scene for ``objects`` under ``params``."""
    spec = build_robot_spec()
    # Wrist cameras are attached with the arms; re-read their quats for offsets.
    _apply_render_params(spec, params, max_size_hw)
    for obj in objects:
        add_object(spec, obj, params.size_scale(obj.name), params.object_rgb_offset.get(obj.name, (0, 0, 0)))
    model = spec.compile()
    _apply_physics_params(model, params, objects)
    return model


def build_robot_model() -> mujoco.MjModel:
    """Robot-only model (no free objects), used for inverse kinematics."""
    return build_robot_spec().compile()
