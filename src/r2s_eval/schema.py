"""The typed schema of the composed configuration, checked once when it is composed.

Every top-level group of conf/config.yaml has a dataclass below; `validate_config` walks the
composed (plain) config against them. A key the schema does not know, a missing key, a value
of the wrong type or out of range, and a cross-group contradiction are all reported in one
``ConfigError``, each problem naming its dotted key and the file (or command-line override)
that set it, with the closest known key when a key looks misplaced or misspelt.

The schema states structure, types and ranges, never values: a field without a default must be
set by the group's YAML file (which owns its default); a field declared ``optional(...)`` may be
left out, and the code that reads it owns its default (named in the field's note). The world
group's keys, with their defaults, are typed in ``r2s_eval.sim.world_spec``; the checker and its
markers are ``r2s_eval.typed``'s. Open-ended
name -> settings maps are checked by their owners' validators: candidate policies by
``r2s_eval.policies.trained_config.validate_policy_cfg`` / ``r2s_eval.policy_sources.validate_source_cfg``,
judges by constructing them with ``r2s_eval.judge.make_judge`` (which contacts no server), the
scripted operator's and the twin's settings against their dataclasses (``OperatorConfig``,
``TwinMagnitudes``).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import operator
import re
import types
import typing
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import yaml

from r2s_eval.errors import ConfigError, R2SError
from r2s_eval.horizon import Horizon
from r2s_eval.typed import (Count, Entries, FieldsOf, Interval, Level, NonEmpty, NonNegative, OneOf, Positive,
                            PositiveInt, Problem, Range, Share, Tagged, _check, _hints, _join, _split, optional)


def _intervals() -> Sequence[str]:
    from r2s_eval.stats import INTERVALS

    return INTERVALS


def _operator_config() -> type:
    from r2s_eval.twin.operator import OperatorConfig

    return OperatorConfig


def _twin_magnitudes() -> type:
    from r2s_eval.twin import TwinMagnitudes

    return TwinMagnitudes


def _check_policy(name: str, entry: dict) -> dict:
    from r2s_eval.policy_sources import validate_candidate_cfg

    return validate_candidate_cfg(entry, name)


def _policy_schema(entry: dict) -> type | None:
    from r2s_eval.policies.types import SUPPORTED_TYPES

    kind = entry.get("type")
    return {"checkpoint": CheckpointPolicy, "server": ServerPolicy, "variant": VariantPolicy,
            "snapshot": SnapshotPolicy}.get(kind) or (
        TrainedPolicy if kind in SUPPORTED_TYPES else None)


def _check_judge(name: str, entry: dict) -> Any:
    from r2s_eval.judge import make_judge

    return make_judge(entry)  # builds the judge object only: no model is loaded, no server asked


def _world_spec() -> type:
    from r2s_eval.sim.world_spec import WorldSpec

    return WorldSpec


# Candidate kinds that are not trained here (r2s_eval.policy_sources).
WITHOUT_TRAINING = ("checkpoint", "server", "variant", "snapshot")
Camera = str  # a camera of the world's rig (checked with the world, in _cross_problems)

# ----------------------------------------------------------------------------- groups


@dataclass
class Region:
    x_range_m: Interval
    y_range_m: Interval
    yaw_range_rad: Interval = optional("the task's own yaw range (r2s_eval.sim.tasks)")


@dataclass
class SuiteTask:
    # null: the task's documented start regions; else {object: region} replacing them.
    init_regions: dict[str, Region] | None


@dataclass
class Twin:
    seed: Count
    magnitudes: Annotated[dict, FieldsOf(_twin_magnitudes)]


@dataclass
class Real:
    source: Literal["twin", "dataset"]
    twin: Twin | None
    dataset_root: str | None
    reference_csv: str | None


@dataclass
class DatasetVideo:
    """Camera-video encoder settings of a recorded dataset: fields of LeRobot's RGBEncoderConfig,
    which checks the codec and its options when the recording starts (importing LeRobot here would
    slow every plan by seconds)."""

    vcodec: str
    preset: int | str | None = optional("lerobot.configs.video.RGBEncoderConfig")
    crf: float | None = optional("lerobot.configs.video.RGBEncoderConfig")
    g: PositiveInt | None = optional("lerobot.configs.video.RGBEncoderConfig")
    pix_fmt: str = optional("lerobot.configs.video.RGBEncoderConfig")


@dataclass
class BoardTake:
    frames: Annotated[int, Range(min=2)]
    image_size: Annotated[list[PositiveInt], NonEmpty()]
    joint_spread_rad: NonNegative
    lens_frames: PositiveInt  # per fixed camera, when the calibration fits the lenses
    video: DatasetVideo


@dataclass
class Teleop:
    episodes_per_task: PositiveInt
    max_duration_s: Positive  # seconds; the world's control rate makes them steps
    keep_failed: bool
    max_attempts_factor: PositiveInt
    operator: Annotated[dict, FieldsOf(_operator_config)]
    video: DatasetVideo
    board_take: BoardTake


@dataclass
class Ingest:
    repo_id: str
    min_length: PositiveInt
    max_length: PositiveInt
    drop_bad_episodes: bool
    check_videos: bool


@dataclass
class HsvSegmenter:
    type: Literal["hsv"]
    hue_tol: Annotated[int, Range(0, 90)] = optional("r2s_eval.calib.segment.make_segmenter")
    sat_min: Annotated[int, Range(0, 255)] = optional("r2s_eval.calib.segment.make_segmenter")
    val_min: Annotated[int, Range(0, 255)] = optional("r2s_eval.calib.segment.make_segmenter")
    blur_px: Count = optional("r2s_eval.calib.segment.make_segmenter")
    min_area_px: Count = optional("r2s_eval.calib.segment.make_segmenter")
    max_area_factor: NonNegative = optional("r2s_eval.calib.episodes.frame_segmenter")


@dataclass
class GroundedSamSegmenter:
    type: Literal["grounded_sam"]
    detector_path: str
    sam_path: str
    box_threshold: Share = optional("r2s_eval.calib.open_vocab.make_grounded_sam")
    text_threshold: Share = optional("r2s_eval.calib.open_vocab.make_grounded_sam")
    device: str = optional("r2s_eval.calib.open_vocab.make_grounded_sam")


@dataclass
class Refine:
    max_iterations: PositiveInt
    tolerance_px: Positive
    supersample: PositiveInt
    appearance: bool
    match: Literal["centroid", "overlap"]
    appearance_window: Literal["box", "object"]


@dataclass
class Calibration:
    episodes_per_task: Count
    measured_poses: str | None


@dataclass
class Joints:
    estimate: bool
    iterations: PositiveInt
    latency: bool
    max_latency_steps: Count


@dataclass
class BoardPose:
    x_m: float
    y_m: float
    yaw_rad: float


def _aruco_dictionaries() -> list[str]:
    import cv2

    return sorted(name for name in dir(cv2.aruco) if name.startswith("DICT_"))


@dataclass
class CalibBoard:
    squares: Annotated[list[Annotated[int, Range(min=2)]], NonEmpty()]
    square_m: Positive
    marker_m: Positive
    dictionary: Annotated[str, OneOf(_aruco_dictionaries)]
    thickness_m: Positive
    mount: str  # table, or an arm of the world's robot (checked with the world in _cross_problems)
    pose: BoardPose
    min_corners: Annotated[int, Range(min=4)]
    min_frames: PositiveInt
    max_reprojection_px: Positive
    intrinsics: bool  # fit each camera's lens from the take too (r2s_eval.calib.board.fit_lens)


@dataclass
class CalibSilhouette:
    fit: bool | Literal["auto"]
    frames: PositiveInt
    stride: PositiveInt
    min_frames: PositiveInt
    supersample: PositiveInt
    blur_px: Annotated[list[Positive], NonEmpty()]
    max_mismatch: Share


@dataclass
class CalibCameras:
    use: Literal["auto", "board", "silhouette", "none"]
    board_take: str | None
    board: CalibBoard
    silhouette: CalibSilhouette


@dataclass
class CalibBackground:
    fit: bool
    frames: PositiveInt
    stride: PositiveInt
    margin_px: Count
    min_free_frames: PositiveInt
    max_unseen: Share


@dataclass
class CalibAppearance:
    fit: bool
    frames_per_task: PositiveInt
    prior: NonNegative
    shadows: bool


@dataclass
class Calib:
    camera: Camera | None  # None: derived from the world when composed (r2s_eval.config)
    segmenter: Annotated[dict, Tagged("type", {"hsv": HsvSegmenter, "grounded_sam": GroundedSamSegmenter})]
    refine: Refine
    calibration: Calibration
    joints: Joints
    cameras: CalibCameras
    background: CalibBackground
    appearance: CalibAppearance


@dataclass
class Replay:
    max_attempts: PositiveInt
    perturb_xy_m: NonNegative
    perturb_yaw_rad: NonNegative
    video: DatasetVideo


@dataclass
class RolloutHorizon:  # r2s_eval.horizon.Horizon is built from it
    chunk: PositiveInt  # predicted actions each query uses
    execute: PositiveInt  # of which run before the next query


@dataclass
class Rollout:
    horizon: RolloutHorizon
    inits_per_task: PositiveInt
    real_inits_per_task: PositiveInt | None
    max_duration_s: Positive  # seconds; the world's control rate makes them steps
    device: str
    batch_episodes: PositiveInt
    model_batch: PositiveInt
    video_camera: Camera | None  # None: derived from the world when composed (r2s_eval.config)
    video_size: tuple[PositiveInt, PositiveInt] | None
    real_video_size: tuple[PositiveInt, PositiveInt] | None
    video_fps: PositiveInt


@dataclass
class Checkpoints:
    start: PositiveInt
    stop: PositiveInt
    step: PositiveInt


@dataclass
class Compare:
    checkpoints: Checkpoints
    allocation: Literal["fixed", "adaptive"]
    alpha: Level
    budget: PositiveInt | None


@dataclass
class Stats:
    n_boot: PositiveInt
    ci_level: Level
    interval: Annotated[str, OneOf(_intervals)]


@dataclass
class Table:
    decimals: Count


@dataclass
class RealSimTable(Table):
    metrics_at: Literal["average", "last"]


@dataclass
class BtScoresTable(Table):
    show_ci: bool


@dataclass
class JudgeAudit:
    human_annotations: str | None
    swapped_letter_columns: list[str]
    swapped_winner_columns: list[str]
    planted_order: list[str] | None
    shuffled_permutations: Count


@dataclass
class Figure:
    width_in: Positive
    height_in: Positive
    font_size: Positive
    dpi: PositiveInt


@dataclass
class WinRateMatrix(Figure):
    cmap: str
    annotate: bool
    decimals: Count


@dataclass
class BtConvergence(Figure):
    columns: PositiveInt
    band_alpha: Share
    marker: str


@dataclass
class OverallRanking(Figure):
    score_color: str
    reference_color: str


@dataclass
class StabilityReport(Figure):
    decimals: Count
    real_color: str
    judge_markers: Annotated[list[str], NonEmpty()]


@dataclass
class SecondsPerTrial:
    execution: NonNegative
    reset: NonNegative
    monitoring: NonNegative
    recording: NonNegative


@dataclass
class HardwareEffort(Figure):
    seconds_per_trial: SecondsPerTrial
    tasks: Annotated[list[PositiveInt], NonEmpty()]
    max_trials_per_task: PositiveInt


@dataclass
class FidelityReport(Figure):
    decimals: Count


@dataclass
class CaseStudy(Figure):
    outcomes: Annotated[list[Literal["success", "failure", "any"]], NonEmpty()]
    rank: Count
    n_frames: PositiveInt
    wrap_chars: PositiveInt


@dataclass
class ResultsBrowser:
    page_size: PositiveInt
    max_pairs_per_policy_pair: PositiveInt | None


@dataclass
class ResolutionFigure:
    decimals: Count
    judge_markers: Annotated[list[str], NonEmpty()]
    success_color: str
    columns: PositiveInt
    panel_width_in: Positive
    panel_height_in: Positive
    font_size: Positive
    dpi: PositiveInt


@dataclass
class Report:
    tasks_table: Table
    realsim_success_table: Table
    realsim_table: RealSimTable
    judge_audit: JudgeAudit
    judge_card_table: Table
    bt_scores_table: BtScoresTable
    win_rate_matrix: WinRateMatrix
    bt_convergence: BtConvergence
    overall_ranking: OverallRanking
    hardware_effort: HardwareEffort
    fidelity: FidelityReport
    case_study: CaseStudy
    results_browser: ResultsBrowser
    stability: StabilityReport
    judge_resolution: ResolutionFigure


@dataclass
class Annotate:
    n_pairs: PositiveInt


def _perturbation_families() -> list[str]:
    from r2s_eval.twin.perturb import ALL_FAMILIES, PERTURBATION_FAMILIES

    return [*PERTURBATION_FAMILIES, ALL_FAMILIES]


def _reality_families() -> list[str]:
    from r2s_eval.twin.perturb import REALITY_FAMILIES

    return list(REALITY_FAMILIES)


def _sim_variants() -> list[str]:
    from r2s_eval.sim.params import SIM_VARIANTS

    return list(SIM_VARIANTS)


@dataclass
class Ablation:
    policies: list[str]  # candidates trained here
    families: Annotated[list[Annotated[str, OneOf(_perturbation_families)]], NonEmpty()]
    alone: list[Annotated[str, OneOf(_reality_families)]]  # the twin with each of these effects alone


@dataclass
class Fidelity:
    ablation: Ablation
    sims: list[Annotated[str, OneOf(_sim_variants)]]  # further sims the crossing runs in


@dataclass
class Stability:
    """The evaluation repeated on disjoint blocks of inits (r2s_eval.stats.stability); 0: off."""

    repetitions: Annotated[int, Range(min=0)]
    real_trials_per_task: PositiveInt
    trials_curve: Annotated[list[PositiveInt], NonEmpty()]
    truth_z: Positive
    networks_in_twin: bool


@dataclass
class Sweep:
    """One planted kind of the resolution sweep: its execution change at its weakest, the dotted
    key of it the levels set, and the levels (increasing; checked with the execution)."""

    key: str
    levels: Annotated[list[float], NonEmpty()]
    execution: dict | None = optional("r2s_eval.compare.resolution (none: the key alone)")


@dataclass
class Resolution:
    """Each judge's resolution (r2s_eval.compare.resolution, r2s_eval.stats.resolution)."""

    policy: str | None  # a candidate of the line-up that is not a variant; None: no sweep
    tasks: Annotated[list[str], NonEmpty()] | None  # of the experiment's tasks; None: all of them
    kinds: list[str]  # keys of sweeps
    sweeps: dict[str, Sweep]
    detect_share: Annotated[float, Range(0.5, 1, open_min=True)]


