"""The reality twin: the perturbed world that plays the physical robot, its scripted
operator and the truth it records.

Modules: ``perturb`` (``TwinMagnitudes``, seeded perturbation of ``WorldParams``),
``operator`` (the scripted teleoperator, differential IK with mink), ``primitives`` (its plan
primitives), ``failures`` (why an episode failed), ``record`` (the
teleop dataset recorded in the twin, with the true initial poses). This package builds on
``r2s_eval.sim``; ``sim`` never imports it, so nothing on the simulation side can read the
twin's parameters or truth except through the artefacts the stages pass on.
"""

from r2s_eval.twin.perturb import TwinMagnitudes, sample_twin_params, twin_world

__all__ = ["TwinMagnitudes", "sample_twin_params", "twin_world"]
