"""The twin's room and its objects' true shapes: what a lab's scene holds that the world's model leaves out.

The simulated world (``r2s_eval.sim``) draws a plain table in an empty grey room, lit without
shadows, and each object as its kind builds it (the cup a tapered cylinder, a block a sharp cube).
A lab's cameras see more, and its objects are not quite their kinds. These are ``RealityEffects``
fields (``r2s_eval.twin.reality``), each off at its default:

- ``table_texture``: the table top's wood grain, tinted by the world's table colour (its
  perturbed colour still applies), a little darker on average than the plain colour.
- ``walls``: four plastered walls round the table, a speckled floor covering, and a photograph on
  the far wall (Grace Hopper's portrait, the photograph matplotlib ships as sample data); the
  wrist cameras see them when they look up from the table.
- ``shadows``: the scene's strongest light (the key light) casts shadows: an arm or an object
  darkens the table under it.
- ``distractors``: things lying on the table that no task touches (``DISTRACTORS``: a pocket
  notebook, a phone, a roll of tape, a marker with a red cap), static, colliding as the table does,
  their footprints in the table's far strip (``distractor_area``: within 26 cm of its far edge,
  +x, away from the robot; beyond x = 0.19 m on the bundled table), so clear of the bundled worlds'
  start regions (x <= 0.10 m, plus the objects' footprints) and of the arms' paths between their
  bases and the objects. ``check_distractors`` refuses a twin whose distractor lies within 2 cm of
  a task's start region (grown by the object's footprint).
- ``cup_handle``: every cup is a mug: a C-shaped handle (three capsules, massless: the cup weighs
  what the world says) on its wall, pointing along the body's -x axis (``r2s_eval.sim.objects``'
  ``HANDLE_AXIS``): up when the cup lies on its side, clear of the table and of the jaws that
  close across it. Its size is the twin's (``true_handle_dims``), in place of any handle the world
  states (a lab's measurement of its mug, which the calibrated sim builds). The scripted
  operator sees it and turns its jaws away from it (``r2s_eval.twin.operator``).
- ``block_edge_radius_m``: every block's edges and corners are rounded with this radius (three
  boxes and twelve capsules in place of the cube: the same size, mass and frame), in place of any
  rounding the world states (``edge_radius_m``, a lab's measurement).

The textures are made here with numpy from fixed seeds (a lab's room is the same in every
episode), the photograph read from matplotlib's sample data: nothing is downloaded. ``scene_adder``
adds them to the twin's model before it compiles (``r2s_eval.sim.assembly.build_model``'s
``add_to_spec``), so the calibrated sim, built from world parameters alone, never has them: the
calibration sees the room only in what the twin records.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np
from scipy import ndimage

from r2s_eval.errors import ConfigError
from r2s_eval.sim.model_files import load_model_spec
from r2s_eval.sim.objects import HANDLE_DIMS, ObjectSpec, add_cup_handle, add_rounded_cube
from r2s_eval.sim.params import WorldParams
from r2s_eval.sim.render_params import key_light
from r2s_eval.sim.robot import Robot
from r2s_eval.sim.rotations import yaw_quat
from r2s_eval.sim.tasks import Task

if TYPE_CHECKING:  # reality imports this module
    from r2s_eval.twin.reality import RealityEffects

ROOM_PREFIX = "room_"  # the names of everything added here start with it (or the object's name)
DRAWN_ONLY = dict(contype=0, conaffinity=0)  # walls and floor covering: out of every arm's reach

# ----------------------------------------------------------------------------- the room
WALL_MARGIN_M = 1.1  # the walls stand this far beyond the table's edges (the key light's slant
# over the walls' height, 0.4 x 1.75 m, stays short of it: the walls shade no part of the table)
WALL_HEIGHT_M = 2.5
WALL_THICKNESS_M = 0.02
TEXTURE_M = 0.5  # the length of table or wall one texture image covers
POSTER_WIDTH_M = 0.5
POSTER_ABOVE_TABLE_M = 0.35  # the photograph's lower edge above the table top
# The key light's shadow map and the half-width it covers (x the model's extent, 5.7 m in the
# bundled world: +-2.8 m, the room): 5.5 mm per texel, an arm's shadow edge sharp to a pixel or two
# of a 128 px head camera at two thirds the cost of a 2048 px map over the whole extent.
SHADOW_MAP_PX = 1024
SHADOW_CLIP_REL = 0.5


@functools.cache
def table_rect(scene: Path, assets: tuple[Path, ...], table_geom: str) -> tuple[float, float, float, float]:
    """(x_lo, x_hi, y_lo, y_hi) of the scene's table top (its box geom's footprint), in metres."""
    model = load_model_spec(scene, assets=assets, where="robot.scene").compile()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    geom = model.geom(table_geom)
    if model.geom_type[geom.id] != mujoco.mjtGeom.mjGEOM_BOX:
        raise ConfigError(f"robot.workspace.geom: the twin's room needs the table {table_geom!r} as a box")
    R = data.geom_xmat[geom.id].reshape(3, 3)
    half = np.abs(R[:2]) @ model.geom_size[geom.id]
    centre = data.geom_xpos[geom.id][:2]
    return (float(centre[0] - half[0]), float(centre[0] + half[0]), float(centre[1] - half[1]),
            float(centre[1] + half[1]))


def robot_table_rect(robot: Robot) -> tuple[float, float, float, float]:
    return table_rect(robot.scene, tuple(robot.scene_assets), robot.table_geom)


def _smooth_noise(rng: np.random.Generator, size: int, cells: tuple[int, int]) -> np.ndarray:
    """Noise in [0, 1] on a ``size`` x ``size`` image, varying over ``cells`` (rows, columns) that
    tile: a random grid wrapped round and interpolated cubically."""
    grid = rng.random(cells)
    image = ndimage.zoom(grid, (size / cells[0], size / cells[1]), order=3, grid_mode=True, mode="grid-wrap")
    return (image - image.min()) / max(float(np.ptp(image)), 1e-9)


def _fractal(rng: np.random.Generator, size: int, cells: tuple[int, int], octaves: int) -> np.ndarray:
    layers = [_smooth_noise(rng, size, (cells[0] * 2**k, cells[1] * 2**k)) * 0.5**k for k in range(octaves)]
    image = np.sum(layers, axis=0)
    return (image - image.min()) / max(float(np.ptp(image)), 1e-9)


def _rgb8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.round(image * 255), 0, 255).astype(np.uint8)


@functools.cache
def wood_texture(size: int = 512) -> np.ndarray:
    """A table top's grain as a gain on its colour (uint8 RGB, 255 = the table's own colour): thin
    dark latewood lines along the image's columns, gently wandering, over streaked pores and broad
    figure, tiling; 0.72-0.97 of the colour, 0.9 on average."""
    rng = np.random.default_rng(20240611)
    columns = np.linspace(0.0, 1.0, size, endpoint=False)[None, :]
    wander = _fractal(rng, size, (1, 2), 2)
    phase = np.mod(14 * columns + 1.5 * wander, 1.0)
    latewood = np.exp(-(((phase - 0.5) / 0.07) ** 2))
    pores = _fractal(rng, size, (2, 96), 2)  # streaks along the grain
    figure = _fractal(rng, size, (2, 2), 2)
    gain = 0.90 + 0.08 * figure - 0.12 * latewood - 0.08 * pores
    return _rgb8(np.clip(gain, 0, 1)[..., None] * np.array([1.0, 0.97, 0.93]))


@functools.cache
def plaster_texture(size: int = 256) -> np.ndarray:
    """An off-white wall's plaster: faint blotches and grain."""
    rng = np.random.default_rng(20240612)
    shade = 0.86 + 0.07 * _fractal(rng, size, (4, 4), 4) + 0.03 * rng.random((size, size))
    return _rgb8(shade[..., None] * np.array([0.98, 0.96, 0.91]))


