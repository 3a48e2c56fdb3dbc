"""Same bytes on every machine of a kind: the CPU kernels that differ between AVX2 and AVX-512
machines are capped at AVX2 before any numeric library initialises."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from r2s_eval.utils.numerics import CPU_NUMERICS_ENV, OPENBLAS_ENV, _has_avx2_fma

# What a stage process computes: r2s_eval is imported first, then the numeric libraries.
PROBE = """
import hashlib, json
import r2s_eval
import numpy as np
from numpy._core._multiarray_umath import __cpu_features__
import torch
x = np.random.default_rng(0).uniform(-5, 5, 200_000)
ops = {"exp64": np.exp(x), "log1p64": np.log1p(np.abs(x)), "log1p32": np.log1p(np.abs(x).astype(np.float32))}
t = torch.from_numpy(x[:4096].reshape(64, 64).astype(np.float32))
ops["matmul"] = (t @ t.T).numpy()
a = x[:40000].reshape(200, 200)  # OpenBLAS: a solve and a least-squares fit, as the calibration's
ops["solve64"] = np.linalg.solve(a @ a.T + 200 * np.eye(200), x[:200])
ops["lstsq64"] = np.linalg.lstsq(a[:, :50], x[:200], rcond=None)[0]
print(json.dumps({
    "hashes": {k: hashlib.sha256(v.tobytes()).hexdigest() for k, v in ops.items()},
    "numpy_avx512": sorted(k for k in ("AVX512F", "AVX512_SKX") if __cpu_features__.get(k)),
    "torch_capability": torch.backends.cpu.get_cpu_capability(),
}))
"""


def _probe(env: dict) -> dict:
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _clean_env() -> dict:
    return {k: v for k, v in os.environ.items() if k not in CPU_NUMERICS_ENV and k not in OPENBLAS_ENV}


def test_importing_r2s_eval_caps_every_library_at_avx2():
    seen = _probe(_clean_env())
    assert seen["numpy_avx512"] == []  # NumPy dispatches no AVX-512 kernel
    assert seen["torch_capability"] in ("AVX2", "DEFAULT")  # "DEFAULT": a machine without AVX2


def test_results_equal_an_explicitly_capped_process():
    """The pins reach every library although nobody set them: the bits equal those of a process
    started with the caps already in its environment (what an AVX2 machine computes)."""
    capped = {**_clean_env(), **CPU_NUMERICS_ENV, **(OPENBLAS_ENV if _has_avx2_fma() else {})}
    assert _probe(_clean_env())["hashes"] == _probe(capped)["hashes"]


def test_a_user_setting_is_kept():
    env = {**_clean_env(), "ATEN_CPU_CAPABILITY": "default"}
    assert _probe(env)["torch_capability"] == "DEFAULT"
