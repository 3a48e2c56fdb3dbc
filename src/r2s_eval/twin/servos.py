"""The twin's servos as a lab's robot answers: late, with play, and with a gripper that gives.

``RealityEnv`` (``r2s_eval.twin.reality``) actuates through them; each is a ``RealityEffects``
field, off at its nominal value (a twin with all of them off steps the simulated servos' bytes).

- Latency, ``latency_s``: each command reaches the servos this long after it was sent (camera,
  bus and processing delays), in seconds, so it may arrive mid control period: the period's
  physics steps are split where it arrives (``LatePipeline``), on whole physics steps. Until the
  first command arrives the servos hold their reset targets. The calibrated sim's answer is a
  whole number of control steps (``WorldParams.command_latency_steps``). Reference: LeRobot's
  Koch arm at 30 fps logs a 33 ms camera read and 1-6 ms bus reads and writes; with the policy's
  own inference a lab's loop answers some 0.1-0.2 s late, one to two control steps at 10 Hz.
- Backlash, ``backlash_rad``: each arm joint's free play, a dead band the command must leave
  before the joint's target follows, then trailing the command by half the band (``Backlash``).
  Reference: hobby servos such as the STS3215 have about 1 deg of free play.
- Gripper strength, ``gripper_strength_scale``: x the gripper servos' stiffness and force limit
  (``weaken_gripper``): the jaws close on an object with less force, so a held object slips
  sooner, and open further when it pulls or pushes on them. Reference: LeRobot's SO-100/SO-101
  follower caps its gripper servo at 50 % of its maximum torque against burnout.
"""

from __future__ import annotations

from collections import deque

import mujoco
import numpy as np

from r2s_eval.sim.robot import Robot


class LatePipeline:
    """Commands on their way to the servos, ``delay_substeps`` physics steps late.

    With ``n_substeps`` physics steps per control period the delay is ``q`` whole periods and
    ``r`` physics steps: in the period a command is sent, the command sent ``q`` periods earlier
    arrives after ``r`` physics steps (at once when ``r`` is 0); the one before it holds until
    then."""

    def __init__(self, delay_substeps: int, n_substeps: int):
        self.periods, self.arrival_substep = divmod(int(delay_substeps), int(n_substeps))
        self._sent: deque[np.ndarray] = deque()

    def clear(self) -> None:
        self._sent.clear()  # a command of the last episode never arrives in this one

    def send(self, command: np.ndarray) -> np.ndarray | None:
        """Send ``command``; the command that arrives in this period (None before the first)."""
        self._sent.append(command)
        if len(self._sent) <= self.periods:
            return None
        while len(self._sent) > self.periods + 1:
            self._sent.popleft()
        return self._sent[0]


def delay_substeps(latency_s: float, timestep_s: float) -> int:
    """``latency_s`` in whole physics steps (the nearest; the command can only change between them)."""
    return int(round(float(latency_s) / float(timestep_s)))


class Backlash:
    """Each arm joint's play: per arm, the joint targets past their dead band of ``band_rad``."""

    def __init__(self, band_rad: float):
        self.half_band_rad = 0.5 * float(band_rad)
        self._targets: dict[str, np.ndarray] = {}

    def reset(self, targets: dict[str, np.ndarray]) -> None:
        """The play taken up around ``targets`` (per arm, the servos' targets at reset)."""
        self._targets = {arm: np.array(q, dtype=float) for arm, q in targets.items()}

    def through(self, arm: str, command: np.ndarray) -> np.ndarray:
        """The arm's joint targets once ``command`` has moved through the play.

        A gear train's free play: the output is dragged only once the command has taken up the
        play on one side, and then trails the command by half the band; a reversal within the
        band leaves the joint where it is."""
        target = np.clip(self._targets[arm], command - self.half_band_rad, command + self.half_band_rad)
        self._targets[arm] = target
        return target.copy()


def weaken_gripper(model: mujoco.MjModel, robot: Robot, strength_scale: float) -> None:
    """Scale the gripper servos' stiffness (kp) and force limit of ``model`` by ``strength_scale``:
    a softer position spring with a lower force limit; the arm servos stay as they are."""
    if strength_scale == 1.0:
        return
    for arm in robot.arms.values():
        for actuator in (arm.gripper.actuator, *(finger.actuator for finger in arm.gripper.fingers)):
            act = model.actuator(arm.named(actuator)).id
            model.actuator_gainprm[act, 0] *= strength_scale
            model.actuator_biasprm[act, 1] *= strength_scale
            model.actuator_forcerange[act] *= strength_scale
