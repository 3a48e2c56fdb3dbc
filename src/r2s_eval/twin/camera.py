"""The twin's cameras as a lab's record: what a real camera adds that no world parameter says.

``RealityEnv.recorded_image`` (``r2s_eval.twin.reality``) records each image, in the order light
goes through a camera: the scene over the exposure (motion blur), the calibrated sim's lens answer
where a world carries one (nominal in the twin), the true lens, the auto exposure and white
balance, then the sensor's noise. Each effect is a ``RealityEffects`` field, off at its nominal
value; a twin with all of them off records the simulated camera's bytes.

1. Motion blur, ``exposure_time_s``: the frame is the mean of ``MOTION_BLUR_SUBFRAMES`` renders
   of the scene spread over the last ``exposure_time_s`` of the control period
   (``exposure_substeps``; the twin keeps the states as it steps, ``exposed_image`` draws them).
   Reference: an indoor webcam exposes 10-33 ms (at most its frame period, 1/30 s); 0.02 s.
2. The true lens, ``lens_distortion[camera]`` = OpenCV's rational model (k1, k2, p1, p2, k3, k4,
   k5, k6) through the camera's own K: the calibrated sim's five-coefficient answer
   (``WorldParams.lens_distortion``) approximates it, never reproduces it. Reference
   (``C920_RATIONAL``): a Logitech C920's OpenCV calibration at 640x480, k1 0.121, k2 -0.262,
   k3 0.103, p1 = p2 = 0, with a small radial denominator k4 0.02, k5 -0.01, k6 0.005 (an
   assumption: the published figures are the five-coefficient fit, and a real lens's profile is
   no polynomial). The denominator moves the corners of a C920's 640x480 image 2.7 px from the
   five-coefficient model; the best five-coefficient fit to the rational lens leaves 0.001 px
   within the C920's own field and 0.02 px RMS (0.19 px at the corners) over the bundled world's
   75 deg wrist cameras at 640x480, whose corners lie past that field.
3. Auto exposure and auto white balance, ``exposure_drift_rel`` and ``white_balance_drift_rel``
   (relative amplitudes): a gain on the whole image, and gains on red and blue (white balance
   scales them against green, which it holds), each wandering smoothly within 1 +- amplitude over
   an episode (``drift_gains``). Reference: a webcam's auto exposure and white balance move a
   static scene's mean level by a few percent as an arm enters and leaves the view; an order of
   magnitude, not a measured figure: 0.05 and 0.03.
4. Sensor noise, the world's ``image_noise_std`` (0-255 units, the read noise) and
   ``shot_noise_var_per_level`` (variance added per level of intensity): Gaussian noise of variance
   ``image_noise_std**2 + shot_noise_var_per_level * intensity`` (``add_sensor_noise``; without
   shot noise, the simulated camera's ``add_image_noise``). Reference: photon shot noise is
   Poisson in electrons; a small-pixel webcam sensor's full well of some 5,000 e- spread over 255
   levels is 0.05 levels per electron, so variance 0.05 * intensity in levels (before the
   camera's gamma, which this model leaves out).
5. Quantisation to uint8: truncated after noise (as ``add_image_noise`` always did), rounded where
   no noise is added.
"""

from __future__ import annotations

import functools
import math

import mujoco
import numpy as np

from r2s_eval.sim.sensor import add_image_noise, is_pinhole, standard_normals, through_lens

# The reference lens (module docstring, 2.): OpenCV's rational model, (k1, k2, p1, p2, k3, k4, k5, k6).
C920_RATIONAL = (0.121, -0.262, 0.0, 0.0, 0.103, 0.02, -0.01, 0.005)
# Sub-frames averaged over the exposure: 5 keeps the ghosts of a moving arm within about a pixel
# of each other at 128 px (0.5 m/s over 20 ms is 1 cm: 2 px at a head camera's 0.85 m, 0.4 px
# between sub-frames; 5.5 px at a wrist camera's 15 cm, 1.1 px between them), at five renders
# per blurred frame.
MOTION_BLUR_SUBFRAMES = 5
# Auto exposure and white balance wander between values drawn every DRIFT_KNOT_S seconds: slower
# than an auto-exposure loop settles (0.5-1 s), so the drift reads as the loop chasing the scene.
DRIFT_KNOT_S = 2.0
_DRIFT_STREAM = 2**31 - 2  # the drifts' generator stream (the encoders' is 2**31 - 1, sim.env)


