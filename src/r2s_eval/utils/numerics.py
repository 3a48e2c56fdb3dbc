"""Pin what makes CPU numerics differ between machines of the same kind.

torch, oneDNN and MKL choose kernels by the processor's instruction set, and kernels of
different vector widths add floats in different orders: the same seeded training then drifts
apart on an AVX-512 and an AVX2 machine. Capping every library at AVX2 (which both have) makes
them run the same kernels. The environment variables are read when each library first
initialises, so `pin_cpu_numerics()` must run before any tensor work: the package calls it on
import. A user who sets a variable keeps their value.
"""

from __future__ import annotations

import os

CPU_NUMERICS_ENV = {
    "ATEN_CPU_CAPABILITY": "avx2",  # ATen's vectorised kernels
    "ONEDNN_MAX_CPU_ISA": "AVX2",  # oneDNN convolutions / matmuls
    "MKL_CBWR": "AVX2",  # MKL's conditional numerical reproducibility
    "MKL_ENABLE_INSTRUCTIONS": "AVX2",
}


def pin_cpu_numerics() -> None:
    for key, value in CPU_NUMERICS_ENV.items():
        os.environ.setdefault(key, value)


def deterministic_torch(threads: int) -> None:
    """A fixed thread count and torch's deterministic algorithms (warn where none exists)."""
    import torch

    torch.set_num_threads(int(threads))
    torch.use_deterministic_algorithms(True, warn_only=True)
