"""The LIBERO side of a LIBERO rollout: runs in LIBERO's own Python environment, never in ours.

    <libero-env>/bin/python libero_side.py JOB.json

LIBERO pins robosuite 1.4, which needs an older mujoco than our world, so this file imports
only the standard library, numpy, LIBERO and openpi-client. It steps LIBERO episodes and asks
the candidate policy for action chunks over the openpi websocket protocol (our policy server on
loopback, the way openpi runs its own LIBERO example). Everything about formats, videos and
episode tables stays on our side: each finished episode is one ``<episode_id>.npz`` in the job's
``out`` folder (written under a temporary name, then renamed), holding the judge video's frames
and the per-step records.

Rendering is what a LIBERO step costs, so with ``render: on_demand`` a frame is rendered only when
someone consumes it: the policy's cameras at its query steps, the judge camera at the video's
frame rate; multisampling and shadows are switched off before robosuite builds its render
context. ``render: default`` is the package's own behaviour (every camera, every step, default
quality), kept for the rendering benchmark.

A crash mid-episode writes ``failed.json`` (task, init index, traceback) and exits with status 1;
the episodes finished before it stay in ``out``. ``current.json`` names the running episode, for
a process that dies without a word.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time
import traceback
from pathlib import Path

import numpy as np

CONTROL_HZ = 20  # LIBERO's control frequency
SETTLE_ACTION = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]  # no motion, gripper open
RESET_KEY = "r2s_eval"  # our server's reset message (see r2s_eval.serving.policy_server)


def _fast_render_quality() -> None:
    """No multisampling, no shadow map: both are read when the render context is made."""
    from robosuite.utils import binding_utils

    make = binding_utils.MjRenderContext._set_mujoco_context_and_buffers
    if getattr(make, "_r2s_fast", False):
        return

    def set_buffers(self):
        self.model.vis.quality.offsamples = 0
        self.model.vis.quality.shadowsize = 0
        make(self)

    set_buffers._r2s_fast = True
    binding_utils.MjRenderContext._set_mujoco_context_and_buffers = set_buffers


def task_of(suite: str, index: int):
    from libero.libero import benchmark, get_libero_path

    suites = benchmark.get_benchmark_dict()
    if suite not in suites:
        raise ValueError(f"unknown LIBERO suite {suite!r}; valid: {sorted(suites)}")
    bench = suites[suite]()
    if not 0 <= index < bench.n_tasks:
        raise ValueError(f"{suite} has tasks 0..{bench.n_tasks - 1}, not {index}")
    task = bench.get_task(index)
    bddl = os.path.join(get_libero_path("bddl_files"), task.problem_folder, task.bddl_file)
    return task, bddl, bench.get_task_init_states(index)


def make_env(bddl: str, render: str, image_hw: tuple[int, int], cameras: list[str]):
    from libero.libero.envs import OffScreenRenderEnv

    if render == "on_demand":
        _fast_render_quality()
        return OffScreenRenderEnv(bddl_file_name=bddl, use_camera_obs=False,
                                  camera_heights=image_hw[0], camera_widths=image_hw[1])
    return OffScreenRenderEnv(bddl_file_name=bddl, camera_names=cameras,
                              camera_heights=image_hw[0], camera_widths=image_hw[1])


def robot_state(obs: dict) -> np.ndarray:
    """The 8-D state LIBERO policies read: end-effector position, axis-angle, gripper fingers."""
    from robosuite.utils.transform_utils import quat2axisangle

    quat = np.asarray(obs["robot0_eef_quat"], dtype=np.float64)
    if quat[3] > 1.0 - 1e-12:  # identity rotation: quat2axisangle divides by sin(0)
        axis_angle = np.zeros(3)
    else:
        axis_angle = quat2axisangle(quat.copy())
    return np.concatenate([obs["robot0_eef_pos"], axis_angle, obs["robot0_gripper_qpos"]]).astype(np.float32)


class Contacts:
    """Summed normal force of the contacts that touch the robot (gripper included), in N."""

    def __init__(self, sim):
        import mujoco

        self._mujoco = mujoco
        model = sim.model._model
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or "" for b in model.geom_bodyid]
        self.robot_geoms = {g for g, n in enumerate(names) if n.startswith(("robot0_", "gripper0_"))}
        self._force = np.zeros(6)

    def force_n(self, sim) -> float:
        model, data = sim.model._model, sim.data._data
        total = 0.0
        for i in range(data.ncon):
            con = data.contact[i]
            if con.geom1 in self.robot_geoms or con.geom2 in self.robot_geoms:
                self._mujoco.mj_contactForce(model, data, i, self._force)
                total += abs(float(self._force[0]))
        return total


class Cameras:
    """The images of one step: rendered on first request (on_demand) or read from the
    observation (default rendering). Images come out upright."""

    def __init__(self, env, render: str, obs: dict):
        self.env, self.render, self.obs, self._cache = env, render, obs, {}

    def image(self, camera: str, hw: tuple[int, int]) -> np.ndarray:
        key = (camera, hw)
        if key not in self._cache:
            if self.render == "default" and f"{camera}_image" in self.obs and self.obs[f"{camera}_image"].shape[:2] == hw:
                raw = self.obs[f"{camera}_image"]
            else:
                raw = self.env.sim.render(hw[1], hw[0], camera_name=camera)
            self._cache[key] = np.ascontiguousarray(raw[::-1])  # OpenGL rows run bottom-up
        return self._cache[key]


def policy_observation(cams: Cameras, job: dict, state: np.ndarray, instruction: str) -> dict:
    obs = {"observation.state": state, "task": instruction}
    hw = tuple(job["image_size"])
    for key, camera in job["cameras"].items():  # observation key -> LIBERO camera
        img = cams.image(camera, hw)
        # LIBERO's training data hold the raw render turned 180 degrees (openpi's example does the
        # same): that is the upright image mirrored left-right.
        obs[key] = np.ascontiguousarray(img[:, ::-1]) if job["rotate_180"] else img
    return obs


def run_episode(env, client, job: dict, ep: dict, instruction: str, init_state: np.ndarray) -> dict:
    render = job["render"]
    env.seed(int(ep["seed"]))
    env.reset()
    obs = env.set_init_state(init_state)
    for _ in range(int(job["settle_steps"])):  # objects drop onto the table at the start
        obs, _, _, _ = env.step(SETTLE_ACTION)
    init_sha = hashlib.sha256(np.asarray(env.sim.get_state().flatten(), dtype=np.float64).tobytes()).hexdigest()
    contacts = Contacts(env.sim)
    client.infer({RESET_KEY: "reset", "seed": int(ep["seed"])})

    video, every, video_hw = job["video"]["camera"], int(job["video"]["every"]), tuple(job["video"]["size"])
    frames, rows = [], {k: [] for k in ("state", "action", "eef_pos", "contact_force_n", "success")}
    queue: list[np.ndarray] = []
    calls, infer_s = 0, 0.0
    cams = Cameras(env, render, obs)
    frames.append(cams.image(video, video_hw))
    success = False
    state = robot_state(obs)
    for step in range(int(ep["max_steps"])):
        if not queue:
            t0 = time.perf_counter()
            reply = client.infer(policy_observation(cams, job, state, instruction))
            infer_s += time.perf_counter() - t0
            calls += 1
            chunk = np.asarray(reply["actions"], dtype=np.float32)
            # The horizon was checked on our side; this guards what the server actually sent.
            if chunk.ndim != 2 or chunk.shape[1] != 7 or len(chunk) < int(job["execute"]):
                raise ValueError(f"the policy returned a chunk of shape {chunk.shape}; LIBERO needs "
                                 f"at least ({job['execute']}, 7)")
            queue = list(chunk[: int(job["execute"])])
        action = queue.pop(0)
        obs, _, _, _ = env.step(action.tolist())
        cams = Cameras(env, render, obs)
        success = bool(env.check_success())
        state = robot_state(obs)  # recorded after the step, as our own trajectories are
        rows["state"].append(state)
        rows["action"].append(action)
        rows["eef_pos"].append(np.asarray(obs["robot0_eef_pos"], dtype=np.float32))
        rows["contact_force_n"].append(contacts.force_n(env.sim))
        rows["success"].append(success)
        if (step + 1) % every == 0:
            frames.append(cams.image(video, video_hw))
        if success:  # LIBERO's evaluations end an episode at its first success
            break
    return {
        "frames": np.stack(frames),
        **{k: np.asarray(v) for k, v in rows.items()},
        "final_success": np.asarray(success),
        "instruction": np.asarray(instruction),
        "init_state_sha256": np.asarray(init_sha),
        "model_calls": np.asarray(calls),
        "inference_s": np.asarray(infer_s),
    }


def save(out: Path, episode_id: str, record: dict) -> None:
    tmp = out / f".{episode_id}.tmp.npz"
    np.savez(tmp, **record)
    os.replace(tmp, out / f"{episode_id}.npz")


def main(job_path: str) -> int:
    job = json.loads(Path(job_path).read_text())
    out = Path(job["out"])
    out.mkdir(parents=True, exist_ok=True)
    from openpi_client.websocket_client_policy import WebsocketClientPolicy

    client = WebsocketClientPolicy(host=job["server"]["host"], port=int(job["server"]["port"]))
    env, env_task, current = None, None, None
    try:
        for ep in job["episodes"]:
            current = ep
            # Names the episode if this process dies without a word (killed, out of memory).
            (out / "current.json").write_text(json.dumps(ep))
            key = (ep["suite"], int(ep["task_index"]))
            task, bddl, init_states = task_of(*key)
            if env_task != key:  # one environment per task: making one takes seconds
                if env is not None:
                    env.close()
                cameras = sorted(set(job["cameras"].values()) | {job["video"]["camera"]})
                env, env_task = make_env(bddl, job["render"], tuple(job["image_size"]), cameras), key
            k = int(ep["init_index"])
            if not 0 <= k < len(init_states):
                raise ValueError(f"{ep['suite']} task {ep['task_index']} has {len(init_states)} initial states, not {k + 1}")
            t0 = time.perf_counter()
            record = run_episode(env, client, job, ep, task.language, init_states[k])
            record["wall_s"] = np.asarray(time.perf_counter() - t0)
            save(out, ep["episode_id"], record)
            print(f"episode {ep['episode_id']} {ep['suite']}/{ep['task_index']} init {k}: "
                  f"{'success' if record['final_success'] else 'failure'} after {len(record['action'])} steps", flush=True)
    except BaseException as exc:
        failure = {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
        if current is not None:
            failure.update(suite=current["suite"], task_index=current["task_index"], init_index=current["init_index"],
                           episode_id=current["episode_id"])
        (out / "failed.json").write_text(json.dumps(failure, indent=1))
        print(failure["traceback"], file=sys.stderr, flush=True)
        return 1
    finally:
        if env is not None:
            env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
