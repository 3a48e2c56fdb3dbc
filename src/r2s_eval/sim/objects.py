"""Parametric tabletop objects, added to the scene as free bodies.

Every object's body frame sits at the centre of its bottom face, z up, so an
object resting upright on the table has body z = table-top height. Dimensions
are in metres and are multiplied by the object's size scale (twin).
Geoms use the object collision group (contype=1, conaffinity=3).

Kinds
-----
cup    hollow and tapered like a real cup: a bottom disc plus a ring of wall boxes
       leaning outwards (open top), so a ball can go in it or be covered by it upside
       down. The taper also tells the opening from the bottom when it lies on its side.
       dims: radius_m (outer, at the rim), base_radius_m (outer, at the bottom),
       height_m, wall_m, bottom_m, n_walls
plate  flat disc with a low rim of boxes. dims: radius_m, thickness_m, rim_height_m,
       rim_width_m, n_rim
ball   solid sphere (body frame at its lowest point). dims: radius_m
block  solid cube. dims: size_m (edge length)
box    open-top rectangular tray: a floor plus four walls.
       dims: length_m (outer, body x), width_m (outer, body y), height_m, wall_m, floor_m
mesh   a scanned object: its surface from a mesh file (``r2s_eval.sim.meshes``), body frame at
       the centre of its bounding box's bottom face; for collisions the surface's convex hull,
       or convex parts (a CoACD decomposition) that let a concave object (a bowl, a mug) hold
       things. dims (read off the mesh): half_x_m, half_y_m, height_m

Placements
----------
An object starts in one of three placements, each a fixed rotation followed by the
planar yaw. The planar pose ``(x_m, y_m, yaw_rad)`` of an object is the centre of its
footprint on its support and the yaw of its body x axis, except ``on_side`` whose yaw is
the direction of the body z axis (a cup's bottom-to-opening axis), which lies flat:

=============  ============================  =========================================
placement      rotation before the yaw       body origin above the support
=============  ============================  =========================================
upright        none                          0 (bottom face on the support)
upside_down    pi about body x               height_m (bottom face up)
on_side        +pi/2 about body y (less the  base radius, shifted -height_m/2 along the
               taper of a cup: it lies on    axis
               a wall line)
=============  ============================  =========================================
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from r2s_eval.errors import ConfigError
from r2s_eval.sim.rotations import matrix_from_quat, quat_multiply, yaw_quat

if TYPE_CHECKING:
    from r2s_eval.sim.meshes import MeshShape

_OBJECT_CONTACT = dict(contype=1, conaffinity=3, condim=4)


@dataclass(frozen=True)
class ObjectSpec:
    """One task object: a name, a kind (builder), colour, nominal dimensions and mass."""

    name: str
    kind: str
    rgba: tuple[float, float, float, float]
    dims: dict = field(default_factory=dict)
    mass_kg: float = 0.1
    friction: float = 1.0
    # How it is found in a camera frame (r2s_eval.calib.segment): an explicit HSV range
    # {hue_lo, hue_hi, sat_min, val_min} (default: around rgba), the open-vocabulary segmenter's
    # text prompt (default: "a <name>").
    hue: dict | None = None
    prompt: str | None = None
    shape: MeshShape | None = field(default=None, compare=False, repr=False)  # a mesh kind's surface and parts
    symmetry: int | None = None  # yaw symmetry where the world gives it (a mesh's; default: its kind's)

    def scaled_dims(self, size_scale: float) -> dict:
        return {k: (v * size_scale if k.endswith("_m") else v) for k, v in self.dims.items()}


PLACEMENTS = ("upright", "upside_down", "on_side")

# Yaw symmetry of each object kind about the vertical axis (0: rotationally symmetric,
# n: looks the same after 2*pi/n). A cup lying on its side has none (1): its opening
# points one way.
YAW_SYMMETRY = {"cup": 0, "plate": 0, "ball": 0, "block": 4, "box": 2, "mesh": 1}
PLACEMENT_YAW_SYMMETRY = {("cup", "on_side"): 1}


def yaw_symmetry(kind: str, placement: str = "upright") -> int:
    """The object's yaw symmetry in that placement (see ``YAW_SYMMETRY``)."""
    return PLACEMENT_YAW_SYMMETRY.get((kind, placement), YAW_SYMMETRY[kind])


