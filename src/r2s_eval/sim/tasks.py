"""Task registry: instruction, objects, initial-pose regions, success and progress.

A task is data plus two functions of the environment state:

* ``success(env) -> bool``: the rule-based check of the current state.
* ``progress(env) -> float`` in [0, 1]: the highest stage reached *in the
  current state*; the env also keeps the running maximum over an episode.

Adding a task = adding object specs (``objects.py`` kinds), regions, and
these two functions, then one ``Task`` entry in ``TASKS``.

Initial regions are axis-aligned boxes on the table top (world frame, metres)
for each object's planar pose (footprint centre, see ``objects.py``), with yaw
uniform in ``yaw_range_rad``; poses are drawn by rejection sampling so
footprints keep ``clearance_m``. A region ``relative_to`` another object is
expressed in that object's planar frame (its x, y rotated by its yaw) and the
object starts on the other's support surface (a block inside a box).
Each object starts in a placement (``upright``, ``upside_down``, ``on_side``).

The seven tasks (key: instruction; objects; success):

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

Success rules (thresholds are the module constants below; "released" = no robot
contact, "at rest" = linear speed < 3 cm/s and angular < 0.5 rad/s):

* cover_ball: cup upside down (within 15 deg), its rim on the table, the ball's centre
  inside the cup's inner radius less the ball's, the ball on the table; cup released and
  at rest.
* ball_in_box: ball centre inside the box's inner walls and below its rim, box upright;
  ball released and slower than 5 cm/s.
* ball_in_cup: cup upright, ball centre inside the cup's inner base radius and below its rim;
  ball and cup released, ball slower than 5 cm/s.
* cup_on_plate: cup upright, bottom on the plate inside its rim; released and at rest.
* stack_blocks: one block's bottom face on the other's top face (both upright within
  15 deg), its centre inside the lower block's top face (inset 5 mm, so it is stable);
  released and both at rest.
* block_from_box: the block's footprint does not overlap the box's (separating axis
  test), the block rests on the table; released and at rest.
* upright_cup: cup upright (within 15 deg) with its bottom on the table; released and
  at rest.

Progress (running maximum kept by the env): 0.2 the gripper reached the object to
manipulate, 0.4 grasped, 0.6 lifted 2 cm, 0.8 grasped in the goal configuration (over the
target, or upright), 1.0 success.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from r2s_eval.sim.objects import ObjectSpec, footprint_radius_m, height_m, yaw_symmetry

if TYPE_CHECKING:  # pragma: no cover
    from r2s_eval.sim.env import TabletopEnv


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
    success: Callable[["TabletopEnv"], bool]
    progress: Callable[["TabletopEnv"], float]
    # The object the operator grasps and moves.
    manipulated: str = ""
    # "left", "right", "nearest" (the arm whose base is nearest to the midpoint of the
    # objects), or "behind_axis" (on_side objects: the arm on the side the object's axis
    # points away from, so the gripper ends pointing along it).
    arm: str = "nearest"
    clearance_m: float = 0.03
    placements: dict[str, str] = field(default_factory=dict)  # missing -> "upright"

    def placement(self, name: str) -> str:
        return self.placements.get(name, "upright")

    @property
    def object_names(self) -> tuple[str, ...]:
        return tuple(o.name for o in self.objects)

    def object(self, name: str) -> ObjectSpec:
        return next(o for o in self.objects if o.name == name)

    def yaw_symmetry(self, name: str) -> int:
        """Yaw symmetry of the object in its start placement (``objects.yaw_symmetry``)."""
        return yaw_symmetry(self.object(name).kind, self.placement(name))


# ---------------------------------------------------------------- objects
# Saturated, well separated hues so the colour segmenter tells them apart from each
# other and from the (low-saturation) wooden table.
CUP = ObjectSpec(
    name="cup",
    kind="cup",
    rgba=(0.85, 0.08, 0.08, 1.0),  # red
    dims=dict(radius_m=0.037, base_radius_m=0.03, height_m=0.085, wall_m=0.006, bottom_m=0.008, n_walls=16),
    mass_kg=0.12,
)
PLATE = ObjectSpec(
    name="plate",
    kind="plate",
    rgba=(0.08, 0.25, 0.85, 1.0),  # blue
    dims=dict(radius_m=0.085, thickness_m=0.008, rim_height_m=0.012, rim_width_m=0.008, n_rim=20),
    mass_kg=0.25,
)
BALL = ObjectSpec(
    name="ball",
    kind="ball",
    rgba=(0.10, 0.75, 0.15, 1.0),  # green
    dims=dict(radius_m=0.02),
    mass_kg=0.045,  # a golf ball's weight
)
BOX = ObjectSpec(
    name="box",
    kind="box",
    rgba=(0.10, 0.30, 0.85, 1.0),  # blue
    dims=dict(length_m=0.17, width_m=0.14, height_m=0.035, wall_m=0.006, floor_m=0.006),
    mass_kg=0.30,
)
BLOCK_A = ObjectSpec(
    name="block_a",
    kind="block",
    rgba=(0.90, 0.80, 0.05, 1.0),  # yellow
    dims=dict(size_m=0.045),
    mass_kg=0.06,
)
BLOCK_B = ObjectSpec(
    name="block_b",
    kind="block",
    rgba=(0.75, 0.10, 0.75, 1.0),  # magenta
    dims=dict(size_m=0.045),
    mass_kg=0.06,
)

# ---------------------------------------------------------------- thresholds
UPRIGHT_MAX_TILT_RAD = np.deg2rad(15.0)
REST_MAX_LIN_SPEED_M_S = 0.03
REST_MAX_ANG_SPEED_RAD_S = 0.5
BALL_MAX_LIN_SPEED_M_S = 0.05  # a ball inside a container may still roll slowly
RESTING_HEIGHT_TOL_M = 0.008  # a face vs the surface it should rest on
STACK_INSET_M = 0.005  # the top block's centre must be this far inside the lower top face
REACHED_DIST_M = 0.05
LIFTED_HEIGHT_M = 0.02


# ---------------------------------------------------------------- geometry helpers
def _tilt_rad(quat_wxyz: np.ndarray) -> float:
    w, x, y, z = quat_wxyz
    cos_tilt = 1.0 - 2.0 * (x * x + y * y)  # world z of the body's z axis
    return float(np.arccos(np.clip(cos_tilt, -1.0, 1.0)))


def _rotation(quat_wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(quat_wxyz, float) / np.linalg.norm(quat_wxyz)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _local(env: "TabletopEnv", frame_obj: str, point_world_m: np.ndarray) -> np.ndarray:
    """``point_world_m`` in the body frame of ``frame_obj``."""
    s = env.object_state(frame_obj)
    return _rotation(s["quat_wxyz"]).T @ (np.asarray(point_world_m) - s["pos_world_m"])


def centre_m(env: "TabletopEnv", name: str) -> np.ndarray:
    """World position of the object's geometric centre (half its height along body z)."""
    s = env.object_state(name)
    kind = env.task.object(name).kind
    half = height_m(kind, env.object_dims(name)) / 2
    return s["pos_world_m"] + _rotation(s["quat_wxyz"])[:, 2] * half


