"""Parametric tabletop objects, added to the scene as free bodies.

Every object's body frame sits at the centre of its bottom face, z up, so an
object resting upright on the table has body z = table-top height. Dimensions
are in metres and are multiplied by the object's size scale (twin).
Geoms use the object collision group (contype=1, conaffinity=3).

Kinds
-----
Each kind is one class (``ObjectKind``; ``KINDS`` maps a world's ``kind`` name to it) that owns
everything the simulator, the task predicates, the scripted operator and the judges ask of its
objects: its dimensions' keys, its geometry (height, footprint, the surface others rest on, taper,
yaw symmetry per placement), its MuJoCo geoms, what the predicates measure on it (a top face, a
container's interior, a cover, a footprint), how the scripted operator grips it, and how it reads
in a frame (what rests on it as a stack, for the video judge). ``ObjectSpec.kind_object`` is an object's kind.

cup    hollow and tapered like a real cup: a bottom disc plus a ring of wall boxes
       leaning outwards (open top), so a ball can go in it or be covered by it upside
       down. The taper also tells the opening from the bottom when it lies on its side.
       dims: radius_m (outer, at the rim), base_radius_m (outer, at the bottom),
       height_m, wall_m, bottom_m, n_walls; a mug also states its handle (``HANDLE_DIMS``,
       all four or none): a C of three capsules on its wall along the body's -x, massless
plate  flat disc with a low rim of boxes. dims: radius_m, thickness_m, rim_height_m,
       rim_width_m, n_rim
ball   solid sphere (body frame at its lowest point). dims: radius_m
block  solid cube. dims: size_m (edge length); edge_radius_m (optional): its edges and
       corners rounded with this radius (three boxes and twelve capsules)
box    open-top rectangular tray: a floor plus four walls.
       dims: length_m (outer, body x), width_m (outer, body y), height_m, wall_m, floor_m
mesh   a scanned object: its surface from a mesh file (``r2s_eval.sim.meshes``), body frame at
       the centre of its bounding box's bottom face; for collisions the surface's convex hull,
       or convex parts (a CoACD decomposition) that let a concave object (a bowl, a mug) hold
       things. dims (read off the mesh): half_x_m, half_y_m, height_m

Placements
----------
An object starts in one of three placements (those its kind allows: a cup all three, a mesh
upright as its file stands, the others upright or upside down), each a fixed rotation followed
by the planar yaw. The planar pose ``(x_m, y_m, yaw_rad)`` of an object is the centre of its
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
from typing import ClassVar, Protocol

import mujoco
import numpy as np

from r2s_eval.errors import ConfigError
from r2s_eval.sim.meshes import MeshShape, add_mesh_geoms
from r2s_eval.sim.rotations import matrix_from_quat, quat_multiply, yaw_quat

_OBJECT_CONTACT = dict(contype=1, conaffinity=3, condim=4)


class Scene(Protocol):
    """What predicates read of a world's current state (``TabletopEnv`` offers it)."""

    table_top_z_m: float
    initial_centre_z_m: dict[str, float]

    def object_state(self, name: str) -> dict: ...  # pos_world_m, quat_wxyz, linvel_world_m_s, angvel_world_rad_s
    def object_dims(self, name: str) -> dict: ...
    def object_kind(self, name: str) -> str: ...
    def robot_touches(self, name: str) -> bool: ...
    def grasped(self, name: str) -> str | None: ...
    def ee_positions(self) -> dict[str, np.ndarray]: ...
    def is_success(self) -> bool: ...


@dataclass(frozen=True)
class ObjectSpec:
    """One task object: a name, a kind (``KINDS``), colour, nominal dimensions and mass."""

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

    @property
    def kind_object(self) -> ObjectKind:
        """Its kind: geometry, building, predicates' measures, grasp (``KINDS``)."""
        return KINDS[self.kind]

    def scaled_dims(self, size_scale: float) -> dict:
        return {k: (v * size_scale if k.endswith("_m") else v) for k, v in self.dims.items()}


PLACEMENTS = ("upright", "upside_down", "on_side")


# ---------------------------------------------------------------- an object's pose in a scene
def tilt_rad(quat_wxyz: np.ndarray) -> float:
    """Angle between the body z axis and world up."""
    w, x, y, z = quat_wxyz
    cos_tilt = 1.0 - 2.0 * (x * x + y * y)  # world z of the body's z axis
    return float(np.arccos(np.clip(cos_tilt, -1.0, 1.0)))


