"""How ``WorldParams``' rendering fields (camera poses, lights, colours) change a compiled model.

The one owner of that mapping. A model is compiled with the world's nominal look, its nominal
values are read once (``render_base``), and ``apply_render_params`` writes a world's values over
them: the build of every world does that once, and the calibration's fits do it for each pose or
colour hypothesis without compiling again.

- Camera offsets are a mount error in the camera's own (MuJoCo) frame: position ``pos + R dpos``,
  orientation ``R * rot(drot)``, relative to the camera's parent body (a wrist camera's error
  moves with its arm).
- Light: every scene light's diffuse colour times ``light_intensity_scale`` (clipped to [0, 1]),
  its direction plus ``light_dir_offset``, normalised. The headlight is left as it is.
- Colours: the table geom's and each task object's RGB plus their offsets (clipped); an object's
  geoms are those drawn in its own colour (a textured mesh keeps its texture).
- Shadows (``shadows``): the key light (the scene light of the largest diffuse colour) casts them,
  through a shadow map of ``SHADOW_MAP_PX``; off, the model is left as its file states it. The map
  size is read when a renderer is made, so it is written at the build, before any renderer.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import mujoco
import numpy as np

from r2s_eval.errors import ConfigError
from r2s_eval.sim.params import WorldParams
from r2s_eval.sim.rotations import matrix_from_quat, quat_multiply, rotvec_quat


@dataclass(frozen=True)
class RenderBase:
    """A compiled model's nominal rendering values, read before any world's parameters."""

    cam_pos: np.ndarray  # (ncam, 3), in each camera's parent body frame
    cam_quat: np.ndarray  # (ncam, 4)
    light_diffuse: np.ndarray  # (nlight, 3)
    light_dir: np.ndarray  # (nlight, 3), unit
    table_geom: int
    table_rgba: np.ndarray
    object_geoms: dict[str, np.ndarray]  # geom ids drawn in the object's colour
    object_rgba: dict[str, np.ndarray]


def render_base(model: mujoco.MjModel, table_geom: str, objects: Iterable) -> RenderBase:
    """``model``'s nominal rendering values; ``objects``: the task's ``ObjectSpec``s (their bodies
    are named after them)."""
    table = model.geom(table_geom).id
    geoms, colours = {}, {}
    for obj in objects:
        body = model.body(obj.name).id
        rgba = np.clip(np.asarray(obj.rgba, float), 0, 1)
        in_body = np.flatnonzero(np.isin(model.geom_bodyid, _subtree(model, body)))
        geoms[obj.name] = in_body[np.all(np.isclose(model.geom_rgba[in_body], rgba, atol=1e-6), axis=1)]
        colours[obj.name] = rgba
    return RenderBase(cam_pos=model.cam_pos.copy(), cam_quat=model.cam_quat.copy(),
                      light_diffuse=model.light_diffuse.copy(), light_dir=model.light_dir.copy(),
                      table_geom=table, table_rgba=model.geom_rgba[table].copy(),
                      object_geoms=geoms, object_rgba=colours)


def _subtree(model: mujoco.MjModel, root: int) -> list[int]:
    bodies = [root]
    for b in range(root + 1, model.nbody):
        if model.body_parentid[b] in bodies:
            bodies.append(b)
    return bodies


def mounted_pose(pos_m, quat_wxyz, dpos_m, drot_rad) -> tuple[np.ndarray, np.ndarray]:
    """(pos, quat) in the parent body's frame of a camera at ``pos_m``/``quat_wxyz`` moved by a
    mount error ``dpos_m``, ``drot_rad`` (in its own frame)."""
    quat = np.asarray(quat_wxyz, float)
    pos = np.asarray(pos_m, float) + matrix_from_quat(quat) @ np.asarray(dpos_m, float)
    return pos, quat_multiply(quat, rotvec_quat(drot_rad))


def apply_cameras(model: mujoco.MjModel, base: RenderBase, params: WorldParams) -> None:
    for cam_id in range(model.ncam):
        name = model.camera(cam_id).name
        model.cam_pos[cam_id], model.cam_quat[cam_id] = mounted_pose(
            base.cam_pos[cam_id], base.cam_quat[cam_id], params.camera_pos_offset_m.get(name, (0.0, 0.0, 0.0)),
            params.camera_rot_offset_rad.get(name, (0.0, 0.0, 0.0)))


def apply_appearance(model: mujoco.MjModel, base: RenderBase, params: WorldParams) -> None:
    model.light_diffuse[:] = np.clip(base.light_diffuse * params.light_intensity_scale, 0, 1)
    directions = base.light_dir + np.asarray(params.light_dir_offset, float)
    model.light_dir[:] = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    model.geom_rgba[base.table_geom, :3] = np.clip(base.table_rgba[:3] + np.asarray(params.table_rgb_offset), 0, 1)
    for name, geoms in base.object_geoms.items():
        offset = np.asarray(params.object_rgb_offset.get(name, (0.0, 0.0, 0.0)), float)
        model.geom_rgba[geoms, :3] = np.clip(base.object_rgba[name][:3] + offset, 0, 1)


# The shadow map: 512 px over half the model's extent (the bundled world's +-2.8 m room: 11 mm a
# texel, an arm's shadow edge within a pixel or two of a 128 px head camera) at about half the
# render time of a 1024 px map (3 against 6 ms a 128 px frame on two cores; 0.8 ms without).
SHADOW_MAP_PX = 512
SHADOW_CLIP_REL = 0.5


def key_light(light_diffuse: np.ndarray) -> int | None:
    """The index of the key light (the largest diffuse colour) of ``light_diffuse`` (nlight, 3);
    None without a scene light (the headlight casts no shadow)."""
    diffuse = np.asarray(light_diffuse, float).reshape(-1, 3)
    return int(np.argmax(diffuse.sum(axis=1))) if len(diffuse) else None


def apply_shadows(model: mujoco.MjModel, params: WorldParams) -> None:
    """The key light casts shadows where ``params.shadows``; raises ``ConfigError`` when the model
    has no scene light to cast them."""
    if not params.shadows:
        return
    key = key_light(model.light_diffuse)
    if key is None:
        raise ConfigError("shadows: the world's model has no scene light to cast them (the headlight casts none); "
                          "add a <light> to the world file or set calib.appearance.shadows: false")
    model.light_castshadow[key] = 1
    model.vis.quality.shadowsize = max(int(model.vis.quality.shadowsize), SHADOW_MAP_PX)
    model.vis.map.shadowclip = SHADOW_CLIP_REL


def apply_render_params(model: mujoco.MjModel, base: RenderBase, params: WorldParams) -> None:
    """Write ``params``' cameras, lights, colours and shadows over ``base`` (the model's nominal
    look). Camera poses take effect at the next kinematics pass (``mj_kinematics``/``mj_forward``)."""
    apply_cameras(model, base, params)
    apply_appearance(model, base, params)
    apply_shadows(model, params)