def footprint_radius_m(kind: str, dims: dict, placement: str = "upright") -> float:
    """Radius of a circle around the object's footprint (for collision-free sampling)."""
    if kind == "cup" and placement == "on_side":
        return float(np.hypot(dims["height_m"] / 2, dims["radius_m"]))
    if kind in ("cup", "plate", "ball"):
        return dims["radius_m"]
    if kind == "block":
        return dims["size_m"] / np.sqrt(2)
    if kind == "box":
        return float(np.hypot(dims["length_m"], dims["width_m"]) / 2)
    if kind == "mesh":
        return float(np.hypot(dims["half_x_m"], dims["half_y_m"]))
    raise ConfigError(f"unknown object kind {kind!r}")


def height_m(kind: str, dims: dict) -> float:
    """Height of the upright object above its support."""
    if kind == "ball":
        return 2 * dims["radius_m"]
    if kind == "block":
        return dims["size_m"]
    if kind == "plate":
        return dims["thickness_m"] + dims["rim_height_m"]
    return dims["height_m"]


def support_top_m(kind: str, dims: dict) -> float:
    """Height above the body origin of the surface other objects rest on (inside or on top)."""
    if kind == "box":
        return dims["floor_m"]
    if kind == "plate":
        return dims["thickness_m"]
    if kind == "cup":
        return dims["bottom_m"]
    return height_m(kind, dims)


def taper_rad(kind: str, dims: dict) -> float:
    """Lean of a tapered cup's wall from vertical (0 for everything else)."""
    if kind != "cup":
        return 0.0
    return float(np.arctan2(dims["radius_m"] - dims.get("base_radius_m", dims["radius_m"]),
                            dims["height_m"] - dims["bottom_m"]))


def placement_quat(placement: str, yaw_rad: float, kind: str = "", dims: dict | None = None) -> np.ndarray:
    """Body orientation (wxyz) of an object in ``placement`` with planar yaw ``yaw_rad``.

    A tapered cup on its side lies on a wall line, so its axis rises towards the (wider)
    opening by the taper angle: pass ``kind`` and ``dims`` for it.
    """
    if placement == "upright":
        base = np.array([1.0, 0.0, 0.0, 0.0])
    elif placement == "upside_down":
        base = np.array([0.0, 1.0, 0.0, 0.0])
    elif placement == "on_side":
        pitch = np.pi / 2 - taper_rad(kind, dims or {})
        base = np.array([np.cos(pitch / 2), 0.0, np.sin(pitch / 2), 0.0])
    else:
        raise ConfigError(f"unknown placement {placement!r} (known: {PLACEMENTS})")
    return quat_multiply(yaw_quat(yaw_rad), base)


def placement_origin_m(kind: str, dims: dict, placement: str, x_m: float, y_m: float, yaw_rad: float,
                       support_z_m: float) -> np.ndarray:
    """World position of the body origin for a planar pose resting on the plane ``support_z_m``."""
    if placement == "upright":
        return np.array([x_m, y_m, support_z_m])
    if placement == "upside_down":
        return np.array([x_m, y_m, support_z_m + height_m(kind, dims)])
    if placement == "on_side":
        lean = taper_rad(kind, dims)
        axis = np.array([np.cos(yaw_rad), np.sin(yaw_rad)])
        xy = np.array([x_m, y_m]) - axis * np.cos(lean) * dims["height_m"] / 2
        # The bottom disc's lowest point touches the support.
        return np.array([xy[0], xy[1], support_z_m + dims.get("base_radius_m", dims["radius_m"]) * np.cos(lean)])
    raise ConfigError(f"unknown placement {placement!r} (known: {PLACEMENTS})")


