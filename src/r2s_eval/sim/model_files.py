"""Model files as their makers ship them, read into one ``mujoco.MjSpec`` for an arm or a scene.

A world names a model file (``r2s_eval.sim.robot``'s model references) that may be:

- a full MJCF model (``<mujoco>``) or a URDF (``<robot>``): read as MuJoCo reads it;
- an include fragment (``<mujocoinclude>``), as packages ship one arm of a multi-arm robot: either
  a piece of a worldbody (bodies, geoms, lights, cameras) or whole sections (``<asset>``,
  ``<worldbody>``, ...). The files that hold the assets, defaults and compiler settings it uses are
  named with it (``assets``) and included before it; file paths inside all of them resolve from
  the fragment's folder, as they would for a model file in that folder that includes them;
- one body subtree of a multi-arm file (``body``): that top body and everything under it, plus the
  actuators, tendons, equalities, contact pairs and excludes and sensors that refer only to its
  elements. The other bodies, the world body's own geoms, sites, lights and cameras, the visual
  settings and the keyframes (which no longer fit) are dropped; assets, defaults and compiler
  settings are kept.

An actuator the file leaves unnamed that drives a joint is named after that joint (its name in the
file), so a world can name it by its joint. A geom the file leaves unnamed in a named body is named
``<body>_geom<i>``, ``i`` its place among that body's geoms in the file (from 0, named ones
counted), so a world can name it (``collision.disable.geoms``). Two elements that would get one
name are an error.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path
from xml.sax.saxutils import quoteattr

import mujoco

from r2s_eval.sim.reading import fail

# Elements that may stand directly in a <worldbody>: a fragment made of them is a piece of one.
_WORLDBODY_CHILDREN = {"body", "geom", "site", "camera", "light", "frame", "replicate", "composite", "flexcomp",
                       "attach", "joint", "freejoint", "inertial", "plugin"}
# Attributes that refer to an asset or a default class, and the section that defines each.
_REFERENCES = {"mesh": "mesh", "material": "material", "hfield": "hfield", "texture": "texture",
               "class": "default class", "childclass": "default class"}


def load_model_spec(path: Path, *, assets: Sequence[Path] = (), body: str | None = None,
                    where: str) -> mujoco.MjSpec:
    """The model ``path`` holds (``assets``: the files an include fragment's assets and defaults come
    from; ``body``: the one top body to keep of a multi-arm file), its unnamed joint actuators named
    by their joints and its unnamed geoms by their body and place in it. ``where`` is the world key
    that names the file (``robot.arms.left.model``)."""
    root = _root(path, where)
    if root.tag == "mujocoinclude":
        spec = _fragment_spec(path, root, assets, where)
    else:
        if assets:
            raise fail(f"{where}.assets", f"{path.name} is a whole model (<{root.tag}>): only an include fragment "
                                          f"(<mujocoinclude>) takes assets files")
        spec = _parsed(lambda: mujoco.MjSpec.from_file(str(path)), path, where)
    if body is not None:
        _keep_body(spec, body, path, where)
    _name_actuators_by_joint(spec, path, where)
    _name_geoms_by_body(spec, path, where)
    return spec


def _root(path: Path, where: str) -> ET.Element:
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as error:
        raise fail(where, f"{path.name} is not an XML file: {error}") from None
    if root.tag not in {"mujoco", "mujocoinclude", "robot"}:
        raise fail(where, f"{path.name} is neither MJCF (<mujoco>, <mujocoinclude>) nor URDF (<robot>): "
                          f"its root is <{root.tag}>")
    return root


def _parsed(read, path: Path, where: str) -> mujoco.MjSpec:
    try:
        return read()
    except ValueError as error:  # MuJoCo's XML errors: keep their first line, under the world's key
        raise fail(where, f"{path.name}: {str(error).strip().splitlines()[0]}") from None


def _fragment_spec(path: Path, root: ET.Element, assets: Sequence[Path], where: str) -> mujoco.MjSpec:
    """An include fragment with the files holding its assets and defaults included before it."""
    asset_roots = [_root(file, f"{where}.assets") for file in assets]
    _check_fragment_references(path, root, asset_roots, where)
    includes = "".join(f"<include file={quoteattr(str(file))}/>" for file in assets)
    fragment = f"<include file={quoteattr(str(path))}/>"
    if all(child.tag in _WORLDBODY_CHILDREN for child in root):
        fragment = f"<worldbody>{fragment}</worldbody>"
    xml = f"<mujoco model={quoteattr(path.stem)}>{includes}{fragment}</mujoco>"
    spec = _parsed(lambda: mujoco.MjSpec.from_string(xml), path, where)
    spec.modelfiledir = str(path.parent)  # mesh and texture files resolve from the fragment's folder
    return spec


def _check_fragment_references(path: Path, root: ET.Element, asset_roots: list[ET.Element], where: str) -> None:
    """Every asset and default class the fragment uses is defined in it or in its assets files."""
    defined: set[tuple[str, str]] = set()
    for tree in (root, *asset_roots):
        for element in tree.iter():
            if element.tag == "default" and element.get("class"):
                defined.add(("default class", element.get("class")))
            elif element.tag in {"mesh", "material", "hfield", "texture"}:
                # An asset without a name is called after its file (MuJoCo's rule).
                name = element.get("name") or Path(element.get("file", "")).stem
                defined.add((element.tag, name))
    used = []
    for element in root.iter():
        if element.tag in {"default", "mesh", "material", "hfield", "texture"}:
            continue
        for attribute, kind in _REFERENCES.items():
            name = element.get(attribute)
            if name and (kind, name) not in defined and (kind, name) not in used:
                used.append((kind, name))
    if used:
        kind, name = used[0]
        more = f" (and {len(used) - 1} more)" if len(used) > 1 else ""
        given = f"the assets files given define no {kind} {name!r}" if asset_roots else "no assets file is given"
        raise fail(f"{where}.assets", f"{path.name} is an include fragment that uses {kind} {name!r}{more}, and "
                                      f"{given}: name the file(s) holding its <asset> and <default> sections "
                                      f"(model: {{..., assets: <model reference or list>}})")


def _subtree(body: mujoco.MjsBody) -> list[mujoco.MjsBody]:
    bodies = [body]
    for child in body.bodies:
        bodies += _subtree(child)
    return bodies


def _keep_body(spec: mujoco.MjSpec, name: str, path: Path, where: str) -> None:
    """Drop everything of ``spec`` but top body ``name``'s subtree and what refers only to it."""
    tops = [b.name for b in spec.worldbody.bodies]
    if name not in tops:
        raise fail(f"{where}.body", f"{path.name} has no top body {name!r}; its top bodies: {tops}")
    kept_bodies = _subtree(spec.body(name))
    kept = {b.name for b in kept_bodies} | {
        element.name for b in kept_bodies for element in (*b.joints, *b.geoms, *b.sites, *b.cameras) if element.name}
    for other in [b for b in spec.worldbody.bodies if b.name != name]:
        spec.delete(other)
    for element in (*spec.worldbody.geoms, *spec.worldbody.sites, *spec.worldbody.lights, *spec.worldbody.cameras):
        spec.delete(element)
    for key in list(spec.keys):
        spec.delete(key)
    spec.visual = mujoco.MjSpec().visual  # the file's scene settings (near plane, ...) are the scene's business

    def refers_to_kept(*names: str) -> bool:
        return all(n in kept for n in names if n)

    for tendon in list(spec.tendons):
        path_ = tendon.path
        if refers_to_kept(*(path_[i].target.name for i in range(len(path_)))):
            kept.add(tendon.name)
        else:
            spec.delete(tendon)
    for element, names in (
        *((a, (a.target, a.refsite, a.slidersite)) for a in spec.actuators),
        *((e, (e.name1, e.name2)) for e in spec.equalities),
        *((x, (x.bodyname1, x.bodyname2)) for x in spec.excludes),
        *((p, (p.geomname1, p.geomname2)) for p in spec.pairs),
        *((s, (s.objname, s.refname)) for s in spec.sensors),
    ):
        if not refers_to_kept(*names):
            spec.delete(element)