LiberoCamera = Literal["agentview", "robot0_eye_in_hand"]


@dataclass
class LiberoObservation:
    # observation.images.<key> -> the LIBERO camera that feeds it (several keys may share one)
    cameras: Annotated[dict[str, LiberoCamera], NonEmpty()]
    image_size: tuple[PositiveInt, PositiveInt]
    rotate_180: bool


@dataclass
class LiberoVideo:
    camera: LiberoCamera
    size: tuple[PositiveInt, PositiveInt]
    fps: Literal[1, 2, 4, 5, 10, 20]  # divisors of LIBERO's 20 Hz control rate


@dataclass
class Libero:
    env_dir: str | None
    tasks: Annotated[list[str], NonEmpty()]  # suites (all their tasks) or tasks <suite>_<index>
    max_steps: dict[str, PositiveInt]  # per suite
    episodes_per_task: Annotated[int, Range(1, 50)]  # the first N official initial states
    settle_steps: Count
    observation: LiberoObservation
    render: Literal["on_demand", "default"]
    video: LiberoVideo


# Candidate policies: the types of an entry's keys (their defaults: conf/policy_defaults.yaml, read
# by r2s_eval.policies.types and r2s_eval.policy_sources).
_POLICY_DEFAULTS = _SOURCE_DEFAULTS = "conf/policy_defaults.yaml"
Beta = Annotated[float, Range(0, 1, open_max=True)]


