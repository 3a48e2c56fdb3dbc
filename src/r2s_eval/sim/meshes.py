"""Scanned objects: a mesh file (OBJ, STL or PLY, what a 3D scan gives; read by trimesh) as a
simulation object, with its texture, and convex collision parts so that a concave object (a bowl,
a mug, a tray) can hold things: CoACD's approximate convex decomposition, computed once per mesh
and settings and kept in a cache folder (``r2s_eval.paths.cache_dir``).

A world's object entry (``world.objects.<name>``)::

    bowl:
      kind: mesh
      mesh: {file: scans/bowl.obj, scale: 0.001, texture: scans/bowl.png}  # file: a path, or
                                       #   {package, resource}; scale: file units -> metres
      collision: {coacd: {threshold: 0.05}}   # or hull (default): the surface's convex hull
      yaw_symmetry: 0                  # optional: 0 round, n: the same after 2 pi / n (default 1)
      rgba: [0.9, 0.9, 0.9, 1.0]       # its colour without a texture; what the colour segmenter looks for
      mass_kg: 0.3

The body frame sits at the centre of the mesh's bounding box's bottom face, z up (the file's
axes, scaled): the dims other code reads (``half_x_m``, ``half_y_m``, ``height_m``) are that box's.

An arm's drawn meshes can be decimated too (``robot.arms.<arm>.visual``, ``r2s_eval.sim.robot``):
``decimated_meshes`` splits a face budget over the mesh files and simplifies them with
``fast-simplification`` (quadric edge collapse), kept in the same cache folder (``visual/``) and
per process.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from r2s_eval import paths
from r2s_eval.sim.reading import as_mapping, check_keys, fail, file_path, finite

COLLISION_GROUP = 3  # collision parts are not drawn (renderers show groups 0-2)
MESH_KEYS = {"mesh", "collision", "yaw_symmetry"}  # a mesh object's keys besides the common ones
COACD_SETTINGS = {"threshold", "max_convex_hull", "preprocess_resolution", "resolution", "mcts_iterations", "mcts_nodes"}


@dataclass(frozen=True)
class MeshShape:
    """A scanned object's surface in its body frame (metres), its texture where it has one, and
    its convex collision parts (empty: the surface's convex hull collides)."""

    vertices: np.ndarray  # (V, 3)
    faces: np.ndarray  # (F, 3) vertex indices
    texcoords: np.ndarray | None  # (V, 2), with a texture
    texture: Path | None
    parts: tuple[tuple[np.ndarray, np.ndarray], ...]

    def dims(self) -> dict[str, float]:
        low, high = self.vertices.min(axis=0), self.vertices.max(axis=0)
        return {"half_x_m": float(high[0] - low[0]) / 2, "half_y_m": float(high[1] - low[1]) / 2,
                "height_m": float(high[2] - low[2])}


def cached_arrays(kind: str, key: bytes, compute: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The arrays ``compute`` gives, computed once per ``key`` and kept in the cache folder
    (``<cache>/<kind>/<hash of key>.npz``, written atomically)."""
    path = paths.cache_dir() / kind / f"{hashlib.sha256(key).hexdigest()[:24]}.npz"
    if path.is_file():
        with np.load(path) as saved:
            return {name: saved[name] for name in saved.files}
    arrays = compute()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
    return arrays


def _decompose(vertices: np.ndarray, faces: np.ndarray, settings: dict) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """CoACD's convex parts of the (body-frame) surface, from the cache when computed before."""

    def compute() -> dict[str, np.ndarray]:
        import coacd

        coacd.set_log_level("error")
        parts = [(np.asarray(v, float), np.asarray(f, np.int64))
                 for v, f in coacd.run_coacd(coacd.Mesh(vertices, faces), seed=0, **settings)]
        return {"n": np.array(len(parts)), **{f"v{i}": v for i, (v, _) in enumerate(parts)},
                **{f"f{i}": f for i, (_, f) in enumerate(parts)}}

    saved = cached_arrays("coacd", vertices.astype("<f8").tobytes() + faces.astype("<i8").tobytes()
                          + json.dumps(settings, sort_keys=True).encode(), compute)
    return tuple((saved[f"v{i}"], saved[f"f{i}"]) for i in range(int(saved["n"])))


# ---------------------------------------------------------------- decimated visual meshes
VISUAL_MIN_FACES = 32  # a mesh is not decimated below this (nor is one with fewer faces touched)
DECIMATION_VERSION = 1  # part of the cache key: bump when the decimation below changes
_DECIMATED: dict[tuple, tuple[tuple[np.ndarray, np.ndarray] | None, ...]] = {}


def face_budget(faces: Sequence[int], uses: Sequence[int], max_faces: int) -> list[int] | None:
    """Per mesh, the faces it keeps so that all drawn together (mesh i ``uses[i]`` times) have at
    most ``max_faces``: the budget is split in proportion to the meshes' faces, no mesh going below
    ``VISUAL_MIN_FACES`` (or its own count, if smaller). None: the floors alone exceed the budget."""
    floors = [min(n, VISUAL_MIN_FACES) for n in faces]
    fixed: set[int] = set()  # meshes held at their floor
    while True:
        free = [i for i in range(len(faces)) if i not in fixed]
        left = max_faces - sum(uses[i] * floors[i] for i in fixed)
        drawn = sum(uses[i] * faces[i] for i in free)
        ratio = left / drawn if drawn else 1.0
        low = [i for i in free if ratio * faces[i] < floors[i]]
        if not low:
            break
        fixed.update(low)
    targets = [floors[i] if i in fixed else min(faces[i], int(ratio * faces[i])) for i in range(len(faces))]
    return targets if sum(u * t for u, t in zip(uses, targets)) <= max_faces else None


def _read_surface(path: Path, where: str) -> tuple[np.ndarray, np.ndarray]:
    """A mesh file's triangles (the file's units), vertices merged (an STL repeats them per face,
    an OBJ per texture seam) so that edges can collapse."""
    import trimesh

    try:
        surface = trimesh.load(path, force="mesh")
    except Exception as err:  # trimesh raises many kinds for a file it cannot read
        raise fail(where, f"cannot read {path} as a mesh: {err}") from None
    surface.merge_vertices(merge_tex=True, merge_norm=True)
    return np.asarray(surface.vertices, float), np.asarray(surface.faces, np.int64)


def _clean(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Without degenerate or repeated faces and unused vertices."""
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    faces = faces[np.sort(np.unique(np.sort(faces, axis=1), axis=0, return_index=True)[1])]
    used = np.unique(faces)
    index = np.full(len(vertices), -1, np.int64)
    index[used] = np.arange(len(used))
    return np.asarray(vertices[used], float), index[faces]


def _cluster(vertices: np.ndarray, faces: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertices within one cell of a ``cell``-sized grid merged (vertex clustering)."""
    _, first, index = np.unique(np.round(vertices / cell).astype(np.int64), axis=0, return_index=True,
                                return_inverse=True)
    return _clean(vertices[first], index.reshape(-1)[faces])


def _decimate(vertices: np.ndarray, faces: np.ndarray, target: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``target`` faces by quadric edge collapse (``fast_simplification``). CAD exports are
    full of slivers (long thin triangles) that no edge collapse may touch without folding a face,
    which stalls the collapses far above a small target; so vertices closer than a tenth of the
    decimated mesh's typical edge are merged first (vertex clustering, below what it can show),
    the cell doubled while the collapses still stall."""
    import fast_simplification

    corners = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1).sum()
    cell = 0.1 * np.sqrt(4 * area / np.sqrt(3) / target)  # a tenth of an equilateral triangle's edge
    for _ in range(10):
        v, f = _cluster(vertices, faces, cell) if cell > 0 else (vertices, faces)
        count = target
        for _ in range(3):  # the simplifier stops near its target, at times a little above it
            if len(f) <= target:
                return v, f
            v, f = _clean(*fast_simplification.simplify(v, f, target_count=min(count, len(f) - 1)))
            if len(f) > 1.2 * target:
                break  # stalled: merge more first
            count = max(1, count * target // len(f) - 1)
        cell *= 2
    return v, f


def decimated_meshes(files: Sequence[tuple[Path, int]], max_faces: int,
                     where: str) -> tuple[tuple[np.ndarray, np.ndarray] | None, ...]:
    """Per mesh file (with how many geoms draw it), its decimated (vertices, faces) in the file's
    units, or None for a file kept as it is, such that all drawn together have at most ``max_faces``
    faces (``face_budget``). Computed once per files' content and budget (the cache folder's
    ``visual/``) and kept per process; ``where`` is the ``visual`` key an error names."""
    stamp = tuple((str(path), path.stat().st_mtime_ns, path.stat().st_size, uses) for path, uses in files)
    if (stamp, max_faces) in _DECIMATED:
        return _DECIMATED[stamp, max_faces]
    digest = hashlib.sha256(json.dumps([DECIMATION_VERSION, max_faces]).encode())
    for path, uses in files:
        digest.update(hashlib.sha256(path.read_bytes()).digest() + json.dumps(uses).encode())

    def compute() -> dict[str, np.ndarray]:
        surfaces = [_read_surface(path, where) for path, _ in files]
        targets = face_budget([len(f) for _, f in surfaces], [uses for _, uses in files], max_faces)
        if targets is None:
            floor = sum(min(len(f), VISUAL_MIN_FACES) * uses for (_, f), (_, uses) in zip(surfaces, files))
            raise fail(f"{where}.max_faces", f"{max_faces} faces cannot draw the arm's {len(files)} meshes "
                                             f"(at least {floor}: {VISUAL_MIN_FACES} per mesh)")
        out = {"n": np.array(len(files))}
        for i, ((vertices, faces), target) in enumerate(zip(surfaces, targets)):
            if target < len(faces):
                v, f = _decimate(vertices, faces, target)
                if len(v) >= 4:  # what MuJoCo takes for a mesh (else the file's is kept)
                    out[f"v{i}"], out[f"f{i}"] = v, f
        return out

    saved = cached_arrays("visual", digest.digest(), compute)
    result = tuple((saved[f"v{i}"], saved[f"f{i}"]) if f"v{i}" in saved else None for i in range(len(files)))
    _DECIMATED[stamp, max_faces] = result
    return result


def load_shape(entry: Mapping, where: str) -> MeshShape:
    """The shape a ``kind: mesh`` object entry (``mesh``, ``collision``) describes; a wrong entry
    is a ``WorldError`` naming its key."""
    import trimesh

    mesh_entry = as_mapping(entry.get("mesh"), f"{where}.mesh")
    check_keys(mesh_entry, {"file", "scale", "texture"}, {"file"}, f"{where}.mesh")
    path = file_path(mesh_entry["file"], f"{where}.mesh.file", "mesh file")
    scale = float(finite(mesh_entry.get("scale", 1.0), f"{where}.mesh.scale", positive=True))
    try:
        surface = trimesh.load(path, force="mesh")
    except Exception as err:  # trimesh raises many kinds for a file it cannot read
        raise fail(f"{where}.mesh.file", f"cannot read {path} as a mesh: {err}") from None
    if len(surface.faces) == 0:
        raise fail(f"{where}.mesh.file", f"{path} holds no triangles")
    vertices = np.asarray(surface.vertices, float) * scale
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    vertices = vertices - np.array([(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, low[2]])
    faces = np.asarray(surface.faces, np.int64)
    texture = texcoords = None
    if mesh_entry.get("texture") is not None:
        texture = file_path(mesh_entry["texture"], f"{where}.mesh.texture", "texture image")
        uv = getattr(surface.visual, "uv", None)
        if uv is None or len(uv) != len(vertices):
            raise fail(f"{where}.mesh.texture", f"{path} has no texture coordinates to map it with")
        texcoords = np.asarray(uv, float)
    collision = entry.get("collision", "hull")
    if collision == "hull":
        parts = ()
    else:
        decomposition = as_mapping(collision, f"{where}.collision")
        check_keys(decomposition, {"coacd"}, {"coacd"}, f"{where}.collision")
        settings = as_mapping(decomposition["coacd"] or {}, f"{where}.collision.coacd")
        check_keys(settings, COACD_SETTINGS, set(), f"{where}.collision.coacd")
        parts = _decompose(vertices, faces, settings)
    return MeshShape(vertices=vertices, faces=faces, texcoords=texcoords, texture=texture, parts=parts)


def add_mesh_geoms(spec: mujoco.MjSpec, body: mujoco.MjsBody, obj, scale: float, rgba, contact: dict) -> None:
    """The object's surface (drawn, massive, not colliding) and its collision parts (or, without
    parts, the surface colliding through its hull), scaled by ``scale`` (the twin's size scale)."""
    shape: MeshShape = obj.shape
    sizes = [scale] * 3
    surface = spec.add_mesh(name=f"{obj.name}_surface", uservert=shape.vertices.flatten().tolist(),
                            userface=shape.faces.flatten().tolist(), scale=sizes)
    surface.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL  # a scan need not be closed
    material = None
    if shape.texture is not None:
        surface.usertexcoord = shape.texcoords.flatten().tolist()
        spec.add_texture(name=f"{obj.name}_texture", file=str(shape.texture), type=mujoco.mjtTexture.mjTEXTURE_2D)
        material = spec.add_material(name=f"{obj.name}_material")
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = f"{obj.name}_texture"
    drawn = body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f"{obj.name}_surface", rgba=rgba,
                          mass=obj.mass_kg, friction=[obj.friction, 0.01, 0.001], condim=contact["condim"],
                          name=f"{obj.name}_surface")
    if material is not None:
        drawn.material = material.name
        drawn.rgba = [1.0, 1.0, 1.0, float(rgba[3])]
    if not shape.parts:
        drawn.contype, drawn.conaffinity = contact["contype"], contact["conaffinity"]
        return
    drawn.contype = drawn.conaffinity = 0
    for i, (vertices, faces) in enumerate(shape.parts):
        spec.add_mesh(name=f"{obj.name}_part{i}", uservert=np.asarray(vertices).flatten().tolist(),
                      userface=np.asarray(faces).flatten().tolist(), scale=sizes)
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f"{obj.name}_part{i}", rgba=rgba, mass=0.0,
                      friction=[obj.friction, 0.01, 0.001], contype=contact["contype"],
                      conaffinity=contact["conaffinity"], condim=contact["condim"], group=COLLISION_GROUP,
                      name=f"{obj.name}_part{i}")


def yaw_symmetry_of(entry: Mapping[str, Any], where: str) -> int | None:
    value = entry.get("yaw_symmetry")
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise fail(f"{where}.yaw_symmetry", f"must be a whole number >= 0 (0: round), got {value!r}")
    return value