# ----------------------------------------------------------------------------- noise


def add_sensor_noise(signal: np.ndarray, rng: np.random.Generator, std: float, shot_noise: float) -> np.ndarray:
    """``signal`` (0-255) plus Gaussian noise of variance ``std**2 + shot_noise * signal``, drawn
    as ``add_image_noise`` draws it (one standard normal per value from ``rng``), clipped and
    truncated to uint8."""
    exposed = np.clip(np.asarray(signal, dtype=np.float32), 0, 255)
    sigma = exposed * np.float32(shot_noise)
    sigma += np.float32(std) ** 2
    np.sqrt(sigma, out=sigma)
    noisy = standard_normals(rng, exposed.shape)
    noisy *= sigma
    noisy += exposed
    np.clip(noisy, 0, 255, out=noisy)
    return noisy.astype(np.uint8)


# ----------------------------------------------------------------------------- exposure, white balance


def drift_gains(drift_key: tuple[int, ...], time_s: float, exposure_rel: float,
                white_balance_rel: float) -> tuple[float, np.ndarray]:
    """(exposure gain, white-balance gains float32[3] on R, G, B) at ``time_s`` into an episode.

    Each wanders smoothly between values drawn uniformly in [-1, 1] every ``DRIFT_KNOT_S``
    (smootherstep in between: continuous slope and curvature, never beyond the values it joins),
    scaled to 1 +- ``exposure_rel`` and, for red and blue, 1 +- ``white_balance_rel`` (green is
    held, as white balance holds it). The values are keyed by ``drift_key`` (the world's noise
    seed, the episode seed, the camera) and their index only: the same gains however often and
    in whatever order a step is rendered."""
    position = float(time_s) / DRIFT_KNOT_S
    knot = math.floor(position)
    f = position - knot
    blend = f * f * f * (f * (6.0 * f - 15.0) + 10.0)
    start, end = np.asarray(_drift_knot(drift_key, knot)), np.asarray(_drift_knot(drift_key, knot + 1))
    wander = start + (end - start) * blend  # exposure, red, blue; each in [-1, 1]
    exposure = 1.0 + float(exposure_rel) * float(wander[0])
    balance = np.array([1.0 + white_balance_rel * wander[1], 1.0, 1.0 + white_balance_rel * wander[2]],
                       dtype=np.float32)
    return exposure, balance


@functools.lru_cache(maxsize=4096)
def _drift_knot(drift_key: tuple[int, ...], knot: int) -> tuple[float, float, float]:
    return tuple(np.random.default_rng([*drift_key, _DRIFT_STREAM, knot]).uniform(-1.0, 1.0, 3).tolist())


# ----------------------------------------------------------------------------- motion blur


def exposure_substeps(n_substeps: int, timestep_s: float, exposure_time_s: float) -> tuple[int, ...]:
    """The physics steps of a control period (1..``n_substeps``) after which the exposure samples
    the scene: the centres of ``MOTION_BLUR_SUBFRAMES`` equal parts of its last ``exposure_time_s``
    (at least one physics step, at most the whole period: a camera cannot expose longer than it
    has between frames), on whole physics steps; () for no blur."""
    if exposure_time_s <= 0:
        return ()
    window = int(np.clip(round(float(exposure_time_s) / float(timestep_s)), 1, n_substeps))
    centres = n_substeps - window + (np.arange(MOTION_BLUR_SUBFRAMES) + 0.5) * window / MOTION_BLUR_SUBFRAMES
    return tuple(sorted({int(np.clip(math.floor(c + 0.5), 1, n_substeps)) for c in centres}))