def _at_rest(env: "TabletopEnv", name: str) -> bool:
    s = env.object_state(name)
    return bool(np.linalg.norm(s["linvel_world_m_s"]) < REST_MAX_LIN_SPEED_M_S
                and np.linalg.norm(s["angvel_world_rad_s"]) < REST_MAX_ANG_SPEED_RAD_S)


def _ball_settled(env: "TabletopEnv") -> bool:
    return bool(np.linalg.norm(env.object_state("ball")["linvel_world_m_s"]) < BALL_MAX_LIN_SPEED_M_S)


def _upright(env: "TabletopEnv", name: str) -> bool:
    return _tilt_rad(env.object_state(name)["quat_wxyz"]) < UPRIGHT_MAX_TILT_RAD


def _upside_down(env: "TabletopEnv", name: str) -> bool:
    return _tilt_rad(env.object_state(name)["quat_wxyz"]) > np.pi - UPRIGHT_MAX_TILT_RAD


def _box_corners_xy(centre_xy, axes_xy, half_extents) -> np.ndarray:
    """Corners of an oriented rectangle (axes_xy: 2 unit vectors as rows)."""
    signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], float)
    return centre_xy + (signs * half_extents) @ axes_xy


def _separated_xy(points_a: np.ndarray, points_b: np.ndarray, axes: list[np.ndarray]) -> bool:
    """Separating-axis test of the convex hulls of two planar point sets."""
    for axis in axes:
        pa, pb = points_a @ axis, points_b @ axis
        if pa.max() <= pb.min() or pb.max() <= pa.min():
            return True
    return False


def _block_corners_world(env: "TabletopEnv", name: str) -> tuple[np.ndarray, np.ndarray]:
    s = env.object_state(name)
    R = _rotation(s["quat_wxyz"])
    half = env.object_dims(name)["size_m"] / 2
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (0, 2)], float)
    return s["pos_world_m"] + (signs * half) @ R.T, R