def rotation(quat_wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(quat_wxyz, float) / np.linalg.norm(quat_wxyz)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def local(scene: Scene, frame_obj: str, point_world_m: np.ndarray) -> np.ndarray:
    """``point_world_m`` in the body frame of ``frame_obj``."""
    s = scene.object_state(frame_obj)
    return rotation(s["quat_wxyz"]).T @ (np.asarray(point_world_m) - s["pos_world_m"])


def kind_in(scene: Scene, name: str) -> ObjectKind:
    """The kind of the scene's object ``name``."""
    return KINDS[scene.object_kind(name)]


def centre_m(scene: Scene, name: str) -> np.ndarray:
    """World position of the object's geometric centre (half its height along body z)."""
    s = scene.object_state(name)
    half = kind_in(scene, name).height_m(scene.object_dims(name)) / 2
    return s["pos_world_m"] + rotation(s["quat_wxyz"])[:, 2] * half


def placement_quat(placement: str, yaw_rad: float, taper_rad: float = 0.0) -> np.ndarray:
    """Body orientation (wxyz) of an object in ``placement`` with planar yaw ``yaw_rad``; a tapered
    object on its side lies on a wall line, its axis rising by ``taper_rad`` (a cup's,
    ``Cup.orientation``)."""
    if placement == "upright":
        base = np.array([1.0, 0.0, 0.0, 0.0])
    elif placement == "upside_down":
        base = np.array([0.0, 1.0, 0.0, 0.0])
    elif placement == "on_side":
        pitch = np.pi / 2 - taper_rad
        base = np.array([np.cos(pitch / 2), 0.0, np.sin(pitch / 2), 0.0])
    else:
        raise ConfigError(f"unknown placement {placement!r} (known: {PLACEMENTS})")
    return quat_multiply(yaw_quat(yaw_rad), base)


# ---------------------------------------------------------------- geoms
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


# ---------------------------------------------------------------- kinds
@dataclass(frozen=True)
class Grasp:
    """How the scripted operator takes an object from above: ``half_width_m`` None closes fully
    open jaws round it with the tcp ``tcp_offset_m`` above the operator's grasp height over the
    table (a cup's wall near the table); otherwise the jaws are pre-shaped just wider than
    ``half_width_m`` and close with the tcp ``tcp_offset_m`` above the object's centre."""

    tcp_offset_m: float
    half_width_m: float | None = None


class ObjectKind:
    """One kind of object (``KINDS``); see the module docstring. The predicate measures a kind
    does not define (``defines``) raise a ``ConfigError`` naming the predicate and the kind."""

    name: ClassVar[str]
    dims_keys: ClassVar[tuple[str, ...]]  # the dimensions a world gives (metres, counts)
    optional_dims_keys: ClassVar[tuple[str, ...]] = ()
    placements: ClassVar[tuple[str, ...]] = ("upright", "upside_down")
    placement_note: ClassVar[str] = ""  # why it starts only in those, where that is not obvious
    upright_yaw_symmetry: ClassVar[int]  # 0: rotationally symmetric, n: the same after 2 pi / n
    table_faces: ClassVar[tuple[str, ...]] = ("bottom", "top")  # what on_table's `face` may name
    pickable: ClassVar[bool] = False  # the scripted operator picks it (``grasp``)
    # An object resting on it reads as a stack in a frame (the video judge's "stack": the two
    # are alike in size, so their centroids lie further apart and either may move).
    stacked_on: ClassVar[bool] = False

    # ------------------------------------------------------------ geometry
    def height_m(self, dims: dict) -> float:
        """Height of the upright object above its support."""
        return dims["height_m"]

    def placed_height_m(self, dims: dict, placement: str) -> float:
        """Height of the object above its support in ``placement``."""
        return self.height_m(dims)

    def footprint_radius_m(self, dims: dict, placement: str = "upright") -> float:
        """Radius of a circle around the object's footprint (for collision-free sampling)."""
        raise NotImplementedError

    def support_top_m(self, dims: dict) -> float:
        """Height above the body origin of the surface other objects rest on (inside or on top)."""
        return self.height_m(dims)

    def taper_rad(self, dims: dict) -> float:
        """Lean of a tapered wall from vertical."""
        return 0.0

    def yaw_symmetry(self, placement: str = "upright", dims: dict | None = None) -> int:
        """The object's yaw symmetry in ``placement`` (0: round, n: the same after 2 pi / n), for
        an object of ``dims`` where its shape depends on them."""
        return self.upright_yaw_symmetry

    def dims_problems(self, dims: dict) -> list[tuple[str, str]]:
        """(key, problem) for dimensions that cannot go together (the keys' presence is checked
        by the world's reader)."""
        return []

    # ------------------------------------------------------------ placements
    def _check_placement(self, placement: str) -> None:
        if placement not in PLACEMENTS:
            raise ConfigError(f"unknown placement {placement!r} (known: {PLACEMENTS})")
        if placement not in self.placements:
            raise ConfigError(f"a {self.name} starts {' or '.join(self.placements)}{self.placement_note}, "
                              f"not {placement}")

    def orientation(self, placement: str, yaw_rad: float, dims: dict) -> np.ndarray:
        """Body orientation (wxyz) in ``placement`` with planar yaw ``yaw_rad``."""
        self._check_placement(placement)
        return placement_quat(placement, yaw_rad, self.taper_rad(dims))

    def origin_m(self, dims: dict, placement: str, x_m: float, y_m: float, yaw_rad: float,
                 support_z_m: float) -> np.ndarray:
        """World position of the body origin for a planar pose resting on the plane ``support_z_m``."""
        self._check_placement(placement)
        if placement == "upside_down":
            return np.array([x_m, y_m, support_z_m + self.height_m(dims)])
        return np.array([x_m, y_m, support_z_m])

    def planar_pose(self, dims: dict, placement: str, pos_world_m, quat_wxyz) -> tuple[float, float, float]:
        """Inverse of ``origin_m``/``orientation``: body pose -> (x_m, y_m, yaw_rad)."""
        R = matrix_from_quat(quat_wxyz)
        pos = np.asarray(pos_world_m, float)
        return float(pos[0]), float(pos[1]), float(np.arctan2(R[1, 0], R[0, 0]))

    # ------------------------------------------------------------ building
    def add_geoms(self, spec: mujoco.MjSpec, body, obj: ObjectSpec, size_scale: float, rgba) -> None:
        """Its geoms on ``body``, dimensions scaled by ``size_scale``."""
        raise NotImplementedError

    # ------------------------------------------------------------ the scripted operator
    def grasp(self, dims: dict, placement: str) -> Grasp | None:
        """How the scripted operator takes it from above (None: it does not pick it)."""
        return None

    def grasp_yaws(self, object_yaw_rad: float, natural_yaw_rad: float) -> tuple[float, float]:
        """The top-down hand's candidate yaws over it: (the yaw they are counted from, their step).
        A round object: the arm's natural yaw, in 22.5 deg steps."""
        return natural_yaw_rad, np.pi / 8

    # ------------------------------------------------------------ what predicates measure
    def defines(self, measure: str) -> bool:
        """Whether this kind defines the predicate measure ``measure`` (a method name)."""
        return getattr(type(self), measure) is not getattr(ObjectKind, measure)

    def _undefined(self, predicate: str, lacks: str, name: str, measure: str) -> ConfigError:
        having = [k for k, kind in KINDS.items() if kind.defines(measure)]
        return ConfigError(f"{predicate}: a {self.name} ({name}) {lacks}; {predicate} is defined for {having}")

    def rests_on_table(self, scene: Scene, name: str, face: str, tolerance_m: float) -> bool:
        """Its ``face`` (bottom, top) rests on the table."""
        table = scene.table_top_z_m
        pos = scene.object_state(name)["pos_world_m"]
        if face == "bottom":
            return bool(abs(pos[2] - table) < tolerance_m)
        if face == "top":
            return bool(abs(pos[2] - self.height_m(scene.object_dims(name)) - table) < tolerance_m)
        raise ConfigError(f"on_table: face {face!r} is not defined for a {self.name} ({name}); "
                          f"its faces are {list(self.table_faces)}")

    def holds_on_top(self, scene: Scene, object: str, support: str, tolerance_m: float, inset_m: float) -> bool:
        """``object``'s bottom face rests on this support's top face, inside its edge."""
        raise self._undefined("on_top_of", "has no top face", support, "holds_on_top")

    def holds_inside(self, scene: Scene, object: str, container: str) -> bool:
        """``object``'s centre is inside this container."""
        raise self._undefined("inside", "is no container", container, "holds_inside")

    def covers(self, scene: Scene, object: str, cover: str, margin_m: float) -> bool:
        """``object`` is under this cover."""
        raise self._undefined("covered_by", "cannot cover", cover, "covers")

    def has_above(self, scene: Scene, object: str, target: str, tolerance_m: float) -> bool:
        """``object`` is above this target, within its opening or face."""
        raise self._undefined("over", "has no opening or face to be over", target, "has_above")

    def over_problem(self, object_kind: str) -> str | None:
        """Why ``over`` cannot judge an object of ``object_kind`` above this kind, if it cannot."""
        return None

    def footprint(self, scene: Scene, name: str) -> tuple[np.ndarray, list[np.ndarray]]:
        """Its footprint's corners on the table and its edge normals."""
        raise self._undefined("apart", "has no footprint", name, "footprint")


# A mug's handle, as a lab measures its mug (metres): the heights of its lower and upper arms'
# centre lines above the cup's bottom, how far its outside stands off the cup's widest wall, and
# the thickness of its tube. It points along the body's -x (``HANDLE_AXIS``): the on_side placement
# turns +x down, so a lying mug rests on its wall with the handle up (along +-y it would lie in the
# jaws' way).
HANDLE_DIMS = ("handle_low_m", "handle_high_m", "handle_out_m", "handle_thickness_m")
HANDLE_AXIS = np.array([-1.0, 0.0])


def has_handle(dims: dict) -> bool:
    """Whether a cup of ``dims`` is a mug (its world states a handle)."""
    return all(k in dims for k in HANDLE_DIMS)


def add_cup_handle(body, name: str, dims: dict, rgba, friction: float) -> None:
    """A mug's C-shaped handle on the wall of cup ``name`` of (scaled) ``dims``: two arms out from
    the wall and a grip joining them, capsules without mass (the cup weighs what its world says)."""
    r, h = dims["radius_m"], dims["height_m"]
    r_base = dims.get("base_radius_m", r)
    tube = dims["handle_thickness_m"] / 2
    z_lo, z_hi = dims["handle_low_m"], dims["handle_high_m"]
    wall_at = {z: r_base + (r - r_base) * z / h for z in (z_lo, z_hi)}  # the outer wall's radius at a height
    grip = max(wall_at.values()) + dims["handle_out_m"] - tube  # the grip's centre line off the axis
    axis = np.r_[HANDLE_AXIS, 0.0]
    points = {"lower": (axis * (wall_at[z_lo] - tube) + [0, 0, z_lo], axis * grip + [0, 0, z_lo]),
              "upper": (axis * (wall_at[z_hi] - tube) + [0, 0, z_hi], axis * grip + [0, 0, z_hi]),
              "grip": (axis * grip + [0, 0, z_lo], axis * grip + [0, 0, z_hi])}
    for part, (start, end) in points.items():
        geom = _add_geom(body, [tube], [0, 0, 0], rgba, 0.0, friction, mujoco.mjtGeom.mjGEOM_CAPSULE,
                         name=f"{name}_handle_{part}")
        geom.fromto = [*start, *end]


class Cup(ObjectKind):
    """Hollow, tapered, open at the top (a ball goes in it, or it covers one upside down); a mug
    where its dims state a handle (``HANDLE_DIMS``)."""

    name = "cup"
    dims_keys = ("radius_m", "height_m", "wall_m", "bottom_m", "n_walls")
    optional_dims_keys = ("base_radius_m", *HANDLE_DIMS)
    placements = PLACEMENTS
    upright_yaw_symmetry = 0
    pickable = True

    def placed_height_m(self, dims: dict, placement: str) -> float:
        return dims["radius_m"] * 2 if placement == "on_side" else self.height_m(dims)

    def footprint_radius_m(self, dims: dict, placement: str = "upright") -> float:
        # The cup's body: a mug's thin handle may reach over a neighbour's clearance, as a real mug's does
        # (counted in, the bundled tasks' regions would leave no room for a mug beside the plate).
        if placement == "on_side":
            return float(np.hypot(dims["height_m"] / 2, dims["radius_m"]))
        return dims["radius_m"]

    def support_top_m(self, dims: dict) -> float:
        return dims["bottom_m"]

    def taper_rad(self, dims: dict) -> float:
        return float(np.arctan2(dims["radius_m"] - dims.get("base_radius_m", dims["radius_m"]),
                                dims["height_m"] - dims["bottom_m"]))

    def yaw_symmetry(self, placement: str = "upright", dims: dict | None = None) -> int:
        if placement == "on_side" or (dims is not None and has_handle(dims)):
            return 1  # lying, its opening points one way; a handle points one way
        return self.upright_yaw_symmetry

    def dims_problems(self, dims):
        stated = [k for k in HANDLE_DIMS if k in dims]
        if not stated:
            return []
        if len(stated) < len(HANDLE_DIMS):
            return [(f"dims.{k}", f"is missing: a mug's handle takes all of {list(HANDLE_DIMS)}")
                    for k in HANDLE_DIMS if k not in dims]
        problems = [(f"dims.{k}", f"must be above 0, got {dims[k]}") for k in HANDLE_DIMS if not dims[k] > 0]
        if not dims["handle_low_m"] < dims["handle_high_m"] <= dims["height_m"]:
            problems.append(("dims.handle_high_m", f"must lie above handle_low_m ({dims['handle_low_m']}) and no "
                             f"higher than the cup's height_m ({dims['height_m']}), got {dims['handle_high_m']}"))
        if not dims["handle_out_m"] >= dims["handle_thickness_m"]:
            problems.append(("dims.handle_out_m", f"must be at least handle_thickness_m "
                             f"({dims['handle_thickness_m']}): it is measured to the handle's outside, got "
                             f"{dims['handle_out_m']}"))
        return problems

    def origin_m(self, dims, placement, x_m, y_m, yaw_rad, support_z_m):
        if placement != "on_side":
            return super().origin_m(dims, placement, x_m, y_m, yaw_rad, support_z_m)
        lean = self.taper_rad(dims)
        axis = np.array([np.cos(yaw_rad), np.sin(yaw_rad)])
        xy = np.array([x_m, y_m]) - axis * np.cos(lean) * dims["height_m"] / 2
        # The bottom disc's lowest point touches the support.
        return np.array([xy[0], xy[1], support_z_m + dims.get("base_radius_m", dims["radius_m"]) * np.cos(lean)])

    def planar_pose(self, dims, placement, pos_world_m, quat_wxyz):
        if placement != "on_side":
            return super().planar_pose(dims, placement, pos_world_m, quat_wxyz)
        axis = matrix_from_quat(quat_wxyz)[:, 2]
        centre = np.asarray(pos_world_m, float) + axis * dims["height_m"] / 2
        return float(centre[0]), float(centre[1]), float(np.arctan2(axis[1], axis[0]))

    def add_geoms(self, spec, body, obj, size_scale, rgba):
        dims = obj.scaled_dims(size_scale)
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
        if has_handle(dims):
            add_cup_handle(body, obj.name, dims, rgba, obj.friction)

    def grasp(self, dims, placement):
        # Round its wall near the table; upside down a little lower, round its rim.
        return Grasp(tcp_offset_m=-0.005 if placement == "upside_down" else 0.0)

    @staticmethod
    def interior(scene: Scene, name: str, cup: str) -> dict:
        """Where object ``name``'s centre lies in the cup's frame, and the cup's inner sizes."""
        dims = scene.object_dims(cup)
        p = local(scene, cup, centre_m(scene, name))
        return dict(offset_m=float(np.hypot(*p[:2])), z_m=float(p[2]), inner_r=dims["radius_m"] - dims["wall_m"],
                    inner_base_r=dims["base_radius_m"] - dims["wall_m"], height_m=dims["height_m"])

    def holds_inside(self, scene, object, container):
        g = self.interior(scene, object, container)
        return bool(g["offset_m"] < g["inner_base_r"] and g["z_m"] < g["height_m"])

    def covers(self, scene, object, cover, margin_m):
        g = self.interior(scene, object, cover)
        return bool(g["offset_m"] < g["inner_r"] - scene.object_dims(object)["radius_m"] + margin_m)

    def has_above(self, scene, object, target, tolerance_m):  # above the opening of an upright cup
        g = self.interior(scene, object, target)
        return bool(g["offset_m"] < g["inner_r"] - scene.object_dims(object)["radius_m"] / 2 and g["z_m"] > 0)


def _on_plate(scene: Scene, name: str, plate: str) -> tuple[float, float, float]:
    """(offset from the plate's centre, the largest offset inside its rim, height above its top)."""
    obj, s = scene.object_state(name), scene.object_state(plate)
    dims, plate_dims = scene.object_dims(name), scene.object_dims(plate)
    offset = float(np.linalg.norm(obj["pos_world_m"][:2] - s["pos_world_m"][:2]))
    bottom_r = dims.get("base_radius_m", dims.get("radius_m", 0.0))
    above = float(obj["pos_world_m"][2] - (s["pos_world_m"][2] + plate_dims["thickness_m"]))
    return offset, plate_dims["radius_m"] - bottom_r, above


class Plate(ObjectKind):
    """A flat disc with a low rim: things are put on it."""

    name = "plate"
    dims_keys = ("radius_m", "thickness_m", "rim_height_m", "rim_width_m", "n_rim")
    upright_yaw_symmetry = 0

    def height_m(self, dims):
        return dims["thickness_m"] + dims["rim_height_m"]

    def footprint_radius_m(self, dims, placement="upright"):
        return dims["radius_m"]

    def support_top_m(self, dims):
        return dims["thickness_m"]

    def add_geoms(self, spec, body, obj, size_scale, rgba):
        dims = obj.scaled_dims(size_scale)
        r, t = dims["radius_m"], dims["thickness_m"]
        rim_h, rim_w = dims["rim_height_m"], dims["rim_width_m"]
        disc_mass = obj.mass_kg * 0.8
        _add_geom(body, [r, t / 2], [0, 0, t / 2], rgba, disc_mass, obj.friction,
                  mujoco.mjtGeom.mjGEOM_CYLINDER, name=f"{obj.name}_disc")
        _ring_of_boxes(body, obj.name, r - rim_w / 2, int(dims["n_rim"]), rim_w / 2, rim_h / 2,
                       t + rim_h / 2, rgba, obj.mass_kg - disc_mass, obj.friction)

    def holds_on_top(self, scene, object, support, tolerance_m, inset_m):  # inside its rim
        offset, max_offset, above = _on_plate(scene, object, support)
        return bool(offset < max_offset and abs(above) < tolerance_m)

    def has_above(self, scene, object, target, tolerance_m):
        offset, max_offset, above = _on_plate(scene, object, target)
        return bool(offset < max_offset and above > -tolerance_m)


class Ball(ObjectKind):
    """A solid sphere (body frame at its lowest point)."""

    name = "ball"
    dims_keys = ("radius_m",)
    upright_yaw_symmetry = 0
    table_faces = ("bottom", "top", "any")  # it has no faces: its lowest point rests, whichever is named
    pickable = True

    def height_m(self, dims):
        return 2 * dims["radius_m"]

    def footprint_radius_m(self, dims, placement="upright"):
        return dims["radius_m"]

    def add_geoms(self, spec, body, obj, size_scale, rgba):
        r = obj.scaled_dims(size_scale)["radius_m"]
        geom = _add_geom(body, [r], [0, 0, r], rgba, obj.mass_kg, obj.friction, mujoco.mjtGeom.mjGEOM_SPHERE,
                         name=f"{obj.name}_sphere")
        # Rolling friction: a real ball stops rolling on a table within a few centimetres.
        geom.condim = 6
        geom.friction = [obj.friction, 0.005, 0.0005]

    def grasp(self, dims, placement):
        # The tcp slightly above the centre keeps the fingertips off the table.
        return Grasp(tcp_offset_m=0.006, half_width_m=dims["radius_m"])

    def rests_on_table(self, scene, name, face, tolerance_m):  # no faces: its lowest point
        return bool(abs(centre_m(scene, name)[2] - scene.object_dims(name)["radius_m"] - scene.table_top_z_m)
                    < tolerance_m)

    def has_above(self, scene, object, target, tolerance_m):  # an upside-down cup over the ball
        if (problem := self.over_problem(scene.object_kind(object))) is not None:
            raise ConfigError(f"over: {problem} ({object} over {target})")
        g = Cup.interior(scene, target, object)
        return bool(g["offset_m"] < g["inner_r"])

    def over_problem(self, object_kind):
        return None if object_kind == "cup" else "over a ball is defined for a cup (upside down, covering it) only"


def _rectangle(scene: Scene, name: str, half_extent: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The footprint corners and edge normals of a rectangle of ``half_extent`` along body x, y."""
    s = scene.object_state(name)
    R = rotation(s["quat_wxyz"])
    axes = [R[:2, 0] / np.linalg.norm(R[:2, 0]), R[:2, 1] / np.linalg.norm(R[:2, 1])]
    signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], float)
    return s["pos_world_m"][:2] + (signs * half_extent) @ np.array(axes), axes


_CAPSULE_ALONG = {0: (float(np.cos(np.pi / 4)), 0.0, float(np.sin(np.pi / 4)), 0.0),  # a capsule's axis along x
                  1: (float(np.cos(np.pi / 4)), float(-np.sin(np.pi / 4)), 0.0, 0.0),  # along y
                  2: (1.0, 0.0, 0.0, 0.0)}  # along z


def add_rounded_cube(body, name: str, half_m: float, radius_m: float, rgba, mass_kg: float, friction: float) -> None:
    """A cube of half edge ``half_m`` (its bottom face at the body's origin) whose edges and corners
    are rounded by ``radius_m``: three boxes (each full along one axis) and a capsule along each of
    its twelve edges, their masses in proportion to their volumes, adding up to ``mass_kg``."""
    inner = half_m - radius_m  # the half edge of the cube whose edges the capsules follow
    centre = np.array([0.0, 0.0, half_m])
    parts = []
    for axis in range(3):
        size = np.full(3, inner)
        size[axis] = half_m
        parts.append((mujoco.mjtGeom.mjGEOM_BOX, size.tolist(), centre.tolist(), None, 8 * float(np.prod(size))))
    capsule_volume = np.pi * radius_m**2 * 2 * inner + 4 / 3 * np.pi * radius_m**3
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        for sa in (-1, 1):
            for sb in (-1, 1):
                pos = centre.copy()
                pos[others[0]] += sa * inner
                pos[others[1]] += sb * inner
                parts.append((mujoco.mjtGeom.mjGEOM_CAPSULE, [radius_m, inner], pos.tolist(), _CAPSULE_ALONG[axis],
                              capsule_volume))
    total = sum(volume for *_, volume in parts)
    for i, (geom_type, size, pos, quat, volume) in enumerate(parts):
        _add_geom(body, size, pos, rgba, mass_kg * volume / total, friction, geom_type, quat=quat,
                  name=f"{name}_rounded{i}")


class Block(ObjectKind):
    """A solid cube, its edges rounded where its dims say (``edge_radius_m``)."""

    name = "block"
    dims_keys = ("size_m",)
    optional_dims_keys = ("edge_radius_m",)
    upright_yaw_symmetry = 4
    table_faces = ("bottom", "top", "any")
    pickable = True
    stacked_on = True

    def height_m(self, dims):
        return dims["size_m"]

    def footprint_radius_m(self, dims, placement="upright"):
        return dims["size_m"] / np.sqrt(2)

    def dims_problems(self, dims):
        if "edge_radius_m" in dims and not 0 < dims["edge_radius_m"] < dims["size_m"] / 2:
            return [("dims.edge_radius_m", f"must lie between 0 and half the edge size_m ({dims['size_m'] / 2:g}), "
                     f"got {dims['edge_radius_m']}")]
        return []

    def add_geoms(self, spec, body, obj, size_scale, rgba):
        dims = obj.scaled_dims(size_scale)
        h = dims["size_m"] / 2
        if "edge_radius_m" in dims:
            add_rounded_cube(body, obj.name, h, dims["edge_radius_m"], rgba, obj.mass_kg, obj.friction)
            return
        _add_geom(body, [h, h, h], [0, 0, h], rgba, obj.mass_kg, obj.friction, mujoco.mjtGeom.mjGEOM_BOX,
                  name=f"{obj.name}_cube")

    def grasp(self, dims, placement):
        return Grasp(tcp_offset_m=0.006, half_width_m=dims["size_m"] / 2)

    def grasp_yaws(self, object_yaw_rad, natural_yaw_rad):  # the jaws square to its faces
        return object_yaw_rad, np.pi / 2

    @staticmethod
    def corners_world(scene: Scene, name: str) -> tuple[np.ndarray, np.ndarray]:
        s = scene.object_state(name)
        R = rotation(s["quat_wxyz"])
        half = scene.object_dims(name)["size_m"] / 2
        signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (0, 2)], float)
        return s["pos_world_m"] + (signs * half) @ R.T, R

    def rests_on_table(self, scene, name, face, tolerance_m):
        if face != "any":
            return super().rests_on_table(scene, name, face, tolerance_m)
        table, size = scene.table_top_z_m, scene.object_dims(name)["size_m"]
        lowest = self.corners_world(scene, name)[0][:, 2].min()
        return bool(abs(lowest - table) < tolerance_m and abs(centre_m(scene, name)[2] - table - size / 2) < tolerance_m)

    @staticmethod
    def _bottom_on_top_face(scene: Scene, name: str, block: str) -> tuple[np.ndarray, float]:
        """The object's bottom centre in the block's frame, and the block's edge."""
        return local(scene, block, scene.object_state(name)["pos_world_m"]), scene.object_dims(block)["size_m"]

    def holds_on_top(self, scene, object, support, tolerance_m, inset_m):  # centre inset_m inside its top face
        p, size = self._bottom_on_top_face(scene, object, support)
        return bool(max(abs(p[0]), abs(p[1])) < size / 2 - inset_m and abs(p[2] - size) < tolerance_m)

    def has_above(self, scene, object, target, tolerance_m):
        p, size = self._bottom_on_top_face(scene, object, target)
        return bool(max(abs(p[0]), abs(p[1])) < size / 2 and p[2] > size - tolerance_m)

    def footprint(self, scene, name):
        corners, R = self.corners_world(scene, name)
        axes = [R[:2, k] / np.linalg.norm(R[:2, k]) for k in range(3) if np.linalg.norm(R[:2, k]) > 0.3]
        return corners[:, :2], axes  # a flat block has two horizontal face normals


class Box(ObjectKind):
    """An open-top rectangular tray: a floor plus four walls."""

    name = "box"
    dims_keys = ("length_m", "width_m", "height_m", "wall_m", "floor_m")
    upright_yaw_symmetry = 2

    def footprint_radius_m(self, dims, placement="upright"):
        return float(np.hypot(dims["length_m"], dims["width_m"]) / 2)

    def support_top_m(self, dims):
        return dims["floor_m"]

    def grasp_yaws(self, object_yaw_rad, natural_yaw_rad):  # the jaws square to its faces
        return object_yaw_rad, np.pi / 2

    def add_geoms(self, spec, body, obj, size_scale, rgba):
        dims = obj.scaled_dims(size_scale)
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

    @staticmethod
    def _within_walls(scene: Scene, name: str, box: str) -> tuple[np.ndarray, bool]:
        """Object ``name``'s centre in the box's frame, and whether it is within the inner walls."""
        d = scene.object_dims(box)
        p = local(scene, box, centre_m(scene, name))
        return p, bool(abs(p[0]) < d["length_m"] / 2 - d["wall_m"] and abs(p[1]) < d["width_m"] / 2 - d["wall_m"])

    def holds_inside(self, scene, object, container):
        p, within = self._within_walls(scene, object, container)
        return bool(within and 0 < p[2] < scene.object_dims(container)["height_m"])

    def has_above(self, scene, object, target, tolerance_m):
        p, within = self._within_walls(scene, object, target)
        return bool(within and p[2] > 0)

    def footprint(self, scene, name):
        dims = scene.object_dims(name)
        return _rectangle(scene, name, np.array([dims["length_m"], dims["width_m"]]) / 2)


class Mesh(ObjectKind):
    """A scanned object (``r2s_eval.sim.meshes`` reads and builds it); what predicates measure on
    it is its bounding box: its top, the box as a container (a bowl), its footprint."""

    name = "mesh"
    dims_keys = ("half_x_m", "half_y_m", "height_m")  # read off the mesh, not given
    placements = ("upright",)
    placement_note = " (as its file stands)"
    upright_yaw_symmetry = 1
    pickable = True

    def footprint_radius_m(self, dims, placement="upright"):
        return float(np.hypot(dims["half_x_m"], dims["half_y_m"]))

    def add_geoms(self, spec, body, obj, size_scale, rgba):
        add_mesh_geoms(spec, body, obj, size_scale, rgba, _OBJECT_CONTACT)

    def grasp(self, dims, placement):  # jaws pre-shaped wider than its bounding box's larger side
        return Grasp(tcp_offset_m=0.006, half_width_m=max(dims["half_x_m"], dims["half_y_m"]))

    @staticmethod
    def _half_extent(scene: Scene, name: str) -> np.ndarray:
        dims = scene.object_dims(name)
        return np.array([dims["half_x_m"], dims["half_y_m"]])

    def _in_bounds(self, scene: Scene, point_world_m: np.ndarray, mesh: str, inset_m: float = 0.0):
        """A point in the mesh's frame, and whether it lies within its footprint (less ``inset_m``)."""
        p = local(scene, mesh, point_world_m)
        return p, bool(np.all(np.abs(p[:2]) < self._half_extent(scene, mesh) - inset_m))

    def holds_on_top(self, scene, object, support, tolerance_m, inset_m):  # on the top of its bounding box
        p, within = self._in_bounds(scene, scene.object_state(object)["pos_world_m"], support, inset_m)
        return bool(within and abs(p[2] - scene.object_dims(support)["height_m"]) < tolerance_m)

    def holds_inside(self, scene, object, container):  # a concave scan (a bowl): within its bounding box
        p, within = self._in_bounds(scene, centre_m(scene, object), container)
        return bool(within and 0 < p[2] < scene.object_dims(container)["height_m"])

    def has_above(self, scene, object, target, tolerance_m):  # above its bottom, within its footprint
        p, within = self._in_bounds(scene, centre_m(scene, object), target)
        return bool(within and p[2] > 0)

    def footprint(self, scene, name):
        return _rectangle(scene, name, self._half_extent(scene, name))


# A world's `kind` name -> the kind.
KINDS: dict[str, ObjectKind] = {kind.name: kind for kind in (Cup(), Plate(), Ball(), Block(), Box(), Mesh())}


def add_object(spec: mujoco.MjSpec, obj: ObjectSpec, size_scale: float) -> None:
    """Append ``obj`` as a free body named ``obj.name`` to the spec's worldbody, in its nominal
    colour (a world's colour offsets are ``r2s_eval.sim.render_params``')."""
    body = spec.worldbody.add_body()
    body.name = obj.name
    body.pos = [0.0, 0.0, 1.0]  # placed properly at reset
    body.add_freejoint().name = f"{obj.name}_free"
    obj.kind_object.add_geoms(spec, body, obj, size_scale, np.clip(np.asarray(obj.rgba, float), 0, 1))
