"""The reality twin: the perturbed world that plays the physical robot, its scripted
operator and the truth it records.

Modules: ``perturb`` (``TwinMagnitudes``, seeded perturbation of ``WorldParams`` and the draw of
the reality effects), ``reality`` (``RealityEffects``, what the twin is beyond its world
parameters, and ``RealityEnv``, the environment with them around it), ``camera`` and ``servos``
(those effects: a lab camera's lens, exposure, blur and noise; late, loose and weak servos),
``scene`` (the room and the objects' true shapes built into the twin's model: a wooden table,
walls, shadows, things on the table, a mug's handle, rounded blocks),
``operator`` (the scripted teleoperator, differential IK with mink), ``primitives`` (its plan
primitives), ``failures`` (why an episode failed), ``record`` (the teleop dataset recorded in
the twin, with the true initial poses), ``board_take`` (the twin's ChArUco board take). This
package builds on ``r2s_eval.sim``; ``sim`` never imports it, so nothing on the simulation side
can read the twin's parameters or truth except through the artefacts the stages pass on.
"""

from r2s_eval.twin.perturb import TwinMagnitudes, sample_reality_effects, sample_twin_params, twin_world
from r2s_eval.twin.reality import RealityEffects, RealityEnv

__all__ = ["RealityEffects", "RealityEnv", "TwinMagnitudes", "sample_reality_effects", "sample_twin_params",
           "twin_world"]