def block_outside_box(env: "TabletopEnv", block: str = "block_a", box: str = "box") -> bool:
    """True when the block's footprint and the box's footprint do not overlap."""
    corners, R_block = _block_corners_world(env, block)
    s = env.object_state(box)
    R_box = _rotation(s["quat_wxyz"])
    dims = env.object_dims(box)
    box_axes = [R_box[:2, 0] / np.linalg.norm(R_box[:2, 0]), R_box[:2, 1] / np.linalg.norm(R_box[:2, 1])]
    box_xy = _box_corners_xy(s["pos_world_m"][:2], np.array(box_axes), np.array([dims["length_m"], dims["width_m"]]) / 2)
    axes = list(box_axes)
    for k in range(3):  # the block's horizontal face normals (a flat block has two)
        a = R_block[:2, k]
        if np.linalg.norm(a) > 0.3:
            axes.append(a / np.linalg.norm(a))
    return _separated_xy(corners[:, :2], box_xy, axes)


def _ball_in_cup_geometry(env: "TabletopEnv") -> dict:
    cup_dims = env.object_dims("cup")
    ball_r = env.object_dims("ball")["radius_m"]
    ball_centre = _local(env, "cup", centre_m(env, "ball"))
    inner_r = cup_dims["radius_m"] - cup_dims["wall_m"]  # at the rim
    inner_base_r = cup_dims["base_radius_m"] - cup_dims["wall_m"]
    return dict(offset_m=float(np.hypot(*ball_centre[:2])), inner_r=inner_r, inner_base_r=inner_base_r, ball_r=ball_r,
                z_local_m=float(ball_centre[2]), cup_h=cup_dims["height_m"])