@functools.cache
def floor_texture(size: int = 256) -> np.ndarray:
    """A grey-blue speckled floor covering."""
    rng = np.random.default_rng(20240613)
    shade = 0.85 + 0.1 * _fractal(rng, size, (3, 3), 3)
    speckle = rng.random((size, size)) < 0.06
    shade = np.where(speckle, shade * rng.uniform(0.6, 1.3, (size, size)), shade)
    return _rgb8(np.clip(shade, 0, 1.0)[..., None] * np.array([0.42, 0.45, 0.50]))


@functools.cache
def poster_image() -> np.ndarray:
    """The photograph on the far wall: matplotlib's sample portrait (uint8 RGB, rows top down)."""
    import matplotlib.cbook
    import matplotlib.image

    with matplotlib.cbook.get_sample_data("grace_hopper.jpg") as file:
        image = matplotlib.image.imread(file, format="jpg")
    return np.ascontiguousarray(image[..., :3]).astype(np.uint8)


def _add_texture(spec: mujoco.MjSpec, name: str, image: np.ndarray, repeat: tuple[float, float] | None) -> str:
    """A 2D texture and its material (``repeat``: images per metre, uniform; None: once over a
    mesh's texture coordinates); returns the material's name."""
    height, width = image.shape[:2]
    texture = spec.add_texture(name=name, type=mujoco.mjtTexture.mjTEXTURE_2D, width=width, height=height, nchannel=3)
    texture.data = np.ascontiguousarray(image).tobytes()
    material = spec.add_material(name=f"{name}_material")
    material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = name
    if repeat is not None:
        material.texrepeat = list(repeat)
        material.texuniform = True
    return material.name


