"""The project's one cache folder (`r2s_eval.paths.cache_dir`) and who keeps things in it."""

from __future__ import annotations


import pytest

from r2s_eval.libero import environment
from r2s_eval.paths import cache_dir


@pytest.fixture
def no_cache_vars(monkeypatch, tmp_path):
    monkeypatch.delenv("R2S_EVAL_CACHE", raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    return tmp_path


def test_the_cache_folder_follows_the_override_then_xdg_then_home(no_cache_vars, monkeypatch):
    tmp_path = no_cache_vars
    assert cache_dir() == tmp_path / "home" / ".cache" / "r2s_eval"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "r2s_eval"
    monkeypatch.setenv("R2S_EVAL_CACHE", str(tmp_path / "mine"))
    assert cache_dir() == tmp_path / "mine"


@pytest.mark.parametrize("xdg", [False, True])
def test_libero_s_environment_lies_in_the_cache_folder(no_cache_vars, monkeypatch, xdg):
    if xdg:
        monkeypatch.setenv("XDG_CACHE_HOME", str(no_cache_vars / "xdg"))
    assert environment.env_dir(None) == cache_dir() / f"libero-{environment.requirements_hash()}"
    assert environment.env_dir(str(no_cache_vars / "elsewhere")) == no_cache_vars / "elsewhere"  # libero.env_dir


def test_the_mesh_shapes_share_the_cache_folder(no_cache_vars, monkeypatch):
    import numpy as np

    from r2s_eval.sim import meshes

    for variable, value in (("XDG_CACHE_HOME", "xdg"), ("R2S_EVAL_CACHE", "mine")):
        monkeypatch.setenv(variable, str(no_cache_vars / value))
        meshes.cached_arrays("probe", variable.encode(), lambda: {"x": np.zeros(1)})
        assert list((cache_dir() / "probe").glob("*.npz")), variable
