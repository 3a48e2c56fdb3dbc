"""Planted quality: a candidate's commands changed on their way to the robot, weights untouched.

A *variant* (``policies.<name>: {type: variant, of: <candidate>, execution: {...}}``) runs
another candidate's checkpoint with one documented execution change, so "the clean run behaves
better" holds by construction while its success stays close: a control of what a judge sees
beyond success. The changes, any of which a variant may combine:

    action_noise_std     Gaussian noise added to every arm-joint command (jitter), in the
                         action's units (radians for the bundled worlds); grippers untouched
    hesitate             {every_steps: N, pause_steps: P}: after every N commands the robot holds
                         its last command for P control steps (stops and restarts); the policy's
                         queued actions wait, nothing is skipped
    gripper_delay_steps  every gripper command reaches the gripper k control steps late (a
                         lagging, late-closing gripper); until then it holds the first command
    lowpass              a in [0, 1): each arm-joint command is a * the last one sent + (1 - a) *
                         the policy's (sluggish, lagging motion)

Everything else is the base's: the weights, the receding horizon, the observations the policy
gets. The noise is drawn from the episode's own seed, so an episode's actions do not depend on
how many run beside it, and with every change switched off the commands are the policy's, bit
for bit. A judge never learns any of this: episode ids are opaque and the videos are the same
kind as every candidate's.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from r2s_eval.errors import PolicyConfigError

# An execution's keys and their values where a variant leaves them out (no change).
DEFAULTS = {"action_noise_std": 0.0, "hesitate": None, "gripper_delay_steps": 0, "lowpass": 0.0}
HESITATE_KEYS = ("every_steps", "pause_steps")
# Salt of the noise's generator, so it never repeats a draw the episode's other seeded parts make.
_NOISE_STREAM = 0x4A17


def complete_execution(cfg: Mapping | None, who: str) -> dict:
    """A completed copy of an ``execution`` entry; unknown keys, bad values and an execution that
    changes nothing are errors naming the key."""
    cfg = dict(cfg or {})
    unknown = sorted(set(cfg) - set(DEFAULTS))
    if unknown:
        raise PolicyConfigError(f"{who}.execution: unknown key(s) {unknown}; allowed: {sorted(DEFAULTS)}")
    out = {**DEFAULTS, **cfg}
    if not float(out["action_noise_std"]) >= 0:
        raise PolicyConfigError(f"{who}.execution.action_noise_std must be >= 0, got {out['action_noise_std']!r}")
    if int(out["gripper_delay_steps"]) < 0:
        raise PolicyConfigError(f"{who}.execution.gripper_delay_steps must be >= 0, got {out['gripper_delay_steps']!r}")
    if not 0 <= float(out["lowpass"]) < 1:
        raise PolicyConfigError(f"{who}.execution.lowpass must be in [0, 1), got {out['lowpass']!r}")
    if out["hesitate"] is not None:
        hesitate = dict(out["hesitate"])
        if sorted(hesitate) != sorted(HESITATE_KEYS) or min(int(v) for v in hesitate.values()) < 1:
            raise PolicyConfigError(f"{who}.execution.hesitate must be {{every_steps: N, pause_steps: P}} with "
                                    f"N, P >= 1, got {out['hesitate']!r}")
        out["hesitate"] = {k: int(hesitate[k]) for k in HESITATE_KEYS}
    out["action_noise_std"], out["lowpass"] = float(out["action_noise_std"]), float(out["lowpass"])
    out["gripper_delay_steps"] = int(out["gripper_delay_steps"])
    if out == DEFAULTS:
        raise PolicyConfigError(f"{who}.execution changes nothing: set at least one of {sorted(DEFAULTS)}")
    return out


@dataclass(frozen=True)
class Execution:
    """One variant's execution change, bound to the robot's layout (which action dimensions are
    arm joints, which are grippers)."""

    action_noise_std: float
    hesitate: tuple[int, int] | None  # (every_steps, pause_steps)
    gripper_delay_steps: int
    lowpass: float
    joints: tuple[int, ...]
    grippers: tuple[int, ...]

    @classmethod
    def from_config(cls, cfg: Mapping, joints: Sequence[int], grippers: Sequence[int]) -> Execution:
        cfg = complete_execution(cfg, "execution")
        hesitate = cfg["hesitate"]
        return cls(cfg["action_noise_std"], None if hesitate is None else (hesitate["every_steps"], hesitate["pause_steps"]),
                   cfg["gripper_delay_steps"], cfg["lowpass"], tuple(int(i) for i in joints), tuple(int(i) for i in grippers))

    def start(self, seed: int) -> ExecutedCommands:
        """The commands of one episode (``seed``: the episode's)."""
        return ExecutedCommands(self, seed)


class ExecutedCommands:
    """What one episode sends to the robot: `next(pop)` takes the policy's next action from
    ``pop`` (the receding horizon's queue) unless the robot is pausing, and changes it."""

    def __init__(self, execution: Execution, seed: int):
        self.execution = execution
        self._rng = np.random.default_rng([int(seed), _NOISE_STREAM])
        self._sent: np.ndarray | None = None
        self._filtered: np.ndarray | None = None
        self._grippers: deque[np.ndarray] = deque()
        self._taken = 0  # policy actions taken so far
        self._paused_after = 0  # the count of taken actions at which the last pause began
        self._pause_left = 0
        self.paused_steps = 0

    def next(self, pop: Callable[[], np.ndarray]) -> np.ndarray:
        ex = self.execution
        if ex.hesitate is not None and self._sent is not None:
            every, pause = ex.hesitate
            if not self._pause_left and self._taken % every == 0 and self._paused_after != self._taken:
                self._paused_after, self._pause_left = self._taken, pause
            if self._pause_left:
                self._pause_left -= 1
                self.paused_steps += 1
                return self._sent.copy()
        popped = pop()
        action = np.array(popped, dtype=np.float64)
        self._taken += 1
        joints = list(ex.joints)
        if ex.lowpass and joints:
            if self._filtered is not None:
                action[joints] = ex.lowpass * self._filtered + (1.0 - ex.lowpass) * action[joints]
            self._filtered = action[joints].copy()
        if ex.action_noise_std and joints:
            action[joints] += self._rng.normal(0.0, ex.action_noise_std, len(joints))
        if ex.gripper_delay_steps and ex.grippers:
            grippers = list(ex.grippers)
            self._grippers.append(action[grippers].copy())
            if len(self._grippers) > ex.gripper_delay_steps:
                action[grippers] = self._grippers.popleft()
            else:
                action[grippers] = self._grippers[0]
        self._sent = action.astype(popped.dtype)
        return self._sent.copy()