def _texture_table(spec: mujoco.MjSpec, robot: Robot) -> None:
    # The world's table colour (and the twin's offset of it) still tints the grain.
    material = _add_texture(spec, f"{ROOM_PREFIX}wood", wood_texture(), (1 / TEXTURE_M, 1 / TEXTURE_M))
    spec.geom(robot.table_geom).material = material


def _wall_quat(normal: str) -> list[float]:
    """The orientation of a box whose local z is the wall's normal (its local x-y: the wall's plane)."""
    c = np.cos(np.pi / 4)
    return {"x": [c, 0.0, c, 0.0], "y": [c, -c, 0.0, 0.0]}[normal]


def _add_walls(spec: mujoco.MjSpec, robot: Robot) -> None:
    x_lo, x_hi, y_lo, y_hi = robot_table_rect(robot)
    x_lo, x_hi, y_lo, y_hi = x_lo - WALL_MARGIN_M, x_hi + WALL_MARGIN_M, y_lo - WALL_MARGIN_M, y_hi + WALL_MARGIN_M
    plaster = _add_texture(spec, f"{ROOM_PREFIX}plaster", plaster_texture(), (1 / TEXTURE_M, 1 / TEXTURE_M))
    half_h, half_t = WALL_HEIGHT_M / 2, WALL_THICKNESS_M / 2
    half_x, half_y = (x_hi - x_lo) / 2, (y_hi - y_lo) / 2
    centre_x, centre_y = (x_hi + x_lo) / 2, (y_hi + y_lo) / 2
    walls = {  # name: (centre, normal, half extent along the wall)
        "far": ([x_hi + half_t, centre_y, half_h], "x", half_y),
        "near": ([x_lo - half_t, centre_y, half_h], "x", half_y),
        "left": ([centre_x, y_hi + half_t, half_h], "y", half_x + 2 * half_t),
        "right": ([centre_x, y_lo - half_t, half_h], "y", half_x + 2 * half_t),
    }
    for name, (pos, normal, half_along) in walls.items():
        # Local x is the wall's height for a wall facing x, its length for one facing y.
        size = [half_h, half_along, half_t] if normal == "x" else [half_along, half_h, half_t]
        spec.worldbody.add_geom(name=f"{ROOM_PREFIX}wall_{name}", type=mujoco.mjtGeom.mjGEOM_BOX, size=size, pos=pos,
                                quat=_wall_quat(normal), material=plaster, rgba=[1, 1, 1, 1], **DRAWN_ONLY)
    covering = _add_texture(spec, f"{ROOM_PREFIX}floor", floor_texture(), (1 / TEXTURE_M, 1 / TEXTURE_M))
    spec.worldbody.add_geom(name=f"{ROOM_PREFIX}floor_covering", type=mujoco.mjtGeom.mjGEOM_BOX,
                            size=[half_x, half_y, 0.001], pos=[centre_x, centre_y, 0.001], material=covering,
                            rgba=[1, 1, 1, 1], **DRAWN_ONLY)
    _add_poster(spec, x_hi - 0.002, centre_y, robot.workspace_z_m + POSTER_ABOVE_TABLE_M)


