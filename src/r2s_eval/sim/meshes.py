"""Scanned objects: a mesh file (OBJ, STL or PLY, what a 3D scan gives; read by trimesh) as a
simulation object, with its texture, and convex collision parts so that a concave object (a bowl,
a mug, a tray) can hold things: CoACD's approximate convex decomposition, computed once per mesh
and settings and kept in a cache folder (``$R2S_EVAL_CACHE``, default ``~/.cache/r2s_eval``).

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
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

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


def cache_dir() -> Path:
    return Path(os.environ.get("R2S_EVAL_CACHE") or Path.home() / ".cache" / "r2s_eval")


def _decompose(vertices: np.ndarray, faces: np.ndarray, settings: dict) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """CoACD's convex parts of the (body-frame) surface, from the cache when computed before."""
    key = hashlib.sha256(vertices.astype("<f8").tobytes() + faces.astype("<i8").tobytes()
                         + json.dumps(settings, sort_keys=True).encode()).hexdigest()[:24]
    path = cache_dir() / "coacd" / f"{key}.npz"
    if path.is_file():
        with np.load(path) as saved:
            return tuple((saved[f"v{i}"], saved[f"f{i}"]) for i in range(int(saved["n"])))
    import coacd

    coacd.set_log_level("error")
    parts = tuple((np.asarray(v, float), np.asarray(f, np.int64))
                  for v, f in coacd.run_coacd(coacd.Mesh(vertices, faces), seed=0, **settings))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
    np.savez(tmp, n=len(parts), **{f"v{i}": v for i, (v, _) in enumerate(parts)},
             **{f"f{i}": f for i, (_, f) in enumerate(parts)})
    os.replace(tmp, path)
    return parts


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
