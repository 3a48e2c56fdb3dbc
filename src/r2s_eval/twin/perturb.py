"""The reality twin: seeded perturbation of the simulated world's parameters.

The twin plays the physical robot. It is the same ``TabletopEnv`` built with
perturbed ``WorldParams`` (``r2s_eval.sim.params``); its true object poses are readable
only through ``env.object_poses()`` (as a person watching the scene would see them).

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
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from r2s_eval.errors import ConfigError
from r2s_eval.sim.params import WorldParams
from r2s_eval.sim.robot import Robot


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

    def scaled(self, factor: float) -> "TwinMagnitudes":
        """All magnitudes multiplied by ``factor`` (0 gives the nominal world)."""
        return TwinMagnitudes(**{k: v * factor for k, v in self.__dict__.items()})


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


def twin_world(twin_cfg: dict, object_names, robot: Robot) -> dict:
    """The twin stage's record: the magnitudes and the world drawn from ``twin_cfg["seed"]``
    (``twin_cfg``: the ``real.twin`` config group).

    All the world's objects are perturbed (``object_names``), so the twin (and its seed) does not
    depend on which tasks run.
    """
    magnitudes = TwinMagnitudes(**(twin_cfg.get("magnitudes") or {}))
    objects = sorted(object_names)
    params = sample_twin_params(np.random.default_rng(int(twin_cfg["seed"])), magnitudes, object_names=tuple(objects),
                                robot=robot)
    return {"magnitudes": dataclasses.asdict(magnitudes), "params": dataclasses.asdict(params)}


# The twin's perturbations grouped as a lab would name what its simulation gets wrong; each
# field of WorldParams belongs to one family (noise_seed only seeds the noise).
PERTURBATION_FAMILIES = {
    "camera": ("camera_pos_offset_m", "camera_rot_offset_rad"),
    "appearance": ("light_intensity_scale", "light_dir_offset", "object_rgb_offset", "table_rgb_offset"),
    "physics": ("friction_scale", "object_mass_scale", "actuator_kp_scale"),
    "joints": ("joint_offset_rad",),
    "noise": ("image_noise_std",),
    "encoders": ("encoder_noise_rad", "encoder_step_rad"),
    "sizes": ("object_size_scale",),
}
ALL_FAMILIES = "all"  # every family at once: the twin becomes the calibrated sim


def without_family(twin: WorldParams, sim: WorldParams, family: str) -> WorldParams:
    """The twin with one family's gap to the calibrated sim taken away: that family's fields
    take the sim's values (nominal, or what the calibration estimated); ``all``: the sim itself
    (with the twin's noise seed)."""
    if family != ALL_FAMILIES and family not in PERTURBATION_FAMILIES:
        raise ConfigError(f"unknown perturbation family {family!r}: one of "
                         f"{[*PERTURBATION_FAMILIES, ALL_FAMILIES]}")
    fields = ([f for names in PERTURBATION_FAMILIES.values() for f in names] if family == ALL_FAMILIES
              else PERTURBATION_FAMILIES[family])
    return dataclasses.replace(twin, **{f: getattr(sim, f) for f in fields})
