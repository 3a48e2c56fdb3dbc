"""World construction shared by the sim-side stages (config slice -> environment)."""

from __future__ import annotations

import json
from pathlib import Path

import dataclasses


from r2s_eval.calib import CameraModel, ObjectGeometry
from r2s_eval.sim import TabletopEnv, Task, WorldParams, get_task
from r2s_eval.sim.objects import height_m, support_top_m
from r2s_eval.errors import ConfigError

# Yaw symmetry of each object kind about the vertical axis (0: rotationally symmetric,
# n: looks the same after 2*pi/n). A cup lying on its side has none (1): its opening
# points one way.
YAW_SYMMETRY = {"cup": 0, "plate": 0, "ball": 0, "block": 4, "box": 2}
PLACEMENT_YAW_SYMMETRY = {("cup", "on_side"): 1}


def image_size(world_cfg: dict) -> tuple[int, int]:
    return int(world_cfg["image_height"]), int(world_cfg["image_width"])


def configured_task(key: str, suite_cfg: dict | None) -> Task:
    """The suite's task with the experiment's start regions, if the config sets any."""
    task = get_task(key)
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


def make_env(task: str, world_cfg: dict, params: WorldParams | None = None, cameras=None, suite_cfg: dict | None = None) -> TabletopEnv:
    return TabletopEnv(
        configured_task(task, suite_cfg),
        params=params,
        image_size=image_size(world_cfg),
        cameras=tuple(world_cfg["cameras"] if cameras is None else cameras),
    )


def load_world_params(path: str | Path) -> WorldParams:
    raw = json.loads(Path(path).read_text())["params"]
    tuples = {"light_dir_offset", "table_rgb_offset"}
    return WorldParams(**{k: tuple(v) if k in tuples else v for k, v in raw.items()})


def yaw_symmetry(env: TabletopEnv, name: str) -> int:
    kind = env.task.object(name).kind
    return PLACEMENT_YAW_SYMMETRY.get((kind, env.task.placement(name)), YAW_SYMMETRY[kind])


def object_geometries(env: TabletopEnv) -> list[ObjectGeometry]:
    """Approximate silhouette-centre heights; the render-based refinement removes the rest."""
    geoms = []
    for name in env.task.object_names:
        dims = env.object_dims(name)
        kind = env.task.object(name).kind
        height = dims["radius_m"] * 2 if env.task.placement(name) == "on_side" else height_m(kind, dims)
        base = 0.0
        parent = env.task.init_regions[name].relative_to
        if parent is not None:  # resting inside another object (a block in a box)
            base = support_top_m(env.task.object(parent).kind, env.object_dims(parent))
        geoms.append(ObjectGeometry(name, centroid_height_m=base + 0.5 * height, yaw_symmetry=yaw_symmetry(env, name)))
    return geoms


def camera_model(env: TabletopEnv, camera: str) -> CameraModel:
    return CameraModel(K=env.camera_K(camera), T_world_from_cam=env.camera_T_world_from_cam(camera))
