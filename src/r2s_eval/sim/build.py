"""Worlds from the experiment's config slices: the world's tasks and their environments."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from r2s_eval.errors import ConfigError
from r2s_eval.sim.env import TabletopEnv
from r2s_eval.sim.params import WorldParams
from r2s_eval.sim.robot import Robot, world_robot
from r2s_eval.sim.tasks import Task, get_task


def image_size(world_cfg: dict) -> tuple[int, int]:
    return int(world_cfg["image_height"]), int(world_cfg["image_width"])


def configured_task(key: str, world_cfg: dict, suite_cfg: dict | None) -> Task:
    """The world's task with the experiment's start regions, if the config sets any."""
    task = get_task(key, world_cfg)
    regions = ((suite_cfg or {}).get(key) or {}).get("init_regions")
    if not regions:
        return task
    new = dict(task.init_regions)
    for name, r in regions.items():
        if name not in new:
            raise ConfigError(f"suite.{key}.init_regions: task {key!r} has no object {name!r} (objects: {sorted(new)})")
        new[name] = dataclasses.replace(
            new[name], x_range_m=tuple(r["x_range_m"]), y_range_m=tuple(r["y_range_m"]),
            yaw_range_rad=tuple(r.get("yaw_range_rad", new[name].yaw_range_rad)),
        )
    return dataclasses.replace(task, init_regions=new)


def make_env(task: str, world_cfg: dict, params: WorldParams | None = None, cameras=None, suite_cfg: dict | None = None,
             **shared) -> TabletopEnv:
    """The task's environment as the ``world`` config slice describes it (image size, cameras);
    ``shared``: a compiled model and renderers to share (`TabletopEnv`)."""
    return TabletopEnv(
        configured_task(task, world_cfg, suite_cfg),
        params=params,
        image_size=image_size(world_cfg),
        cameras=tuple(world_cfg["cameras"] if cameras is None else cameras),
        robot=world_robot(world_cfg),
        **shared,
    )


def feature_ranges(robot: Robot) -> dict[str, tuple[float, float]]:
    """Per dataset feature, the range its values can take in the dataset's units: a limited joint's
    range from the model, a gripper's open..closed; unlimited joints are left out. Ingest checks a
    recording against it, so a wrong unit in ``robot.features`` (degrees read as radians, -100..100
    read as degrees) stops there instead of silently skewing the calibration."""
    from r2s_eval.sim.assembly import build_robot_model

    model = build_robot_model(robot)
    ranges = {}
    for f in robot.features:
        arm = robot.arms[f.arm]
        if f.joint is None:
            model_range = (0.0, 1.0)  # the closing fraction
        else:
            joint = model.joint(arm.named(f.joint))
            if not model.jnt_limited[joint.id]:
                continue
            model_range = tuple(float(v) for v in model.jnt_range[joint.id])
        lo, hi = sorted((v - f.offset) / f.scale for v in model_range)
        ranges[f.name] = (lo, hi)
    return ranges


def check_world_params(params: WorldParams, world_cfg: dict, source: str, world_name: str = "this world") -> None:
    """Raise ConfigError (one line naming ``source``) when ``params`` were fitted for another
    world: they name an arm, a joint count, a camera or an object ``world_cfg`` does not have."""
    robot = world_robot(world_cfg)
    objects = set(world_cfg.get("objects") or {})
    for arm, offsets in params.joint_offset_rad.items():
        if arm not in robot.arms:
            raise ConfigError(f"{source}: world parameters of another world: joint offsets of arm {arm!r}, "
                              f"{world_name} has arms {sorted(robot.arms)}")
        if len(offsets) != len(robot.arms[arm].joints):
            raise ConfigError(f"{source}: world parameters of another world: {len(offsets)} joint offsets for arm "
                              f"{arm!r}, which has {len(robot.arms[arm].joints)} joints in {world_name}")
    for key in ("camera_pos_offset_m", "camera_rot_offset_rad", "lens_distortion", "background_plates"):
        for camera in getattr(params, key):
            if camera not in robot.rig:
                raise ConfigError(f"{source}: world parameters of another world: {key} of camera {camera!r}, "
                                  f"{world_name} has cameras {sorted(robot.rig)}")
    for camera, coefficients in params.lens_distortion.items():
        if len(coefficients) != 5:
            raise ConfigError(f"{source}: lens_distortion of camera {camera!r} has {len(coefficients)} coefficients, "
                              "OpenCV's model has five (k1, k2, p1, p2, k3)")
    for camera, plate in params.background_plates.items():
        if not Path(plate).is_file():
            raise ConfigError(f"{source}: background_plates: camera {camera!r}'s plate {plate} does not exist")
    for i, state in enumerate(params.background_states):
        if len(state) != robot.action_dim:
            raise ConfigError(f"{source}: background_states[{i}] has {len(state)} values, a state of {world_name} "
                              f"has {robot.action_dim}")
    for key, unit in (("background_margin_px", "pixels"), ("command_latency_steps", "control steps")):
        value = getattr(params, key)
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ConfigError(f"{source}: {key} must be a whole number of {unit} >= 0, got {value!r}")
    for key in ("object_mass_scale", "object_size_scale", "object_rgb_offset"):
        for name in getattr(params, key):
            if name not in objects:
                raise ConfigError(f"{source}: world parameters of another world: {key} of object {name!r}, "
                                  f"{world_name} has objects {sorted(objects)}")
