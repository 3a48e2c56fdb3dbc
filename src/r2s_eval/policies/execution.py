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
    fumble               {after_steps: K, open_steps: N, opening: s}: once per episode and gripper,
                         after the policy has commanded that gripper closed (closing >= half its
                         range) for K commands in a row, it is commanded s of its range more open
                         (s in (0, 1], default 1: fully open) for the next N commands, then gets the
                         policy's again: it lets go of what it grasped and closes on it again
    overshoot            F in [0, 1): the arm-joint commands go through an underdamped servo whose
                         step response overshoots its target by the fraction F at the third
                         command after a step and rings back (a badly tuned position loop)

Counts of steps are of the policy's commands: a hesitation's pause holds what was last sent.

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
DEFAULTS = {"action_noise_std": 0.0, "hesitate": None, "gripper_delay_steps": 0, "lowpass": 0.0, "fumble": None,
            "overshoot": 0.0}
HESITATE_KEYS = ("every_steps", "pause_steps")
FUMBLE_KEYS = ("after_steps", "open_steps")  # and optionally `opening`
# A gripper command at or past this share of the way from open to closed counts as closed.
CLOSED_AT = 0.5
# The overshooting servo peaks at this command after a step of its target (each command is where
# it is one control step on): slow enough that the sent commands show the swing (a peak after one
# step would alternate around the target, a blur), fast enough that the arm still follows the
# policy's motion; a whole number of steps puts a command on the peak, so the sent peak is F exactly.
OVERSHOOT_PEAK_STEPS = 3
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
    if out["fumble"] is not None:
        out["fumble"] = _fumble(out["fumble"], who)
    if not 0 <= float(out["overshoot"]) < 1:
        raise PolicyConfigError(f"{who}.execution.overshoot must be in [0, 1), got {out['overshoot']!r}")
    out["action_noise_std"], out["lowpass"] = float(out["action_noise_std"]), float(out["lowpass"])
    out["overshoot"] = float(out["overshoot"])
    out["gripper_delay_steps"] = int(out["gripper_delay_steps"])
    if out == DEFAULTS:
        raise PolicyConfigError(f"{who}.execution changes nothing: set at least one of {sorted(DEFAULTS)}")
    return out


def _fumble(cfg, who: str) -> dict:
    """A checked ``fumble`` entry: whole counts >= 1, ``opening`` in (0, 1] (1.0 where left out)."""
    bad = PolicyConfigError(f"{who}.execution.fumble must be {{after_steps: K, open_steps: N}} (and optionally "
                            f"opening: s) with whole K, N >= 1 and s in (0, 1], got {cfg!r}")
    try:
        fumble = {"opening": 1.0, **dict(cfg)}
        counts = [fumble[k] for k in FUMBLE_KEYS]
        whole = all(not isinstance(v, bool) and int(v) == v >= 1 for v in counts)
        opening = float(fumble["opening"])
    except (KeyError, TypeError, ValueError):
        raise bad from None
    if sorted(fumble) != sorted((*FUMBLE_KEYS, "opening")) or not whole or not 0 < opening <= 1:
        raise bad
    return {**{k: int(fumble[k]) for k in FUMBLE_KEYS}, "opening": opening}


def _servo_step(overshoot: float) -> np.ndarray:
    """The overshooting servo's exact one-control-step update, as coefficients of its error to the
    target e and rate v: (e, v) -> (c[0] e + c[1] v, c[2] e + c[3] v). Exact for a target held over
    the step, so it is stable at any frequency (the update's eigenvalues have modulus exp(-zeta wn) < 1)."""
    log_f = np.log(overshoot)
    zeta = -log_f / np.sqrt(np.pi ** 2 + log_f ** 2)  # the damping ratio whose step response overshoots by F
    wd = np.pi / OVERSHOOT_PEAK_STEPS  # the peak comes at pi / wd
    wn = wd / np.sqrt(1.0 - zeta ** 2)
    sigma, decay, cos, sin = zeta * wn, np.exp(-zeta * wn), np.cos(wd), np.sin(wd)
    # e(t) = exp(-sigma t) (e0 cos wd t + (v0 + sigma e0) / wd sin wd t) and its derivative, at t = 1.
    return decay * np.array([cos + sigma / wd * sin, sin / wd, -wn ** 2 / wd * sin, cos - sigma / wd * sin])


