"""The reality twin: seeded perturbation of the simulated world's parameters.

The twin plays the physical robot. It is the same ``TabletopEnv`` built with
perturbed ``WorldParams`` (``r2s_eval.sim.params``), with its reality effects around it
(``r2s_eval.twin.reality.RealityEnv``); its true object poses are readable only through
``env.object_poses()`` (as a person watching the scene would see them).

Perturbations (``TwinMagnitudes`` defaults; each sampled uniformly in
[-m, +m] around nominal unless noted):

==========================  ===========================  ==================
parameter                   effect                       default magnitude
==========================  ===========================  ==================
friction_scale              x all sliding friction       +-15 %
object_mass_scale[obj]      x object mass and inertia    +-20 %
actuator_kp_scale           x arm/gripper servo gains    +-10 %
object_size_scale[obj]      x object dimensions          +-3 %
camera_pos_offset_m[cam]    camera position shift        +-4 mm per axis
camera_rot_offset_rad[cam]  camera rotation (rot. vec.)  +-1 deg per axis
light_intensity_scale       x light diffuse              +-25 %
light_dir_offset            added to light directions    +-0.2 per axis
object_rgb_offset[obj]      added to object RGB          +-0.06
table_rgb_offset            added to table RGB           +-0.05
image_noise_std             additive Gaussian, 0-255     U(0, 3)
joint_offset_rad[arm]       servo zero offset per joint  +-2 deg
encoder_noise_rad           joint reading noise (std)    0.05 deg (fixed)
encoder_step_rad            joint reading resolution     360/4096 deg (fixed)
==========================  ===========================  ==================

The encoders are a property of the robot, not a draw: every twin reads its joints with the
magnitudes' noise and resolution (a 12-bit encoder per turn, as on common hobby and research
servos). ``conf/real/twin_lab.yaml`` is the ``lab`` preset: cameras placed from a drawing or
a tape measure (centimetres, degrees) and another room's light and paint.

The twin's reality effects (``r2s_eval.twin.reality.RealityEffects``: what no world parameter
expresses) are drawn from a stream of their own (``reality_rng``), so the world parameters of a
seed are what they were before the effects existed. Their magnitudes are off by default (today's
twins: a simulated camera and servos); each is drawn as noted, with the reference a lab's
hardware suggests (sources in ``r2s_eval.twin.camera`` and ``r2s_eval.twin.servos``):

===========================  =================================  ===========================
effect                       draw (magnitude m)                 reference magnitude
===========================  =================================  ===========================
lens_distortion[cam]         the shared lens x (1 + U(-s, s))   camera.C920_RATIONAL, s 0.1
exposure_drift_rel           U(0, m)                            0.05
white_balance_drift_rel      U(0, m)                            0.03
exposure_time_s              U(0, m)                            0.02 s
shot_noise_var_per_level     U(0, m)                            0.05
latency_s                    U(lo, hi)                          (0.1, 0.2) s
backlash_rad                 U(0, m)                            1 deg
gripper_strength_scale       U(1 - m, 1)                        m = 0.5
table_texture                on where true                      on
walls                        on where true                      on
shadows                      on where true                      on
distractors                  the first m of scene.DISTRACTORS   4
cup_handle                   on where true                      on
block_edge_radius_m          U(0, m)                            0.004 m
===========================  =================================  ===========================

The lens's per-coefficient spread (``lens_spread_rel``, s) is each unit's difference from its
make's calibration (an assumption: +-10 % per coefficient); the gripper's reference is LeRobot's
SO-100/SO-101 follower, which caps its gripper servo at 50 % of its maximum torque, so m = 0.5
draws anything from a full-strength gripper to one at half strength. The room (a wooden table,
walls, shadows, things on the table no task touches) and the objects' true shapes (a mug's handle,
a block's rounded edges) are ``r2s_eval.twin.scene``'s; their references are a lab's room as the
large robot datasets show it (DROID, Open X-Embodiment: wooden and laminate tables, cluttered
backgrounds under ceiling lights) and a wooden toy block's sanded edges (a few millimetres, an
assumption).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from r2s_eval.errors import ConfigError
from r2s_eval.sim.params import WorldParams
from r2s_eval.sim.robot import Robot
from r2s_eval.sim.sensor import RATIONAL_COEFFICIENTS
from r2s_eval.twin.reality import RealityEffects, reality_record
from r2s_eval.twin.scene import DISTRACTORS, draw_distractors


@dataclass(frozen=True)
class TwinMagnitudes:
    """Half-widths of the uniform perturbation ranges (see module table)."""

    friction_rel: float = 0.15
    mass_rel: float = 0.20
    kp_rel: float = 0.10
    size_rel: float = 0.03
    camera_pos_m: float = 0.004
    camera_rot_rad: float = float(np.deg2rad(1.0))
    light_intensity_rel: float = 0.25
    light_dir: float = 0.2
    object_rgb: float = 0.06
    table_rgb: float = 0.05
    image_noise_std_max: float = 3.0
    # The arm's kinematic calibration error: each joint is held this far from its command, so
    # recorded joint targets replayed in the nominal sim put the gripper millimetres off.
    joint_offset_rad: float = float(np.deg2rad(2.0))
    # The joint encoders (not drawn: every twin has them): reading noise and resolution.
    encoder_noise_rad: float = float(np.deg2rad(0.05))
    encoder_step_rad: float = float(2 * np.pi / 4096)
    # The twin's reality effects (off by default, see the module docstring), drawn from their own
    # stream: the lens every camera shares (OpenCV's rational model: k1, k2, p1, p2, k3, k4, k5,
    # k6) and each camera's relative spread around it; the maxima of the drifts' amplitudes, the
    # exposure time (s) and the shot noise (variance per level), each drawn in [0, m]; the
    # latency's range (s); the arm joints' play (rad, U(0, m)); the gripper's weakness (its
    # strength U(1 - m, 1)).
    lens_distortion: tuple[float, float, float, float, float, float, float, float] = (0.0,) * 8
    lens_spread_rel: float = 0.0
    exposure_drift_rel_max: float = 0.0
    white_balance_drift_rel_max: float = 0.0
    exposure_time_s_max: float = 0.0
    shot_noise_var_per_level_max: float = 0.0
    latency_s_range: tuple[float, float] = (0.0, 0.0)
    backlash_rad: float = 0.0
    gripper_weakness_rel: float = 0.0
    # --- The room and the objects' true shapes (r2s_eval.twin.scene), each off by default: the
    # textured table, the walls, the shadows (each on where true); how many of scene.DISTRACTORS lie
    # on the table (their poses drawn); every cup a mug with a handle; every block's edge radius
    # (U(0, m)).
    table_texture: bool = False
    walls: bool = False
    shadows: bool = False
    distractors: int = 0
    cup_handle: bool = False
    block_edge_radius_m: float = 0.0

    def __post_init__(self):
        # A config gives these as lists; held as tuples (hashable, as frozen fields are).
        lens = tuple(float(c) for c in self.lens_distortion)
        if len(lens) != len(RATIONAL_COEFFICIENTS):
            raise ConfigError(f"real.twin.magnitudes.lens_distortion: eight coefficients {RATIONAL_COEFFICIENTS} "
                              f"(OpenCV's rational model), got {self.lens_distortion!r}")
        latency = tuple(float(v) for v in self.latency_s_range)
        if len(latency) != 2 or not 0 <= latency[0] <= latency[1]:
            raise ConfigError(f"real.twin.magnitudes.latency_s_range: [low, high] seconds with 0 <= low <= high, "
                              f"got {self.latency_s_range!r}")
        object.__setattr__(self, "lens_distortion", lens)
        object.__setattr__(self, "latency_s_range", latency)

    def scaled(self, factor: float) -> "TwinMagnitudes":
        """All magnitudes multiplied by ``factor`` (0 gives the nominal world); a tuple (the lens,
        the latency's range) entry by entry."""
        return TwinMagnitudes(**{k: tuple(x * factor for x in v) if isinstance(v, tuple) else v * factor
                                 for k, v in self.__dict__.items()})


def sample_twin_params(
    rng: np.random.Generator,
    magnitudes: TwinMagnitudes | None = None,
    *,
    object_names: tuple[str, ...],
    robot: Robot,
) -> WorldParams:
    """Draw one perturbed world of ``robot`` with the objects ``object_names`` (a world's: the twin
    perturbs each physical object once, whichever task it appears in). Same rng state -> same
    parameters."""
    m = magnitudes or TwinMagnitudes()
    camera_names = robot.camera_names

    def u(half_width: float, size=None):
        return rng.uniform(-half_width, half_width, size)

    def vec3(half_width: float) -> tuple[float, float, float]:
        return tuple(float(x) for x in u(half_width, 3))

    return WorldParams(
        friction_scale=1.0 + float(u(m.friction_rel)),
        object_mass_scale={o: 1.0 + float(u(m.mass_rel)) for o in object_names},
        actuator_kp_scale=1.0 + float(u(m.kp_rel)),
        object_size_scale={o: 1.0 + float(u(m.size_rel)) for o in object_names},
        camera_pos_offset_m={c: vec3(m.camera_pos_m) for c in camera_names},
        camera_rot_offset_rad={c: vec3(m.camera_rot_rad) for c in camera_names},
        light_intensity_scale=1.0 + float(u(m.light_intensity_rel)),
        light_dir_offset=vec3(m.light_dir),
        object_rgb_offset={o: vec3(m.object_rgb) for o in object_names},
        table_rgb_offset=vec3(m.table_rgb),
        image_noise_std=float(rng.uniform(0.0, m.image_noise_std_max)),
        noise_seed=int(rng.integers(0, 2**31 - 1)),
        # Drawn last, so the draws above are what they were before this parameter existed.
        joint_offset_rad={name: tuple(float(x) for x in u(m.joint_offset_rad, len(arm.joints)))
                          for name, arm in robot.arms.items()},
        encoder_noise_rad=float(m.encoder_noise_rad),
        encoder_step_rad=float(m.encoder_step_rad),
    )


def reality_rng(seed: int) -> np.random.Generator:
    """The twin's reality effects' own stream of the twin's ``seed`` (its world parameters draw
    from ``default_rng(seed)``; this one never moves them)."""
    return np.random.default_rng([int(seed), 1])


def sample_reality_effects(rng: np.random.Generator, magnitudes: TwinMagnitudes | None = None, *,
                           robot: Robot) -> RealityEffects:
    """Draw one twin's reality effects (module docstring) for ``robot``'s cameras and arms; every
    draw is made whatever the magnitudes, so one effect's magnitude never moves another's draw.
    Same rng state -> same effects."""
    m = magnitudes or TwinMagnitudes()
    camera_names = robot.camera_names
    spread = rng.uniform(-m.lens_spread_rel, m.lens_spread_rel, (len(camera_names), len(m.lens_distortion)))
    lens = {} if not any(m.lens_distortion) else {  # no lens: pinhole cameras
        c: tuple(float(k * (1.0 + s)) for k, s in zip(m.lens_distortion, row)) for c, row in zip(camera_names, spread)}
    return RealityEffects(
        lens_distortion=lens,
        exposure_drift_rel=float(rng.uniform(0.0, m.exposure_drift_rel_max)),
        white_balance_drift_rel=float(rng.uniform(0.0, m.white_balance_drift_rel_max)),
        exposure_time_s=float(rng.uniform(0.0, m.exposure_time_s_max)),
        shot_noise_var_per_level=float(rng.uniform(0.0, m.shot_noise_var_per_level_max)),
        latency_s=float(rng.uniform(*m.latency_s_range)),
        backlash_rad=float(rng.uniform(0.0, m.backlash_rad)),
        gripper_strength_scale=1.0 - float(rng.uniform(0.0, m.gripper_weakness_rel)),
        **_sample_scene(rng, m, robot),
    )


def _sample_scene(rng: np.random.Generator, m: TwinMagnitudes, robot: Robot) -> dict:
    """The room's and the true shapes' fields of ``RealityEffects``, drawn after the effects above
    (so theirs are what they were). The distractors are drawn last: all of them, the first
    ``m.distractors`` kept, so their number moves no other draw (none drawn without any: a world
    whose table the room cannot read draws the rest). A scaled magnitude
    (``TwinMagnitudes.scaled``) of a switch is on while above 0."""
    block_edge_radius_m = float(rng.uniform(0.0, m.block_edge_radius_m))
    count = int(round(m.distractors))
    if not 0 <= count <= len(DISTRACTORS):
        raise ConfigError(f"real.twin.magnitudes.distractors: 0 to {len(DISTRACTORS)} (scene.DISTRACTORS), "
                          f"got {m.distractors!r}")
    distractors = draw_distractors(rng, robot)[:count] if count else ()
    return dict(table_texture=bool(m.table_texture > 0), walls=bool(m.walls > 0), shadows=bool(m.shadows > 0),
                distractors=distractors, cup_handle=bool(m.cup_handle > 0), block_edge_radius_m=block_edge_radius_m)


def twin_world(twin_cfg: dict, object_names, robot: Robot) -> dict:
    """The twin stage's record: the magnitudes, the world parameters drawn from
    ``twin_cfg["seed"]`` and the reality effects drawn from their own stream of it
    (``reality_rng``); ``twin_cfg``: the ``real.twin`` config group.

    All the world's objects are perturbed (``object_names``), so the twin (and its seed) does not
    depend on which tasks run.
    """
    magnitudes = TwinMagnitudes(**(twin_cfg.get("magnitudes") or {}))
    objects = sorted(object_names)
    seed = int(twin_cfg["seed"])
    params = sample_twin_params(np.random.default_rng(seed), magnitudes, object_names=tuple(objects), robot=robot)
    reality = sample_reality_effects(reality_rng(seed), magnitudes, robot=robot)
    return {"magnitudes": dataclasses.asdict(magnitudes), "params": dataclasses.asdict(params),
            **reality_record(reality)}


# The twin's perturbations grouped as a lab would name what its simulation gets wrong. Per
# family, the fields of WorldParams it perturbs (each field in one family; noise_seed only seeds
# the noise) ...
PERTURBATION_FAMILIES = {
    "camera": ("camera_pos_offset_m", "camera_rot_offset_rad"),
    "appearance": ("light_intensity_scale", "light_dir_offset", "object_rgb_offset", "table_rgb_offset"),
    "physics": ("friction_scale", "object_mass_scale", "actuator_kp_scale"),
    "joints": ("joint_offset_rad",),
    "noise": ("image_noise_std",),
    "encoders": ("encoder_noise_rad", "encoder_step_rad"),
    "sizes": ("object_size_scale",),
    # The twin's own effects (REALITY_FAMILIES) and, where the calibrated sim answers one, that
    # answer: taken away, the twin runs with the sim's answer in place of the effect.
    "lens": ("lens_distortion",),
    "exposure": (),
    "blur": (),
    "sensor_noise": (),
    "latency": ("command_latency_steps",),
    "backlash": (),
    "gripper": (),
    # The room and the true shapes (r2s_eval.twin.scene). The sim's answer to the room, its
    # background plates (and the states they were taken at), are pictures of this twin's own room:
    # no family hands them to a twin. Its
    # shadows are the key light's, as the twin's: taken away, the twin casts the sim's.
    "table_texture": (),
    "walls": (),
    "shadows": ("shadows",),
    "distractors": (),
    "shapes": (),
}
# ... and the fields of RealityEffects it holds (each field in one family).
REALITY_FAMILIES = {
    "lens": ("lens_distortion",),
    "exposure": ("exposure_drift_rel", "white_balance_drift_rel"),
    "blur": ("exposure_time_s",),
    "sensor_noise": ("shot_noise_var_per_level",),
    "latency": ("latency_s",),
    "backlash": ("backlash_rad",),
    "gripper": ("gripper_strength_scale",),
    # The room and the true shapes (r2s_eval.twin.scene).
    "table_texture": ("table_texture",),
    "walls": ("walls",),
    "shadows": ("shadows",),
    "distractors": ("distractors",),
    "shapes": ("cup_handle", "block_edge_radius_m"),
}
# ... and the TwinMagnitudes that draw it: a twin whose magnitudes are all nominal has no such effect.
REALITY_MAGNITUDES = {
    "lens": ("lens_distortion",),
    "exposure": ("exposure_drift_rel_max", "white_balance_drift_rel_max"),
    "blur": ("exposure_time_s_max",),
    "sensor_noise": ("shot_noise_var_per_level_max",),
    "latency": ("latency_s_range",),
    "backlash": ("backlash_rad",),
    "gripper": ("gripper_weakness_rel",),
    "table_texture": ("table_texture",),
    "walls": ("walls",),
    "shadows": ("shadows",),
    "distractors": ("distractors",),
    "shapes": ("cup_handle", "block_edge_radius_m"),
}
ALL_FAMILIES = "all"  # every family at once: the twin becomes the calibrated sim
NO_EFFECT = "none"  # the twin with none of its reality effects (the reference of reality_alone)


def _family_fields(family: str, families: dict[str, tuple[str, ...]]) -> tuple[str, ...]:
    if family != ALL_FAMILIES and family not in PERTURBATION_FAMILIES:
        raise ConfigError(f"unknown perturbation family {family!r}: one of "
                          f"{[*PERTURBATION_FAMILIES, ALL_FAMILIES]}")
    if family == ALL_FAMILIES:
        return tuple(f for names in families.values() for f in names)
    return families.get(family, ())


def without_family(twin: WorldParams, sim: WorldParams, family: str) -> WorldParams:
    """The twin's world parameters with one family's gap to the calibrated sim taken away: that
    family's fields take the sim's values (nominal, or what the calibration estimated: its lens,
    its latency in steps); ``all``: the sim itself (with the twin's noise seed, without its
    background plates and their states, which no twin takes). The twin's own
    effects of the family go with it: ``reality_without_family``."""
    return dataclasses.replace(twin, **{f: getattr(sim, f) for f in _family_fields(family, PERTURBATION_FAMILIES)})


def reality_without_family(reality: RealityEffects, family: str) -> RealityEffects:
    """The twin's reality effects with one family's set off (``all``: every one)."""
    nominal = RealityEffects()
    return dataclasses.replace(reality, **{f: getattr(nominal, f) for f in _family_fields(family, REALITY_FAMILIES)})


def reality_alone(reality: RealityEffects, family: str) -> RealityEffects:
    """The twin's reality effects with only one family's on (``none``: every one off): what that
    effect does on its own, the twin's parameter errors kept."""
    nominal = RealityEffects()
    if family == NO_EFFECT:
        return nominal
    if family not in REALITY_FAMILIES:
        raise ConfigError(f"unknown reality effect {family!r}: one of {[*REALITY_FAMILIES, NO_EFFECT]}")
    return dataclasses.replace(nominal, **{f: getattr(reality, f) for f in REALITY_FAMILIES[family]})


def has_effect(magnitudes: dict, family: str) -> bool:
    """Whether a twin drawn with these magnitudes (``real.twin.magnitudes``, the rest at
    TwinMagnitudes' defaults) has the reality effect ``family`` at all."""
    defaults = TwinMagnitudes()
    values = [magnitudes.get(f, getattr(defaults, f)) for f in REALITY_MAGNITUDES[family]]
    return any(np.any(np.asarray(v, dtype=float) != 0) for v in values)
