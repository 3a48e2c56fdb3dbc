"""Why a scripted episode failed: the phase the operator was in and what went wrong there.

While the operator works, ``EpisodeWatch`` looks at the scene as a person beside the robot would
(it reads the simulation, never steers it: the actions are the same with or without it). An
episode whose task check is false at its end is given the first thing that went wrong:

====================  ======================================================================
reason                seen (the detail says where and how far)
====================  ======================================================================
target_not_reached    a move that waits for the real hand (the approach) ended with it farther
                      than 1.5 cm from its target, or a move timed out: out of the arm's reach,
                      or blocked (e.g. jaws too narrow for the object, resting on its top)
closed_on_nothing     the gripper closed without both jaws on the object
slipped               the held object moved 3 cm from where it sat in the hand before the
                      release (with the hand's height above the table then)
joint_out_of_range    a joint of an arm (a finger) went past its range by more than 5 % of it
out_of_time           the episode's steps ran out before the plan's end
task_check_false      the plan ran to its end: the parts of the task's success condition that
                      are false, by their keys (``r2s_eval.sim.predicates.false_parts``)
====================  ======================================================================
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from r2s_eval.sim import assembly
from r2s_eval.sim.env import TabletopEnv
from r2s_eval.sim.predicates import centre_m, false_parts

REASONS = ("target_not_reached", "closed_on_nothing", "slipped", "joint_out_of_range", "out_of_time",
           "task_check_false")
MISSED_M = 0.015  # a move that ends with the real tcp farther than this from its target missed it
SLIP_M = 0.03  # a held object this far from where it sat in the hand (hand frame) has slipped
RANGE_TOLERANCE = 0.05  # beyond a joint's limits by more than this part of its range is out of it


@dataclass(frozen=True)
class Failure:
    phase: str  # the operator's phase (segment) when it went wrong: approach, close, lift, ...
    reason: str  # one of REASONS
    detail: str  # what was seen, one line

    def __str__(self) -> str:
        return f"{self.phase}: {self.detail}"

    def row(self) -> dict:
        return {"phase": self.phase, "reason": self.reason, "detail": self.detail}


def summary(failures: Iterable[Failure | dict | None]) -> str:
    """The failures counted by phase and reason, most frequent first ("2 close: closed_on_nothing, ...");
    empty when there are none. Takes ``Failure``s or their rows; None (a success) is skipped."""
    counts = Counter(f"{f['phase']}: {f['reason']}" if isinstance(f, dict) else f"{f.phase}: {f.reason}"
                     for f in failures if f is not None and (not isinstance(f, dict) or f.get("reason")))
    return ", ".join(f"{n} {what}" for what, n in counts.most_common())


class EpisodeWatch:
    """Watches one episode of the operator (commanding ``arm``, moving ``held``) for what goes wrong."""

    def __init__(self, env: TabletopEnv, arm: str, held: str):
        self.env, self.arm, self.held = env, arm, held
        self.events: list[Failure] = []
        self._in_hand: np.ndarray | None = None  # where the held object sits in the hand (hand frame)
        m = env.model
        self._joints = []  # (arm, joint name in the world file, qpos address, low, high) of every limited joint
        for name, arm_spec in env.robot.arms.items():
            root = m.body_rootid[m.site_bodyid[m.site(assembly.ee_site(name)).id]]
            prefix = arm_spec.named("")
            for j in range(m.njnt):
                if m.jnt_limited[j] and m.body_rootid[m.jnt_bodyid[j]] == root:
                    low, high = m.jnt_range[j]
                    self._joints.append((name, m.joint(j).name.removeprefix(prefix), int(m.jnt_qposadr[j]), low, high))
        self._out_of_range: set[tuple[str, str]] = set()  # (arm, joint) seen out of range, named once

    def _add(self, phase: str, reason: str, detail: str) -> None:
        self.events.append(Failure(phase, reason, detail))

    def step(self, phase: str) -> None:
        """Each control step: the joints within their ranges; a held object where it sat in the hand."""
        qpos = self.env.data.qpos
        for arm, joint, adr, low, high in self._joints:
            slack = RANGE_TOLERANCE * (high - low)
            if not low - slack <= qpos[adr] <= high + slack and (arm, joint) not in self._out_of_range:
                self._out_of_range.add((arm, joint))
                self._add(phase, "joint_out_of_range",
                          f"joint {joint} of arm {arm} reached {qpos[adr]:.3g}, range {low:.3g} to {high:.3g}")
        if self._in_hand is not None:
            moved = np.linalg.norm(self._hand_frame() - self._in_hand)
            if moved > SLIP_M:
                tcp_z = self.env.ee_positions()[self.arm][2] - self.env.table_top_z_m
                self._add(phase, "slipped", f"{self.held} slipped from the hand ({100 * moved:.1f} cm from where it "
                                            f"sat) with the hand {100 * tcp_z:.1f} cm above the table")
                self._in_hand = None

    def _hand_frame(self) -> np.ndarray:
        """The held object's centre in the hand's frame."""
        env = self.env
        return env.ee_rotations()[self.arm].T @ (centre_m(env, self.held) - env.ee_positions()[self.arm])

    def segment_started(self, name: str, gripper: float) -> None:
        if gripper < 1.0:  # opening: whatever it held it lets go
            self._in_hand = None

    def segment_ended(self, name: str, target_m: np.ndarray, gave_up: bool, check_reach: bool) -> None:
        """A segment ended: with ``check_reach`` (a move that waits for the real hand), whether the
        hand got to ``target_m``; after closing, whether the jaws hold the object."""
        tcp = self.env.ee_positions()[self.arm]
        miss = float(np.linalg.norm(tcp - target_m))
        if (gave_up or check_reach) and miss > MISSED_M:
            dz = tcp[2] - target_m[2]
            self._add(name, "target_not_reached",
                      f"{'timed out' if gave_up else 'stopped'} with the hand {100 * miss:.1f} cm from its target "
                      f"({100 * abs(dz):.1f} cm {'above' if dz > 0 else 'below'} it)")
        if name == "close":
            if self.env.grasped(self.held) is None:
                off = float(np.linalg.norm(tcp - centre_m(self.env, self.held)))
                self._add(name, "closed_on_nothing", f"the gripper closed without both jaws on {self.held} "
                                                     f"(its centre {100 * off:.1f} cm from the grasp centre)")
            else:
                self._in_hand = self._hand_frame()

    def failure(self, phase: str, plan_done: bool, steps: int) -> Failure | None:
        """Why the episode failed (None when its task check holds): the first thing that went wrong."""
        if self.env.is_success():
            return None
        if self.events:
            return self.events[0]
        if not plan_done:
            return Failure(phase, "out_of_time", f"the episode's {steps} steps ran out")
        task = self.env.task
        parts = false_parts(task.success_condition, self.env, f"tasks.{task.key}.success")
        return Failure(phase, "task_check_false", "the task check is false: " + "; ".join(parts))