def _add_poster(spec: mujoco.MjSpec, x_m: float, y_m: float, bottom_z_m: float) -> None:
    """The photograph as a quad facing the room (-x) on the far wall: a mesh with texture
    coordinates, so the image stands upright and unmirrored."""
    image = poster_image()
    half_w = POSTER_WIDTH_M / 2
    height = POSTER_WIDTH_M * image.shape[0] / image.shape[1]
    # Seen from the room (looking +x), the image's left edge is at +y.
    vertices = [[x_m, y_m + half_w, bottom_z_m], [x_m, y_m - half_w, bottom_z_m],
                [x_m, y_m - half_w, bottom_z_m + height], [x_m, y_m + half_w, bottom_z_m + height]]
    # MuJoCo puts texture coordinate v = 0 at the data's first row: the image goes in bottom row first.
    texcoords = [[0, 0], [1, 0], [1, 1], [0, 1]]
    material = _add_texture(spec, f"{ROOM_PREFIX}poster", image[::-1], None)
    mesh = spec.add_mesh(name=f"{ROOM_PREFIX}poster", uservert=np.ravel(vertices).tolist(),
                         userface=[0, 1, 2, 0, 2, 3], usertexcoord=np.ravel(texcoords).tolist())
    mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL  # a flat quad has no volume
    spec.worldbody.add_geom(name=f"{ROOM_PREFIX}poster", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh.name,
                            material=material, rgba=[1, 1, 1, 1], **DRAWN_ONLY)


def _cast_shadows(spec: mujoco.MjSpec) -> None:
    lights = list(spec.lights)
    if not lights:
        return
    key = lights[key_light([light.diffuse for light in lights])]
    key.castshadow = True
    spec.visual.quality.shadowsize = SHADOW_MAP_PX
    spec.visual.map.shadowclip = SHADOW_CLIP_REL


# ----------------------------------------------------------------------------- distractors
@dataclass(frozen=True)
class Distractor:
    """A thing lying on the table: its parts as (MuJoCo geom type, size, centre above the table in
    its own frame, rgba, quat), and the radius of a circle round its footprint."""

    parts: tuple[tuple[str, tuple[float, ...], tuple[float, float, float], tuple[float, ...], tuple[float, ...]], ...]
    footprint_radius_m: float


_UPRIGHT = (1.0, 0.0, 0.0, 0.0)
_ALONG_X = (float(np.cos(np.pi / 4)), 0.0, float(np.sin(np.pi / 4)), 0.0)  # a capsule's axis along x
# Ordinary desk things in their own, mostly muted colours; the marker's cap is red, as the cup is.
DISTRACTORS: dict[str, Distractor] = {
    "notebook": Distractor((("box", (0.07, 0.045, 0.006), (0.0, 0.0, 0.006), (0.20, 0.30, 0.26, 1.0), _UPRIGHT),),
                           float(np.hypot(0.07, 0.045))),
    "phone": Distractor((("box", (0.075, 0.036, 0.004), (0.0, 0.0, 0.004), (0.06, 0.06, 0.07, 1.0), _UPRIGHT),
                         ("box", (0.068, 0.031, 0.0005), (0.0, 0.0, 0.0085), (0.10, 0.12, 0.16, 1.0), _UPRIGHT)),
                        float(np.hypot(0.075, 0.036))),
    "tape_roll": Distractor((("cylinder", (0.048, 0.024), (0.0, 0.0, 0.024), (0.88, 0.87, 0.82, 1.0), _UPRIGHT),
                             ("cylinder", (0.034, 0.0005), (0.0, 0.0, 0.0485), (0.45, 0.36, 0.25, 1.0), _UPRIGHT)),
                            0.048),
    "marker": Distractor((("capsule", (0.009, 0.05), (-0.01, 0.0, 0.009), (0.05, 0.05, 0.05, 1.0), _ALONG_X),
                          ("capsule", (0.0095, 0.018), (0.058, 0.0, 0.0095), (0.80, 0.10, 0.10, 1.0), _ALONG_X)),
                         0.086),
}
DISTRACTOR_STRIP_M = 0.26  # the table's far strip the distractors lie in (measured from its far edge)
DISTRACTOR_GAP_M = 0.02  # between two distractors' footprints, and from the table's edge
TASK_CLEARANCE_M = 0.02  # between a distractor's footprint and a task object's start region


