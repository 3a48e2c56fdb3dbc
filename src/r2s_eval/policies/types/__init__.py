"""Policy types trained here, one module each, registered by name (`policy_type("act")`).

A new type is one new module here (a `PolicyType` subclass decorated with `@register`) and its
import below; nothing else in r2s-eval names a type.
"""

from r2s_eval.policies.types import act, diffusion, pi0, pi05, smolvla, xvla  # noqa: F401 (each registers itself)
from r2s_eval.policies.types.registry import (
    NOT_SUPPORTED_YET,
    TOP_LEVEL_DEFAULTS,
    PolicyType,
    loaded_type,
    policy_type,
    register,
    registered,
)

SUPPORTED_TYPES = registered()

__all__ = ["NOT_SUPPORTED_YET", "SUPPORTED_TYPES", "TOP_LEVEL_DEFAULTS", "PolicyType", "loaded_type",
           "policy_type", "register", "registered"]
