"""What the twin is that the simulator is not: effects no world parameter expresses.

The twin plays the physical robot, so it must also carry what a lab's camera and servos add to the
modelled world: a real lens, auto exposure, motion blur, brightness-dependent noise
(``r2s_eval.twin.camera``), actuation latency, joint play and a gripper that gives under load
(``r2s_eval.twin.servos``), and the room and the objects' true shapes its cameras and gripper
meet (``r2s_eval.twin.scene``). They are ``RealityEffects``, kept apart from ``WorldParams`` so the
calibration can never fit them exactly: the calibrated sim answers some of them with world
parameters it estimates from the recordings (a five-coefficient lens, a latency in whole control
steps), and the world report scores those answers against the effects here.

``RealityEnv`` applies them around the simulated environment: it records each image through the
twin's camera and actuates through the twin's servos, in a model with the twin's room and shapes
added. With every effect off (``RealityEffects()``, the default twin's) it steps and records the
same bytes as ``TabletopEnv``.

The twin stage writes them beside the world parameters (``results/real/twin_params.json``:
``{"magnitudes", "params", "reality"}``); ``load_reality_effects`` reads them back (None for a
file without them, as the calibrated sim's is). Only the twin's side (teleop, board take, the
real arm's rollouts) and the scoring (calib_error, the world and fidelity reports) read them.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from r2s_eval.errors import ConfigError
from r2s_eval.sim import assembly
from r2s_eval.sim.build import configured_task, image_size, make_env
from r2s_eval.sim.env import TabletopEnv
from r2s_eval.sim.params import WorldParams
from r2s_eval.sim.robot import Robot, world_robot
from r2s_eval.sim.sensor import RATIONAL_COEFFICIENTS, checked_coefficients
from r2s_eval.sim.tasks import Task
from r2s_eval.twin.camera import TwinCamera, exposed_image, exposure_substeps
from r2s_eval.twin.scene import DISTRACTORS, check_distractors, scene_adder
from r2s_eval.twin.servos import Backlash, LatePipeline, delay_substeps, weaken_gripper

REALITY_KEY = "reality"  # where a world-parameter file holds the twin's effects


@dataclass
class RealityEffects:
    """The twin's physical truth beyond its world parameters; defaults are off (a simulated
    camera and servos, the world's room and shapes). References and sources:
    ``r2s_eval.twin.camera``, ``r2s_eval.twin.servos``, ``r2s_eval.twin.scene``."""

    # Per camera, its true lens: OpenCV's rational model (k1, k2, p1, p2, k3, k4, k5, k6) on
    # normalised coordinates, through the camera's own K; missing -> a pinhole.
    lens_distortion: dict[str, tuple[float, ...]] = field(default_factory=dict)
    # Auto exposure (a gain on the image) and auto white balance (gains on red and blue) wandering
    # within 1 +- these relative amplitudes over an episode.
    exposure_drift_rel: float = 0.0
    white_balance_drift_rel: float = 0.0
    exposure_time_s: float = 0.0  # motion blur: the frame averages the scene over this long
    # Shot noise: the pixel noise's variance grows by this much per level of intensity (0-255
    # levels), on top of the world's read noise (WorldParams.image_noise_std squared).
    shot_noise_var_per_level: float = 0.0
    latency_s: float = 0.0  # each command reaches the servos this long after it was sent
    backlash_rad: float = 0.0  # each arm joint's free play (the width of its dead band)
    gripper_strength_scale: float = 1.0  # x the gripper servos' stiffness and force limit
    # --- The room and the objects' true shapes, built into the twin's model (r2s_eval.twin.scene):
    table_texture: bool = False  # the table top's wood grain
    walls: bool = False  # plastered walls, a floor covering and a photograph round the table
    shadows: bool = False  # the key light casts shadows
    # Things on the table no task touches: (kind of scene.DISTRACTORS, x_m, y_m, yaw_rad) each.
    distractors: tuple[tuple[str, float, float, float], ...] = ()
    cup_handle: bool = False  # every cup is a mug with a handle
    block_edge_radius_m: float = 0.0  # every block's edges rounded with this radius (0: sharp)

    @property
    def camera_effects(self) -> bool:
        """Whether the twin's camera records anything the simulated camera does not."""
        return (any(any(c) for c in self.lens_distortion.values()) or self.exposure_drift_rel > 0
                or self.white_balance_drift_rel > 0 or self.exposure_time_s > 0 or self.shot_noise_var_per_level > 0)

    @classmethod
    def from_dict(cls, raw: dict) -> "RealityEffects":
        """From its JSON record (``dataclasses.asdict``): each lens and distractor back to a tuple."""
        raw = dict(raw)
        raw["lens_distortion"] = {cam: tuple(c) for cam, c in (raw.get("lens_distortion") or {}).items()}
        raw["distractors"] = tuple((str(kind), float(x), float(y), float(yaw))
                                   for kind, x, y, yaw in raw.get("distractors") or ())
        return cls(**raw)


