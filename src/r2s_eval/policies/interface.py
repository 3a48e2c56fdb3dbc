"""One interface for every candidate policy: in-process LeRobot, a checkpoint folder, a server.

A `ChunkPolicy` takes a batch of observations (one per episode slot) and returns a batch of
action chunks. It declares what it consumes (`PolicySpec`): the cameras, whether it reads the
joint state and the task instruction, how wide its actions are and how many it can predict per
call. Every policy is offered the same observation streams; each takes what its spec names.

The evaluation, not the checkpoint, owns the receding horizon: `RecedingHorizon` asks the
policy for a chunk, executes its first `horizon.execute` actions and asks again (`Horizon`,
built once from ``rollout.horizon``).

Observation dicts carry `observation.state` (float32, robot joint layout), the cameras as
`observation.images.<name>` (uint8 HxWx3) and `task` (the instruction text).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from r2s_eval.errors import PolicyError
from r2s_eval.horizon import Horizon

STATE_KEY = "observation.state"
TASK_KEY = "task"
IMAGE_PREFIX = "observation.images."




@dataclass(frozen=True)
class PolicySpec:
    cameras: tuple[str, ...]  # observation keys, e.g. "observation.images.head_left"
    action_dim: int  # width of the actions the policy returns
    max_chunk: int  # most actions one call can return
    uses_state: bool = True
    uses_task: bool = False
    state_dim: int | None = None  # width of the state it expects, when it reads one

    def to_dict(self) -> dict:
        return {**asdict(self), "cameras": list(self.cameras)}

    @classmethod
    def from_dict(cls, d: dict) -> PolicySpec:
        return cls(**{**d, "cameras": tuple(d["cameras"])})


class ChunkPolicy:
    """Base class: a batch of observations in, a batch of action chunks out.

    `slots` identify episodes that run side by side; a policy with per-episode state (an
    observation history, a seeded noise generator) keeps it per slot.
    """

    spec: PolicySpec
    name: str = "policy"
    # Rows of every model call, when fixed (slot `s` then sits in row `s % call_batch`, so callers
    # that run many episodes keep two in flight out of one row); None: as many as asked.
    call_batch: int | None = None

    def reset(self, slot: int, seed: int) -> None:
        """A new episode starts in `slot`."""

    # Whether `observe` needs every control step's observation (a policy conditioned on a
    # history of observations); otherwise a loop may show it only the observations it predicts
    # from, and render nothing in between.
    observes_every_step: bool = False

    def observe(self, slot: int, obs: dict) -> None:
        """A control step's observation (policies that condition on a history keep it): every
        step's when `observes_every_step`, else at least those it is asked to predict from."""

    def release(self, slot: int) -> None:
        """The slot's episode is over for good (a server's connection closed): drop its state."""

    def predict_chunks(self, slots: Sequence[int], observations: Sequence[dict]) -> np.ndarray:
        """Float32 array (len(slots), T, spec.action_dim), T <= spec.max_chunk."""
        raise NotImplementedError

    def close(self) -> None:
        """Release models, sockets, processes."""

    def metadata(self) -> dict:
        """What identifies this policy's behaviour (cached episodes are keyed by it)."""
        return {"name": self.name, "spec": self.spec.to_dict()}

    def select(self, obs: dict) -> dict:
        """The part of `obs` this policy consumes; missing or malformed streams are named."""
        keys = list(self.spec.cameras) + ([STATE_KEY] if self.spec.uses_state else [])
        missing = [k for k in keys if k not in obs]
        if missing:
            raise PolicyError(f"policy {self.name!r} needs {missing}; the world offers {sorted(k for k in obs if k != TASK_KEY)}")
        out = {}
        for key in self.spec.cameras:
            img = np.asarray(obs[key])
            if img.ndim != 3 or img.shape[-1] != 3 or img.dtype != np.uint8:
                raise PolicyError(f"policy {self.name!r}: observation {key!r} must be uint8 HxWx3, got {img.dtype} {img.shape}")
            out[key] = img
        if self.spec.uses_state:
            state = np.asarray(obs[STATE_KEY], dtype=np.float32)
            if self.spec.state_dim is not None and state.shape != (self.spec.state_dim,):
                raise PolicyError(f"policy {self.name!r} expects a {self.spec.state_dim}-D state, got {state.shape}")
            out[STATE_KEY] = state
        if self.spec.uses_task:
            out[TASK_KEY] = str(obs.get(TASK_KEY, ""))
        return out


