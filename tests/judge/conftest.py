"""Rollouts for judge tests: synthetic trajectories with known smoothness, pauses, progress and
force, and real simulator episodes of the scripted operator (clean, jittered, gripper held open)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

DT = 0.1


def _min_jerk(phase: np.ndarray) -> np.ndarray:
    return 10 * phase**3 - 15 * phase**4 + 6 * phase**5


def make_trajectory(
    path: Path,
    *,
    steps: int = 80,
    noise: float = 0.0,
    stall_at: float | None = None,
    pauses: int = 0,
    peak_force: float = 5.0,
    spikes: int = 0,
    reach: float = 1.0,
    offset: float = 0.0,
    seed: int = 0,
) -> Path:
    """Write one trajectory parquet following the rollout stage's contract.

    noise: std of white noise on joints (rad), end effectors (m/100) and actions -> jerk/jitter.
    stall_at: the motion freezes at this phase (progress stalls below 1).
    pauses: number of mid-task stop-and-go pauses of 6 steps each.
    peak_force / spikes: smooth contact force level and number of one-step force spikes.
    reach: final phase reached (< 1 -> incomplete; 0 -> never moves).
    offset: shift of the start configuration (rad), to make otherwise equal rollouts differ.
    """
    rng = np.random.default_rng(seed)
    move_steps = steps - 10  # rest at the end
    rate = np.ones(steps)
    rate[move_steps:] = 0.0
    for k in range(pauses):  # idle windows spread over the motion
        s0 = int((k + 1) * move_steps / (pauses + 1))
        rate[s0:s0 + 6] = 0.0
    phase = np.concatenate([[0.0], np.cumsum(rate[1:])])
    phase = phase / max(phase.max(), 1e-9) * reach
    if stall_at is not None:
        phase = np.minimum(phase, stall_at)
    s = _min_jerk(np.clip(phase, 0, 1))

    q0, q1 = np.full(14, offset), np.linspace(0.3, 1.2, 14)
    state = q0 + np.outer(s, q1 - q0)
    action = np.vstack([state[1:], state[-1:]])  # commands lead the state by one step
    ee_l = np.array([0.3, 0.2, 0.1]) + np.outer(s, [0.2, -0.1, 0.15])
    ee_r = np.array([0.3, -0.2, 0.1]) + np.outer(s, [0.2, 0.1, 0.15])
    if noise:
        state = state + rng.normal(0, noise, state.shape)
        action = action + rng.normal(0, noise, action.shape)
        ee_l = ee_l + rng.normal(0, noise / 100 * 10, ee_l.shape)
        ee_r = ee_r + rng.normal(0, noise / 100 * 10, ee_r.shape)
    progress = np.floor(s * 4 + 1e-9) / 4  # staged progress: 0, .25, .5, .75, 1
    force = np.where(s > 0.5, peak_force * np.clip((s - 0.5) * 4, 0, 1), 0.0)
    for k in range(spikes):
        force[int(steps * (0.4 + 0.1 * k))] += 60.0

    def lists(a: np.ndarray) -> pa.Array:
        return pa.array(a.tolist(), type=pa.list_(pa.float64()))

    table = pa.table({
        "step": np.arange(steps),
        "time_s": np.arange(steps) * DT,
        "state": lists(state),
        "action": lists(action),
        "ee_pos_left": lists(ee_l),
        "ee_pos_right": lists(ee_r),
        "contact_force_n": force,
        "progress": progress,
        "obj_pos.cube": lists(np.outer(s, [0.1, 0.0, 0.05])),
        "obj_quat.cube": lists(np.tile([1.0, 0.0, 0.0, 0.0], (steps, 1))),
    })
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path)
    return path


def make_episode_table(root: Path, specs: list[dict]) -> pd.DataFrame:
    """Episode table + files under `root`; each spec: policy, task, init_id, traj kwargs (dict).

    File and folder names deliberately spell out the policy and the outcome, as a careless
    rollout writer might, so tests can check that none of it reaches a judge.
    """
    rows = []
    for n, sp in enumerate(specs):
        policy, task, init = sp["policy"], sp.get("task", "lift"), sp.get("init_id", 0)
        outcome = "SUCCESS" if sp.get("success", True) else "FAILURE"
        stem = f"{policy}/{task}_{init}_{outcome}_{n}"
        traj_kw = {"offset": 1e-3 * n, **sp.get("traj", {})}  # distinct content per episode
        traj = make_trajectory(root / f"{stem}.parquet", seed=n, **traj_kw)
        video = root / f"{stem}.mp4"
        video.write_bytes(b"fake video " + str(n).encode())
        rows.append({
            "episode_id": f"ep{n:04d}",
            "policy": policy,
            "arm": "sim",
            "task": task,
            "instruction": f"pick up the cube ({task})",
            "init_id": init,
            "seed": 1000 + n,
            "success": sp.get("success", True),
            "length": pq.read_metadata(traj).num_rows,
            "video_path": str(video.relative_to(root)),
            "trajectory_path": str(traj.relative_to(root)),
        })
    return pd.DataFrame(rows)


@pytest.fixture
def traj_factory(tmp_path):
    counter = iter(range(10**6))

    def make(**kw) -> Path:
        return make_trajectory(tmp_path / "traj" / f"t{next(counter)}.parquet", **kw)

    return make


@pytest.fixture
def episode_table():
    return make_episode_table


class ChangedOperator:
    """The scripted operator (``tests.helpers.policies.OperatorPolicy``) with its commands changed:
    `jitter_rad` Gaussian noise on every arm-joint command (as the planted ``action_noise_std``
    variant adds), `open_gripper`, grippers held open (the arm moves as smoothly, the cup is
    never grasped: a smooth failure), or `hesitate` (every_steps, pause_steps), the planted
    variant's stops and restarts (``r2s_eval.policies.execution``)."""

    def __init__(self, env, jitter_rad: float = 0.0, open_gripper: bool = False, seed: int = 0,
                 hesitate: tuple[int, int] | None = None):
        from r2s_eval.policies.execution import Execution
        from tests.helpers.policies import OperatorPolicy
        from tests.helpers.worlds import bundled_robot

        self.base, self.jitter_rad, self.open_gripper, self.seed = OperatorPolicy(env), jitter_rad, open_gripper, seed
        features = bundled_robot().features
        self.joints = [i for i, f in enumerate(features) if f.joint is not None]
        self.grippers = [i for i, f in enumerate(features) if f.joint is None]
        self.execution = None if hesitate is None else Execution.from_config(
            {"hesitate": {"every_steps": hesitate[0], "pause_steps": hesitate[1]}}, self.joints, self.grippers)

    def reset(self):
        self.base.reset()
        self.rng = np.random.default_rng(self.seed)
        self.commands = None if self.execution is None else self.execution.start(self.seed)

    def act(self, obs):
        def operator() -> np.ndarray:
            return np.array(self.base.act(obs), dtype=float)

        action = operator() if self.commands is None else self.commands.next(operator)
        action[self.joints] += self.rng.normal(0.0, self.jitter_rad, len(self.joints)) if self.jitter_rad else 0.0
        if self.open_gripper:
            action[self.grippers] = 0.0
        return action


