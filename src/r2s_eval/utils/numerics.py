"""Pin what makes CPU numerics differ between machines of the same kind.

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

CPU_NUMERICS_ENV = {
    "ATEN_CPU_CAPABILITY": "avx2",  # ATen's vectorised kernels
    "ONEDNN_MAX_CPU_ISA": "AVX2",  # oneDNN convolutions / matmuls
    "MKL_CBWR": "AVX2",  # MKL's conditional numerical reproducibility
    "MKL_ENABLE_INSTRUCTIONS": "AVX2",
    # NumPy's runtime dispatch: every AVX-512 target it may pick (names it does not know are ignored).
    "NPY_DISABLE_CPU_FEATURES": "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL "
                                "AVX512_ICL AVX512_SPR",
}


def pin_cpu_numerics() -> None:
    for key, value in CPU_NUMERICS_ENV.items():
        os.environ.setdefault(key, value)


def deterministic_torch(threads: int) -> None:
    """A fixed thread count and torch's deterministic algorithms (warn where none exists)."""
    import torch

    torch.set_num_threads(int(threads))
    torch.use_deterministic_algorithms(True, warn_only=True)
