"""``TabletopEnv``: one task of a world (its robot, rig and objects) simulated for every stage.

Action and ``observation.state``: the world's dataset layout (``robot.features``, see
``r2s_eval.sim.robot``; ``env.action_dim`` entries). The bundled world's is 14-D: per arm
(left, right) six joint targets (rad) then a gripper command, normalised 0 = fully open (each
jaw 0.05 m from the centre) .. 1 = fully closed, mapped linearly to the jaw target. In
``observation.state`` the gripper entries are the *measured* opening in the same units
(holding the cup reads about 0.3); arm entries are measured joint angles.

Timing: ``step(action)`` holds the action (servo targets) for one control period
(``robot.control_hz``; the bundled world: 10 Hz = 50 physics steps of 2 ms).

Servos (``apply_action``; nominal: every command acts at once and exactly): a world's
``command_latency_steps`` (the calibrated sim's answer to a robot's latency) delays each command
by whole control steps; the servos hold their reset targets until the first one arrives, and
``reset`` drops the commands under way.

Observation: ``{"observation.state": float32[action_dim],
"observation.images.<camera>": uint8[H, W, 3]}`` for each requested camera of the rig
(the bundled world: ``head_left``, ``head_right``, ``wrist_left``, ``wrist_right``), default
H = W = 128. Images are what the world's camera records (``recorded_image``,
``r2s_eval.sim.sensor``: the world's lens distortion, the robot and task objects over the world's
background plate of that camera where it has one, then its pixel noise; a nominal world's is a
pinhole without noise), ``render()`` returns clean pinhole images unless asked. A camera's noise
at a control step is drawn from a generator keyed by (world noise seed, episode seed, step,
camera), so an image is the same whether or not the steps before it were rendered: a loop renders
only the steps a policy consumes.

The reality twin (``r2s_eval.twin.reality``) subclasses this environment around its own effects
(a real lens, exposure, a late and loose actuation): ``_control_period`` and ``recorded_image``
are where it steps and records differently.

Frames: world x away from the robot across the table, y to the robot's
left, z up; the table top at ``robot.workspace.z_m`` (the bundled world: 0.75 m). Object body poses refer to the centre of
the object's bottom face; planar poses ``(x_m, y_m, yaw_rad)`` (what
``reset`` takes and ``object_poses`` reports as ``planar``) follow the task's
placement of each object (``objects.py``: upright, upside down, on its side).
"""

from __future__ import annotations

import os
import threading
import warnings
import weakref
from collections import deque

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering unless the user chose otherwise

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from r2s_eval.sim import cameras as cam_geom  # noqa: E402
from r2s_eval.sim import assembly  # noqa: E402
from r2s_eval.sim.predicates import centre_m  # noqa: E402
from r2s_eval.sim.params import WorldParams  # noqa: E402
from r2s_eval.sim.robot import Robot  # noqa: E402
from r2s_eval.sim.sensor import add_image_noise, is_pinhole, through_lens  # noqa: E402
from r2s_eval.sim.tasks import Task, sample_initial_poses  # noqa: E402
from r2s_eval.errors import ConfigError, DataError, PolicyError  # noqa: E402

SETTLE_STEPS = 100  # physics steps (0.2 s) after placing objects at reset
_ENCODER_STREAM = 2**31 - 1  # the encoders' noise stream; the cameras' are their rig indices
_HIDDEN_GROUP = 5  # the geom group plate_shadows_image moves what it leaves out to
# The room with a plate's shadows (plate_shadows_image), per model: every environment of a shared
# model reads the same images, made once under the lock ({model: {(camera, size, look): image}}).
_PLATE_SHADOWS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_PLATE_SHADOWS_LOCK = threading.Lock()
_BUFFER_LOCK = threading.Lock()  # a shared model's offscreen buffer size is grown under it


