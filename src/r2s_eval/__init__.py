"""r2s-eval: rank robot manipulation policies from their behaviour, via a calibrated simulator."""

__version__ = "0.1.0"