@dataclass
class TrainedPolicy:
    """A candidate trained here (act, diffusion, the VLA types)."""

    type: str
    name: str | None = optional(_POLICY_DEFAULTS)
    steps: PositiveInt = optional(_POLICY_DEFAULTS)
    episodes_fraction: Annotated[float, Range(0, 1, open_min=True)] = optional(_POLICY_DEFAULTS)
    batch_size: PositiveInt = optional(_POLICY_DEFAULTS)
    lr: Positive = optional(_POLICY_DEFAULTS)
    weight_decay: NonNegative | None = optional(_POLICY_DEFAULTS)
    grad_clip_norm: Positive | None = optional(_POLICY_DEFAULTS)
    warmup_steps: Count = optional(_POLICY_DEFAULTS)
    threads: PositiveInt = optional(_POLICY_DEFAULTS)
    device: str = optional(_POLICY_DEFAULTS)
    log_every: PositiveInt = optional(_POLICY_DEFAULTS)
    image_keys: Annotated[list[str], NonEmpty()] = optional(_POLICY_DEFAULTS)
    image_size: tuple[PositiveInt, PositiveInt] | None = optional(_POLICY_DEFAULTS)
    chunk_size: PositiveInt = optional(_POLICY_DEFAULTS)
    std_floor: NonNegative = optional(_POLICY_DEFAULTS)
    overrides: dict = optional(_POLICY_DEFAULTS)
    pretrained_path: str | None = optional(_POLICY_DEFAULTS)
    tokenizer_path: str | None = optional(_POLICY_DEFAULTS)
    scheduler: Literal["constant", "cosine"] = optional(_POLICY_DEFAULTS)
    decay_lr: NonNegative | None = optional(_POLICY_DEFAULTS)
    ema_decay: Level | None = optional(_POLICY_DEFAULTS)
    betas: tuple[Beta, Beta] | None = optional(_POLICY_DEFAULTS)
    seeds: PositiveInt = optional(_POLICY_DEFAULTS)
    seed: Count | None = optional(_POLICY_DEFAULTS)


@dataclass
class ExternalPolicy:
    """What every candidate that is not trained here takes (its `type` picks the rest)."""

    type: str
    name: str | None = optional(_SOURCE_DEFAULTS)
    arms: dict[Literal["real", "sim"], dict | None] | None = optional(_SOURCE_DEFAULTS)
    action_map: list[Count] | None = optional(_SOURCE_DEFAULTS)
    device: str | None = optional(_SOURCE_DEFAULTS)


@dataclass
class CheckpointPolicy(ExternalPolicy):
    """A LeRobot checkpoint folder the lab already has."""

    type: Literal["checkpoint"]
    path: str | None = optional(_SOURCE_DEFAULTS)


_KEY_MAP = "r2s_eval.serving.keymap"


def _key_map_presets() -> Sequence[str]:
    from r2s_eval.serving.keymap import PRESETS

    return sorted(PRESETS)


def _key_map_dtypes() -> Sequence[str]:
    from r2s_eval.serving.keymap import DTYPES

    return DTYPES


