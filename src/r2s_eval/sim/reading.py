"""Reading a world file: the error that names a wrong entry by its key (or lists every wrong
entry), and the checks its readers share. The keys themselves are typed in
``r2s_eval.sim.world_spec``."""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from r2s_eval.errors import ConfigError
from r2s_eval.paths import REPO_ROOT


class WorldError(ConfigError):
    """A wrong entry of a world: ``path`` is its dotted key (``world.tasks.<key>...``);
    ``problems`` every (key, message) when a world has several."""

    def __init__(self, path: str, message: str):
        super().__init__(f"{path}: {message}")
        self.path, self.message = path, message
        self.problems = [(path, message)]

    @classmethod
    def listing(cls, problems: list[tuple[str, str]]) -> WorldError:
        """One error for every problem: the problem's own line, or a count and one line each."""
        error = cls(*problems[0])
        if len(problems) > 1:
            error.args = (f"{len(problems)} world problems:\n" + "\n".join(f"  - {p}: {m}" for p, m in problems),)
            error.problems = list(problems)
        return error


def fail(where: str, message: str) -> WorldError:
    return WorldError(f"world.{where}", message)


def as_mapping(value: Any, where: str) -> dict:
    if not isinstance(value, Mapping):
        raise fail(where, f"must be a mapping, got {value!r}")
    return dict(value)


def check_keys(entry: dict, allowed: set[str], required: set[str], where: str) -> None:
    unknown, missing = sorted(set(entry) - allowed), sorted(required - set(entry))
    if unknown:
        raise fail(where, f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    if missing:
        raise fail(where, f"missing {missing}")


def finite(value: Any, where: str, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise fail(where, f"must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise fail(where, f"must be positive, got {value!r}")
    return value


def package_dir(name: str, where: str) -> Path:
    """The directory of an installed package, found without importing it: a package installed
    with ``--no-deps`` (to ship model files) may not import."""
    top, *sub = name.split(".")
    spec = importlib.util.find_spec(top) if top else None
    if spec is None:
        raise fail(where, f"package {name!r} is not installed")
    locations = spec.submodule_search_locations
    return (Path(next(iter(locations))) if locations else Path(spec.origin).parent).joinpath(*sub)


def file_path(ref: Any, where: str, what: str = "file") -> Path:
    """The file a world names: a path (relative to the repository, or absolute), ``{path}``, or
    ``{package, resource}``, a file shipped inside an installed package; it must exist."""
    if isinstance(ref, Mapping) and "path" in ref:
        check_keys(dict(ref), {"path"}, {"path"}, where)
        return file_path(ref["path"], f"{where}.path", what)
    if isinstance(ref, Mapping):
        check_keys(dict(ref), {"package", "resource"}, {"package", "resource"}, where)
        path = package_dir(str(ref["package"]), f"{where}.package") / str(ref["resource"])
    elif isinstance(ref, str) and ref:
        path = Path(ref) if Path(ref).is_absolute() else REPO_ROOT / ref
    else:
        raise fail(where, f"must be a path or {{package, resource}}, got {ref!r}")
    if not path.is_file():
        raise fail(where, f"no such {what}: {path}")
    return path
