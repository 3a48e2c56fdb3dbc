"""World parameters: the physics and rendering knobs one simulated world is built with.

``WorldParams()`` is the nominal world (no perturbation); the reality twin
(``r2s_eval.twin``) samples perturbed ones. ``load_world_params`` reads them back from the
JSON the twin and calibration stages write (``{"params": {...}}``); a twin's file also holds
its reality effects (``"reality"``, ``r2s_eval.twin.reality``), which no world parameter
expresses and this never reads.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class WorldParams:
    """Physics and rendering parameters of one world; defaults are nominal."""

    friction_scale: float = 1.0
    object_mass_scale: dict[str, float] = field(default_factory=dict)  # missing -> 1.0
    actuator_kp_scale: float = 1.0
    # Per arm, its joints' zero offsets (rad): each servo holds its joint this far from the
    # commanded angle (a robot's kinematic calibration error); missing -> 0.
    joint_offset_rad: dict[str, tuple[float, ...]] = field(default_factory=dict)
    object_size_scale: dict[str, float] = field(default_factory=dict)  # missing -> 1.0
    camera_pos_offset_m: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    camera_rot_offset_rad: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    light_intensity_scale: float = 1.0
    light_dir_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    object_rgb_offset: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    table_rgb_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    image_noise_std: float = 0.0  # in 0-255 intensity units
    noise_seed: int = 0  # seeds the image-noise and encoder-noise generators (and the twin's camera drifts)
    # The joint encoders: each measured arm joint angle in observation.state carries Gaussian
    # noise of this standard deviation (rad) and is rounded to whole steps of the encoder's
    # resolution (rad; 0: not quantised), as a robot's encoders report it.
    encoder_noise_rad: float = 0.0
    encoder_step_rad: float = 0.0

    # The calibrated sim's answers to what its model leaves out (the twin's side has the effects
    # themselves, r2s_eval.twin.reality): nominal, none of them.
    # Per camera, OpenCV's lens distortion (k1, k2, p1, p2, k3) on normalised coordinates, as a
    # board calibration fits it; the camera records through it (env.render(add_noise=True),
    # r2s_eval.sim.sensor). Missing -> a pinhole.
    lens_distortion: dict[str, tuple[float, float, float, float, float]] = field(default_factory=dict)
    # Each command reaches the servos this many whole control steps after it was given (the
    # latency the recordings show); until the first one arrives they hold their reset targets.
    command_latency_steps: int = 0
    # Per fixed camera, a PNG of the room behind the robot as the recordings show it (the
    # calibrated sim's answer to a room no world file holds, r2s_eval.calib.background): the camera
    # records the sim's robot and task objects over it. Missing -> the sim's own surroundings.
    background_plates: dict[str, str] = field(default_factory=dict)
    # The robot's recorded states (observation.state) at the frames the plates are the median of:
    # the sim takes the same median of its own room at them (r2s_eval.sim.env), so it draws the
    # shadows a plate lacks (an arm's at home, when the frames show that arm mostly at work) and
    # not those it holds. Empty -> a plate is taken to hold the shadows of the robot at home.
    background_states: tuple[tuple[float, ...], ...] = ()
    # How far around the robot a plate's frame did not count as room (calib.background.margin_px,
    # in the plate's pixels): the sim's median of its own room leaves out as much.
    background_margin_px: int = 2
    # The key light casts shadows (the arm's and the objects' on the table, which the recordings
    # show and a plate, the room standing still, does not hold): over a plate the sim darkens it by
    # its own shadows' share (r2s_eval.sim.env). False: the world file's lights as they are.
    shadows: bool = False

    def mass_scale(self, obj: str) -> float:
        return float(self.object_mass_scale.get(obj, 1.0))

    def size_scale(self, obj: str) -> float:
        return float(self.object_size_scale.get(obj, 1.0))

    def joint_offsets(self, arm: str, n_joints: int) -> np.ndarray:
        return np.asarray(self.joint_offset_rad.get(arm, (0.0,) * n_joints), dtype=float)


# The calibrated sim's answers to what its world files cannot state (each by the fields above that
# hold it), and the sims a fidelity experiment crosses the checkpoints into besides the calibrated
# one (fidelity.sims): the world as its files state it (nothing calibrated), the calibration
# without its answers, the calibration without one answer.
ANSWERS = {"lens": ("lens_distortion",),
           "background": ("background_plates", "background_states", "background_margin_px"),
           "latency": ("command_latency_steps",), "shadows": ("shadows",)}
NOMINAL_SIM = "nominal"
WITHOUT_ANSWERS = "without_answers"
SIM_VARIANTS = (NOMINAL_SIM, WITHOUT_ANSWERS, *(f"without_{answer}" for answer in ANSWERS))


def sim_variant(calibrated: WorldParams, name: str) -> WorldParams:
    """One of ``SIM_VARIANTS`` from the calibrated sim's parameters: ``nominal`` is
    ``WorldParams()``; ``without_answers`` and ``without_<answer>`` are the calibrated parameters
    with those answers' fields back at their nominal values (the camera poses stay as the
    calibration fitted them, through its lens where it fitted one)."""
    if name == NOMINAL_SIM:
        return WorldParams()
    answers = list(ANSWERS) if name == WITHOUT_ANSWERS else [name.removeprefix("without_")]
    if name not in SIM_VARIANTS:
        raise ValueError(f"unknown sim variant {name!r}: one of {list(SIM_VARIANTS)}")
    nominal = WorldParams()
    return dataclasses.replace(calibrated, **{f: getattr(nominal, f) for a in answers for f in ANSWERS[a]})


def load_world_params(path: str | Path) -> WorldParams:
    """The ``params`` of a world-parameter JSON file (as the twin stage writes it)."""
    return world_params_from_record(json.loads(Path(path).read_text())["params"])


def world_params_from_record(raw: Mapping) -> WorldParams:
    """``WorldParams`` from its JSON record (a world-parameter file's ``params``)."""
    return WorldParams(**{k: _tuples(v) for k, v in raw.items()})


def _tuples(value):
    """JSON arrays back to the tuples ``WorldParams`` holds, inside dicts and arrays too (per-camera,
    per-object and per-arm vectors, the recorded states), so a round trip gives an equal
    ``WorldParams``."""
    if isinstance(value, list):
        return tuple(_tuples(v) for v in value)
    if isinstance(value, dict):
        return {k: _tuples(v) for k, v in value.items()}
    return value