@dataclass
class ServerSpec:
    """What a foreign server consumes and returns (r2s_eval.policies.interface.PolicySpec)."""

    cameras: list[str] = optional("its key map, else the server's metadata")
    action_dim: PositiveInt = optional("its key map's preset, else the server's metadata")
    max_chunk: PositiveInt = optional("the server's metadata")
    uses_state: bool = optional("its key map, else the server's metadata")
    uses_task: bool = optional("its key map, else the server's metadata")
    state_dim: PositiveInt | None = optional("the server's metadata")


@dataclass
class ServerKey:
    """One key of a server's request: the stream that fills it (one of camera, state,
    instruction), an image's size and the dtype; checked further by r2s_eval.serving.keymap."""

    camera: str | None = optional(_KEY_MAP)
    state: bool | tuple[Count, PositiveInt] | None = optional(_KEY_MAP)  # true: all of it; [start, stop]
    instruction: bool | None = optional(_KEY_MAP)
    size: tuple[PositiveInt, PositiveInt] | None = optional(_KEY_MAP)  # [height, width]
    dtype: Annotated[str, OneOf(_key_map_dtypes)] | None = optional(_KEY_MAP)


@dataclass
class ServerPolicy(ExternalPolicy):
    """An openpi-protocol policy server."""

    type: Literal["server"]
    host: str = optional(_SOURCE_DEFAULTS)
    port: Annotated[int, Range(1, 65535)] | None = optional(_SOURCE_DEFAULTS)
    api_key_env: str | None = optional(_SOURCE_DEFAULTS)
    spec: ServerSpec | None = optional(_SOURCE_DEFAULTS)
    # The server's own request keys (null: ours): a preset of openpi's example clients, and
    # entries that override it key by key (null drops a preset key).
    preset: Annotated[str, OneOf(_key_map_presets)] | None = optional(_KEY_MAP)
    keys: dict[str, ServerKey | None] | None = optional(_KEY_MAP)
    connect_timeout_s: Positive = optional(_SOURCE_DEFAULTS)
    reply_timeout_s: Positive = optional(_SOURCE_DEFAULTS)
    connect_retries: Count = optional(_SOURCE_DEFAULTS)


_EXECUTION = "r2s_eval.policies.execution"


@dataclass
class Hesitation:
    """Stops and restarts: after every `every_steps` commands, hold the last for `pause_steps`."""

    every_steps: PositiveInt
    pause_steps: PositiveInt


@dataclass
class Fumble:
    """Once the gripper has closed for `after_steps`, it opens for `open_steps` and closes again."""

    after_steps: PositiveInt
    open_steps: PositiveInt
    opening: Annotated[float, Range(0, 1, open_min=True)] = optional(_EXECUTION)


@dataclass
class Execution:
    """How a variant's commands change on their way to the robot (r2s_eval.policies.execution)."""

    action_noise_std: NonNegative = optional(_EXECUTION)
    hesitate: Hesitation | None = optional(_EXECUTION)
    gripper_delay_steps: Count = optional(_EXECUTION)
    lowpass: Annotated[float, Range(0, 1, open_max=True)] = optional(_EXECUTION)
    fumble: Fumble | None = optional(_EXECUTION)
    overshoot: Annotated[float, Range(0, 1, open_max=True)] = optional(_EXECUTION)


@dataclass
class VariantPolicy:
    """Another candidate's checkpoint run with an execution change: planted quality."""

    type: Literal["variant"]
    of: str  # a candidate of the line-up that is not a variant (checked with the line-up)
    execution: Execution
    name: str | None = optional("r2s_eval.policy_sources")


@dataclass
class SnapshotPolicy:
    """A candidate trained here, as its weights were after `step` optimisation steps (its
    training saves them on the way: no training of its own)."""

    type: Literal["snapshot"]
    of: str  # a candidate of the line-up trained here (checked with the line-up)
    step: PositiveInt  # below that candidate's `steps` (checked with the line-up)
    name: str | None = optional("r2s_eval.policy_sources")


@dataclass
class Config:
    """The whole composed configuration (the experiment group is `_global_`: it adds no key)."""

    tasks: Annotated[list[str], NonEmpty()]  # keys of world.tasks
    seed: Count
    suite: dict[str, SuiteTask]  # keys of world.tasks
    world: Annotated[dict, FieldsOf(_world_spec)]  # the world's keys: r2s_eval.sim.world_spec
    real: Real
    teleop: Teleop
    ingest: Ingest
    calib: Calib
    replay: Replay
    policies: Annotated[dict[str, dict], NonEmpty(), Entries(_check_policy, _policy_schema)]
    rollout: Rollout
    judges: Annotated[dict[str, dict], NonEmpty(), Entries(_check_judge)]
    compare: Compare
    stats: Stats
    report: Report
    annotate: Annotate
    fidelity: Fidelity
    stability: Stability
    resolution: Resolution
    libero: Libero | None = optional("LIBERO experiments compose it (conf/libero); the real-to-sim setting has none")


# Keys that were renamed: a config still using the old name is told the new one.
RENAMED = {
    "rollout.chunk_size": "rollout.horizon.chunk",
    "rollout.n_action_steps": "rollout.horizon.execute",
    # Episode lengths are times: the same seconds at any control rate.
    "teleop.max_steps": "teleop.max_duration_s (seconds; the world's robot.control_hz makes them steps)",
    "rollout.max_steps": "rollout.max_duration_s (seconds; the world's robot.control_hz makes them steps)",
}


def _renamed(problem: Problem) -> Problem:
    if problem.unknown and problem.path in RENAMED:
        return Problem(problem.path, f"was renamed {RENAMED[problem.path]}")
    return problem

# ----------------------------------------------------------------------------- cross-group checks