def reality_record(reality: RealityEffects | None) -> dict:
    """``{"reality": ...}`` to add to a world-parameter file, or {} for none."""
    return {} if reality is None else {REALITY_KEY: dataclasses.asdict(reality)}


def load_reality_effects(path: str | Path) -> RealityEffects | None:
    """The ``reality`` of a world-parameter JSON file (the twin's, a twin ablation's), or None
    where it holds none (the calibrated sim's)."""
    raw = json.loads(Path(path).read_text()).get(REALITY_KEY)
    return None if raw is None else RealityEffects.from_dict(raw)


def check_reality_effects(reality: RealityEffects, robot: Robot, params: WorldParams, source: str) -> None:
    """A ConfigError naming ``source`` unless ``reality`` fits ``robot``'s rig and has physical
    values; a twin is late through its ``latency_s`` or, with the latency family taken away,
    through the calibrated sim's ``command_latency_steps`` in ``params``, never both."""
    for camera, coefficients in reality.lens_distortion.items():
        if camera not in robot.rig:
            raise ConfigError(f"{source}: the twin's lens of camera {camera!r}, the world has cameras "
                              f"{sorted(robot.rig)}")
        try:
            checked_coefficients(coefficients, len(RATIONAL_COEFFICIENTS))
        except ConfigError as err:
            raise ConfigError(f"{source}: camera {camera!r}: {err}") from None
    for name in ("exposure_drift_rel", "white_balance_drift_rel", "exposure_time_s", "shot_noise_var_per_level",
                 "latency_s", "backlash_rad", "block_edge_radius_m"):
        if not getattr(reality, name) >= 0:
            raise ConfigError(f"{source}: reality {name} must be >= 0, got {getattr(reality, name)!r}")
    if not 0 < reality.gripper_strength_scale <= 1:
        raise ConfigError(f"{source}: reality gripper_strength_scale must be in (0, 1], "
                          f"got {reality.gripper_strength_scale!r}")
    for kind, *_ in reality.distractors:
        if kind not in DISTRACTORS:
            raise ConfigError(f"{source}: unknown distractor {kind!r}, one of {sorted(DISTRACTORS)}")
    if reality.latency_s > 0 and params.command_latency_steps > 0:
        raise ConfigError(f"{source}: the twin is late by its own latency_s ({reality.latency_s} s) and by "
                          f"command_latency_steps ({params.command_latency_steps}) at once; keep one")