def exposed_image(model: mujoco.MjModel, scratch: mujoco.MjData, data: mujoco.MjData, renderer: mujoco.Renderer,
                  camera: str, samples: list[np.ndarray]) -> np.ndarray:
    """The mean of the scene's renders at the exposure's joint positions ``samples`` (motion
    blur), drawn from ``scratch`` so the stepped state ``data`` (contacts, forces) stays as it is."""
    scratch.mocap_pos[:], scratch.mocap_quat[:] = data.mocap_pos, data.mocap_quat
    total = None
    for qpos in samples:
        scratch.qpos[:] = qpos
        # What drawing reads: body, geom and site poses, then cameras and lights.
        mujoco.mj_kinematics(model, scratch)
        mujoco.mj_comPos(model, scratch)
        mujoco.mj_camlight(model, scratch)
        renderer.update_scene(scratch, camera=camera)
        frame = renderer.render()
        total = frame.astype(np.float32) if total is None else total + frame
    total /= len(samples)
    np.rint(total, out=total)
    return total.astype(np.uint8)


# ----------------------------------------------------------------------------- the camera


class TwinCamera:
    """The twin's cameras after the calibrated sim's lens answer: the true lens, exposure and
    white-balance drift, noise (motion blur, which needs the scene over time, is the
    environment's: ``exposure_substeps``, ``exposed_image``)."""

    def __init__(self, lens_distortion: dict, exposure_drift_rel: float, white_balance_drift_rel: float,
                 shot_noise_var_per_level: float, image_noise_std: float):
        self.noise_std = float(image_noise_std)
        self.shot_noise = float(shot_noise_var_per_level)
        self.exposure_rel = float(exposure_drift_rel)
        self.white_balance_rel = float(white_balance_drift_rel)
        # An all-zero lens is a pinhole: left out, so it records the same bytes as none.
        self.lens = {cam: tuple(float(c) for c in coefficients) for cam, coefficients in lens_distortion.items()
                     if not is_pinhole(coefficients)}

    @property
    def noisy(self) -> bool:
        return self.noise_std > 0 or self.shot_noise > 0

    @property
    def drifts(self) -> bool:
        return self.exposure_rel > 0 or self.white_balance_rel > 0

    def distorts(self, camera: str) -> bool:
        return camera in self.lens

    def record(self, rgb: np.ndarray, camera: str, *, K: np.ndarray | None = None,
               drift_key: tuple[int, ...] = (), time_s: float = 0.0,
               noise_rng: np.random.Generator | None = None) -> np.ndarray:
        """The image ``rgb`` (uint8[H, W, 3], the scene as far as the sim's lens) as the camera
        records it: through the true lens (``K``: the camera's intrinsics at this size, needed
        when it distorts), the exposure and white balance at ``time_s`` (``drift_key``: see
        ``drift_gains``), then the sensor's noise from ``noise_rng`` (needed when ``noisy``)."""
        if self.distorts(camera):
            rgb = through_lens(rgb, K, self.lens[camera])
        if not self.drifts:
            if self.shot_noise > 0:
                return add_sensor_noise(rgb, noise_rng, self.noise_std, self.shot_noise)
            return add_image_noise(rgb, noise_rng, self.noise_std) if self.noise_std > 0 else rgb
        exposure, balance = drift_gains(drift_key, time_s, self.exposure_rel, self.white_balance_rel)
        signal = rgb.astype(np.float32)
        signal *= np.float32(exposure) * balance
        if self.shot_noise > 0:
            return add_sensor_noise(signal, noise_rng, self.noise_std, self.shot_noise)
        if self.noise_std > 0:
            return add_image_noise(signal, noise_rng, self.noise_std)
        np.rint(signal, out=signal)
        np.clip(signal, 0, 255, out=signal)
        return signal.astype(np.uint8)