def _camera_calibration_problems(cfg: dict, robot) -> list[Problem]:
    from r2s_eval.calib.camera_plan import silhouette_possible

    cameras, twin = cfg["calib"]["cameras"], cfg["real"]["source"] == "twin"
    problems = []
    board = cameras["board"]
    if board["mount"] != "table" and board["mount"] not in robot.arms:
        problems.append(Problem("calib.cameras.board.mount", f"must be table or an arm of the robot "
                                                             f"{list(robot.arms)}, got {board['mount']!r}"))
    if len(board["squares"]) != 2:
        problems.append(Problem("calib.cameras.board.squares", f"must be [columns, rows], got {board['squares']}"))
    if board["marker_m"] >= board["square_m"]:
        problems.append(Problem("calib.cameras.board.marker_m", f"must be smaller than square_m "
                                                                f"({board['square_m']}), got {board['marker_m']}"))
    if twin and cameras["board_take"] is not None:
        problems.append(Problem("calib.cameras.board_take", "is for a lab's own take (real.source dataset): the "
                                                            "twin records its own (teleop.board_take)"))
    if twin and board["mount"] != "table":
        problems.append(Problem("calib.cameras.board.mount", "the twin's board take lies on the table "
                                                             "(a carried board is for a lab's own take)"))
    if cameras["use"] == "board" and not twin and cameras["board_take"] is None:
        problems.append(Problem("calib.cameras.use", "is board, but calib.cameras.board_take names no take: record "
                                                     "one, or use silhouette (the robot in your recordings) or none"))
    if len(cfg["teleop"]["board_take"]["image_size"]) != 2:
        problems.append(Problem("teleop.board_take.image_size", "must be [height, width]"))
    if not silhouette_possible(robot, cfg["calib"]["segmenter"]["type"]):
        if cameras["use"] == "silhouette":
            problems.append(Problem("calib.cameras.use", "is silhouette, which needs world.robot.find.hue (how the "
                                                         "robot looks) with the hsv segmenter"))
        if cameras["silhouette"]["fit"] is True:
            problems.append(Problem("calib.cameras.silhouette.fit", "is true, which needs world.robot.find.hue (how "
                                                                    "the robot looks) with the hsv segmenter"))
    return problems


def _cross_problems(cfg: dict) -> list[Problem]:
    """Contradictions between groups (run once every group has passed its own schema)."""
    from r2s_eval.sim.assembly import load_world
    from r2s_eval.sim.reading import WorldError

    problems: list[Problem] = []
    real, world = cfg["real"], cfg["world"]
    try:
        robot, tasks = load_world(world)
    except WorldError as err:
        return [Problem(path, message, owner=True) for path, message in err.problems]
    def stranger(key: str) -> str:
        close = difflib.get_close_matches(key, list(tasks), n=1)
        return f"world.tasks {sorted(tasks)}" + (f"; did you mean {close[0]!r}?" if close else "")

    for i, key in enumerate(cfg["tasks"]):
        if key not in tasks:
            problems.append(Problem(f"tasks[{i}]", f"must be a task of {stranger(key)}, got {key!r}"))
    problems += [Problem(f"suite.{key}", f"is not a task of {stranger(key)}") for key in cfg["suite"] if key not in tasks]
    if problems:
        return problems
    if real["source"] == "twin" and real["twin"] is None:
        problems.append(Problem("real.twin", "must be set when real.source is twin"))
    if real["source"] == "dataset":
        for key in ("dataset_root", "reference_csv"):
            if real[key] is None:
                problems.append(Problem(f"real.{key}", "must be set when real.source is dataset"))
    if cfg["ingest"]["min_length"] > cfg["ingest"]["max_length"]:
        problems.append(Problem("ingest.min_length", f"must be <= ingest.max_length ({cfg['ingest']['max_length']})"))
    c = cfg["compare"]["checkpoints"]
    if c["start"] > c["stop"]:
        problems.append(Problem("compare.checkpoints.start", f"must be <= compare.checkpoints.stop ({c['stop']})"))
    budget = cfg["compare"]["budget"]
    if budget is not None and budget > c["stop"]:
        problems.append(Problem("compare.budget", f"must be <= compare.checkpoints.stop ({c['stop']}): the last "
                                                  f"checkpoint holds everything judged"))
    if cfg["compare"]["allocation"] == "fixed" and budget is not None:
        problems.append(Problem("compare.budget", "is read only by compare.allocation: adaptive (the fixed "
                                                  "allocation judges compare.checkpoints.stop per pair)"))
    if cfg["calib"]["camera"] not in world["cameras"]:
        problems.append(Problem("calib.camera", f"must be one of the recorded world.cameras {world['cameras']}, "
                                                f"got {cfg['calib']['camera']!r}"))
    problems += _camera_calibration_problems(cfg, robot)
    calibration = cfg["calib"]["calibration"]["episodes_per_task"]
    if real["source"] == "twin" and calibration >= cfg["teleop"]["episodes_per_task"]:
        problems.append(Problem("calib.calibration.episodes_per_task",
                                f"must be below teleop.episodes_per_task ({cfg['teleop']['episodes_per_task']}): "
                                f"the calibration episodes are never scored, so none would be left"))
    for task, settings in cfg["suite"].items():
        problems += _region_problems(tasks[task], settings["init_regions"])
    rollout = cfg["rollout"]
    if rollout["video_camera"] not in world["cameras"]:
        problems.append(Problem("rollout.video_camera", f"must be one of the recorded world.cameras {world['cameras']}, "
                                                        f"got {rollout['video_camera']!r}"))
    control_hz = round(robot.control_hz)
    if control_hz % rollout["video_fps"]:
        problems.append(Problem("rollout.video_fps", f"must divide the control rate ({control_hz} Hz): the video "
                                                     f"keeps every k-th control step, got {rollout['video_fps']}"))
    trained = {name: p for name, entry in cfg["policies"].items()
               if (p := _check_policy(name, entry))["type"] not in WITHOUT_TRAINING}
    problems += _variant_problems(cfg["policies"])
    problems += _snapshot_problems(cfg["policies"], trained)
    problems += _stability_problems(cfg)
    problems += _resolution_problems(cfg)
    for i, name in enumerate(cfg["fidelity"]["ablation"]["policies"]):
        if name not in trained:
            problems.append(Problem(f"fidelity.ablation.policies[{i}]", f"must be a candidate trained here "
                                                                         f"{sorted(trained)}, got {name!r}"))
    if cfg["fidelity"]["ablation"]["policies"] and real["source"] != "twin":
        problems.append(Problem("fidelity.ablation.policies", "needs real.source twin: the ablation takes the "
                                                              "twin's perturbations away one family at a time "
                                                              "(set fidelity.ablation.policies=[] for your own data)"))
    problems += _fidelity_sim_problems(cfg)
    for name, policy in trained.items():  # an external candidate's needs are checked when it is opened
        cameras = [k.removeprefix("observation.images.") for k in policy["image_keys"]]
        missing = [c for c in cameras if c not in world["cameras"]]
        if missing:
            problems.append(Problem(f"policies.{name}.image_keys",
                                    f"uses cameras {missing} that world.cameras {world['cameras']} does not record"))
    problems += _horizon_problems(rollout["horizon"], trained)
    if cfg.get("libero") is not None:
        problems += _libero_problems(cfg)
    planted = cfg["report"]["judge_audit"]["planted_order"]
    strangers = sorted(set(planted or ()) - set(cfg["policies"]))
    if strangers:
        problems.append(Problem("report.judge_audit.planted_order",
                                f"names {strangers}, not candidates of this line-up {sorted(cfg['policies'])}; "
                                f"list the line-up's planted order (best first) or set it to null"))
    return problems


