"""r2s-eval: rank robot manipulation policies from their behaviour, via a calibrated simulator."""

import os

# Headless rendering unless the user chose a GL backend; must precede any mujoco import.
os.environ.setdefault("MUJOCO_GL", "egl")

from r2s_eval.utils.numerics import pin_cpu_numerics  # noqa: E402
from r2s_eval.utils.package_index import fast_package_index  # noqa: E402

# Same bytes on every machine of a kind: before torch, oneDNN or MKL initialise.
pin_cpu_numerics()
# Before lerobot imports transformers and diffusers, which map every installed file at import.
fast_package_index()

__version__ = "0.1.0"