class RealityEnv(TabletopEnv):
    """``TabletopEnv`` of a twin: its world parameters, and around them its ``reality`` effects
    (module docstring). The same arguments as ``TabletopEnv`` besides ``reality``; a ``model``
    passed in is this twin's compiled model (its gripper already as weak as ``reality`` says, its
    room and shapes added: ``r2s_eval.twin.scene.scene_adder``)."""

    def __init__(self, task: Task, params: WorldParams | None = None, reality: RealityEffects | None = None,
                 image_size: tuple[int, int] = (128, 128), cameras=None, model: mujoco.MjModel | None = None,
                 renderers: dict | None = None, *, robot: Robot):
        params = params or WorldParams()
        self.reality = reality or RealityEffects()
        check_reality_effects(self.reality, robot, params, "the twin's reality effects")
        check_distractors(self.reality.distractors, task, params, "the twin's reality effects")
        if model is None:
            max_hw = (max(480, int(image_size[0])), max(640, int(image_size[1])))
            # The room and the true shapes go into this model only, never into the world's.
            model = assembly.build_model(robot, task.objects, params, max_size_hw=max_hw,
                                         add_to_spec=scene_adder(self.reality, robot, task.objects, params))
            weaken_gripper(model, robot, float(self.reality.gripper_strength_scale))
        # What reset (called by TabletopEnv's constructor) clears: set before it.
        self.twin_camera = TwinCamera(self.reality.lens_distortion, self.reality.exposure_drift_rel,
                                      self.reality.white_balance_drift_rel, self.reality.shot_noise_var_per_level,
                                      params.image_noise_std)
        self._pipeline: LatePipeline | None = None
        self._backlash = Backlash(self.reality.backlash_rad) if self.reality.backlash_rad > 0 else None
        self._exposure_samples: list[np.ndarray] = []  # the joint positions the last period's exposure saw
        self._exposure_end_qpos: np.ndarray | None = None  # the state those samples lead up to
        self._exposure_data: mujoco.MjData | None = None  # scratch state the sub-frames are drawn from
        super().__init__(task, params, image_size, cameras, model, renderers, robot=robot)
        timestep_s = float(self.model.opt.timestep)
        delay = delay_substeps(self.reality.latency_s, timestep_s)
        self._pipeline = LatePipeline(delay, self.n_substeps) if delay > 0 else None
        # Motion blur: the physics steps of a period after which the exposure samples the scene.
        self._exposure_substeps = exposure_substeps(self.n_substeps, timestep_s, self.reality.exposure_time_s)

    # ------------------------------------------------------------ episode
    def reset(self, object_poses=None, seed=None, settle: bool = True, observe: bool = True):
        if self._pipeline is not None:
            self._pipeline.clear()
        self._exposure_samples, self._exposure_end_qpos = [], None
        observation = super().reset(object_poses, seed=seed, settle=settle, observe=observe)
        if self._backlash is not None:  # the play taken up around the reset targets
            self._backlash.reset({arm: self.data.ctrl[self._arm_act[arm]] for arm in self.robot.arms})
        return observation

    # ------------------------------------------------------------ servos
    def _control_period(self, action: np.ndarray) -> None:
        """The period's physics steps, split where the late command arrives and where the
        exposure samples the scene; the same physics either way (stepping in parts steps the
        same states)."""
        arriving, arrival = action, 0
        if self._pipeline is not None:
            arriving = self._pipeline.send(self.checked_action(action))
            arrival = self._pipeline.arrival_substep
        if arrival == 0 and arriving is not None:
            self.apply_action(arriving)
        done, samples = 0, []
        for at in sorted({arrival, *self._exposure_substeps} - {0}):
            mujoco.mj_step(self.model, self.data, nstep=at - done)
            done = at
            if at == arrival and arriving is not None:
                self.apply_action(arriving)
            if at in self._exposure_substeps:
                samples.append(self.data.qpos.copy())
        if self.n_substeps > done:
            mujoco.mj_step(self.model, self.data, nstep=self.n_substeps - done)
        self._exposure_samples = samples
        self._exposure_end_qpos = self.data.qpos.copy() if samples else None

    def apply_action(self, action: np.ndarray) -> None:
        """The command as it reaches the servos (``TabletopEnv.apply_action``), each arm joint's
        target then moved through its play."""
        super().apply_action(action)
        if self._backlash is None:
            return
        for arm in self.robot.arms:
            act = self._arm_act[arm]
            ctrl_range = self.model.actuator_ctrlrange[act]
            self.data.ctrl[act] = np.clip(self._backlash.through(arm, self.data.ctrl[act]),
                                          ctrl_range[:, 0], ctrl_range[:, 1])

    # ------------------------------------------------------------ camera
    def recorded_image(self, camera: str, size_hw: tuple[int, int],
                       noise_rng: np.random.Generator | None = None) -> np.ndarray:
        """What the twin's camera records: the scene over the exposure, through the calibrated
        sim's lens answer where the world carries one (nominal in the twin), then the twin's
        camera (``TwinCamera.record``: true lens, exposure and white balance, sensor noise)."""
        if not self.reality.camera_effects:
            return super().recorded_image(camera, size_hw, noise_rng)
        samples = self._blur_samples()
        if samples:
            if self._exposure_data is None:
                self._exposure_data = mujoco.MjData(self.model)
            rgb = exposed_image(self.model, self._exposure_data, self.data, self.renderer(size_hw), camera, samples)
        else:
            rgb = self.pinhole_image(camera, size_hw)
        rgb = self.lens_image(rgb, camera)
        if noise_rng is None and self.twin_camera.noisy:
            noise_rng = self.noise_rng(camera)
        camera_index = self.robot.camera_names.index(camera)
        return self.twin_camera.record(
            rgb, camera, K=self.camera_K(camera, size_hw) if self.twin_camera.distorts(camera) else None,
            drift_key=(*self._noise_key, camera_index), time_s=self.steps * self.control_dt_s, noise_rng=noise_rng)

    def _blur_samples(self) -> list[np.ndarray]:
        """The joint positions the camera's exposure saw in the last period, or [] (no blur, or
        the state was set since: a teleported or posed scene has no motion to blur)."""
        if self._exposure_end_qpos is None or not np.array_equal(self._exposure_end_qpos, self.data.qpos):
            return []
        return self._exposure_samples


def make_reality_env(task: str, world_cfg: dict, params: WorldParams | None, reality: RealityEffects | None,
                     cameras=None, suite_cfg: dict | None = None, **shared) -> RealityEnv:
    """The twin's environment of ``task`` as the ``world`` config slice describes it
    (``r2s_eval.sim.build.make_env`` with the twin's ``reality`` around it)."""
    return RealityEnv(
        configured_task(task, world_cfg, suite_cfg),
        params=params,
        reality=reality,
        image_size=image_size(world_cfg),
        cameras=tuple(world_cfg["cameras"] if cameras is None else cameras),
        robot=world_robot(world_cfg),
        **shared,
    )


def make_world_env(task: str, world_cfg: dict, params: WorldParams | None, reality: RealityEffects | None,
                   cameras=None, suite_cfg: dict | None = None, **shared) -> TabletopEnv:
    """The environment of a world-parameter file's ``params`` and ``reality``
    (``load_reality_effects``): the twin's (``RealityEnv``) where it holds reality effects (the
    twin's file, a twin ablation's), else the simulated world's (``make_env``: the calibrated
    sim's file, or None for the nominal world)."""
    if reality is not None:
        return make_reality_env(task, world_cfg, params, reality, cameras, suite_cfg, **shared)
    return make_env(task, world_cfg, params, cameras, suite_cfg, **shared)
