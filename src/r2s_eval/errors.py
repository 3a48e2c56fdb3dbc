"""r2s-eval's errors: one base class for every fault a user can cause or fix.

A stage that fails with an ``R2SError`` failed for a reason its message explains (a damaged
dataset, a wrong config, a server that will not answer), so the stage runner prints that message
as one paragraph and keeps the traceback for the log file or ``--debug``. Any other exception is
a bug in r2s-eval and is shown with its traceback.

Each subclass also derives from the built-in exception callers used to catch before the
hierarchy existed (``ValueError``, ``RuntimeError``), so code written against those still works.
"""

from __future__ import annotations


class R2SError(Exception):
    """Base of r2s-eval's expected errors; the message names the file, episode, pair or key."""


class ConfigError(R2SError, ValueError):
    """A configuration value that is missing, unknown or out of range."""


class PolicyConfigError(ConfigError):
    """A candidate policy's config (trained here, a checkpoint or a server) that cannot be used."""


class DataError(R2SError, ValueError):
    """A dataset, index or artefact on disk that breaks its contract."""


class PolicyLoadError(R2SError, RuntimeError):
    """A policy that cannot be loaded, reached, or mapped onto the robot."""


class PolicyError(PolicyLoadError):
    """A policy that cannot be loaded, reached, or mapped onto the robot, or that returns actions the
    robot cannot take; the message names it.

    `slot`: the episode slot it concerns, when it concerns one (a batched call names the episode).
    """

    slot: int | None = None


class JudgeError(R2SError, RuntimeError):
    """A judge that cannot answer: its server failed past every retry, or its deadline passed."""


class EstimationError(R2SError, RuntimeError):
    """An initial-pose estimate that cannot be made from the given frame."""


class StatsError(R2SError, ValueError):
    """Comparisons from which no ranking can be computed."""


class StoreError(R2SError, RuntimeError):
    """The artefact store (DVC) refused an operation: its command and message say which and why."""
