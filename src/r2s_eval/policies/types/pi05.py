"""pi0.5: pi0's architecture and loading, its own lerobot config class and checkpoints."""

from __future__ import annotations

from r2s_eval.policies.types.registry import register
from r2s_eval.policies.types.pi0 import Pi0


@register
class Pi05(Pi0):
    name = "pi05"