def distractor_area(robot: Robot, kind: str) -> tuple[float, float, float, float]:
    """(x_lo, x_hi, y_lo, y_hi) the centre of a distractor of ``kind`` may take: its footprint in
    the table's far strip (+x, away from the robot), clear of the table's edges."""
    x_lo, x_hi, y_lo, y_hi = robot_table_rect(robot)
    r = DISTRACTORS[kind].footprint_radius_m + DISTRACTOR_GAP_M
    return x_hi - DISTRACTOR_STRIP_M + r, x_hi - r, y_lo + r, y_hi - r


def draw_distractors(rng: np.random.Generator, robot: Robot) -> tuple[tuple[str, float, float, float], ...]:
    """Every distractor of ``DISTRACTORS`` placed (kind, x_m, y_m, yaw_rad) in the table's far strip,
    apart from one another (rejection sampling, in catalogue order)."""
    placed: list[tuple[str, float, float, float]] = []
    for kind in DISTRACTORS:
        x_lo, x_hi, y_lo, y_hi = distractor_area(robot, kind)
        for _ in range(1000):
            x, y, yaw = rng.uniform(x_lo, x_hi), rng.uniform(y_lo, y_hi), rng.uniform(-np.pi, np.pi)
            if all(np.hypot(x - px, y - py) > DISTRACTORS[kind].footprint_radius_m
                   + DISTRACTORS[other].footprint_radius_m + DISTRACTOR_GAP_M for other, px, py, _ in placed):
                placed.append((kind, float(x), float(y), float(yaw)))
                break
        else:
            raise ConfigError(f"the twin's table leaves no room for a {kind} among its distractors")
    return tuple(placed)


def check_distractors(distractors: Sequence[tuple[str, float, float, float]], task: Task, params: WorldParams,
                      source: str) -> None:
    """A ConfigError naming ``source`` for an unknown distractor or one whose footprint reaches into
    a start region of ``task``'s objects (the region grown by the object's footprint)."""
    for kind, x, y, _ in distractors:
        if kind not in DISTRACTORS:
            raise ConfigError(f"{source}: unknown distractor {kind!r}, one of {sorted(DISTRACTORS)}")
        for name, region in task.init_regions.items():
            if region.relative_to is not None:  # within the object it is placed relative to
                continue
            obj = task.object(name)
            reach = (obj.kind_object.footprint_radius_m(obj.scaled_dims(params.size_scale(name)), task.placement(name))
                     + DISTRACTORS[kind].footprint_radius_m + TASK_CLEARANCE_M)
            dx = max(region.x_range_m[0] - x, 0.0, x - region.x_range_m[1])
            dy = max(region.y_range_m[0] - y, 0.0, y - region.y_range_m[1])
            if np.hypot(dx, dy) < reach:
                raise ConfigError(f"{source}: the distractor {kind} at ({x:.3f}, {y:.3f}) m lies within "
                                  f"{reach:.3f} m of task {task.key}'s start region of {name}")


def _add_distractors(spec: mujoco.MjSpec, robot: Robot, distractors) -> None:
    table = spec.geom(robot.table_geom)
    contact = dict(contype=table.contype, conaffinity=table.conaffinity, condim=table.condim,
                   friction=list(table.friction))  # it collides as the table does
    for i, (kind, x, y, yaw) in enumerate(distractors):
        body = spec.worldbody.add_body(name=f"{ROOM_PREFIX}distractor{i}_{kind}", pos=[x, y, robot.workspace_z_m],
                                       quat=list(yaw_quat(yaw)))
        for j, (geom_type, size, pos, rgba, quat) in enumerate(DISTRACTORS[kind].parts):
            body.add_geom(name=f"{ROOM_PREFIX}distractor{i}_{kind}_{j}",
                          type=getattr(mujoco.mjtGeom, f"mjGEOM_{geom_type.upper()}"),
                          size=[*size, *[0.0] * (3 - len(size))], pos=list(pos), quat=list(quat), rgba=list(rgba),
                          **contact)


# ----------------------------------------------------------------------------- true shapes
# The twin's mug, in proportion to the world's cup (its rim radius and height): a handle between a
# quarter and four fifths of the height whose tube is 0.24 x the rim radius thick (8.9 mm on the
# bundled cup) and stands 0.67 x the rim radius off the wall (25 mm).
HANDLE_SPAN = (0.25, 0.80)  # its lower and upper arms, as fractions of the cup's height
HANDLE_OUT_REL = 0.67
HANDLE_THICKNESS_REL = 0.24