def planar_pose(kind: str, dims: dict, placement: str, pos_world_m, quat_wxyz) -> tuple[float, float, float]:
    """Inverse of ``placement_origin_m``/``placement_quat``: body pose -> (x_m, y_m, yaw_rad)."""
    R = matrix_from_quat(quat_wxyz)
    pos = np.asarray(pos_world_m, float)
    if placement == "on_side":
        axis = R[:, 2]
        centre = pos + axis * dims["height_m"] / 2
        return float(centre[0]), float(centre[1]), float(np.arctan2(axis[1], axis[0]))
    return float(pos[0]), float(pos[1]), float(np.arctan2(R[1, 0], R[0, 0]))


def _add_geom(body, size, pos, rgba, mass_kg, friction, geom_type, quat=None, name=""):
    geom = body.add_geom()
    geom.name = name
    geom.type = geom_type
    geom.size = np.pad(np.asarray(size, float), (0, 3 - len(size)))
    geom.pos = pos
    if quat is not None:
        geom.quat = quat
    geom.rgba = rgba
    geom.mass = mass_kg
    geom.friction = [friction, 0.01, 0.001]
    geom.contype = _OBJECT_CONTACT["contype"]
    geom.conaffinity = _OBJECT_CONTACT["conaffinity"]
    geom.condim = _OBJECT_CONTACT["condim"]
    return geom


def _ring_of_boxes(body, name, radius_m, n, half_radial_m, half_height_m, z_centre_m, rgba, mass_kg, friction,
                   lean_rad=0.0, max_radius_m=None):
    # Tangential half-length slightly above radius*tan(pi/n) so neighbours overlap (no gaps).
    half_tangential_m = 1.08 * (max_radius_m or radius_m) * np.tan(np.pi / n)
    lean = np.array([np.cos(lean_rad / 2), 0.0, np.sin(lean_rad / 2), 0.0])  # about the tangent: tilts outwards
    for i in range(n):
        angle = 2 * np.pi * i / n
        pos = [radius_m * np.cos(angle), radius_m * np.sin(angle), z_centre_m]
        _add_geom(body, [half_radial_m, half_tangential_m, half_height_m], pos, rgba,
                  mass_kg / n, friction, mujoco.mjtGeom.mjGEOM_BOX, quat=quat_multiply(yaw_quat(angle), lean),
                  name=f"{name}_wall{i}")


def add_cup(body, obj: ObjectSpec, dims: dict, rgba) -> None:
    r, h, wall, bottom = dims["radius_m"], dims["height_m"], dims["wall_m"], dims["bottom_m"]
    r_base = dims.get("base_radius_m", r)
    bottom_mass = obj.mass_kg * 0.3
    _add_geom(body, [r_base, bottom / 2], [0, 0, bottom / 2], rgba, bottom_mass, obj.friction,
              mujoco.mjtGeom.mjGEOM_CYLINDER, name=f"{obj.name}_bottom")
    wall_h = h - bottom
    lean_rad = float(np.arctan2(r - r_base, wall_h))
    # Wall boxes are centred half-way up, leaning so their outer faces run base -> rim.
    r_mid = 0.5 * (r + r_base) - wall / 2
    _ring_of_boxes(body, obj.name, r_mid, int(dims["n_walls"]), wall / 2, wall_h / 2 / np.cos(lean_rad),
                   bottom + wall_h / 2, rgba, obj.mass_kg - bottom_mass, obj.friction, lean_rad=lean_rad,
                   max_radius_m=r - wall / 2)


