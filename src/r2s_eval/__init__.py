"""r2s-eval: rank robot manipulation policies from their behaviour, via a calibrated simulator."""

import os

# Headless rendering unless the user chose a GL backend; must precede any mujoco import.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