def _style_of(body: mujoco.MjsBody) -> dict:
    """How the body's first geom collides and looks: what the shapes added to the body copy."""
    geom = body.geoms[0]
    return dict(contype=geom.contype, conaffinity=geom.conaffinity, condim=geom.condim, friction=list(geom.friction),
                rgba=list(geom.rgba))


def true_handle_dims(dims: dict) -> dict:
    """The twin's mug handle (``HANDLE_DIMS``) on a cup of (scaled) ``dims``."""
    r, h = dims["radius_m"], dims["height_m"]
    return {"handle_low_m": HANDLE_SPAN[0] * h, "handle_high_m": HANDLE_SPAN[1] * h,
            "handle_out_m": HANDLE_OUT_REL * r, "handle_thickness_m": HANDLE_THICKNESS_REL * r}


def _add_handle(spec: mujoco.MjSpec, obj: ObjectSpec, size_scale: float) -> None:
    """The twin's true handle on the cup's wall (``true_handle_dims``), in place of any handle the
    world states (a lab's measurement of its mug: the calibrated sim's answer, never the twin's)."""
    dims = {k: v for k, v in obj.scaled_dims(size_scale).items() if k not in HANDLE_DIMS}
    body = spec.body(obj.name)
    for geom in [g for g in body.geoms if g.name.startswith(f"{obj.name}_handle_")]:
        spec.delete(geom)
    style = _style_of(body)
    add_cup_handle(body, obj.name, {**dims, **true_handle_dims(dims)}, style["rgba"], style["friction"][0])


def _round_block(spec: mujoco.MjSpec, obj: ObjectSpec, size_scale: float, radius_m: float) -> None:
    """The block's geoms replaced by the twin's cube of the same size with edges and corners rounded
    by ``radius_m`` (``add_rounded_cube``), in place of any rounding the world states."""
    half = obj.scaled_dims(size_scale)["size_m"] / 2
    if not 0 < radius_m < half:
        raise ConfigError(f"the twin's block_edge_radius_m {radius_m} must be below half the edge of {obj.name} "
                          f"({half:.4f} m)")
    body = spec.body(obj.name)
    style = _style_of(body)
    for geom in list(body.geoms):
        spec.delete(geom)
    add_rounded_cube(body, obj.name, half, radius_m, style["rgba"], obj.mass_kg, style["friction"][0])


# ----------------------------------------------------------------------------- the twin's model
def scene_adder(reality: RealityEffects, robot: Robot, objects: Sequence[ObjectSpec], params: WorldParams,
                then: Callable[[mujoco.MjSpec], None] | None = None) -> Callable[[mujoco.MjSpec], None] | None:
    """What ``build_model``'s ``add_to_spec`` adds for ``reality``'s room and shapes (``RealityEffects``)
    to a model of ``objects``, after ``then`` (a caller's own bodies, a calibration board); just
    ``then`` where there is nothing to add (the world's model as it is). The model keeps the
    statistics it has without them."""
    steps = []
    if reality.table_texture:
        steps.append(lambda spec: _texture_table(spec, robot))
    if reality.walls:
        steps.append(lambda spec: _add_walls(spec, robot))
    if reality.shadows:
        steps.append(_cast_shadows)
    if reality.distractors:
        steps.append(lambda spec: _add_distractors(spec, robot, reality.distractors))
    for obj in objects:
        if obj.kind == "cup" and reality.cup_handle:
            steps.append(functools.partial(_add_handle, obj=obj, size_scale=params.size_scale(obj.name)))
        if obj.kind == "block" and reality.block_edge_radius_m > 0:
            steps.append(functools.partial(_round_block, obj=obj, size_scale=params.size_scale(obj.name),
                                           radius_m=float(reality.block_edge_radius_m)))
    if not steps:
        return then

    def add(spec: mujoco.MjSpec) -> None:
        if then is not None:
            then(spec)
        # The world's model statistics, kept: its extent scales the cameras' near plane (walls
        # round the room would push it out and clip what a wrist camera sees up close).
        world = spec.compile().stat
        for step in steps:
            step(spec)
        for key in ("center", "extent", "meanmass", "meansize"):
            setattr(spec.stat, key, np.copy(getattr(world, key)) if key == "center" else float(getattr(world, key)))

    return add