def _name_actuators_by_joint(spec: mujoco.MjSpec, path: Path, where: str) -> None:
    names = {a.name for a in spec.actuators if a.name}
    for actuator in spec.actuators:
        if actuator.name or actuator.trntype != mujoco.mjtTrn.mjTRN_JOINT or not actuator.target:
            continue
        if actuator.target in names:
            raise fail(where, f"{path.name}: an unnamed actuator of joint {actuator.target!r} would be named after "
                              f"it (unnamed actuators are named by their joint), but {actuator.target!r} names "
                              f"another actuator already")
        actuator.name = actuator.target
        names.add(actuator.target)


def unnamed_geom_name(body: str, index: int | str) -> str:
    """The name an unnamed geom gets: its body's and its place among the body's geoms."""
    return f"{body}_geom{index}"


def _name_geoms_by_body(spec: mujoco.MjSpec, path: Path, where: str) -> None:
    names = {g.name for g in spec.geoms if g.name}
    for body in spec.bodies:
        if not body.name:  # no stable name to derive one from
            continue
        # Counting the named geoms too keeps a derived name when the maker names another geom.
        for i, geom in enumerate(body.geoms):
            if geom.name:
                continue
            name = unnamed_geom_name(body.name, i)
            if name in names:
                raise fail(where, f"{path.name}: the unnamed geom {i} of body {body.name!r} would be named {name!r} "
                                  f"(unnamed geoms are named by their body), but {name!r} names another geom already")
            geom.name = name
            names.add(name)


__all__ = ["load_model_spec", "unnamed_geom_name"]