@dataclass(frozen=True)
class Execution:
    """One variant's execution change, bound to the robot's layout (which action dimensions are
    arm joints, which are grippers)."""

    action_noise_std: float
    hesitate: tuple[int, int] | None  # (every_steps, pause_steps)
    gripper_delay_steps: int
    lowpass: float
    fumble: tuple[int, int, float] | None  # (after_steps, open_steps, opening)
    overshoot: float
    joints: tuple[int, ...]
    grippers: tuple[int, ...]
    gripper_open: tuple[float, ...] = ()  # per gripper, its open and closed commands in the action's units
    gripper_closed: tuple[float, ...] = ()

    @classmethod
    def from_config(cls, cfg: Mapping, joints: Sequence[int], grippers: Sequence[int],
                    gripper_open: Sequence[float] = (), gripper_closed: Sequence[float] = ()) -> Execution:
        """``gripper_open``, ``gripper_closed``: per gripper, the commands (action units) that
        open and close it fully; a fumble needs them."""
        cfg = complete_execution(cfg, "execution")
        hesitate, fumble = cfg["hesitate"], cfg["fumble"]
        gripper_open, gripper_closed = tuple(float(v) for v in gripper_open), tuple(float(v) for v in gripper_closed)
        if fumble is not None and (len(gripper_open) != len(grippers) or len(gripper_closed) != len(grippers)
                                   or any(o == c for o, c in zip(gripper_open, gripper_closed))):
            raise PolicyConfigError(f"execution.fumble needs each gripper's distinct open and closed commands, got "
                                    f"{gripper_open} and {gripper_closed} for grippers {tuple(grippers)}")
        return cls(
            action_noise_std=cfg["action_noise_std"],
            hesitate=None if hesitate is None else (hesitate["every_steps"], hesitate["pause_steps"]),
            gripper_delay_steps=cfg["gripper_delay_steps"], lowpass=cfg["lowpass"],
            fumble=None if fumble is None else (fumble["after_steps"], fumble["open_steps"], fumble["opening"]),
            overshoot=cfg["overshoot"], joints=tuple(int(i) for i in joints), grippers=tuple(int(i) for i in grippers),
            gripper_open=gripper_open, gripper_closed=gripper_closed)

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
        # The overshooting servo: its one-step update and state (None until the first command).
        self._servo = None if not execution.overshoot else _servo_step(execution.overshoot)
        self._servo_state: tuple[np.ndarray, np.ndarray] | None = None  # (position, rate) per arm joint
        # Per gripper: commands closed in a row, open commands left to send, whether it has fumbled.
        n = len(execution.grippers)
        self._closed_run, self._open_left, self._fumbled = np.zeros(n, int), np.zeros(n, int), np.zeros(n, bool)

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
        if self._servo is not None and joints:
            action[joints] = self._overshoot(action[joints])
        if ex.action_noise_std and joints:
            action[joints] += self._rng.normal(0.0, ex.action_noise_std, len(joints))
        grippers = list(ex.grippers)
        if ex.fumble is not None and grippers:
            action[grippers] = self._fumble(action[grippers])
        if ex.gripper_delay_steps and grippers:
            self._grippers.append(action[grippers].copy())
            if len(self._grippers) > ex.gripper_delay_steps:
                action[grippers] = self._grippers.popleft()
            else:
                action[grippers] = self._grippers[0]
        self._sent = action.astype(popped.dtype)
        return self._sent.copy()

    def _overshoot(self, target: np.ndarray) -> np.ndarray:
        """The servo's position after one control step towards ``target``; it starts at rest on the
        first target, so the first command is the policy's."""
        if self._servo_state is None:
            self._servo_state = (target.copy(), np.zeros_like(target))
            return target
        position, rate = self._servo_state
        error = position - target
        c = self._servo
        error, rate = c[0] * error + c[1] * rate, c[2] * error + c[3] * rate
        self._servo_state = (target + error, rate)
        return target + error

    def _fumble(self, command: np.ndarray) -> np.ndarray:
        """The gripper commands after the fumble: a gripper that has fumbled, or has not been closed
        long enough, gets the policy's command."""
        ex = self.execution
        after, open_steps, opening = ex.fumble
        opened, closed = np.array(ex.gripper_open), np.array(ex.gripper_closed)
        closing = (command - opened) / (closed - opened)  # 0 open, 1 closed, whatever the units' sign
        out = command.copy()
        for g in range(len(command)):
            if self._open_left[g]:
                # `opening` of the range more open than the policy's command, never past fully open.
                out[g] = opened[g] + max(0.0, min(closing[g], 1.0) - opening) * (closed[g] - opened[g])
                self._open_left[g] -= 1
            elif not self._fumbled[g]:
                self._closed_run[g] = self._closed_run[g] + 1 if closing[g] >= CLOSED_AT else 0
                if self._closed_run[g] == after:  # this command still goes out closed; the next N open
                    self._fumbled[g], self._open_left[g] = True, open_steps
        return out