OPERATOR_RUNS = {"clean": {}, "jittery": {"jitter_rad": 0.01}, "open_gripper": {"open_gripper": True},
                 "open_gripper_jittery": {"jitter_rad": 0.01, "open_gripper": True},
                 "hesitant": {"hesitate": (10, 3)}}


@pytest.fixture(scope="session")
def operator_runs(tmp_path_factory) -> dict[str, dict]:
    """Real simulator episodes of cup_on_plate from the same initial poses (as
    ``tests.helpers.videos.render_sim_episodes`` renders them: 128 px head_left, 10 fps): the
    scripted operator (``clean``, succeeds), the same with jittered arm commands (``jittery``,
    succeeds), with its grippers held open (``open_gripper``, fails smoothly), both
    (``open_gripper_jittery``, fails as far, shaking) and holding its command 3 control steps in
    every 13 (``hesitant``, as the validation line-up's act_hesitant). Per name:
    ``instruction``, ``video_path`` (a frame per control step), ``video_5fps_path`` (every second
    frame, as the rollout stage records at its default ``video_fps: 5``), ``trajectory_path`` and
    the episode's ``success``."""
    from r2s_eval.rollout import run_episode
    from r2s_eval.rollout.mp4 import write_video

    from tests.helpers.videos import SIM_TASK
    from tests.helpers.worlds import bundled_env

    root = tmp_path_factory.mktemp("operator_runs")
    env = bundled_env(SIM_TASK, image_size=(128, 128), cameras=("head_left",))
    runs = {}
    try:
        poses = env.sample_initial_poses(np.random.default_rng(4))
        for name, change in OPERATOR_RUNS.items():
            policy = ChangedOperator(env, **change)
            policy.reset()
            result = run_episode(env, policy, poses, seed=1, max_steps=120, video_camera="head_left")
            write_video(root / f"{name}.mp4", result.frames, fps=10)
            write_video(root / f"{name}_5fps.mp4", result.frames[::2], fps=5)
            result.trajectory.to_parquet(root / f"{name}.parquet")
            runs[name] = {"instruction": env.task.instruction, "video_path": root / f"{name}.mp4",
                          "video_5fps_path": root / f"{name}_5fps.mp4", "trajectory_path": root / f"{name}.parquet",
                          "success": bool(result.success)}
    finally:
        env.close()
    return runs
