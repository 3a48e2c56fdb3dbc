"""Episodes of one candidate stepped side by side, one batched model call per query step.

`run_batched` keeps up to `batch_episodes` episodes in flight, one per *lane*. The lanes step in
lockstep; at each step, the lanes whose receding horizon has run out of actions ask for a chunk
together, in one `predict_chunks` call (one per instruction, for a policy that reads it). A lane
whose episode has ended takes the next one at the next query step (every `horizon.execute` steps),
so that the lanes keep querying at the same steps. Physics, rendering and video encoding run on
`threads` worker threads (MuJoCo releases the GIL while it steps and renders); a lane always runs
on the same worker, since a GL context belongs to the thread that made it.

An episode's bytes do not depend on how many run beside it: each is recorded by the same
`EpisodeRecorder` as the one-at-a-time `run_episode`, in an environment reset from its own
initial poses and seed, and asks the policy through its own slot, its index in the plan (what a
model call gives a slot is independent of the other slots: `r2s_eval.policies.lerobot_policy`).
Finished episodes are written as they finish (`on_finished`); an error stops the run, drops the
episodes in flight, and names the episode it concerns.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import mujoco

from r2s_eval.horizon import Horizon
from r2s_eval.policies.interface import (
    STATE_KEY,
    TASK_KEY,
    ChunkPolicy,
    PolicyError,
    RecedingHorizon,
)
from r2s_eval.policies.execution import ExecutedCommands, Execution
from r2s_eval.rollout.loop import EpisodeRecorder
from r2s_eval.sim import TabletopEnv

log = logging.getLogger("r2s_eval.rollout")


@dataclass(frozen=True)
class PlannedEpisode:
    slot: int  # its index in the plan: the policy slot it asks through
    task: str
    init_id: int
    seed: int
    episode_id: str
    object_poses: dict = field(repr=False)


class EnvPool:
    """The lanes' environments: one compiled model per task, shared by all its environments
    (MuJoCo only reads a model while stepping); one set of renderers per task and worker
    thread, shared by the environments that thread renders; one environment per lane, reused
    episode after episode (`TabletopEnv.reset` restores everything an episode reads) and
    replaced when the lane moves on to another task (an environment's MjData holds a 16 MB
    arena; with shared model and renderers a new one takes a few ms).

    `make_env(task, **shared)` builds an environment; `shared` holds the `renderers` to use and,
    once the task has one, its `model`."""

    def __init__(self, make_env: Callable[..., TabletopEnv]):
        self._make_env = make_env
        self._lock = threading.Lock()
        self._models: dict[str, mujoco.MjModel] = {}
        self._renderers: dict[tuple[int, str], dict] = {}
        self._envs: dict[int, TabletopEnv] = {}

    def get(self, lane: int, task: str) -> TabletopEnv:
        """The lane's environment for `task`; call it from the lane's worker thread."""
        env = self._envs.get(lane)
        if env is None or env.task.key != task:
            renderers = self._renderers.setdefault((threading.get_ident(), task), {})
            with self._lock:  # compiling a task's model once is worth the wait
                if task not in self._models:
                    env = self._make_env(task, renderers=renderers)
                    self._models[task] = env.model
                else:
                    env = self._make_env(task, model=self._models[task], renderers=renderers)
            self._envs[lane] = env
        return env

    def close_thread(self) -> None:
        """Close the renderers this thread made (a GL context is freed where it is current)."""
        for (thread, _), renderers in list(self._renderers.items()):
            if thread == threading.get_ident():
                for renderer in renderers.values():
                    renderer.close()
                renderers.clear()


class _Workers:
    """Runs one function per worker, each on its own thread (inline when there is one)."""

    def __init__(self, threads: int):
        self.n = max(1, int(threads))
        self._pools = [ThreadPoolExecutor(1, thread_name_prefix=f"rollout-{i}") for i in range(self.n)] if self.n > 1 else []

    def run(self, fn: Callable[[int], None]) -> None:
        if not self._pools:
            fn(0)
            return
        futures = [pool.submit(fn, i) for i, pool in enumerate(self._pools)]
        errors = [f.exception() for f in futures]  # wait for all before raising
        for err in errors:
            if err is not None:
                raise err

    def close(self) -> None:
        for pool in self._pools:
            pool.shutdown()


class _Lane:
    """One episode in flight: `planned` once assigned, `episode` once its world is reset."""

    def __init__(self, index: int):
        self.index = index
        self.planned: PlannedEpisode | None = None
        self.episode: EpisodeRecorder | None = None
        self.runner: RecedingHorizon | None = None
        self.commands: ExecutedCommands | None = None  # a variant's execution change
        self.sink = None  # what the episode's frames go to (its video writer)
        self.finished = False


def _where(arm: str, planned: Sequence[PlannedEpisode]) -> str:
    episodes = ", ".join(f"task {p.task}, init {p.init_id}" for p in planned)
    return f"[{arm} rollout, {episodes}]" if len(planned) == 1 else f"[{arm} rollout, one model call for: {episodes}]"


def _named(exc: BaseException, planned: Sequence[PlannedEpisode], arm: str) -> BaseException:
    """`exc` naming the episode(s) it concerns: in a PolicyError's message, as the one-at-a-time
    loop always did; in a note on other errors."""
    where = _where(arm, planned)
    if isinstance(exc, PolicyError):
        named = PolicyError(f"{exc} {where}")
        named.slot = exc.slot
        named.__cause__ = exc
        return named
    exc.add_note(where)
    return exc


def run_batched(
    policy: ChunkPolicy,
    planned: Sequence[PlannedEpisode],
    envs: EnvPool,
    *,
    arm: str,
    horizon: Horizon,
    action_map,
    max_steps: int,
    video_camera: str,
    video_size: tuple[int, int] | None,
    open_episode: Callable[[PlannedEpisode], object],
    on_finished: Callable[[PlannedEpisode, EpisodeRecorder, dict, object], None],
    batch_episodes: int = 1,
    threads: int = 1,
    success_hold_steps: int = 3,
    frame_every: int = 1,
    execution: Execution | None = None,
) -> None:
    """Run every episode of `planned`, up to `batch_episodes` at a time.

    `open_episode(planned)` returns the sink the episode's frames go to (its `add(frame)` is
    called from a worker thread); `on_finished(planned, recorder, policy_stats, sink)` writes a
    finished episode (from a worker thread). `policy` is called from this thread only.
    `execution`: a variant's change of the commands on their way to the robot (None: none).
    """
    lanes = [_Lane(i) for i in range(max(1, int(batch_episodes)))]
    workers = _Workers(min(int(threads), len(lanes)))
    queue = list(planned)
    rows_per_call = policy.call_batch or len(lanes)

    def on_workers(fn: Callable[[_Lane], None]) -> None:
        def run(worker: int) -> None:
            for lane in lanes[worker :: workers.n]:
                if lane.planned is not None:
                    try:
                        fn(lane)
                    except BaseException as exc:
                        raise _named(exc, [lane.planned], arm)
        workers.run(run)

    def start(lane: _Lane) -> None:  # on the lane's worker
        if lane.episode is None:
            p = lane.planned
            lane.sink = open_episode(p)
            lane.episode = EpisodeRecorder(envs.get(lane.index, p.task), p.object_poses, p.seed, max_steps,
                                           video_camera, video_size, success_hold_steps, on_frame=lane.sink.add,
                                           frame_every=frame_every)

    def observe(lane: _Lane) -> None:  # on the lane's worker
        if policy_reads(lane):
            lane.episode.render_observation()

    def advance(lane: _Lane) -> None:  # on the lane's worker
        pop = lane.runner.pop_action
        lane.episode.step(pop() if lane.commands is None else lane.commands.next(pop))
        if lane.episode.done:
            on_finished(lane.planned, lane.episode, lane.runner.stats, lane.sink)
            lane.finished = True

    def assign() -> list[_Lane]:
        """Give free lanes the next episodes; prefer one whose row of the model call no episode
        in flight holds (a shared row costs a second call; results are the same either way)."""
        taken = {lane.planned.slot % rows_per_call for lane in lanes if lane.planned is not None}
        assigned = []
        for lane in lanes:
            if lane.planned is None and queue:
                pick = next((p for p in queue if p.slot % rows_per_call not in taken), queue[0])
                queue.remove(pick)
                taken.add(pick.slot % rows_per_call)
                lane.planned, lane.finished = pick, False
                assigned.append(lane)
        return assigned

    try:
        step = 0
        while queue or any(lane.planned is not None for lane in lanes):
            if step % horizon.execute == 0 and queue:
                assigned = assign()
                on_workers(start)
                for lane in assigned:
                    try:
                        lane.runner = RecedingHorizon(policy, horizon, action_map,
                                                      slot=lane.planned.slot, seed=lane.planned.seed)
                        lane.commands = None if execution is None else execution.start(lane.planned.seed)
                    except BaseException as exc:
                        raise _named(exc, [lane.planned], arm)
            active = [lane for lane in lanes if lane.planned is not None]
            on_workers(observe)  # renders belong to the lane's worker (its GL contexts)
            _query(policy, active, arm)
            on_workers(advance)
            for lane in active:
                if lane.finished:
                    policy.release(lane.planned.slot)
                    log.info("%s init %d: %s in %d steps", lane.planned.task, lane.planned.init_id,
                             "success" if lane.episode.success else "failure", len(lane.episode.rows))
                    lane.planned = lane.episode = lane.runner = lane.commands = lane.sink = None
            step += 1
    except BaseException:
        for lane in lanes:  # episodes in flight are dropped; finished ones are already written
            if lane.sink is not None and not lane.finished:
                lane.sink.abort()
        raise
    finally:
        workers.run(lambda worker: envs.close_thread())
        workers.close()


def policy_reads(lane: _Lane) -> bool:
    """Whether the policy reads the lane's observation at this step: to predict from it, or to
    keep it in a history."""
    return lane.runner.needs_chunk() or lane.runner.policy.observes_every_step


def _query(policy: ChunkPolicy, active: list[_Lane], arm: str) -> None:
    """Every lane observes; the lanes out of actions get a chunk, in one call per group."""
    groups: dict[str | None, list[tuple[_Lane, dict]]] = defaultdict(list)
    for lane in active:
        if not policy_reads(lane):
            continue  # nothing reads this step's images: they were never rendered
        needs_chunk = lane.runner.needs_chunk()
        obs = lane.episode.policy_obs
        try:
            policy.observe(lane.planned.slot, obs)
            if needs_chunk:
                # A policy that reads the instruction is asked per instruction: its text's
                # padding must not depend on the other episodes' texts.
                groups[obs[TASK_KEY] if policy.spec.uses_task else None].append((lane, policy.select(obs)))
        except BaseException as exc:
            raise _named(exc, [lane.planned], arm)
    for members in groups.values():
        t0 = time.perf_counter()
        try:
            chunks = policy.predict_chunks([lane.planned.slot for lane, _ in members], [obs for _, obs in members])
        except BaseException as exc:
            slot = getattr(exc, "slot", None)
            culprits = [lane.planned for lane, _ in members if lane.planned.slot == slot]
            raise _named(exc, culprits or [lane.planned for lane, _ in members], arm)
        share = (time.perf_counter() - t0) / len(members)  # each episode's part of the call
        for i, (lane, _) in enumerate(members):
            try:
                lane.runner.take_chunk(chunks[i], lane.episode.obs.get(STATE_KEY, ()), share)
            except BaseException as exc:
                raise _named(exc, [lane.planned], arm)
