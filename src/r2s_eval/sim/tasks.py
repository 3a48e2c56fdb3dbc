"""Task registry: instruction, objects, initial-pose regions, success and progress.

A task is data plus two functions of the environment state:

* ``success(env) -> bool``: the rule-based check of the current state.
* ``progress(env) -> float`` in [0, 1]: the highest stage reached *in the
  current state*; the env also keeps the running maximum over an episode.

Adding a task = adding object specs (``objects.py`` kinds), regions, and
these two functions, then one ``Task`` entry in ``TASKS``.

Initial regions are axis-aligned boxes on the table top (world frame, metres)
for each object's bottom centre, with yaw uniform in ``yaw_range_rad``;
poses are drawn by rejection sampling so footprints keep ``clearance_m``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from r2s_eval.sim.objects import ObjectSpec, footprint_radius_m

if TYPE_CHECKING:  # pragma: no cover
    from r2s_eval.sim.env import TabletopEnv


@dataclass(frozen=True)
class Region:
    x_range_m: tuple[float, float]
    y_range_m: tuple[float, float]
    yaw_range_rad: tuple[float, float] = (-np.pi, np.pi)


@dataclass(frozen=True)
class Task:
    key: str
    instruction: str
    objects: tuple[ObjectSpec, ...]
    init_regions: dict[str, Region]
    success: Callable[["TabletopEnv"], bool]
    progress: Callable[["TabletopEnv"], float]
    # "left", "right", or "nearest": the arm whose base is nearest to the
    # midpoint of the object to grasp and its target.
    arm: str = "nearest"
    clearance_m: float = 0.03

    @property
    def object_names(self) -> tuple[str, ...]:
        return tuple(o.name for o in self.objects)

    def object(self, name: str) -> ObjectSpec:
        return next(o for o in self.objects if o.name == name)


# ---------------------------------------------------------------- objects
CUP = ObjectSpec(
    name="cup",
    kind="cup",
    rgba=(0.85, 0.08, 0.08, 1.0),  # saturated red
    dims=dict(radius_m=0.035, height_m=0.085, wall_m=0.006, bottom_m=0.008, n_walls=16),
    mass_kg=0.12,
)
PLATE = ObjectSpec(
    name="plate",
    kind="plate",
    rgba=(0.08, 0.25, 0.85, 1.0),  # saturated blue
    dims=dict(radius_m=0.085, thickness_m=0.008, rim_height_m=0.012, rim_width_m=0.008, n_rim=20),
    mass_kg=0.25,
)

# ---------------------------------------------------------------- thresholds
UPRIGHT_MAX_TILT_RAD = np.deg2rad(15.0)
REST_MAX_LIN_SPEED_M_S = 0.03
REST_MAX_ANG_SPEED_RAD_S = 0.5
RESTING_HEIGHT_TOL_M = 0.008  # cup bottom vs plate top surface
REACHED_DIST_M = 0.05
LIFTED_HEIGHT_M = 0.02


def _tilt_rad(quat_wxyz: np.ndarray) -> float:
    w, x, y, z = quat_wxyz
    cos_tilt = 1.0 - 2.0 * (x * x + y * y)  # world z of the body's z axis
    return float(np.arccos(np.clip(cos_tilt, -1.0, 1.0)))


def _cup_on_plate_geometry(env: "TabletopEnv") -> dict:
    cup = env.object_state("cup")
    plate = env.object_state("plate")
    cup_dims, plate_dims = env.object_dims("cup"), env.object_dims("plate")
    plate_top_z_m = plate["pos_world_m"][2] + plate_dims["thickness_m"]
    offset_xy_m = float(np.linalg.norm(cup["pos_world_m"][:2] - plate["pos_world_m"][:2]))
    return dict(
        tilt_rad=_tilt_rad(cup["quat_wxyz"]),
        offset_xy_m=offset_xy_m,
        max_offset_xy_m=plate_dims["radius_m"] - cup_dims["radius_m"],
        height_above_plate_m=float(cup["pos_world_m"][2] - plate_top_z_m),
        lin_speed_m_s=float(np.linalg.norm(cup["linvel_world_m_s"])),
        ang_speed_rad_s=float(np.linalg.norm(cup["angvel_world_rad_s"])),
    )


def cup_on_plate_success(env: "TabletopEnv") -> bool:
    """Cup upright, bottom resting on the plate inside its rim, at rest, released."""
    g = _cup_on_plate_geometry(env)
    return bool(
        g["tilt_rad"] < UPRIGHT_MAX_TILT_RAD
        and g["offset_xy_m"] < g["max_offset_xy_m"]
        and abs(g["height_above_plate_m"]) < RESTING_HEIGHT_TOL_M
        and g["lin_speed_m_s"] < REST_MAX_LIN_SPEED_M_S
        and g["ang_speed_rad_s"] < REST_MAX_ANG_SPEED_RAD_S
        and not env.robot_touches("cup")
    )


def cup_on_plate_progress(env: "TabletopEnv") -> float:
    """Stages: reached 0.2, grasped 0.4, lifted 0.6, above plate 0.8, placed 1.0."""
    if cup_on_plate_success(env):
        return 1.0
    g = _cup_on_plate_geometry(env)
    cup = env.object_state("cup")
    grasped = env.grasped("cup") is not None
    cup_bottom_z_m = cup["pos_world_m"][2]
    lifted = cup_bottom_z_m > env.table_top_z_m + LIFTED_HEIGHT_M
    above_plate = g["offset_xy_m"] < g["max_offset_xy_m"] and g["tilt_rad"] < UPRIGHT_MAX_TILT_RAD
    if above_plate and (lifted or grasped) and g["height_above_plate_m"] > -RESTING_HEIGHT_TOL_M:
        return 0.8
    if grasped and lifted:
        return 0.6
    if grasped:
        return 0.4
    cup_centre_m = cup["pos_world_m"] + np.array([0, 0, env.object_dims("cup")["height_m"] / 2])
    tcp_dist_m = min(np.linalg.norm(p - cup_centre_m) for p in env.ee_positions().values())
    return 0.2 if tcp_dist_m < REACHED_DIST_M else 0.0


TASKS: dict[str, Task] = {
    "cup_on_plate": Task(
        key="cup_on_plate",
        instruction="Pick the Cup and Place it on the Plate",
        objects=(CUP, PLATE),
        init_regions={
            "cup": Region(x_range_m=(-0.12, 0.06), y_range_m=(-0.16, 0.16)),
            "plate": Region(x_range_m=(-0.12, 0.06), y_range_m=(-0.16, 0.16)),
        },
        success=cup_on_plate_success,
        progress=cup_on_plate_progress,
        arm="nearest",
    ),
}


def get_task(key: str) -> Task:
    try:
        return TASKS[key]
    except KeyError:
        raise KeyError(f"unknown task {key!r}; known: {sorted(TASKS)}") from None


def sample_initial_poses(
    task: Task, rng: np.random.Generator, size_scales: dict[str, float] | None = None, max_tries: int = 1000
) -> dict[str, tuple[float, float, float]]:
    """Planar poses {name: (x_m, y_m, yaw_rad)} inside the task regions, footprints apart."""
    size_scales = size_scales or {}
    radii = {
        o.name: footprint_radius_m(o.kind, o.scaled_dims(size_scales.get(o.name, 1.0))) for o in task.objects
    }
    for _ in range(max_tries):
        poses: dict[str, tuple[float, float, float]] = {}
        for obj in task.objects:
            region = task.init_regions[obj.name]
            poses[obj.name] = (
                float(rng.uniform(*region.x_range_m)),
                float(rng.uniform(*region.y_range_m)),
                float(rng.uniform(*region.yaw_range_rad)),
            )
        names = list(poses)
        ok = all(
            np.hypot(poses[a][0] - poses[b][0], poses[a][1] - poses[b][1])
            > radii[a] + radii[b] + task.clearance_m
            for i, a in enumerate(names)
            for b in names[i + 1 :]
        )
        if ok:
            return poses
    raise RuntimeError(f"could not sample collision-free poses for {task.key}")
