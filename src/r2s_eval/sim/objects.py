"""Parametric tabletop objects, added to the scene as free bodies.

Every object's body frame sits at the centre of its bottom face, z up, so an
object resting upright on the table has body z = table-top height. Dimensions
are in metres and are multiplied by the object's size scale (twin).
Geoms use the object collision group (contype=1, conaffinity=3).

Kinds
-----
cup    hollow: a bottom disc plus a ring of wall boxes (open top), so a ball
       can go in it or be covered by it upside down.
       dims: radius_m (outer), height_m, wall_m, bottom_m, n_walls
plate  flat disc with a low rim of boxes. dims: radius_m, thickness_m, rim_height_m,
       rim_width_m, n_rim
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

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

    def scaled_dims(self, size_scale: float) -> dict:
        return {k: (v * size_scale if k.endswith("_m") else v) for k, v in self.dims.items()}


def footprint_radius_m(kind: str, dims: dict) -> float:
    """Radius of the object's footprint on the table (for collision-free sampling)."""
    if kind in ("cup", "plate"):
        return dims["radius_m"]
    raise KeyError(f"unknown object kind {kind!r}")


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


def _yaw_quat(yaw_rad: float) -> np.ndarray:
    return np.array([np.cos(yaw_rad / 2), 0.0, 0.0, np.sin(yaw_rad / 2)])


def _ring_of_boxes(body, name, radius_m, n, half_radial_m, half_height_m, z_centre_m, rgba, mass_kg, friction):
    # Tangential half-length slightly above radius*tan(pi/n) so neighbours overlap (no gaps).
    half_tangential_m = 1.08 * radius_m * np.tan(np.pi / n)
    for i in range(n):
        angle = 2 * np.pi * i / n
        pos = [radius_m * np.cos(angle), radius_m * np.sin(angle), z_centre_m]
        _add_geom(body, [half_radial_m, half_tangential_m, half_height_m], pos, rgba,
                  mass_kg / n, friction, mujoco.mjtGeom.mjGEOM_BOX, quat=_yaw_quat(angle),
                  name=f"{name}_wall{i}")


def add_cup(body, obj: ObjectSpec, dims: dict, rgba) -> None:
    r, h, wall, bottom = dims["radius_m"], dims["height_m"], dims["wall_m"], dims["bottom_m"]
    bottom_mass = obj.mass_kg * 0.3
    _add_geom(body, [r, bottom / 2], [0, 0, bottom / 2], rgba, bottom_mass, obj.friction,
              mujoco.mjtGeom.mjGEOM_CYLINDER, name=f"{obj.name}_bottom")
    wall_half_h = (h - bottom) / 2
    _ring_of_boxes(body, obj.name, r - wall / 2, int(dims["n_walls"]), wall / 2, wall_half_h,
                   bottom + wall_half_h, rgba, obj.mass_kg - bottom_mass, obj.friction)


def add_plate(body, obj: ObjectSpec, dims: dict, rgba) -> None:
    r, t = dims["radius_m"], dims["thickness_m"]
    rim_h, rim_w = dims["rim_height_m"], dims["rim_width_m"]
    disc_mass = obj.mass_kg * 0.8
    _add_geom(body, [r, t / 2], [0, 0, t / 2], rgba, disc_mass, obj.friction,
              mujoco.mjtGeom.mjGEOM_CYLINDER, name=f"{obj.name}_disc")
    _ring_of_boxes(body, obj.name, r - rim_w / 2, int(dims["n_rim"]), rim_w / 2, rim_h / 2,
                   t + rim_h / 2, rgba, obj.mass_kg - disc_mass, obj.friction)


BUILDERS = {"cup": add_cup, "plate": add_plate}


def add_object(spec: mujoco.MjSpec, obj: ObjectSpec, size_scale: float, rgb_offset) -> None:
    """Append ``obj`` as a free body named ``obj.name`` to the spec's worldbody."""
    body = spec.worldbody.add_body()
    body.name = obj.name
    body.pos = [0.0, 0.0, 1.0]  # placed properly at reset
    body.add_freejoint().name = f"{obj.name}_free"
    rgba = np.clip(np.r_[np.asarray(obj.rgba[:3]) + np.asarray(rgb_offset), obj.rgba[3]], 0, 1)
    BUILDERS[obj.kind](body, obj, obj.scaled_dims(size_scale), rgba)