@dataclass(frozen=True)
class ActionMap:
    """Where each of the policy's action dimensions goes in the robot's action vector.

    `robot_indices[i]` is the robot dimension that policy output `i` drives; robot dimensions no
    output drives hold their current joint position (read from the state).
    """

    robot_dim: int
    robot_indices: tuple[int, ...] | None = None  # None: identity (widths must match)

    def check(self, policy: ChunkPolicy) -> None:
        width = policy.spec.action_dim
        if self.robot_indices is None:
            if width != self.robot_dim:
                raise PolicyError(
                    f"policy {policy.name!r} returns {width}-D actions, the robot takes {self.robot_dim}-D; "
                    f"give an action map (robot index per policy output)"
                )
            return
        idx = self.robot_indices
        if len(idx) != width:
            raise PolicyError(f"policy {policy.name!r}: action map lists {len(idx)} indices for {width}-D actions")
        if len(set(idx)) != len(idx) or min(idx) < 0 or max(idx) >= self.robot_dim:
            raise PolicyError(f"policy {policy.name!r}: action map {list(idx)} must name distinct robot indices < {self.robot_dim}")
        if not policy.spec.uses_state:
            raise PolicyError(f"policy {policy.name!r}: a partial action map holds unmapped joints at the state, which it does not read")

    def to_robot(self, chunk: np.ndarray, state: np.ndarray) -> np.ndarray:
        if self.robot_indices is None:
            return chunk
        out = np.repeat(np.asarray(state, dtype=np.float32)[None, : self.robot_dim], len(chunk), axis=0)
        out[:, list(self.robot_indices)] = chunk
        return out


@dataclass
class EpisodeStats:
    steps: int = 0
    model_calls: int = 0
    inference_s: float = 0.0
    chunk_times_s: list[float] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {
            "steps": self.steps,
            "model_calls": self.model_calls,
            "inference_s": self.inference_s,
            "mean_chunk_s": self.inference_s / self.model_calls if self.model_calls else 0.0,
        }


class RecedingHorizon:
    """Closed-loop stepping of one episode slot: query a chunk, execute `horizon.execute`, repeat.

    `act(obs)` returns one robot action; the model is called only when the queue is empty.
    """

    def __init__(self, policy: ChunkPolicy, horizon: Horizon,
                 action_map: ActionMap | None = None, slot: int = 0, seed: int = 0):
        horizon.check(policy.spec.max_chunk, f"policy {policy.name!r}")
        self.policy = policy
        self.horizon = horizon
        self.action_map = action_map or ActionMap(policy.spec.action_dim)
        self.action_map.check(policy)
        self.slot = slot
        self.seed = int(seed)
        self.total_model_calls = 0
        self.total_inference_s = 0.0
        self.reset()

    @property
    def image_keys(self) -> list[str]:
        return list(self.policy.spec.cameras)

    def reset(self, seed: int | None = None) -> None:
        if seed is not None:
            self.seed = int(seed)
        self._queue: deque[np.ndarray] = deque()
        self.last_chunk: np.ndarray | None = None
        self._stats = EpisodeStats()
        self.policy.reset(self.slot, self.seed)

    @property
    def stats(self) -> dict:
        return self._stats.as_dict()

    @property
    def chunk_times_s(self) -> list[float]:
        return self._stats.chunk_times_s

    @property
    def model_calls(self) -> int:
        return self._stats.model_calls

    def needs_chunk(self) -> bool:
        return not self._queue

    def take_chunk(self, chunk: np.ndarray, state: np.ndarray, elapsed_s: float) -> None:
        """Queue the first `horizon.execute` of a chunk predicted for this slot (batched callers)."""
        chunk = np.asarray(chunk, dtype=np.float32)
        use = self.horizon.chunk
        if chunk.ndim != 2 or chunk.shape[0] < use or chunk.shape[1] != self.policy.spec.action_dim:
            raise PolicyError(
                f"policy {self.policy.name!r} returned a chunk of shape {chunk.shape}, expected at least "
                f"({use}, {self.policy.spec.action_dim})"
            )
        if not np.isfinite(chunk).all():
            raise PolicyError(f"policy {self.policy.name!r} returned non-finite actions")
        chunk = self.action_map.to_robot(chunk[:use], state)
        self.last_chunk = chunk
        self._queue.extend(chunk[: self.horizon.execute])
        self._stats.model_calls += 1
        self._stats.inference_s += elapsed_s
        self._stats.chunk_times_s.append(elapsed_s)
        self.total_model_calls += 1
        self.total_inference_s += elapsed_s

    def pop_action(self) -> np.ndarray:
        self._stats.steps += 1
        return self._queue.popleft().copy()

    def act(self, obs: dict) -> np.ndarray:
        self.policy.observe(self.slot, obs)
        if self.needs_chunk():
            t0 = time.perf_counter()
            chunk = self.policy.predict_chunks([self.slot], [self.policy.select(obs)])
            self.take_chunk(np.asarray(chunk)[0], obs.get(STATE_KEY, ()), time.perf_counter() - t0)
        return self.pop_action()