# Each answer a sim variant takes away, and the calibration setting that gives the sim that answer.
_ANSWER_SETTINGS = {"lens": "calib.cameras.board.intrinsics", "background": "calib.background.fit",
                    "latency": "calib.joints.latency", "shadows": "calib.appearance.shadows"}


def _fidelity_sim_problems(cfg: dict) -> list[Problem]:
    """A sim without an answer needs the calibration to give that answer; effects alone need
    the policies that roll out there (and the twin, whose effects they are)."""
    problems = []
    for i, name in enumerate(cfg["fidelity"]["sims"]):
        setting = _ANSWER_SETTINGS.get(name.removeprefix("without_"))
        if setting and not functools.reduce(operator.getitem, setting.split("."), cfg):
            problems.append(Problem(f"fidelity.sims[{i}]", f"{name!r} takes away an answer the calibration does not "
                                                           f"give ({setting} is off): the sim would be the calibrated one"))
    ablation = cfg["fidelity"]["ablation"]
    if ablation["alone"] and not ablation["policies"]:
        problems.append(Problem("fidelity.ablation.alone", "needs fidelity.ablation.policies: the candidates whose "
                                                           "pi^S rolls out in the twin with each effect alone"))
    if ablation["alone"] and cfg["real"]["source"] == "twin":
        from r2s_eval.twin.perturb import has_effect

        magnitudes = cfg["real"]["twin"]["magnitudes"] or {}
        for i, effect in enumerate(ablation["alone"]):
            if not has_effect(magnitudes, effect):
                problems.append(Problem(f"fidelity.ablation.alone[{i}]", f"this twin has no {effect!r} effect "
                                                                         f"(real.twin.magnitudes leaves it off, as "
                                                                         f"real=twin_unmodelled sets it on)"))
    return problems


def _stability_problems(cfg: dict) -> list[Problem]:
    """Repetitions need the twin (its other trials are the truth) and blocks of the real side's
    inits large enough for the real trials asked (the sim may roll out more: each repetition
    takes its share of the sim-only inits too)."""
    k = cfg["stability"]["repetitions"]
    if not k:
        return []
    if k == 1:
        return [Problem("stability.repetitions", "must be 0 (off) or at least 2, got 1")]
    if cfg["real"]["source"] != "twin" or cfg.get("libero") is not None:
        return [Problem("stability.repetitions", "needs real.source twin: the twin's trials of the other "
                                                 "repetitions are the truth (set stability.repetitions=0)")]
    from r2s_eval.stats.stability import real_side_inits

    inits = cfg["rollout"]["inits_per_task"]
    in_real = real_side_inits(inits, cfg["rollout"]["real_inits_per_task"])
    per_block = in_real // k
    wanted = max(cfg["stability"]["real_trials_per_task"], *cfg["stability"]["trials_curve"])
    if per_block < wanted:
        key = "rollout.inits_per_task" if in_real == inits else "rollout.real_inits_per_task"
        return [Problem("stability.repetitions", f"{k} repetitions of {key} {in_real} leave {per_block} real "
                                                 f"inits per task each, fewer than the {wanted} real trials asked")]
    return []


def _resolution_problems(cfg: dict) -> list[Problem]:
    """The sweep runs a candidate of the line-up that has weights of its own, in both worlds of
    the real-to-sim setting; every kind it names is swept, over increasing levels that each make
    a valid execution change, under names the line-up does not use."""
    from r2s_eval.compare.resolution import with_key
    from r2s_eval.policies.execution import complete_execution

    res, policies = cfg["resolution"], cfg["policies"]
    if res["policy"] is None:
        return []
    if cfg.get("libero") is not None:
        return [Problem("resolution.policy", "the sweep runs in the real-to-sim setting only: set it to null "
                                             "(LIBERO's checkpoints run in LIBERO's own rollouts)")]
    if res["policy"] not in policies or policies[res["policy"]].get("type") == "variant":
        others = sorted(p for p, e in policies.items() if e.get("type") != "variant")
        return [Problem("resolution.policy", f"must name a candidate of this line-up that is not a variant "
                                             f"{others}, got {res['policy']!r}")]
    problems = [Problem(f"resolution.tasks[{i}]", f"must be one of the experiment's tasks {cfg['tasks']}, got {task!r}")
                for i, task in enumerate(res["tasks"] or []) if task not in cfg["tasks"]]
    for i, kind in enumerate(res["kinds"]):
        if kind not in res["sweeps"]:
            problems.append(Problem(f"resolution.kinds[{i}]", f"must be a key of resolution.sweeps "
                                                              f"{sorted(res['sweeps'])}, got {kind!r}"))
            continue
        sweep = res["sweeps"][kind]
        if any(b <= a for a, b in zip(sweep["levels"], sweep["levels"][1:])):
            problems.append(Problem(f"resolution.sweeps.{kind}.levels", f"must increase, from barely there to "
                                                                        f"plain, got {sweep['levels']}"))
        for j, value in enumerate(sweep["levels"]):
            try:
                complete_execution(with_key(sweep.get("execution"), sweep["key"], value), f"resolution.sweeps.{kind}")
            except R2SError as err:
                problems.append(Problem(f"resolution.sweeps.{kind}.levels[{j}]", str(err)))
        if f"{res['policy']}.{kind}.1" in policies:
            problems.append(Problem(f"resolution.sweeps.{kind}", f"its levels are named {res['policy']}.{kind}.<i>, "
                                                                 f"which the line-up uses: rename that candidate"))
    return problems


def _variant_problems(policies: dict) -> list[Problem]:
    """A variant runs a candidate of the same line-up that has weights of its own."""
    problems = []
    for name, entry in policies.items():
        if entry.get("type") != "variant":
            continue
        base = entry.get("of")
        if base not in policies or policies[base].get("type") == "variant":
            others = sorted(p for p, e in policies.items() if e.get("type") != "variant")
            problems.append(Problem(f"policies.{name}.of", f"must name a candidate of this line-up that is not a "
                                                           f"variant {others}, got {base!r}"))
    return problems