# ---------------------------------------------------------------- success rules
def _cup_on_plate_geometry(env: "TabletopEnv") -> dict:
    cup = env.object_state("cup")
    plate = env.object_state("plate")
    cup_dims, plate_dims = env.object_dims("cup"), env.object_dims("plate")
    plate_top_z_m = plate["pos_world_m"][2] + plate_dims["thickness_m"]
    offset_xy_m = float(np.linalg.norm(cup["pos_world_m"][:2] - plate["pos_world_m"][:2]))
    return dict(
        tilt_rad=_tilt_rad(cup["quat_wxyz"]),
        offset_xy_m=offset_xy_m,
        max_offset_xy_m=plate_dims["radius_m"] - cup_dims["base_radius_m"],
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


def _cup_over_plate(env: "TabletopEnv") -> bool:
    g = _cup_on_plate_geometry(env)
    return bool(g["offset_xy_m"] < g["max_offset_xy_m"] and g["tilt_rad"] < UPRIGHT_MAX_TILT_RAD
                and g["height_above_plate_m"] > -RESTING_HEIGHT_TOL_M)


def cover_ball_success(env: "TabletopEnv") -> bool:
    """Cup upside down with its rim on the table and the whole ball under it; released, at rest."""
    cup = env.object_state("cup")
    cup_h = env.object_dims("cup")["height_m"]
    g = _ball_in_cup_geometry(env)
    ball_bottom_z = centre_m(env, "ball")[2] - g["ball_r"]
    return bool(
        _upside_down(env, "cup")
        and abs(cup["pos_world_m"][2] - cup_h - env.table_top_z_m) < RESTING_HEIGHT_TOL_M
        and g["offset_m"] < g["inner_r"] - g["ball_r"] + 0.002
        and abs(ball_bottom_z - env.table_top_z_m) < RESTING_HEIGHT_TOL_M
        and _at_rest(env, "cup")
        and not env.robot_touches("cup")
    )


def _cup_over_ball(env: "TabletopEnv") -> bool:
    g = _ball_in_cup_geometry(env)
    return bool(_upside_down(env, "cup") and g["offset_m"] < g["inner_r"])


def ball_in_cup_success(env: "TabletopEnv") -> bool:
    """Ball inside the upright cup (within its inner radius, below its rim); both released."""
    g = _ball_in_cup_geometry(env)
    return bool(
        _upright(env, "cup")
        and g["offset_m"] < g["inner_base_r"]
        and g["z_local_m"] < g["cup_h"]
        and _ball_settled(env)
        and not env.robot_touches("ball")
        and not env.robot_touches("cup")
    )


def _ball_over_cup(env: "TabletopEnv") -> bool:
    g = _ball_in_cup_geometry(env)
    return bool(_upright(env, "cup") and g["offset_m"] < g["inner_r"] - g["ball_r"] / 2 and g["z_local_m"] > 0)


def _ball_in_box_local(env: "TabletopEnv") -> tuple[np.ndarray, dict]:
    return _local(env, "box", centre_m(env, "ball")), env.object_dims("box")


def ball_in_box_success(env: "TabletopEnv") -> bool:
    """Ball centre inside the box's inner walls and below its rim; box upright; ball released."""
    p, d = _ball_in_box_local(env)
    inside = abs(p[0]) < d["length_m"] / 2 - d["wall_m"] and abs(p[1]) < d["width_m"] / 2 - d["wall_m"]
    return bool(inside and 0 < p[2] < d["height_m"] and _upright(env, "box") and _ball_settled(env)
                and not env.robot_touches("ball"))


def _ball_over_box(env: "TabletopEnv") -> bool:
    p, d = _ball_in_box_local(env)
    return bool(abs(p[0]) < d["length_m"] / 2 - d["wall_m"] and abs(p[1]) < d["width_m"] / 2 - d["wall_m"] and p[2] > 0)


def _stacked(env: "TabletopEnv", top: str, bottom: str) -> bool:
    if not (_upright(env, top) and _upright(env, bottom)):
        return False
    d_bottom = env.object_dims(bottom)["size_m"]
    p = _local(env, bottom, env.object_state(top)["pos_world_m"])  # top block's bottom centre
    inside = max(abs(p[0]), abs(p[1])) < d_bottom / 2 - STACK_INSET_M
    return bool(inside and abs(p[2] - d_bottom) < RESTING_HEIGHT_TOL_M)


def stack_blocks_success(env: "TabletopEnv") -> bool:
    """One block resting on the other's top face, its centre inside it; released, both at rest."""
    for top, bottom in (("block_a", "block_b"), ("block_b", "block_a")):
        if (_stacked(env, top, bottom)
                and abs(env.object_state(bottom)["pos_world_m"][2] - env.table_top_z_m) < RESTING_HEIGHT_TOL_M
                and _at_rest(env, top) and _at_rest(env, bottom)
                and not env.robot_touches(top) and not env.robot_touches(bottom)):
            return True
    return False


def _block_over_block(env: "TabletopEnv") -> bool:
    p = _local(env, "block_b", env.object_state("block_a")["pos_world_m"])
    d = env.object_dims("block_b")["size_m"]
    return bool(max(abs(p[0]), abs(p[1])) < d / 2 and p[2] > d - RESTING_HEIGHT_TOL_M)


def block_from_box_success(env: "TabletopEnv") -> bool:
    """The block's footprint clear of the box's, the block resting on the table; released, at rest."""
    size = env.object_dims("block_a")["size_m"]
    on_table = abs(_block_corners_world(env, "block_a")[0][:, 2].min() - env.table_top_z_m) < RESTING_HEIGHT_TOL_M
    return bool(block_outside_box(env) and on_table and abs(centre_m(env, "block_a")[2] - env.table_top_z_m - size / 2)
                < RESTING_HEIGHT_TOL_M and _at_rest(env, "block_a") and not env.robot_touches("block_a"))


def _block_clear_of_box(env: "TabletopEnv") -> bool:
    return block_outside_box(env)


def upright_cup_success(env: "TabletopEnv") -> bool:
    """Cup upright with its bottom on the table; released, at rest."""
    cup = env.object_state("cup")
    return bool(_upright(env, "cup") and abs(cup["pos_world_m"][2] - env.table_top_z_m) < RESTING_HEIGHT_TOL_M
                and _at_rest(env, "cup") and not env.robot_touches("cup"))


def _cup_held_upright(env: "TabletopEnv") -> bool:
    return _upright(env, "cup")


# ---------------------------------------------------------------- progress
def staged_progress(
    env: "TabletopEnv", candidates: tuple[str, ...], goal_configuration: Callable[["TabletopEnv"], bool],
) -> float:
    """Stages: reached 0.2, grasped 0.4, lifted 0.6, held in the goal configuration 0.8, success 1.0.

    "Lifted" is 2 cm above where the object's centre started (``env.initial_centre_z_m``).

    ``candidates`` are the objects that may be manipulated; the best one counts.
    """
    if env.is_success():  # the task's own rule (computed once per state by the env)
        return 1.0
    best = 0.0
    for name in candidates:
        grasped = env.grasped(name) is not None
        lifted = centre_m(env, name)[2] > env.initial_centre_z_m[name] + LIFTED_HEIGHT_M
        if grasped and goal_configuration(env):
            best = max(best, 0.8)
        elif grasped and lifted:
            best = max(best, 0.6)
        elif grasped:
            best = max(best, 0.4)
        else:
            tcp_dist_m = min(np.linalg.norm(p - centre_m(env, name)) for p in env.ee_positions().values())
            if tcp_dist_m < REACHED_DIST_M:
                best = max(best, 0.2)
    return best


def cup_on_plate_progress(env: "TabletopEnv") -> float:
    """Stages: reached 0.2, grasped 0.4, lifted 0.6, above plate 0.8, placed 1.0."""
    return staged_progress(env, ("cup",), _cup_over_plate)


def _progress(candidates, goal):
    def progress(env: "TabletopEnv") -> float:
        return staged_progress(env, candidates, goal)

    progress.__doc__ = f"Staged progress of {candidates} towards {goal.__name__} (see staged_progress)."
    return progress


_FULL_REGION = dict(x_range_m=(-0.12, 0.06), y_range_m=(-0.16, 0.16))

TASKS: dict[str, Task] = {
    "cover_ball": Task(
        key="cover_ball",
        instruction="Cover the Ball with the Cup",
        objects=(CUP, BALL),
        init_regions={"cup": Region(**_FULL_REGION), "ball": Region(**_FULL_REGION)},
        success=cover_ball_success,
        progress=_progress(("cup",), _cup_over_ball),
        manipulated="cup",
        placements={"cup": "upside_down"},
    ),
    "ball_in_box": Task(
        key="ball_in_box",
        instruction="Pick the Ball and Place it in the Box",
        objects=(BALL, BOX),
        init_regions={"ball": Region(**_FULL_REGION), "box": Region(**_FULL_REGION)},
        success=ball_in_box_success,
        progress=_progress(("ball",), _ball_over_box),
        manipulated="ball",
    ),
    "ball_in_cup": Task(
        key="ball_in_cup",
        instruction="Pick the Ball and Place it in the Cup",
        objects=(BALL, CUP),
        init_regions={"ball": Region(**_FULL_REGION), "cup": Region(**_FULL_REGION)},
        success=ball_in_cup_success,
        progress=_progress(("ball",), _ball_over_cup),
        manipulated="ball",
    ),
    "cup_on_plate": Task(
        key="cup_on_plate",
        instruction="Pick the Cup and Place it on the Plate",
        objects=(CUP, PLATE),
        init_regions={"cup": Region(**_FULL_REGION), "plate": Region(**_FULL_REGION)},
        success=cup_on_plate_success,
        progress=cup_on_plate_progress,
        manipulated="cup",
    ),
    "stack_blocks": Task(
        key="stack_blocks",
        instruction="Stack the Two Blocks",
        objects=(BLOCK_A, BLOCK_B),
        init_regions={"block_a": Region(**_FULL_REGION), "block_b": Region(**_FULL_REGION)},
        success=stack_blocks_success,
        progress=_progress(("block_a", "block_b"), _block_over_block),
        manipulated="block_a",
    ),
    "block_from_box": Task(
        key="block_from_box",
        instruction="Take the Block out of the Box",
        objects=(BOX, BLOCK_A),
        init_regions={
            "box": Region(x_range_m=(-0.10, 0.04), y_range_m=(-0.12, 0.12)),
            # In the box's frame: the block sits near the box centre, any yaw.
            "block_a": Region(x_range_m=(-0.015, 0.015), y_range_m=(-0.01, 0.01), relative_to="box"),
        },
        success=block_from_box_success,
        progress=_progress(("block_a",), _block_clear_of_box),
        manipulated="block_a",
    ),
    "upright_cup": Task(
        key="upright_cup",
        instruction="Upright the Fallen Cup",
        objects=(CUP,),
        # Yaw is the direction the opening points; away from the robot, +-80 deg.
        init_regions={"cup": Region(x_range_m=(-0.10, 0.05), y_range_m=(-0.14, 0.14),
                                    yaw_range_rad=(-1.4, 1.4))},
        success=upright_cup_success,
        progress=_progress(("cup",), _cup_held_upright),
        manipulated="cup",
        arm="behind_axis",
        placements={"cup": "on_side"},
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
    """Planar poses {name: (x_m, y_m, yaw_rad)} inside the task regions, footprints apart.

    Objects placed relative to another (a block in a box) are exempt from the clearance
    check against that object.
    """
    size_scales = size_scales or {}
    radii = {
        o.name: footprint_radius_m(o.kind, o.scaled_dims(size_scales.get(o.name, 1.0)), task.placement(o.name))
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
    raise RuntimeError(f"could not sample collision-free poses for {task.key}")
