"""A world's cameras, light and colours, written over a compiled model (one owner for both the
build and the calibration's hypotheses)."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from r2s_eval.sim import WorldParams
from r2s_eval.sim import cameras as cam_geom
from r2s_eval.sim.render_params import apply_render_params, render_base
from r2s_eval.sim.rotations import matrix_from_quat
from tests.helpers.worlds import bundled_env

LOOK = WorldParams(light_intensity_scale=0.8, light_dir_offset=(0.1, 0.0, -0.05), table_rgb_offset=(0.05, -0.02, 0.0),
                   object_rgb_offset={"cup": (0.0, 0.1, 0.0)},
                   camera_pos_offset_m={"head_left": (0.01, 0.0, -0.02), "wrist_left": (0.0, 0.01, 0.0)},
                   camera_rot_offset_rad={"head_left": (0.02, 0.0, 0.01), "wrist_left": (0.05, 0.0, 0.0)})


def test_a_wrist_cameras_mount_error_turns_and_moves_it_in_its_own_frame():
    """The wrist camera's model writes its orientation as xyaxes: its offset used to be dropped."""
    nominal = bundled_env("cup_on_plate", cameras=())
    moved = bundled_env("cup_on_plate", LOOK, cameras=())
    cam = nominal.model.camera("wrist_left").id
    R = matrix_from_quat(nominal.model.cam_quat[cam])
    assert np.allclose(moved.model.cam_pos[cam], nominal.model.cam_pos[cam] + R @ np.array([0.0, 0.01, 0.0]))
    turned = nominal.model.cam_quat[cam] @ moved.model.cam_quat[cam]
    assert abs(abs(turned) - np.cos(0.025)) < 1e-9  # a 0.05 rad turn
    for env in (nominal, moved):
        env.close()


def test_writing_a_look_over_a_nominal_model_renders_as_building_with_it():
    built = bundled_env("cup_on_plate", LOOK, cameras=("head_left",))
    rewritten = bundled_env("cup_on_plate", cameras=("head_left",))
    apply_render_params(rewritten.model, render_base(rewritten.model, rewritten.robot.table_geom,
                                                     rewritten.task.objects), LOOK)
    for env in (built, rewritten):
        env.reset(seed=3, settle=False, observe=False)
        mujoco.mj_forward(env.model, env.data)
    assert np.array_equal(built.render("head_left"), rewritten.render("head_left"))
    assert np.allclose(built.camera_T_world_from_cam("head_left"), rewritten.camera_T_world_from_cam("head_left"))
    for env in (built, rewritten):
        env.close()


def test_a_mount_error_reads_back_from_the_pose_it_gives():
    env = bundled_env("cup_on_plate", LOOK, cameras=())
    nominal = bundled_env("cup_on_plate", dataclasses.replace(LOOK, camera_pos_offset_m={}, camera_rot_offset_rad={}),
                          cameras=())
    cam = env.model.camera("head_left").id
    dpos, drot = cam_geom.mount_error(nominal.model.cam_pos[cam], nominal.model.cam_quat[cam],
                                      cam_geom.T_parent_from_cam(env.model.cam_pos[cam], env.model.cam_quat[cam]))
    assert np.allclose(dpos, LOOK.camera_pos_offset_m["head_left"]) and np.allclose(drot, LOOK.camera_rot_offset_rad["head_left"])
    env.close()
    nominal.close()