def _snapshot_problems(policies: dict, trained: dict[str, dict]) -> list[Problem]:
    """A snapshot is taken from a training of the same line-up, before its last step."""
    problems = []
    for name, entry in policies.items():
        if entry.get("type") != "snapshot":
            continue
        base = entry.get("of")
        if base not in trained:
            problems.append(Problem(f"policies.{name}.of", f"must name a candidate of this line-up trained here "
                                                           f"{sorted(trained)}, got {base!r}"))
        elif not entry["step"] < int(trained[base]["steps"]):
            problems.append(Problem(f"policies.{name}.step", f"must be below {base}'s steps ({trained[base]['steps']}): "
                                                             f"{base} itself is its last step, got {entry['step']}"))
    return problems


def _horizon_problems(horizon: dict, trained: dict[str, dict]) -> list[Problem]:
    """The receding horizon against the shortest chunk a candidate trained here predicts (its
    `chunk_size`); external candidates are checked when they are opened."""
    name = min(trained, key=lambda n: trained[n]["chunk_size"]) if trained else None
    try:
        Horizon.from_config(horizon).check(None if name is None else int(trained[name]["chunk_size"]),
                                           f"policies.{name}")
    except ConfigError as exc:
        return [Problem("rollout.horizon", str(exc), owner=True)]
    return []


def _libero_problems(cfg: dict) -> list[Problem]:
    from r2s_eval.libero import selected_tasks

    problems = []
    from r2s_eval.libero import SUITES

    try:
        selected_tasks(cfg["libero"]["tasks"], cfg["libero"]["max_steps"])
    except R2SError as exc:
        problems.append(Problem("libero.tasks", str(exc), owner=True))
    strangers = sorted(set(cfg["libero"]["max_steps"]) - set(SUITES))
    if strangers:
        problems.append(Problem("libero.max_steps", f"names {strangers}; LIBERO's suites are {sorted(SUITES)}"))
    for name, entry in cfg["policies"].items():
        if entry.get("type") not in ("checkpoint", "server"):
            problems.append(Problem(f"policies.{name}.type", "a LIBERO candidate is a `checkpoint` or `server` "
                                                             f"entry (nothing is trained here), got {entry.get('type')!r}"))
        elif entry.get("action_map") is not None:
            problems.append(Problem(f"policies.{name}.action_map", "LIBERO takes the policy's 7-D actions as they "
                                                                   "are; a LIBERO candidate has no action map"))
    return problems


def _region_problems(task, regions: dict | None) -> list[Problem]:
    objects = list(task.init_regions)
    return [Problem(f"suite.{task.key}.init_regions.{name}", f"is not an object of task {task.key} {objects}", True)
            for name in regions or {} if name not in objects]


# ----------------------------------------------------------------------------- where a key was set


@dataclass
class Source:
    """One layer of the composition: a YAML file (its content placed at its package) or an override."""

    label: str  # "conf/experiment/smoke.yaml" or "the command-line override 'stats.n_boot=5'"
    data: dict | None = None
    override_key: str | None = None
    group: str | None = None  # the config group of a group file

    def sets(self, path: str) -> bool:
        if self.override_key is not None:
            k = self.override_key
            return path == k or path.startswith(k + ".") or k.startswith(path + ".")
        node: Any = self.data
        for part in path.split("."):
            if isinstance(node, list):  # a list is set whole: whatever lies inside it was set here
                return True
            if not isinstance(node, dict) or part not in node:
                return False
            node = node[part]
        return True


def _package_of(path: Path, group: str | None) -> str:
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            break
        m = re.match(r"#\s*@package\s+(\S+)", line)
        if m:
            return {"_global_": "", "_group_": group or ""}.get(m.group(1), m.group(1))
    return group or ""


def _yaml_source(config_dir: Path, rel: str, group: str | None) -> Source:
    path = config_dir / rel
    data = yaml.safe_load(path.read_text()) or {}
    if isinstance(data, dict):
        data = {k: v for k, v in data.items() if k != "defaults"}
    package = _package_of(path, group)
    for part in reversed(package.split(".") if package else []):
        data = {part: data}
    return Source(f"{config_dir.name}/{rel}", data, group=group)


def composition_sources(config_dir: str | Path, config_name: str, choices: dict[str, Any],
                        overrides: Sequence[str]) -> list[Source]:
    """The layers of one composition, highest precedence first: the command-line overrides, then
    the files in the reverse order of the root defaults list (`_self_` is the root file)."""
    config_dir = Path(config_dir)
    root = yaml.safe_load((config_dir / f"{config_name}.yaml").read_text()) or {}
    order: list[str | None] = []  # group names; None for _self_
    for item in root.get("defaults", []):
        if item == "_self_":
            order.append(None)
        elif isinstance(item, dict):
            order += [str(k).split("@")[0].lstrip("/") for k in item]
    order += [g for g in choices if g not in order and not g.startswith("hydra")]
    if None not in order:
        order.insert(0, None)  # Hydra puts _self_ first when the list does not say
    layers = []
    for group in order:
        if group is None:
            layers.append(_yaml_source(config_dir, f"{config_name}.yaml", None))
            continue
        chosen = choices.get(group)
        for option in chosen if isinstance(chosen, list) else [chosen]:
            if option and (config_dir / group / f"{option}.yaml").is_file():
                layers += _group_layers(config_dir, group, str(option))
    for line in overrides:
        key = _override_key(line)
        if key is not None and not (key in choices and "." not in key):  # a group choice is a file above
            layers.append(Source(f"the command-line override {line!r}", override_key=key))
    return list(reversed(layers))


def _group_layers(config_dir: Path, group: str, option: str) -> list[Source]:
    """A group file, after the options of its own group it builds on (`defaults: [default, _self_]`)."""
    rel = f"{group}/{option}.yaml"
    data = yaml.safe_load((config_dir / rel).read_text()) or {}
    layers = []
    for item in data.get("defaults", []) if isinstance(data, dict) else []:
        if isinstance(item, str) and item != "_self_" and (config_dir / group / f"{item}.yaml").is_file():
            layers += _group_layers(config_dir, group, item)
    return [*layers, _yaml_source(config_dir, rel, group)]


def _override_key(line: str) -> str | None:
    m = re.match(r"\s*(?:~|\+\+|\+)?([\w.\-/@]+)\s*=?", line)
    return m.group(1) if m else None


def _setter(path: str, sources: Sequence[Source]) -> Source | None:
    """The layer that set `path` (the effective one), if any did."""
    bare = re.sub(r"\[\d+\]", "", path)
    return next((source for source in sources if source.sets(bare)), None)


