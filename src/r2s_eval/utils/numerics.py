"""Pin what makes CPU numerics differ between machines of the same kind, and keep every thread
pool of a stage within the CPUs its job was given.

torch, oneDNN, MKL and NumPy choose kernels by the processor's instruction set, and kernels of
different vector widths add floats in different orders or use other approximations: the same
seeded training then drifts apart on an AVX-512 and an AVX2 machine. NumPy's float64 `exp` and
`log1p` (and float32 `log1p`) are such kernels: on an AVX-512 machine they return other last
bits than on an AVX2 one, and a few ulps early in a simulated episode can flip its outcome.
Capping every library at AVX2 (which both have) makes them run the same kernels. The
environment variables are read when each library first initialises, so `pin_cpu_numerics()`
must run before any of them is imported: the package calls it on import, and stage processes
import the package first. A user who sets a variable keeps their value.
"""

from __future__ import annotations

import os
import sys

from r2s_eval.errors import ConfigError

CPU_NUMERICS_ENV = {
    "ATEN_CPU_CAPABILITY": "avx2",  # ATen's vectorised kernels
    "ONEDNN_MAX_CPU_ISA": "AVX2",  # oneDNN convolutions / matmuls
    "MKL_CBWR": "AVX2",  # MKL's conditional numerical reproducibility
    "MKL_ENABLE_INSTRUCTIONS": "AVX2",
    # NumPy's runtime dispatch: every AVX-512 target it may pick (names it does not know are ignored).
    "NPY_DISABLE_CPU_FEATURES": "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL "
                                "AVX512_ICL AVX512_SPR",
}
# OpenBLAS (NumPy's and SciPy's linear algebra: least squares, solves) is not capped but told its
# kernel: Haswell's is the AVX2 + FMA one that AVX2 machines (AMD's Zen included) run. Without it
# a camera fit by scipy's least squares came out 0.59 deg off on an AVX-512 machine and 0.62 deg
# on an AVX2 one. Set only where the processor has AVX2 and FMA: elsewhere the kernel would not run.
OPENBLAS_ENV = {"OPENBLAS_CORETYPE": "Haswell"}


def _has_avx2_fma() -> bool:
    try:
        with open("/proc/cpuinfo") as info:
            flags = next((line.split(":", 1)[1].split() for line in info if line.startswith("flags")), [])
    except OSError:
        return False
    return "avx2" in flags and "fma" in flags


def pin_cpu_numerics() -> None:
    for key, value in CPU_NUMERICS_ENV.items():
        os.environ.setdefault(key, value)
    if _has_avx2_fma():
        for key, value in OPENBLAS_ENV.items():
            os.environ.setdefault(key, value)


def deterministic_torch(threads: int) -> None:
    """A fixed thread count and torch's deterministic algorithms (warn where none exists)."""
    import torch

    torch.set_num_threads(int(threads))
    torch.use_deterministic_algorithms(True, warn_only=True)


# Thread pools sized by environment variables: OpenMP (torch, MKL, OpenBLAS, numexpr) and Mesa's
# llvmpipe, which renders with one thread per CPU unless told (read when a GL context is made).
THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS", "LP_NUM_THREADS")


def job_threads() -> int:
    """The CPU threads this process may use: what the workflow gave its job (Snakemake sets
    OMP_NUM_THREADS to the job's threads in every shell command, locally and on a cluster node),
    else every CPU the process may run on."""
    value = os.environ.get("OMP_NUM_THREADS", "")
    if value.isdigit() and int(value) >= 1:
        return int(value)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def limit_threads(threads: int | None = None) -> int:
    """Hold the process's thread pools to ``threads`` (default: :func:`job_threads`): the
    environment, for libraries that start later and for child processes, and the pools of
    OpenCV (which otherwise takes every CPU of the node) and of torch where it is loaded already.
    Rendering and the video encoder give the same bytes with any thread count; where torch's
    count changes numbers, the stage sets it itself (train: its job's threads, rollout: one)."""
    n = int(threads) if threads is not None else job_threads()
    if n < 1:
        raise ConfigError(f"threads must be >= 1, got {n}")
    for key in THREAD_ENV:
        # LP_NUM_THREADS=0 makes llvmpipe rasterise in the rendering thread itself: no extra thread.
        if not (key == "LP_NUM_THREADS" and os.environ.get(key) == "0"):
            os.environ[key] = str(n)
    import cv2  # a dependency, quick to load; its pool is set at run time only

    cv2.setNumThreads(n)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(n)
    return n
