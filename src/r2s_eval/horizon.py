"""The evaluation's receding horizon, built once from the config and handed to every loop.

Every query asks the policy for a chunk, uses its first `chunk` actions and executes the first
`execute` of them before asking again. The config owns the
values (``rollout.horizon.chunk`` / ``rollout.horizon.execute`` in conf/rollout/default.yaml);
what a policy can predict per call (its ``max_chunk``, a trained policy's ``chunk_size``) is the
policy's own, and `Horizon.check` is the one place the two are held against each other.

This module imports nothing but the error family: the config schema, the policy interface and
the LIBERO launcher all read it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from r2s_eval.errors import ConfigError


@dataclass(frozen=True)
class Horizon:
    """Per query: use the first `chunk` predicted actions, execute the first `execute`."""

    chunk: int
    execute: int

    @classmethod
    def from_config(cls, horizon: Mapping) -> Horizon:
        """From the ``rollout.horizon`` config slice (``{"chunk": ..., "execute": ...}``)."""
        return cls(chunk=int(horizon["chunk"]), execute=int(horizon["execute"]))

    def check(self, max_chunk: int | None, policy: str = "the policy") -> None:
        """Raise ConfigError unless 1 <= execute <= chunk <= `max_chunk`, the most actions
        `policy` (its description, e.g. "policy 'act'") predicts per call; None: no policy is
        known yet, only 1 <= execute <= chunk is checked."""
        bound = self.chunk if max_chunk is None else max_chunk
        if not 1 <= self.execute <= self.chunk <= bound:
            rule = (f"the receding horizon needs 1 <= rollout.horizon.execute ({self.execute}) "
                    f"<= rollout.horizon.chunk ({self.chunk})")
            if max_chunk is not None:
                rule += f" <= {max_chunk}, the most actions {policy} predicts per call"
            raise ConfigError(rule)

    def to_dict(self) -> dict:
        """The config slice this horizon was built from (what a LIBERO job carries)."""
        return {"chunk": self.chunk, "execute": self.execute}