class TabletopEnv:
    """One task's world (nominal or twin). Build once, then reset/step many episodes."""

    def __init__(
        self,
        task: Task,
        params: WorldParams | None = None,
        image_size: tuple[int, int] = (128, 128),
        cameras: tuple[str, ...] | list[str] | None = None,
        model: mujoco.MjModel | None = None,
        renderers: dict | None = None,
        *,
        robot: Robot,
    ):
        """``task`` and ``robot``: one of the world's tasks and its robot and rig (``get_task(key,
        world)``, ``world_robot(world)``; ``r2s_eval.sim.build.make_env`` builds both from the
        ``world`` config slice); ``cameras``: the rig's cameras to observe (default: all). ``model``: this task's compiled model in this world, to share (MuJoCo only reads a
        model while stepping, so environments stepped side by side can share one).
        ``renderers``: renderers to share with other environments of that model that render
        from the same thread (a renderer draws any MjData of its model); whoever made the dict
        closes them."""
        if not isinstance(task, Task):
            raise ConfigError(f"TabletopEnv: task {task!r} is not a task of a world; pass get_task(key, world)")
        self.task, self.robot = task, robot
        self.params = params or WorldParams()
        self.image_size = (int(image_size[0]), int(image_size[1]))
        self.cameras = self.robot.camera_names if cameras is None else tuple(cameras)
        max_hw = (max(480, self.image_size[0]), max(640, self.image_size[1]))
        self.model = model if model is not None else assembly.build_model(
            self.robot, self.task.objects, self.params, max_size_hw=max_hw)
        self.data = mujoco.MjData(self.model)
        self.table_top_z_m = self.robot.workspace_z_m
        self.control_dt_s = self.robot.control_dt_s
        self.n_substeps = assembly.substeps(self.robot, self.model.opt.timestep)
        self.action_dim = self.robot.action_dim
        self._owns_renderers = renderers is None
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {} if renderers is None else renderers
        self._noise_key = (int(self.params.noise_seed), 0)
        self.steps = 0  # control steps since reset
        self._pending_commands: deque[np.ndarray] = deque()  # sent, not yet at the servos (latency)
        self._plates: dict = {}  # background plates read, by (camera, size)
        self._index_model()
        self.max_task_progress = 0.0
        self.initial_centre_z_m: dict[str, float] = {}
        self._eval_cache: dict = {}
        self.reset()

    # ------------------------------------------------------------ indexing
    def _index_model(self) -> None:
        m, arms = self.model, self.robot.arms
        self._arm_qpos_adr = {a: np.array([m.joint(arm.named(j)).qposadr[0] for j in arm.joints]) for a, arm in arms.items()}
        self._arm_dof_adr = {a: np.array([m.joint(arm.named(j)).dofadr[0] for j in arm.joints]) for a, arm in arms.items()}
        self._arm_act = {a: np.array([m.actuator(arm.named(x)).id for x in arm.actuators]) for a, arm in arms.items()}
        self._grip_act = {a: m.actuator(arm.named(arm.gripper.actuator)).id for a, arm in arms.items()}
        self._grip_qpos_adr = {a: [int(m.joint(arm.named(j)).qposadr[0]) for j in arm.gripper.joints] for a, arm in arms.items()}
        self._grip_dof_adr = {a: int(m.joint(arm.named(arm.gripper.joints[0])).dofadr[0]) for a, arm in arms.items()}
        # A gripper's further fingers (each its actuator and joint) and coupled joints (q = ratio * q_first).
        self._finger_adr = {a: [(m.actuator(arm.named(f.actuator)).id, int(m.joint(arm.named(f.joint)).qposadr[0]), f)
                                for f in arm.gripper.fingers] for a, arm in arms.items()}
        self._coupled_adr = {a: [(int(m.joint(arm.named(j)).qposadr[0]), ratio) for j, ratio in arm.gripper.couple]
                             for a, arm in arms.items()}
        self._ee_site = {a: m.site(assembly.ee_site(a)).id for a in arms}
        self._arm_root = {a: int(m.body_rootid[m.site_bodyid[sid]]) for a, sid in self._ee_site.items()}
        self._obj_body = {o.name: m.body(o.name).id for o in self.task.objects}
        self._obj_qpos_adr = {o.name: int(m.joint(f"{o.name}_free").qposadr[0]) for o in self.task.objects}
        self._obj_dof_adr = {o.name: int(m.joint(f"{o.name}_free").dofadr[0]) for o in self.task.objects}
        self._obj_dims = {o.name: o.scaled_dims(self.params.size_scale(o.name)) for o in self.task.objects}

        # Segmentation labels, one per geom, via each geom's root body: 0 background, 1 table,
        # then one per arm, then the task's objects.
        self.segmentation_names = ["background", "table", *(f"robot_{a}" for a in arms), *self.task.object_names]
        first_object = 2 + len(arms)
        table_root = int(m.body_rootid[m.geom_bodyid[m.geom(self.robot.table_geom).id]])
        label_of_root = {table_root: 1, **{root: 2 + i for i, root in enumerate(self._arm_root.values())}}
        label_of_root.update({self._obj_body[n]: first_object + i for i, n in enumerate(self.task.object_names)})
        root_of_geom = m.body_rootid[m.geom_bodyid]
        self._geom_label = np.array([label_of_root.get(int(r), 0) for r in root_of_geom], dtype=np.int32)
        self._obj_geoms = {n: set(np.flatnonzero(m.geom_bodyid == b)) for n, b in self._obj_body.items()}
        # Per-geom lookup tables, so contact queries are array indexing (they run every step).
        self._geom_is_robot = (self._geom_label >= 2) & (self._geom_label < first_object)
        self._geom_object = np.full(m.ngeom, -1, dtype=np.int32)
        for i, n in enumerate(self.task.object_names):
            self._geom_object[list(self._obj_geoms[n])] = i
        self._geom_finger = np.zeros(m.ngeom, dtype=np.int32)  # 1 + 2 * arm index + (0: jaw a, 1: jaw b)
        for i, arm in enumerate(arms.values()):
            for k, pad in enumerate(arm.gripper.pads):
                pad_id = m.body(arm.named(pad)).id
                in_pad = [b for b in range(m.nbody) if self._descends(b, pad_id)]
                self._geom_finger[np.isin(m.geom_bodyid, in_pad)] = 1 + 2 * i + k

    def _descends(self, body: int, ancestor: int) -> bool:
        while body > 0:
            if body == ancestor:
                return True
            body = int(self.model.body_parentid[body])
        return False

    # ------------------------------------------------------------ episode
    def reset(
        self, object_poses: dict[str, tuple[float, float, float]] | None = None, seed: int | None = None,
        settle: bool = True, observe: bool = True,
    ) -> dict | None:
        """Robot at home, objects resting in their task placement at planar poses {name: (x_m, y_m, yaw_rad)}.

        Without ``object_poses`` the task's nominal sampler is used with ``seed``.
        ``seed`` also keys the image noise (reproducible episodes).
        ``settle=False`` skips the 0.2 s of physics that lets objects come to rest (pure
        kinematics, for rendering a pose hypothesis); ``observe=False`` returns None
        instead of rendering the observation.
        """
        m, d = self.model, self.data
        if object_poses is None:
            object_poses = self.sample_initial_poses(np.random.default_rng(seed))
        self._noise_key = (int(self.params.noise_seed), 0 if seed is None else int(seed))
        self.steps = 0
        mujoco.mj_resetData(m, d)
        self._robot_home(d)
        self._pending_commands.clear()  # a command of the last episode never arrives in this one
        missing = set(self.task.object_names) - set(object_poses)
        if missing:
            raise DataError(f"task {self.task.key}: no initial pose for {sorted(missing)}")
        for name in self.task.object_names:
            x_m, y_m, yaw_rad = object_poses[name]
            placement = self.task.placement(name)
            support_z_m = self.table_top_z_m + 0.0005
            parent = self.task.init_regions[name].relative_to if name in self.task.init_regions else None
            if parent is not None:  # resting on (inside) another object that starts upright
                support_z_m += self.task.object(parent).kind_object.support_top_m(self._obj_dims[parent]) + 0.0005
            kind = self.task.object(name).kind_object
            origin = kind.origin_m(self._obj_dims[name], placement, x_m, y_m, yaw_rad, support_z_m)
            quat = kind.orientation(placement, yaw_rad, self._obj_dims[name])
            self.set_object_pose(name, origin, quat, forward=False)
        mujoco.mj_forward(m, d)
        if settle:
            mujoco.mj_step(m, d, nstep=SETTLE_STEPS)
        d.time = 0.0
        self.max_task_progress = 0.0
        self.initial_centre_z_m = {n: float(centre_m(self, n)[2]) for n in self.task.object_names}
        if not observe:
            return None
        return self.observation()

    def pose_robot(self, state) -> None:
        """Hold the robot still at a dataset-layout ``state`` (arm joints at its angles, fingers at
        its closing): kinematics only, as a recorded frame shows the robot. Objects stay put."""
        self._pose_data(self.data, state)
        mujoco.mj_forward(self.model, self.data)

    def _pose_data(self, d: mujoco.MjData, state) -> None:
        """``d``'s robot joints at ``state`` (``pose_robot``), at rest; the caller updates what
        depends on them."""
        for name, (q, closing) in self.robot.to_model(state).items():
            d.qpos[self._arm_qpos_adr[name]] = q
            d.qpos[self._grip_qpos_adr[name]] = self.robot.arms[name].gripper.position(closing)
            for _, adr, finger in self._finger_adr[name]:
                d.qpos[adr] = finger.position(closing)
            for adr, ratio in self._coupled_adr[name]:
                d.qpos[adr] = ratio * self.robot.arms[name].gripper.position(closing)
        d.qvel[:] = 0.0

    def step(self, action: np.ndarray, images: bool = True) -> dict:
        """Hold ``action`` (14-D, see module table) for one control period; the observation
        after it, without the camera images when ``images`` is false (``images()`` renders them
        later in the same step, with the same pixels)."""
        self._control_period(action)
        self.steps += 1
        self.max_task_progress = max(self.max_task_progress, self.task_progress())
        return self.observation(images=images)

    def _control_period(self, action: np.ndarray) -> None:
        """One control period's physics under ``action``: the servos take it, then the period's
        physics steps run (the twin splits them: a command arriving mid-period, an exposure)."""
        self.apply_action(action)
        mujoco.mj_step(self.model, self.data, nstep=self.n_substeps)

    def checked_action(self, action: np.ndarray) -> np.ndarray:
        """``action`` as a float vector of the action's width; a PolicyError if any entry is not finite."""
        action = np.asarray(action, dtype=float).reshape(self.action_dim)
        if not np.all(np.isfinite(action)):
            raise PolicyError(f"task {self.task.key}: the action contains non-finite values")
        return action

    def apply_action(self, action: np.ndarray) -> None:
        """Send ``action`` (one control step's command) to the servos: it reaches them
        ``params.command_latency_steps`` calls later (until then they keep what they hold)."""
        action = self.checked_action(action)
        latency = int(self.params.command_latency_steps)
        if latency > 0:
            self._pending_commands.append(action)
            if len(self._pending_commands) <= latency:
                return  # nothing has arrived yet: the servos keep their reset targets
            action = self._pending_commands.popleft()
        d = self.data
        for name, (q, closing) in self.robot.to_model(action).items():
            ctrl_range = self.model.actuator_ctrlrange[self._arm_act[name]]
            d.ctrl[self._arm_act[name]] = np.clip(q, ctrl_range[:, 0], ctrl_range[:, 1])
            d.ctrl[self._grip_act[name]] = self.robot.arms[name].gripper.ctrl(closing)
            for act, _, finger in self._finger_adr[name]:
                d.ctrl[act] = finger.ctrl(closing)

    @property
    def time_s(self) -> float:
        return float(self.data.time)

    # ------------------------------------------------------------ observation
    def state(self) -> np.ndarray:
        """Measured state, in the action's layout and units: the arm joints as the world's encoders
        read them (``WorldParams.encoder_noise_rad``, ``encoder_step_rad``; exact in a nominal world)."""
        d = self.data
        joints = {name: d.qpos[self._arm_qpos_adr[name]] for name in self.robot.arms}
        if self.params.encoder_noise_rad > 0 or self.params.encoder_step_rad > 0:
            joints = self._encoder_readings(joints)
        return self.robot.from_model({
            name: (joints[name], arm.gripper.closing(d.qpos[self._grip_qpos_adr[name][0]]))
            for name, arm in self.robot.arms.items()}).astype(np.float32)

    def _encoder_readings(self, joints: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        # Keyed like the image noise (world noise seed, episode seed, step): the same reading
        # however often a step's state is asked for.
        rng = np.random.default_rng([*self._noise_key, self.steps, _ENCODER_STREAM])
        noise, step = float(self.params.encoder_noise_rad), float(self.params.encoder_step_rad)
        readings = {}
        for name, q in joints.items():
            q = q + rng.normal(0.0, noise, q.shape) if noise > 0 else q.copy()
            readings[name] = np.round(q / step) * step if step > 0 else q
        return readings

    def joint_velocities(self) -> np.ndarray:
        """Velocities in the action's layout (per second; grippers: closing fraction/s, + = closing)."""
        d = self.data
        per_arm = {name: (d.qvel[self._arm_dof_adr[name]], arm.gripper.closing_rate(d.qvel[self._grip_dof_adr[name]]))
                   for name, arm in self.robot.arms.items()}
        return (self.robot.from_model(per_arm, offsets=False)).astype(np.float32)

    def observation(self, images: bool = True) -> dict:
        obs = {"observation.state": self.state()}
        if images:
            obs.update(self.images())
        return obs

    def images(self) -> dict:
        """The cameras' images now, as the world's camera records them (``render(add_noise=True)``)."""
        return {f"observation.images.{cam}": self.render(cam, add_noise=True) for cam in self.cameras}

    def renderer(self, size_hw: tuple[int, int]) -> mujoco.Renderer:
        """This environment's renderer of images of ``size_hw`` (H, W): made once, closed with it."""
        if size_hw not in self._renderers:
            # Each renderer's offscreen buffer is exactly its image size: software GL clears and
            # rasterises the whole buffer, and a 128 px image drawn in a 640x480 buffer costs
            # ~10 % more for the same pixels. The model's own buffer size is left as it was.
            with _BUFFER_LOCK:
                vis = self.model.vis.global_
                model_size = vis.offheight, vis.offwidth
                vis.offheight, vis.offwidth = size_hw
                try:
                    self._renderers[size_hw] = mujoco.Renderer(self.model, height=size_hw[0], width=size_hw[1])
                except Exception as err:  # GL backend is fixed when mujoco is first imported
                    raise ConfigError(
                        "could not create an offscreen GL context; set MUJOCO_GL=egl (or osmesa) before "
                        "mujoco is first imported, e.g. import r2s_eval.sim first"
                    ) from err
                finally:
                    vis.offheight, vis.offwidth = model_size
        return self._renderers[size_hw]

    def render(
        self, camera: str, size: tuple[int, int] | None = None, segmentation: bool = False, add_noise: bool = False,
        noise_rng: np.random.Generator | None = None,
    ):
        """RGB uint8[H, W, 3], or with ``segmentation`` (labels int32[H, W], {label: name}).

        ``add_noise``: the image as the world's camera records it (``recorded_image``: its lens,
        its pixel noise), else the clean pinhole image (a hypothesis render). ``noise_rng``: the
        pixel noise's generator (default: the world's, keyed by episode, step and camera).

        Labels: 0 background, 1 table, one per arm (``robot_<arm>``), then the task objects in
        task order (see ``segmentation_names``).
        """
        if segmentation:
            geom_ids = self.render_geoms(camera, size)
            labels = np.where(geom_ids >= 0, self._geom_label[np.clip(geom_ids, 0, None)], 0).astype(np.int32)
            return labels, dict(enumerate(self.segmentation_names))
        size_hw = tuple(int(s) for s in (size or self.image_size))
        if add_noise:
            return self.recorded_image(camera, size_hw, noise_rng)
        return self.pinhole_image(camera, size_hw)

    def pinhole_image(self, camera: str, size_hw: tuple[int, int]) -> np.ndarray:
        """The scene now through ``camera``'s pinhole, RGB uint8[H, W, 3] at ``size_hw``."""
        renderer = self.renderer(size_hw)
        renderer.update_scene(self.data, camera=camera)
        return renderer.render()

    def recorded_image(self, camera: str, size_hw: tuple[int, int],
                       noise_rng: np.random.Generator | None = None) -> np.ndarray:
        """What the world's camera records now: the pinhole image through the world's lens
        (``lens_image``), composited over the camera's background plate where the world has one
        (``background_plate``: the plate wherever the lensed ``foreground_mask`` is not; with the
        world's ``shadows``, the plate darkened by the sim's shadows, ``shadow_shade``), then its
        pixel noise (``params.image_noise_std``) from ``noise_rng``
        (default: ``noise_rng(camera)``)."""
        pinhole = self.pinhole_image(camera, size_hw)
        rgb = self.lens_image(pinhole, camera)
        plate = self.background_plate(camera, size_hw)
        if plate is not None:  # the sim's robot and objects over the room the recordings show
            drawn = self.foreground_mask(camera, size_hw)
            foreground = self.lens_image(drawn.astype(np.uint8) * 255, camera)
            alpha = foreground[..., None].astype(np.float32) / 255.0
            if self.params.shadows:
                shade = self.lens_image(self.shadow_shade(camera, size_hw, pinhole, drawn), camera)
                plate = plate * (shade.astype(np.float32) / 255.0)
            rgb = (alpha * rgb + (1.0 - alpha) * plate).round().astype(np.uint8)
        std = float(self.params.image_noise_std)
        if std <= 0:
            return rgb
        return add_image_noise(rgb, self.noise_rng(camera) if noise_rng is None else noise_rng, std)

    def _robot_home(self, d: mujoco.MjData) -> None:
        """Every arm of ``d`` at home, its gripper open, commanded to stay there."""
        for name, arm in self.robot.arms.items():
            d.qpos[self._arm_qpos_adr[name]] = arm.home
            d.ctrl[self._arm_act[name]] = arm.home
            d.qpos[self._grip_qpos_adr[name]] = arm.gripper.position_open
            d.ctrl[self._grip_act[name]] = arm.gripper.ctrl_open
            for act, adr, finger in self._finger_adr[name]:
                d.qpos[adr], d.ctrl[act] = finger.position_open, finger.ctrl_open
            for adr, ratio in self._coupled_adr[name]:
                d.qpos[adr] = ratio * arm.gripper.position_open

    def shadow_shade(self, camera: str, size_hw: tuple[int, int], pinhole: np.ndarray, drawn: np.ndarray) -> np.ndarray:
        """uint8[H, W, 3]: how much the shadows of what moves (the arms, the objects) darken each
        pixel of ``camera``'s ``pinhole`` image that is room (not ``drawn``, the foreground mask),
        255 = not at all: the image over the room's render with the shadows a plate holds already
        (``plate_shadows_image``), clipped at 255 (where the plate holds a shadow the robot has
        left, the plate is kept as it is)."""
        still = self.plate_shadows_image(camera, size_hw).astype(np.float32)
        ratio = np.where(still > 0, pinhole.astype(np.float32) / np.maximum(still, 1.0), 1.0)
        ratio[drawn] = 1.0
        return (255.0 * np.clip(ratio, 0.0, 1.0)).round().astype(np.uint8)

    def plate_shadows_image(self, camera: str, size_hw: tuple[int, int]) -> np.ndarray:
        """``camera``'s pinhole image of the room with the shadows a background plate holds,
        without the task objects (they start elsewhere in each episode), made once per model,
        camera, size and look. A plate is the median of recorded frames, so it holds the shadows
        the median of those frames holds: with their recorded states (``params.background_states``)
        the same median of the sim's own renders at them (``_median_room``); an arm that works in
        most of them leaves no shadow there, not even where it rests at home. Without them, the
        robot's fixed parts and its arms at home (``_room_at_home``)."""
        m = self.model
        look = (m.light_diffuse.tobytes(), m.light_dir.tobytes(), m.light_pos.tobytes(), m.geom_rgba.tobytes())
        key = (camera, tuple(size_hw), hash(look))
        with _PLATE_SHADOWS_LOCK:
            images = _PLATE_SHADOWS.setdefault(m, {})
            if key not in images:
                states = self.params.background_states
                images[key] = (self._median_room(camera, size_hw, states) if states
                               else self._room_at_home(camera, size_hw))
            return images[key]

    def _room_at_home(self, camera: str, size_hw: tuple[int, int]) -> np.ndarray:
        """``camera``'s pinhole image of the room with the robot's fixed parts and its arms at
        home, where an arm that no task moves stays; where an arm at home hides the room, the room
        without the arms. What a render leaves out is moved to a geom group it does not draw, then
        back: a transparent geom would still cast its shadow."""
        m = self.model
        d = self._data_at_home()
        moving = m.body_weldid[m.geom_bodyid] != 0
        at_home, no_arms = (self._render_without(d, camera, size_hw, hide) for hide in (self._object_geoms(), moving))
        geoms = self._geoms_drawn(d, camera, size_hw)
        arm = (geoms >= 0) & moving[np.clip(geoms, 0, None)]
        return np.where(arm[..., None], no_arms, at_home)

    def _median_room(self, camera: str, size_hw: tuple[int, int], states) -> np.ndarray:
        """``camera``'s pinhole image of the room as a plate taken at the recorded ``states``
        holds it (``r2s_eval.calib.background.plate_from_frames``): per pixel, the median of the
        sim's renders at those states, the task objects left out, over the states in which the
        robot (widened as the plate's frames were: ``params.background_margin_px`` of the plate's
        pixels) does not cover it; where it always does, the room with the arms at home."""
        import cv2

        d = self._data_at_home()
        objects = self._object_geoms()
        home = self._render_without(d, camera, size_hw, objects)
        plate = self._read_plate(camera)
        widen = self.params.background_margin_px * (1.0 if plate is None else size_hw[1] / plate.shape[1])
        margin = np.ones((2 * round(widen) + 1,) * 2, np.uint8)
        renders, free = [], []
        for state in states:
            self._pose_data(d, state)
            mujoco.mj_kinematics(self.model, d)
            mujoco.mj_camlight(self.model, d)  # the cameras and lights where the bodies now put them
            renders.append(self._render_without(d, camera, size_hw, objects))
            geoms = self._geoms_drawn(d, camera, size_hw)
            robot = (geoms >= 0) & self._geom_is_robot[np.clip(geoms, 0, None)]
            free.append(cv2.dilate(robot.astype(np.uint8), margin) == 0)
        values = np.where(np.stack(free)[..., None], np.stack(renders).astype(np.float32), np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a pixel the robot always covers
            median = np.nanmedian(values, axis=0)
        return np.where(np.isnan(median), home, np.nan_to_num(median)).round().astype(np.uint8)

    def _data_at_home(self) -> mujoco.MjData:
        """A fresh MjData of the model with every arm at home, its cameras and lights placed."""
        d = mujoco.MjData(self.model)
        self._robot_home(d)
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_camlight(self.model, d)
        return d

    def _object_geoms(self) -> np.ndarray:
        """bool per geom: the task objects' geoms."""
        m = self.model
        return np.isin(m.body_rootid[m.geom_bodyid], list(self._obj_body.values()))

    def _geoms_drawn(self, d: mujoco.MjData, camera: str, size_hw: tuple[int, int]) -> np.ndarray:
        """The geom ``camera`` draws at each pixel of ``d`` (int32[H, W]; -1 where none is)."""
        renderer = self.renderer(tuple(size_hw))
        renderer.update_scene(d, camera=camera)
        renderer.enable_segmentation_rendering()
        try:
            seg = renderer.render()
        finally:
            renderer.disable_segmentation_rendering()
        is_geom = seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
        return np.where(is_geom & (seg[..., 0] >= 0), seg[..., 0], -1).astype(np.int32)

    def _render_without(self, d: mujoco.MjData, camera: str, size_hw: tuple[int, int], hide: np.ndarray) -> np.ndarray:
        """``camera``'s pinhole image of ``d`` without the geoms ``hide`` (bool per geom)."""
        m = self.model
        groups = m.geom_group.copy()
        option = mujoco.MjvOption()
        option.geomgroup[_HIDDEN_GROUP] = 0
        renderer = self.renderer(tuple(size_hw))
        try:
            m.geom_group[hide] = _HIDDEN_GROUP
            renderer.update_scene(d, camera=camera, scene_option=option)
            return renderer.render()
        finally:
            m.geom_group[:] = groups

    def lens_image(self, rgb: np.ndarray, camera: str) -> np.ndarray:
        """``rgb`` (a pinhole image of ``camera``) through the world's lens of that camera
        (``params.lens_distortion``: OpenCV's five coefficients through the camera's own K at the
        image's size); unchanged where the world has none."""
        coefficients = self.params.lens_distortion.get(camera)
        if is_pinhole(coefficients):
            return rgb
        return through_lens(rgb, self.camera_K(camera, rgb.shape[:2]), coefficients)

    def background_plate(self, camera: str, size_hw: tuple[int, int]) -> np.ndarray | None:
        """The world's background plate of ``camera`` (``params.background_plates``) at ``size_hw``,
        RGB uint8; None where the world has none. Read once per camera and size."""
        key = (camera, tuple(size_hw))
        if key not in self._plates:
            import cv2

            plate = self._read_plate(camera)
            if plate is None:
                return None
            if plate.shape[:2] != tuple(size_hw):
                plate = cv2.resize(plate, (int(size_hw[1]), int(size_hw[0])), interpolation=cv2.INTER_AREA)
            self._plates[key] = plate.astype(np.float32)
        return self._plates[key]

    def _read_plate(self, camera: str) -> np.ndarray | None:
        """``camera``'s background plate as its file holds it (RGB uint8), None where it has none."""
        path = self.params.background_plates.get(camera)
        if path is None:
            return None
        import cv2

        raw = cv2.imread(str(path))
        if raw is None:
            raise ConfigError(f"background plate of camera {camera!r}: cannot read {path}")
        return cv2.cvtColor(raw, cv2.COLOR_BGR2RGB)

    def foreground_mask(self, camera: str, size_hw: tuple[int, int], geoms: np.ndarray | None = None) -> np.ndarray:
        """bool[H, W]: where ``camera``'s pinhole image shows the robot or a task object (what a
        background plate does not hold); ``geoms``: that image's ``render_geoms``, where drawn already."""
        geoms = self.render_geoms(camera, size_hw) if geoms is None else geoms
        return (geoms >= 0) & (self._geom_label[np.clip(geoms, 0, None)] >= 2)

    def noise_rng(self, camera: str) -> np.random.Generator:
        """The generator of ``camera``'s pixel noise at this step of this episode."""
        return np.random.default_rng([*self._noise_key, self.steps, self.robot.camera_names.index(camera)])

    def render_geoms(self, camera: str, size: tuple[int, int] | None = None) -> np.ndarray:
        """The geom drawn at each pixel (int32[H, W] geom ids; -1 where no geom is)."""
        return self._geoms_drawn(self.data, camera, tuple(int(s) for s in (size or self.image_size)))

    @property
    def geom_is_robot(self) -> np.ndarray:
        """Per geom, whether it belongs to one of the robot's arms."""
        return self._geom_is_robot

    # ------------------------------------------------------------ cameras
    def camera_K(self, camera: str, size: tuple[int, int] | None = None) -> np.ndarray:
        """3x3 intrinsics for ``camera`` rendered at ``size`` (H, W); OpenCV pixel convention."""
        h, w = size or self.image_size
        return cam_geom.model_K(self.model, camera, h, w)

    def camera_T_world_from_cam(self, camera: str) -> np.ndarray:
        """4x4 pose of the OpenCV camera frame (x right, y down, z forward) in the world."""
        return cam_geom.T_world_from_cam(self.model, self.data, camera)

    # ------------------------------------------------------------ objects
    def object_state(self, name: str) -> dict:
        d = self.data
        qadr, vadr = self._obj_qpos_adr[name], self._obj_dof_adr[name]
        return dict(
            pos_world_m=d.qpos[qadr : qadr + 3].copy(),
            quat_wxyz=d.qpos[qadr + 3 : qadr + 7].copy(),
            linvel_world_m_s=d.qvel[vadr : vadr + 3].copy(),
            angvel_world_rad_s=d.qvel[vadr + 3 : vadr + 6].copy(),  # free joint: local frame; norm is what we use
        )

    def object_poses(self) -> dict[str, dict]:
        """Ground-truth poses: {name: dict(pos_world_m, quat_wxyz, yaw_rad, planar)}.

        ``pos_world_m``/``quat_wxyz`` are the body pose (bottom centre); ``planar`` is the
        ``(x_m, y_m, yaw_rad)`` in the object's task placement (what ``reset`` takes), and
        ``yaw_rad`` its yaw.
        """
        out = {}
        for name in self.task.object_names:
            s = self.object_state(name)
            planar = self.task.object(name).kind_object.planar_pose(self._obj_dims[name], self.task.placement(name),
                                                                     s["pos_world_m"], s["quat_wxyz"])
            out[name] = dict(pos_world_m=s["pos_world_m"], quat_wxyz=s["quat_wxyz"], yaw_rad=planar[2], planar=planar)
        return out

    def object_dims(self, name: str) -> dict:
        """Object dimensions in this world (size scale applied)."""
        return dict(self._obj_dims[name])

    def object_kind(self, name: str) -> str:
        return self.task.object(name).kind

    def set_object_pose(self, name: str, pos_world_m, quat_wxyz=(1.0, 0.0, 0.0, 0.0), forward: bool = True) -> None:
        """Teleport an object (zero velocity); recomputes kinematics and contacts."""
        qadr, vadr = self._obj_qpos_adr[name], self._obj_dof_adr[name]
        quat = np.asarray(quat_wxyz, dtype=float)
        self.data.qpos[qadr : qadr + 3] = pos_world_m
        self.data.qpos[qadr + 3 : qadr + 7] = quat / np.linalg.norm(quat)
        self.data.qvel[vadr : vadr + 6] = 0.0
        if forward:
            mujoco.mj_forward(self.model, self.data)

    def sample_initial_poses(self, rng: np.random.Generator) -> dict[str, tuple[float, float, float]]:
        """Random collision-free planar poses inside the task's regions (documented in tasks.py)."""
        sizes = {n: self.params.size_scale(n) for n in self.task.object_names}
        return sample_initial_poses(self.task, rng, sizes)

    # ------------------------------------------------------------ robot
    def ee_positions(self) -> dict[str, np.ndarray]:
        """Grasp-centre positions of the grippers, world frame (m)."""
        return {arm: self.data.site_xpos[sid].copy() for arm, sid in self._ee_site.items()}

    def ee_rotations(self) -> dict[str, np.ndarray]:
        """3x3 gripper frames in the world (x approach, y jaw closing axis)."""
        return {arm: self.data.site_xmat[sid].reshape(3, 3).copy() for arm, sid in self._ee_site.items()}

    def arm_base_positions(self) -> dict[str, np.ndarray]:
        """Where each arm's model is rooted (its mount), world frame (m)."""
        return {arm: self.data.xpos[root].copy() for arm, root in self._arm_root.items()}

    # ------------------------------------------------------------ contacts
    def _contacts(self):
        n = self.data.ncon
        return self.data.contact.geom1[:n], self.data.contact.geom2[:n]

    def _robot_object_contacts(self, name: str | None = None) -> np.ndarray:
        """Indices of robot-object contacts (with object ``name``, or with any task object)."""
        g1, g2 = self._contacts()
        o1, o2 = self._geom_object[g1], self._geom_object[g2]
        if name is None:
            hit = (self._geom_is_robot[g1] & (o2 >= 0)) | (self._geom_is_robot[g2] & (o1 >= 0))
        else:
            i = self.task.object_names.index(name)
            hit = (self._geom_is_robot[g1] & (o2 == i)) | (self._geom_is_robot[g2] & (o1 == i))
        return np.flatnonzero(hit)

    def robot_touches(self, name: str) -> bool:
        return len(self._robot_object_contacts(name)) > 0

    def grasped(self, name: str) -> str | None:
        """Arm whose two jaws both touch object ``name``, else None."""
        g1, g2 = self._contacts()
        i = self.task.object_names.index(name)
        fingers = np.concatenate([self._geom_finger[g1][self._geom_object[g2] == i],
                                  self._geom_finger[g2][self._geom_object[g1] == i]])
        for k, arm in enumerate(self.robot.arms):
            if np.any(fingers == 1 + 2 * k) and np.any(fingers == 2 + 2 * k):
                return arm
        return None

    def contact_force_n(self) -> float:
        """Total normal contact force (N) between the robot and all task objects."""
        force = np.zeros(6)
        total = 0.0
        for i in self._robot_object_contacts():
            mujoco.mj_contactForce(self.model, self.data, int(i), force)
            total += abs(force[0])
        return float(total)

    # ------------------------------------------------------------ task
    def _state_key(self) -> bytes:
        d = self.data
        return d.qpos.tobytes() + d.qvel.tobytes() + np.float64(d.time).tobytes() + np.int64(d.ncon).tobytes()

    def _evaluated(self, what: str, fn) -> float:
        # The rollout loop asks for success and progress of the same state several times per
        # step; both are pure functions of the state, so each is computed once per state.
        key = self._state_key()
        if self._eval_cache.get("key") != key:
            self._eval_cache = {"key": key}
        if what not in self._eval_cache:
            self._eval_cache[what] = fn(self)
        return self._eval_cache[what]

    def is_success(self) -> bool:
        return bool(self._evaluated("success", self.task.success))

    def task_progress(self) -> float:
        return float(self._evaluated("progress", self.task.progress))

    def close(self) -> None:
        if self._owns_renderers:
            for r in self._renderers.values():
                r.close()
            self._renderers.clear()
        else:
            self._renderers = {}

    def __del__(self):  # renderers hold GL contexts
        try:
            self.close()
        except Exception:
            pass