def where(path: str, sources: Sequence[Source]) -> str:
    """Which layer set `path` (the effective one), as words for a message."""
    bare = re.sub(r"\[\d+\]", "", path)
    source = _setter(bare, sources)
    if source is not None:
        return f"set in {source.label}" if source.override_key is None else f"set by {source.label}"
    group = bare.split(".", 1)[0]
    files = [s for s in sources if s.override_key is None]
    owner = next((s for s in files if s.group == group), files[-1] if files else None)  # else the root file
    return f"expected in {owner.label}" if owner else "set nowhere"


# ----------------------------------------------------------------------------- suggestions


def known_paths(cls: type = Config, prefix: str = "") -> list[str]:
    """Every dotted key path the schema spells out (open maps contribute their own name only)."""
    out = []
    hints = _hints(cls)
    for f in dataclasses.fields(cls):
        path = _join(prefix, f.name)
        out.append(path)
        for tp in _schemas_of(hints[f.name]):
            out += known_paths(tp, path)
    return out


def _schemas_of(tp: Any) -> Iterator[type]:
    tp, markers = _split(tp)
    for m in markers:
        if isinstance(m, FieldsOf):
            yield m.cls()
        if isinstance(m, Tagged):
            yield from m.options.values()
    for a in typing.get_args(tp) if typing.get_origin(tp) in (Union, types.UnionType) else (tp,):
        if dataclasses.is_dataclass(a):
            yield a


def suggest(path: str, known: Sequence[str]) -> str | None:
    """The known key `path` was most likely meant to be: the same key elsewhere, else a close spelling."""
    leaf = path.rsplit(".", 1)[-1]
    same_leaf = [k for k in known if k.rsplit(".", 1)[-1] == leaf and k != path]
    if same_leaf:
        return max(same_leaf, key=lambda k: difflib.SequenceMatcher(None, k, path).ratio())
    close = difflib.get_close_matches(path, known, n=1, cutoff=0.75)
    return close[0] if close else None


# ----------------------------------------------------------------------------- entry point


# What the LIBERO setting never reads: its protocol is libero.* (the receding horizon and the
# model's device, rollout.horizon / device, are shared with real-to-sim).
LIBERO_UNREAD = ("tasks", "suite", "world", "real", "teleop", "ingest", "calib", "replay", "fidelity",
                 "rollout.inits_per_task",
                 "rollout.real_inits_per_task", "rollout.max_duration_s", "rollout.batch_episodes", "rollout.model_batch",
                 "rollout.video_camera", "rollout.video_size", "rollout.real_video_size", "rollout.video_fps")


def _unread_in_libero(sources: Sequence[Source]) -> list[Problem]:
    """Keys an experiment file or an override sets that a LIBERO run would ignore."""
    return [Problem(path, "is not read in the LIBERO setting (its protocol is libero.*: tasks, max_steps, "
                          "episodes_per_task, observation, video)")
            for path in LIBERO_UNREAD
            if any(src.sets(path) for src in sources if src.override_key is not None or src.group == "experiment")]


def config_problems(cfg: dict, sources: Sequence[Source] = ()) -> list[str]:
    """Every problem of the composed `cfg`, one line each naming the key and where it was set."""
    problems = [_renamed(p) for p in _check(cfg, Config, "")]
    if not problems:
        problems = _cross_problems(cfg)
    if not problems and cfg.get("libero") is not None:
        problems = _unread_in_libero(sources)
    known = known_paths() if problems else []
    lines = []
    for p in problems:
        line = f"{p.path} ({where(p.path, sources)}){':' if p.owner else ''} {p.message}"
        if p.unknown and (hint := suggest(p.path, known)):
            line += f"; did you mean {hint}?"
        if p.path == "world.cameras" and foreign_cameras(cfg.get("world")):
            line += _foreign_cameras_advice(cfg["world"], sources)
        lines.append(line)
    return lines


def foreign_cameras(world: Any) -> list[str]:
    """The cameras ``world.cameras`` records that the world's rig does not place."""
    if not isinstance(world, dict) or not isinstance(world.get("rig"), dict):
        return []
    cameras = world.get("cameras")
    return [c for c in cameras if c not in world["rig"]] if isinstance(cameras, list) else []


def _foreign_cameras_advice(world: dict, sources: Sequence[Source]) -> str:
    """What to do when a layer above the world's own file (an experiment written for another
    world, an override) set cameras the rig does not place; empty when the world file set them."""
    source = _setter("world.cameras", sources)
    if source is None or source.group == "world":
        return ""
    own = next((s.data["world"]["cameras"] for s in sources if s.group == "world" and s.sets("world.cameras")), None)
    example = f"world.cameras=[{','.join(own if isinstance(own, list) else sorted(world['rig']))}]"
    if source.override_key is not None:
        return f"; name cameras of this world's rig, e.g. {example}"
    return (f"; {source.label} names the cameras of another world: override world.cameras for this world "
            f"(e.g. {example}) or write an experiment of your own for it (docs/experiments.md)")


def problems_error(lines: Sequence[str]) -> ConfigError:
    """One ConfigError for the problem lines: the line itself, or a count and one line each."""
    if len(lines) == 1:
        return ConfigError(lines[0])
    return ConfigError(f"{len(lines)} configuration problems:\n" + "\n".join(f"  - {line}" for line in lines))


def validate_config(cfg: dict, sources: Sequence[Source] = ()) -> None:
    """Raise one ConfigError listing every problem of the composed `cfg`; return when it is sound."""
    lines = config_problems(cfg, sources)
    if lines:
        raise problems_error(lines)


OPEN_MAPS = ("suite", "policies", "judges")  # groups whose entries are names chosen by the user


def unknown_override_problem(key: str, line: str) -> str:
    """The problem line for an override of a key the composed config does not have (Hydra refused it)."""
    by = f"set by the command-line override {line!r}"
    if key in RENAMED:
        return f"{key} ({by}) was renamed {RENAMED[key]}"
    known = known_paths()
    if key in known or key.split(".", 1)[0] in OPEN_MAPS or any(k.startswith(key + ".") for k in known):
        return f"{key} ({by}) is not in the composed config; to add it, write '+{line.lstrip('+')}'"
    parent = key.rsplit(".", 1)[0] if "." in key else "the config"
    hint = suggest(key, known)
    return f"{key} ({by}) is not a key of {parent}" + (f"; did you mean {hint}?" if hint else "")