def add_plate(body, obj: ObjectSpec, dims: dict, rgba) -> None:
    r, t = dims["radius_m"], dims["thickness_m"]
    rim_h, rim_w = dims["rim_height_m"], dims["rim_width_m"]
    disc_mass = obj.mass_kg * 0.8
    _add_geom(body, [r, t / 2], [0, 0, t / 2], rgba, disc_mass, obj.friction,
              mujoco.mjtGeom.mjGEOM_CYLINDER, name=f"{obj.name}_disc")
    _ring_of_boxes(body, obj.name, r - rim_w / 2, int(dims["n_rim"]), rim_w / 2, rim_h / 2,
                   t + rim_h / 2, rgba, obj.mass_kg - disc_mass, obj.friction)


def add_ball(body, obj: ObjectSpec, dims: dict, rgba) -> None:
    r = dims["radius_m"]
    geom = _add_geom(body, [r], [0, 0, r], rgba, obj.mass_kg, obj.friction, mujoco.mjtGeom.mjGEOM_SPHERE,
                     name=f"{obj.name}_sphere")
    # Rolling friction: a real ball stops rolling on a table within a few centimetres.
    geom.condim = 6
    geom.friction = [obj.friction, 0.005, 0.0005]


def add_block(body, obj: ObjectSpec, dims: dict, rgba) -> None:
    h = dims["size_m"] / 2
    _add_geom(body, [h, h, h], [0, 0, h], rgba, obj.mass_kg, obj.friction, mujoco.mjtGeom.mjGEOM_BOX,
              name=f"{obj.name}_cube")


def add_box(body, obj: ObjectSpec, dims: dict, rgba) -> None:
    hl, hw, h = dims["length_m"] / 2, dims["width_m"] / 2, dims["height_m"]
    wall, floor = dims["wall_m"], dims["floor_m"]
    floor_mass = obj.mass_kg * 0.4
    _add_geom(body, [hl, hw, floor / 2], [0, 0, floor / 2], rgba, floor_mass, obj.friction,
              mujoco.mjtGeom.mjGEOM_BOX, name=f"{obj.name}_floor")
    wall_half_h = (h - floor) / 2
    z = floor + wall_half_h
    walls = [  # (half sizes, centre): two long walls along x, two short ones along y between them
        ([hl, wall / 2, wall_half_h], [0, hw - wall / 2, z]),
        ([hl, wall / 2, wall_half_h], [0, -hw + wall / 2, z]),
        ([wall / 2, hw - wall, wall_half_h], [hl - wall / 2, 0, z]),
        ([wall / 2, hw - wall, wall_half_h], [-hl + wall / 2, 0, z]),
    ]
    for i, (size, pos) in enumerate(walls):
        _add_geom(body, size, pos, rgba, (obj.mass_kg - floor_mass) / 4, obj.friction, mujoco.mjtGeom.mjGEOM_BOX,
                  name=f"{obj.name}_wall{i}")


BUILDERS = {"cup": add_cup, "plate": add_plate, "ball": add_ball, "block": add_block, "box": add_box}
KINDS = (*BUILDERS, "mesh")  # a mesh is built from its file (r2s_eval.sim.meshes)


def add_object(spec: mujoco.MjSpec, obj: ObjectSpec, size_scale: float) -> None:
    """Append ``obj`` as a free body named ``obj.name`` to the spec's worldbody, in its nominal
    colour (a world's colour offsets are ``r2s_eval.sim.render_params``')."""
    body = spec.worldbody.add_body()
    body.name = obj.name
    body.pos = [0.0, 0.0, 1.0]  # placed properly at reset
    body.add_freejoint().name = f"{obj.name}_free"
    rgba = np.clip(np.asarray(obj.rgba, float), 0, 1)
    if obj.kind == "mesh":
        from r2s_eval.sim.meshes import add_mesh_geoms

        add_mesh_geoms(spec, body, obj, size_scale, rgba, _OBJECT_CONTACT)
        return
    BUILDERS[obj.kind](body, obj, obj.scaled_dims(size_scale), rgba)
