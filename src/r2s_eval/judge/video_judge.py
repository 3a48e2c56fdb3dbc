"""The built-in offline video judge (backend "video").

This judge is NOT a vision-language model, but unlike the kinematic judge it sees only what a VLM
judge sees: the rollout's video and the task instruction. It never opens the trajectory or the
episode table. It decodes the video (and reads its frame rate from the file, the same for every
rollout of a run), measures motion from optical flow and frame differences and segments the
task's objects by colour (the HSV segmenter of ``r2s_eval.calib.segment``; the instruction is
mapped to a task of ``r2s_eval.sim.tasks`` by word overlap, as a VLM would know what a cup and a
plate look like), and writes the same four-criterion description, with the numbers behind it.

Describe (per rollout, from pixels only):
  * motion smoothness, on an absolute scale: dense optical flow (OpenCV's DIS) between consecutive
    grey frames downscaled to ``flow_side_px`` on the long side, averaged over square cells of
    ``flow_cell_px``, in image fractions (of the long side) per second. ``flow_reversals_per_s``:
    how often a moving patch of the image turns back, i.e. the (cell, frame step)s whose
    consecutive flows point against each other (negative dot product), both faster than
    ``reversal_min_speed``, per second of moving-cell time. Jitter shakes the arm back and forth
    and raises it whatever the run's motion level; smooth motion turns back only where the task
    does (down to a grasp and up again). ``flow_speed_rms`` and ``moving_cell_share`` say how
    much moves (not scored). (The flow's RMS second difference does not tell jittered from clean
    runs at 5 fps: the arm's own accelerations swamp the jitter's; it is left out.) A still
    scene (no moving frame, below) has no smoothness number;
  * motion energy per frame: share of pixels whose luminance changed by more than
    ``diff_threshold`` (0..255) since the previous frame (after a ``blur_px`` blur, which keeps
    sensor noise out); a frame is moving when its energy exceeds ``moving_energy``;
  * action continuity: ``idle_fraction`` = share of still frames within the active span (first to
    last moving frame; a robot that never moves counts 1.0), ``pauses_per_100_frames`` = still
    runs of at least ``min_pause_frames`` followed by motion, per 100 active frames, and
    ``slowdowns_per_s``: short stops, the frame steps whose image speed (the mean of the cell
    flow) is a local minimum below ``slowdown_ratio`` of the fastest motion within
    ``slowdown_window_s`` on either side (both faster than ``slowdown_floor``), per second of the
    time the image moves faster than that floor. A stop of a few control steps spans one or two
    frame steps at 5 fps, and the arm settles only partly in it: too short for a pause and too
    busy for a still frame, it shows as a dip in the speed. A clean run slows down where its task
    does (to grasp, to let go); one that stops and restarts dips between;
  * task progress: object masks per frame; the goal relation of the task in the frames of the
    final ``end_s`` seconds (at least one; "on"/"in"/"cover": the moved object's centroid within
    ``near_max`` target radii of the target's; "stack": within ``stack_near_max``; "out": at least ``out_min``
    radii away; "upright": mask height/width >= ``upright_aspect``). ``goal_gap`` is how far the
    end is from that relation (the largest of those frames' gaps: 0 where it holds in each), ``goal_closure`` the share of the
    starting gap closed, ``max_move`` the largest displacement of the manipulated object from its
    start (its radii). No rest is asked of the object: a rollout ends a few control steps after
    its task succeeds (less than a frame apart at 5 fps), a dropped ball still rolls in its box,
    and the segmenter's centroid shifts as the gripper lets go; an object carried past its goal
    is told apart by the relation having to hold in every one of those frames.
    Label: "successful" when the moved object has moved (``max_move`` >= ``move_ref``/2) and the
    relation holds in each of the final frames it is seen in; ``goal_reached_s`` is then when it
    began to hold for good (seconds from the video's start, read from the frames, never from the
    video's length) and its score 1 / (1 + goal_reached_s / ref): of two successes the one that
    got there sooner made more progress per second. Else ``progress_score`` = min(0.9, 0.5 x
    goal_closure + 0.5 x min(1, max_move / ``move_ref``)), scored as it is, "partially successful"
    when it reaches ``partial_min_score``, "failed" below;
  * force/effort control: from object centroid speeds (radii per frame, only between frames in
    which the object is well visible): ``peak_object_speed``, ``object_speed_spikes`` (steps
    faster than ``spike_speed``) and ``bystander_move`` (largest displacement of the task's other
    objects, which the robot should not shove).

Compare (from the two descriptions alone, deterministic, no position bias):
  1. success before style: when exactly one description is labelled "successful", it wins,
     however it moved. A careful person prefers the run that completes the task to one that does
     not; the other criteria say how well a task was done, not whether;
  2. neither successful (``failures``): "progress" (the default, as the success_first prompt asks
     of a VLM judge): the higher task-progress score (``progress_score``, below) wins where the two
     differ by more than ``progress_margin``, else a tie (step 4); how the two moved never counts.
     What a failing run's motion shows is how it failed (a clean policy dithers near an object it
     cannot grasp, one that pauses dithers less). The margin keeps pixel noise out and keeps what
     the score is good for here: a success the end frames did not show (the object hidden, the
     relation just short), read as a failure near the goal, still beats a run that got nowhere
     (docs/judges.md, "Success before style"). "Partially successful" and "failed" are never
     ranked by their labels: the line between them is a threshold on that pixel estimate. "tie":
     two failures are a tie;
  3. both successful: each criterion gets a score in [0, 1] (smoothness,
     continuity, force: geometric mean over the evidence numbers x of 1 / (1 + x / ref[x]); task
     progress: the goal time's score); a criterion with nothing to judge (no robot motion for
     smoothness, no object motion for force) scores ``no_motion_score``, and a robot that never
     visibly moves scores 0 on continuity. A style criterion (smoothness, continuity, force)
     counts only where the two scores differ by more than ``style_margin``, the goal time always
     (it is read to a frame): runs a person cannot tell apart differ by noise in the style scores
     (the clean act and its one-step-late gripper, 190 pairs of successes of the validation run:
     smoothness more than 0.13 apart in a tenth of them, force more than 0.04, the goal time's
     score at most 0.03 in nine of ten), and without the margin that noise outvoted the goal
     time, the one view a 5 fps video gives of short stops. The counted scores are averaged with
     equal weight and the higher mean wins when the means differ by more than ``score_tie_eps``;
  4. exact tie: the smaller description hash wins (swapping A and B flips the letter) and
     identical descriptions get a letter from a hash parity.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from r2s_eval.errors import ConfigError, DataError
from r2s_eval.judge.cache import cache_key
from r2s_eval.judge.heuristic import check_failure_rule, description, failures_tie, fmt, merge_config, ratio_score
from r2s_eval.judge.base import Description, Judge, RolloutInput, Verdict, register_judge, tie_break

DEFAULTS: dict[str, Any] = {
    "backend": "video",
    "name": "video-pixel-heuristic-not-vlm",
    "segmenter": {"type": "hsv"},  # r2s_eval.calib.segment.make_segmenter config
    "blur_px": 3,  # Gaussian blur before frame differencing (odd; 0 = off)
    "diff_threshold": 12,  # luminance change (0..255) that counts a pixel as changed
    "moving_energy": 0.002,  # share of changed pixels above which a frame is moving
    # Optical flow: grey frames downscaled to this long side (fast; the arm spans many cells)...
    "flow_side_px": 128,
    "flow_cell_px": 8,  # ...and averaged over cells this size, which keeps single-pixel noise out
    # Image fractions per second below which a cell counts as still: about half a pixel per
    # frame at 128 px and 5 fps; in a still scene 99 % of the cells stay below a tenth of it.
    "reversal_min_speed": 0.02,
    "min_pause_frames": 3,
    # Short stops (``slowdowns_per_s``): a dip below this share of the speed around it...
    "slowdown_ratio": 0.35,
    "slowdown_window_s": 0.6,  # ...the fastest motion within this many seconds on either side...
    "slowdown_floor": 0.005,  # ...which must exceed this (image fractions per second; still scenes stay below)
    "min_visible_share": 0.5,  # a mask counts when its area is >= this share of the object's first-frame area
    # ...and down to this share for where an object ends up (a gripper may still cover what it set down)
    "part_visible_share": 0.1,
    # The end read for the goal: 0.3 s, the 3 control steps (at 10 Hz) a rollout's success must
    # hold before it ends: 2 frames at 5 fps, 3 at 10 fps.
    "end_s": 0.3,
    # The cup's mask sits above the plate's in an oblique view, so "on" holds a little beyond the
    # plate's radius: in the unmodelled_fidelity experiment's cup_on_plate sim rollouts (its nine
    # repetitions' run, inits 0-59 of 180) 0.8 found 36 % of the successes, 0.95 86 % with 5.3 % of the failures read
    # as successes (4.0 % at 0.8); the other 120 inits, not used to choose it, 87 % and 6.2 %.
    # Over all 180: cover_ball 69 % -> 81 % of the successes (failures 4.7 % -> 5.7 %), ball_in_box
    # 99 % -> 100 % (none of its failures comes within 0.95).
    "near_max": 0.95,
    "stack_near_max": 1.2,
    "out_min": 1.5,
    "upright_aspect": 1.15,
    "move_ref": 1.0,
    "partial_min_score": 0.2,
    "spike_speed": 0.5,
    "no_motion_score": 0.5,
    "failures": "progress",  # two failed runs: "progress" or "tie" (heuristic.FAILURE_RULES)
    "progress_margin": 0.25,  # failures: progress, the smallest progress-score difference that counts
    # Two successes: a style criterion's scores must differ by more than this to count (step 3).
    "style_margin": 0.1,
    "score_tie_eps": 1e-9,
    # Reference levels: an evidence number equal to its reference scores 0.5.
    "ref": {
        # From the bundled world's rollouts (cup_on_plate, ball_in_box, cover_ball; 224 px at
        # 5 fps; ACT and its variant with action_noise_std 0.01 rad, 60 seeds per task each):
        # successful clean runs turn back 0.12/s (median; 90th percentile 0.41), the same runs
        # jittered 1.21/s (10th percentile 0.87), failed clean runs (dithering near the object)
        # 1.86/s. At 0.5 a clean success scores about 0.8 ("smooth"), a jittered one about 0.3.
        "flow_reversals_per_s": 0.5,
        "idle_fraction": 0.2,
        "pauses_per_100_frames": 2.0,
        # The unmodelled_fidelity experiment's sim rollouts (25 successes each, 224 px, 5 fps): act
        # slows down 0.30 times a second (median; quartiles 0.24-0.39), the same weights pausing
        # 3 control steps in every 13 (act_hesitant) 0.72 (0.66-0.80), jittered 0.17 (the jitter
        # fills the dips). At 0.7 act's number scores 0.70, the hesitant one's 0.49.
        "slowdowns_per_s": 0.7,
        "peak_object_speed": 0.5,
        "object_speed_spikes": 1.0,
        "bystander_move": 0.5,
        # When a successful run's goal began to hold for good: the demo's act gets there in 5.0 s
        # on cup_on_plate, 4.6 s on ball_in_box, 6.8 s on cover_ball (medians at 5 fps); a run
        # at 6 s scores 0.5, one at 12 s 0.33.
        "goal_reached_s": 6.0,
    },
    "good_score": 0.67,
    "fair_score": 0.4,
}

SCORED: dict[str, tuple[str, ...]] = {
    "motion_smoothness": ("flow_reversals_per_s",),
    "action_continuity": ("idle_fraction", "pauses_per_100_frames", "slowdowns_per_s"),
    "force_control": ("peak_object_speed", "object_speed_spikes", "bystander_move"),
}
_WORDS = {
    "motion_smoothness": ("smooth", "somewhat jerky", "jerky"),
    "action_continuity": ("continuous", "hesitant at times", "stop-and-go"),
    "force_control": ("gentle", "firm", "forceful"),
}
# What each relational predicate of a task's success looks like in pixels: (relation, the moved
# object's parameter, the reference object's parameter). A judge knows what the instruction asks
# for; it reads that from the task's definition, never from the outcome.
RELATION_OF_PREDICATE: dict[str, tuple[str, str, str]] = {
    "on_top_of": ("on", "object", "support"),
    "inside": ("in", "object", "container"),
    "covered_by": ("cover", "cover", "object"),  # the cup moves over the ball
    "apart": ("out", "object", "other"),
}


def _predicates(condition) -> list[tuple[str, dict]]:
    """The (predicate, parameters) of a condition in the order the world lists them."""
    if isinstance(condition, list):
        return [p for c in condition for p in _predicates(c)]
    (name, params), = condition.items()
    if name in ("all", "any"):
        return _predicates(params)
    if name == "not":
        return []  # what must not hold is no goal to look for
    return [(name, params)]


def goal_relation(task) -> tuple[str, str, str | None]:
    """(relation, moved object, reference object) of a task: its success condition's first
    relational predicate ("stack" for an object on a support whose kind reads as a stack, a
    block's), else "upright" of the object it must stand up."""
    found = _predicates(task.success_condition)
    for name, params in found:
        if name in RELATION_OF_PREDICATE:
            relation, mover, reference = RELATION_OF_PREDICATE[name]
            if name == "on_top_of" and task.object(params["support"]).kind_object.stacked_on:
                relation = "stack"
            return relation, params[mover], params[reference]
    upright = [params["object"] for name, params in found if name == "upright"]
    if upright:
        return "upright", upright[0], None
    raise ConfigError(f"video judge: task {task.key!r} has no goal the judge can see (on_top_of, inside, "
                     f"covered_by, apart or upright in its success)")


def _words(text: str) -> set[str]:
    return {w for w in re.findall(r"[a-z]+", text.lower()) if w not in {"the", "and", "it", "with", "of", "a"}}


def task_from_instruction(instruction: str, tasks: Mapping[str, Any]) -> str:
    """The key of the task (of ``tasks``, the world's) whose instruction shares the most words with
    `instruction` (ValueError if none fits)."""
    words = _words(instruction)
    best, best_score = None, 0.0
    for key, task in sorted(tasks.items()):
        ref = _words(task.instruction)
        score = len(words & ref) / max(len(words | ref), 1)
        if score > best_score:
            best, best_score = key, score
    if best is None or best_score < 0.5:
        raise DataError(f"video judge: no known task matches the instruction {instruction!r}")
    return best


# ---------------------------------------------------------------- pixel measurements
def video_fps(path) -> float:
    """Frames per second of a video file, from its container: what a player of the file knows, the
    same for every rollout of a run (needed to state motion per second)."""
    import av

    with av.open(str(path)) as container:
        rate = container.streams.video[0].average_rate
    if not rate or not float(rate) > 0:
        raise DataError(f"video judge: {path} states no frame rate")
    return float(rate)


def grey(frames: np.ndarray) -> np.ndarray:
    """Luminance frames (T, H, W) uint8 of RGB frames."""
    import cv2

    return np.stack([cv2.cvtColor(np.ascontiguousarray(f), cv2.COLOR_RGB2GRAY) for f in frames])


def shrink(luma: np.ndarray, side_px: int) -> np.ndarray:
    """Luminance frames shrunk (area average) to `side_px` on the long side, when larger."""
    import cv2

    h, w = luma.shape[1:3]
    scale = side_px / max(h, w)
    if scale >= 1.0:
        return luma
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    return np.stack([cv2.resize(g, size, interpolation=cv2.INTER_AREA) for g in luma])


def motion_energy(luma: np.ndarray, blur_px: int, diff_threshold: float) -> np.ndarray:
    """Share of pixels whose (blurred) luminance (`grey` frames) changed by more than
    `diff_threshold`, per frame step."""
    import cv2

    if blur_px:
        luma = np.stack([cv2.GaussianBlur(g, (blur_px, blur_px), 0) for g in luma])
    if len(luma) < 2:
        return np.zeros(0)
    return (np.abs(np.diff(luma.astype(np.int16), axis=0)) > diff_threshold).mean(axis=(1, 2))


def cell_flow(luma: np.ndarray, fps: float, side_px: int, cell_px: int) -> np.ndarray:
    """Dense optical flow between consecutive (`grey`) frames shrunk to `side_px`, (T-1, rows,
    cols, 2), averaged over square cells, in image fractions (of the long side) per second: an
    absolute scale, the same for a 224 or a 448 px video of the same motion."""
    import cv2

    g = shrink(luma, side_px)
    if len(g) < 2 or min(g.shape[1:]) < max(12, cell_px):  # DIS needs 12 px; nothing to measure
        return np.zeros((0, 0, 0, 2))
    # DIS (OpenCV's dense inverse-search flow), its fastest preset: on the bundled world's videos
    # it separates jittered from clean runs as well as Farneback does, four times as fast.
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST)
    flow = np.stack([dis.calc(g[t], g[t + 1], None) for t in range(len(g) - 1)])
    rows, cols = g.shape[1] // cell_px, g.shape[2] // cell_px
    flow = flow[:, :rows * cell_px, :cols * cell_px].reshape(len(flow), rows, cell_px, cols, cell_px, 2).mean((2, 4))
    return flow * fps / max(g.shape[1:])


def flow_reversals_per_s(v: np.ndarray, fps: float, min_speed: float) -> float | None:
    """How often a moving patch of the image turns back: the cells whose flow points against
    their flow one frame before (both faster than `min_speed`), per second of moving-cell time.
    A count of events, so unlike a jerk divided by the run's mean motion, jitter on top of any
    motion raises it. None when nothing moves."""
    fast = np.linalg.norm(v, axis=-1) > min_speed
    both = fast[:-1] & fast[1:]
    if not both.any():
        return None
    back = (np.sum(v[:-1] * v[1:], axis=-1) < 0) & both
    return float(back.sum() / both.sum() * fps)


def smoothness(v: np.ndarray, fps: float, c: Mapping[str, Any]) -> dict[str, Any]:
    """The motion smoothness evidence of a run's cell flow `v` (image fractions per second)."""
    speed = np.linalg.norm(v, axis=-1)
    fast = speed > c["reversal_min_speed"]
    return {
        "flow_reversals_per_s": flow_reversals_per_s(v, fps, c["reversal_min_speed"]),
        "flow_speed_rms": float(np.sqrt(np.mean(speed[fast] ** 2))) if fast.any() else 0.0,
        "moving_cell_share": float(fast.mean()) if fast.size else 0.0,
    }


def slowdowns_per_s(v: np.ndarray, fps: float, c: Mapping[str, Any]) -> float:
    """Short stops in a run's cell flow `v` (see the module docstring), per second of the time the
    image moves faster than ``slowdown_floor``; 0 when it never does."""
    speed = np.linalg.norm(v, axis=-1).mean(axis=(1, 2)) if v.size else np.zeros(0)
    floor, ratio = float(c["slowdown_floor"]), float(c["slowdown_ratio"])
    moving = np.flatnonzero(speed > floor)
    if len(moving) == 0:
        return 0.0
    w = max(1, round(float(c["slowdown_window_s"]) * fps))
    dips = 0
    for i in range(1, len(speed) - 1):
        around = min(speed[max(0, i - w):i].max(), speed[i + 1:i + 1 + w].max())
        if speed[i] <= min(speed[i - 1], speed[i + 1]) and around > floor and speed[i] < ratio * around:
            dips += 1
    return float(dips * fps / (moving[-1] - moving[0] + 1))


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, end) of each run of True."""
    out, start = [], None
    for i, m in enumerate(mask):
        if m and start is None:
            start = i
        elif not m and start is not None:
            out.append((start, i))
            start = None
    if start is not None:
        out.append((start, len(mask)))
    return out


def continuity(e: np.ndarray, c: Mapping[str, Any]) -> dict[str, Any]:
    """Stills and pauses from the motion energy, within the active span."""
    moving = e > c["moving_energy"]
    idx = np.flatnonzero(moving)
    if len(idx) == 0:
        return {"idle_fraction": 1.0, "pauses_per_100_frames": 0.0, "pauses": 0, "motion_bursts": 0,
                "robot_moved": False}
    span = e[idx[0]: idx[-1] + 1]
    still = span <= c["moving_energy"]
    pauses = sum(1 for s, t in _runs(still) if t - s >= c["min_pause_frames"])  # runs inside the span end in motion
    return {
        "idle_fraction": float(still.mean()),
        "pauses_per_100_frames": 100.0 * pauses / len(span),
        "pauses": int(pauses),
        "motion_bursts": len(_runs(~still)),
        "robot_moved": True,
    }


def object_tracks(frames: np.ndarray, segmenter: Any, names: tuple[str, ...], min_visible_share: float,
                  part_visible_share: float):
    """Per object: centroids ``c`` (T, 2) as (row, col) with NaN where not well visible (area below
    ``min_visible_share`` of its first frame's), ``part_c`` the same down to ``part_visible_share``
    (an object partly hidden by the gripper), radius ``r`` (px), ``aspect`` (T,)."""
    masks = {n: [] for n in names}
    for f in frames:
        seg = segmenter.segment(f)
        for n in names:
            masks[n].append(np.asarray(seg.get(n, np.zeros(f.shape[:2], bool)), bool))
    tracks = {}
    for n in names:
        areas = np.array([m.sum() for m in masks[n]], float)
        ref_area = areas[0] if areas[0] > 0 else (areas.max() if areas.max() > 0 else 0.0)
        cents = np.full((len(frames), 2), np.nan)
        part = np.full((len(frames), 2), np.nan)
        aspect = np.full(len(frames), np.nan)
        for t, m in enumerate(masks[n]):
            if ref_area > 0 and areas[t] >= part_visible_share * ref_area and areas[t] > 0:
                rc = np.argwhere(m)
                part[t] = rc.mean(0)
                if areas[t] >= min_visible_share * ref_area:
                    cents[t] = part[t]
                    h, w = rc.max(0) - rc.min(0) + 1
                    aspect[t] = h / w
        radius = math.sqrt(ref_area / math.pi) if ref_area > 0 else 1.0
        tracks[n] = {"c": cents, "part_c": part, "r": max(radius, 1.0), "aspect": aspect, "area0": float(areas[0])}
    return tracks


def _last_valid(a: np.ndarray, k: int) -> np.ndarray | None:
    ok = np.flatnonzero(~np.isnan(a.reshape(len(a), -1)).any(1))
    if len(ok) == 0:
        return None
    return np.nanmean(a[ok[-k:]], axis=0)


def _first_valid(a: np.ndarray) -> np.ndarray | None:
    ok = np.flatnonzero(~np.isnan(a.reshape(len(a), -1)).any(1))
    return None if len(ok) == 0 else a[ok[0]]


def _speeds(c: np.ndarray, r: float) -> np.ndarray:
    v = np.linalg.norm(np.diff(c, axis=0), axis=1) / r
    return v[~np.isnan(v)]


def task_objects(task) -> tuple[str, ...]:
    """The objects the judge follows in a task's video: the one moved and the reference."""
    _, mover, target = goal_relation(task)
    return tuple(n for n in (mover, target) if n)


def end_frame_count(end_s: float, fps: float) -> int:
    """The frames that span the last ``end_s`` seconds of a video at ``fps``, at least one."""
    return max(1, math.ceil(end_s * fps - 1e-9))


def progress_force(frames: np.ndarray, fps: float, task, segmenter: Any, c: Mapping[str, Any]):
    rel, mover, target = goal_relation(task)
    names = task_objects(task)
    tr = object_tracks(frames, segmenter, names, c["min_visible_share"], c["part_visible_share"])
    k = end_frame_count(float(c["end_s"]), fps)
    m = tr[mover]
    start = _first_valid(m["c"])
    seen = start is not None
    disp = np.linalg.norm(m["c"] - start, axis=1) / m["r"] if seen else np.zeros(1)
    max_move = float(np.nanmax(disp)) if seen and not np.isnan(disp).all() else 0.0

    def gap(pos: np.ndarray | None, tpos: np.ndarray | None, aspect: float | None) -> float | None:
        if rel == "upright":
            return None if aspect is None else max(0.0, c["upright_aspect"] - float(aspect))
        if pos is None or tpos is None:
            return None
        d = float(np.linalg.norm(pos - tpos)) / tr[target]["r"]
        if rel == "out":
            return max(0.0, c["out_min"] - d)
        return max(0.0, d - (c["stack_near_max"] if rel == "stack" else c["near_max"]))

    t0 = tend = None
    if rel != "upright":
        t0 = _first_valid(tr[target]["c"])
        tend = _last_valid(tr[target]["c"], k)
        tend = t0 if tend is None else tend

    # The gap at the end: the largest over the last k frames that show the moved object, partly
    # hidden included (the gripper that set it down may still cover it; the reference where it is
    # seen there, else where it was last seen), 0 only where the relation holds in each of them.
    # Where none of them shows it, the last k frames that show it whole.
    def target_at(i: int) -> np.ndarray | None:
        if rel == "upright" or np.isnan(tr[target]["c"][i]).any():
            return tend
        return tr[target]["c"][i]

    n = len(frames)
    pos, at = m["c"], np.flatnonzero(~np.isnan(m["c"]).any(1))[-k:]  # the last k frames showing it whole
    partly = [i for i in range(max(0, n - k), n) if not np.isnan(m["part_c"][i]).any()]
    if rel != "upright" and partly:
        pos, at = m["part_c"], partly
    end_gaps = [gap(pos[i], target_at(i), m["aspect"][i]) for i in at]

    def reached_s() -> float:
        """When the relation began to hold for good: the first of the frames showing the object
        from which it holds in each to the end (seconds from the video's start)."""
        first = at[0]
        for i in range(first - 1, -1, -1):
            if np.isnan(pos[i]).any():
                continue
            g = gap(pos[i], target_at(i), m["aspect"][i])
            if g is None or g > 0:
                break
            first = i
        return round(first / fps, 6)

    g0 = gap(start, t0, _first_valid(m["aspect"]))
    g1 = max(end_gaps) if end_gaps and None not in end_gaps else None
    if g0 is None or g1 is None:
        closure = 0.0
    else:
        closure = 1.0 if g0 <= 0 else round(float(np.clip(1.0 - g1 / g0, 0.0, 1.0)), 6)
    goal_met = bool(g1 is not None and g1 <= 0 and max_move >= 0.5 * c["move_ref"])
    goal_reached_s = reached_s() if goal_met else None
    score = 1.0 if goal_met else round(min(0.9, 0.5 * closure + 0.5 * min(1.0, max_move / c["move_ref"])), 6)
    label = ("successful" if goal_met else
             "partially successful" if score >= c["partial_min_score"] else "failed")
    prog = {
        "task": task.key, "relation": rel, "object": mover, "reference": target,
        "object_visible": seen, "goal_gap": g1, "goal_closure": closure, "max_move": max_move,
        "goal_met": goal_met, "goal_reached_s": goal_reached_s, "progress_score": score,
    }

    speeds = _speeds(m["c"], m["r"])
    bystander = 0.0
    if target and rel != "stack":  # in stacking both blocks may be moved
        t = tr[target]
        t0 = _first_valid(t["c"])
        if t0 is not None:
            d = np.linalg.norm(t["c"] - t0, axis=1) / t["r"]
            bystander = float(np.nanmax(d)) if not np.isnan(d).all() else 0.0
    force = {
        "peak_object_speed": float(speeds.max()) if len(speeds) else 0.0,
        "object_speed_spikes": int((speeds > c["spike_speed"]).sum()),
        "bystander_move": bystander,
        "object_moved": bool(max_move >= 0.5 * c["move_ref"] or bystander >= 0.5 * c["move_ref"]),
    }
    return prog, label, force


@register_judge("video")
class VideoJudge(Judge):
    """Offline pixel-reading judge; NOT a VLM (see the module docstring for its rules)."""

    # v2: smoothness from optical-flow reversals; success before style. v3: short slowdowns in
    # continuity; the goal "on"/"in"/"cover" within 0.95 target radii (was 0.8)
    prompt_version = "video-v3"
    compare_version = "video-compare-v3"  # v3: failures and style differences count beyond a margin
    compare_keys = ("failures", "progress_margin", "style_margin")
    inputs = ("video",)

    def __init__(self, cfg: Mapping[str, Any] | None = None):
        super().__init__(cfg)
        self.cfg = merge_config('video', DEFAULTS, self.cfg, nested=["ref"])
        if self.cfg["backend"] != "video":
            raise ValueError(f"video judge built with backend {self.cfg['backend']!r}")
        check_failure_rule("video", self.cfg["failures"])
        if not float(self.cfg["style_margin"]) >= 0:
            raise ConfigError(f"video judge: style_margin must be >= 0, got {self.cfg['style_margin']}")
        bad_ref = {k: v for k, v in self.cfg["ref"].items() if not float(v) > 0}
        if bad_ref:
            raise ConfigError(f"video judge: ref levels must be > 0, got {bad_ref}")
        if int(self.cfg["blur_px"]) and int(self.cfg["blur_px"]) % 2 == 0:
            raise ConfigError(f"video judge: blur_px must be odd or 0, got {self.cfg['blur_px']}")
        if not 1 <= int(self.cfg["flow_cell_px"]) <= int(self.cfg["flow_side_px"]):
            raise ConfigError(f"video judge: need 1 <= flow_cell_px <= flow_side_px, got "
                              f"{self.cfg['flow_cell_px']} and {self.cfg['flow_side_px']}")
        if not float(self.cfg["reversal_min_speed"]) > 0:
            raise ConfigError(f"video judge: reversal_min_speed must be > 0, got {self.cfg['reversal_min_speed']}")
        if not 0 < float(self.cfg["slowdown_ratio"]) < 1:
            raise ConfigError(f"video judge: slowdown_ratio must be in (0, 1), got {self.cfg['slowdown_ratio']}")
        if not (float(self.cfg["slowdown_window_s"]) > 0 and float(self.cfg["slowdown_floor"]) > 0):
            raise ConfigError(f"video judge: slowdown_window_s and slowdown_floor must be > 0, got "
                              f"{self.cfg['slowdown_window_s']} and {self.cfg['slowdown_floor']}")
        if not float(self.cfg["end_s"]) > 0:
            raise ConfigError(f"video judge: end_s must be > 0 seconds, got {self.cfg['end_s']}")
        self._segmenters: dict[str, Any] = {}
        self._tasks: Mapping[str, Any] | None = None  # what the judge knows of the tasks (know_tasks)

    def know_tasks(self, tasks: Mapping[str, Any]) -> None:
        """The world's tasks: what each instruction asks for (its goal relation) and what its
        objects look like (their colours). It is part of the judge's identity, so answers given
        with other knowledge are never reused."""
        self._tasks, self._segmenters = tasks, {}

    @property
    def tasks(self) -> Mapping[str, Any]:
        if self._tasks is None:
            raise ConfigError("video judge: it knows no world's tasks; call know_tasks(world_tasks(world)) "
                              "(r2s_eval.world_judging.world_judge builds a judge that knows them)")
        return self._tasks

    def identity(self) -> dict[str, str]:
        def looks(obj) -> list:  # its colour, and the world's explicit colour range where it gives one
            return list(obj.rgba) + ([obj.hue] if obj.hue else [])

        knowledge = {key: [t.instruction, list(goal_relation(t)), {n: looks(t.object(n)) for n in task_objects(t)}]
                     for key, t in sorted(self.tasks.items())}
        return {**super().identity(), "tasks": cache_key(knowledge)}

    def segmenter(self, task_key: str):
        """A segmenter of the objects the judge follows in ``task_key`` only: each object's mask
        is the same whichever others are segmented beside it, and the rest would cost time."""
        if task_key not in self._segmenters:
            from r2s_eval.calib.segment import finders, make_segmenter

            task = self.tasks[task_key]
            followed = [task.object(n) for n in task_objects(task)]
            self._segmenters[task_key] = make_segmenter(self.cfg["segmenter"], {o.name: o.rgba for o in followed},
                                                        finders(followed))
        return self._segmenters[task_key]

    # ---------------------------------------------------------------- describe
    def describe(self, rollout: RolloutInput) -> Description:
        if rollout.video_path is None:
            raise DataError("the video judge reads videos; the rollout input has no video_path")
        from r2s_eval.rollout.mp4 import read_video

        c = self.cfg
        frames = read_video(rollout.video_path)
        task_key = task_from_instruction(rollout.instruction, self.tasks)
        luma = grey(frames)
        cont = continuity(motion_energy(luma, int(c["blur_px"]), float(c["diff_threshold"])), c)
        fps = video_fps(rollout.video_path)
        flow = cell_flow(luma, fps, int(c["flow_side_px"]), int(c["flow_cell_px"]))
        smooth = smoothness(flow, fps, c)
        if cont["robot_moved"]:
            cont["slowdowns_per_s"] = slowdowns_per_s(flow, fps, c)
        else:  # a still scene: what flow there is, is noise
            cont["slowdowns_per_s"] = 0.0
            smooth["flow_reversals_per_s"] = None
        prog, label, force = progress_force(frames, fps, self.tasks[task_key], self.segmenter(task_key), c)

        w = {k: self._word(k, ev) for k, ev in
             (("motion_smoothness", smooth), ("action_continuity", cont), ("force_control", force))}
        moved = smooth["flow_reversals_per_s"] is not None
        if moved:
            s_text = (f"Motion is {w['motion_smoothness']}: moving parts of the image turn back "
                      f"{fmt(smooth['flow_reversals_per_s'])} times per second (optical-flow direction "
                      f"reversals), moving at {fmt(smooth['flow_speed_rms'])} image sizes per second (RMS).")
        else:
            s_text = "No robot motion is visible, so smoothness cannot be judged."
        if cont["robot_moved"]:
            c_text = (f"Execution is {w['action_continuity']}: still {100 * cont['idle_fraction']:.0f}% of the "
                      f"active span, {cont['pauses']} pauses, {cont['motion_bursts']} bursts of motion, "
                      f"{fmt(cont['slowdowns_per_s'])} short slowdowns per second.")
        else:
            c_text = "Execution is stop-and-go at its worst: the robot never visibly moves."
        gap = "unknown" if prog["goal_gap"] is None else fmt(prog["goal_gap"])
        p_text = (f"Task {label}: the {prog['object']} moved up to {fmt(prog['max_move'])} of its sizes; "
                  f"goal relation '{prog['relation']}'"
                  + (f" to the {prog['reference']}" if prog["reference"] else "")
                  + (f" holds from {fmt(prog['goal_reached_s'])} s to the end." if prog["goal_met"] else
                     f" does not hold at the end (gap {gap}, {100 * prog['goal_closure']:.0f}% closed)."))
        if force["object_moved"]:
            f_text = (f"Object handling is {w['force_control']}: peak object speed {fmt(force['peak_object_speed'])} "
                      f"sizes/frame, {force['object_speed_spikes']} abrupt jumps, other object displaced "
                      f"{fmt(force['bystander_move'])} sizes.")
        else:
            f_text = "No object is visibly moved, so contact force cannot be judged."
        summary = (f"Video pixel analysis (not a VLM; trajectory not read): {label}; "
                   f"{w['motion_smoothness'] if moved else 'no visible'} motion, "
                   f"{w['action_continuity']}, "
                   f"{w['force_control'] + ' contact' if force['object_moved'] else 'no object moved'}.")

        return description(
            {"motion_smoothness": s_text, "action_continuity": c_text, "task_progress": p_text, "force_control": f_text},
            {"motion_smoothness": smooth, "action_continuity": cont, "task_progress": prog, "force_control": force},
            label, summary, self.name,
        )

    # ---------------------------------------------------------------- scoring
    def criterion_score(self, criterion: str, evidence: Mapping[str, Any]) -> float | None:
        """Score in [0, 1] from a criterion's evidence; None when a number is absent."""
        if criterion == "task_progress":
            if evidence.get("goal_met") and evidence.get("goal_reached_s") is not None:  # how soon
                return ratio_score(evidence, ("goal_reached_s",), self.cfg["ref"])
            x = evidence.get("progress_score")
            return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else None
        if criterion == "motion_smoothness" and evidence.get("flow_reversals_per_s", 0) is None:
            return float(self.cfg["no_motion_score"])
        if criterion == "action_continuity" and evidence.get("robot_moved") is False:
            return 0.0
        if criterion == "force_control" and evidence.get("object_moved") is False:
            return float(self.cfg["no_motion_score"])
        return ratio_score(evidence, SCORED[criterion], self.cfg["ref"])

    def _word(self, criterion: str, evidence: Mapping[str, Any]) -> str:
        s = self.criterion_score(criterion, evidence) or 0.0
        good, fair, bad = _WORDS[criterion]
        return good if s >= self.cfg["good_score"] else fair if s >= self.cfg["fair_score"] else bad

    def scores(self, d: Description) -> dict[str, float | None]:
        return {k: (self.criterion_score(k, d.criteria[k].evidence) if k in d.criteria else None)
                for k in ("motion_smoothness", "action_continuity", "task_progress", "force_control")}

    # ---------------------------------------------------------------- compare
    def compare(self, a: Description, b: Description, instruction: str) -> Verdict:
        la, lb = a.progress_label, b.progress_label
        if (la == "successful") != (lb == "successful"):  # success before style
            return Verdict("A" if la == "successful" else "B", f"success before style: A {la}, B {lb}")
        sa, sb = self.scores(a), self.scores(b)
        if la != "successful":  # neither successful
            if self.cfg["failures"] == "tie":
                return failures_tie(a, b, instruction)
            pa, pb = sa["task_progress"], sb["task_progress"]
            if pa is not None and pb is not None and abs(pa - pb) > float(self.cfg["progress_margin"]):
                return Verdict("A" if pa > pb else "B", f"neither successful; task progress A {pa:.3f} vs B {pb:.3f}")
            return tie_break(a, b, instruction)
        margin = float(self.cfg["style_margin"])
        counted = [k for k in sa if sa[k] is not None and sb[k] is not None
                   and (k == "task_progress" or abs(sa[k] - sb[k]) > margin)]
        ma = sum(sa[k] for k in counted) / len(counted) if counted else 0.0  # equal weights
        mb = sum(sb[k] for k in counted) / len(counted) if counted else 0.0
        if abs(ma - mb) > float(self.cfg["score_tie_eps"]):
            parts = ", ".join(f"{k.replace('_', ' ')} {sa[k]:.2f}/{sb[k]:.2f}" for k in counted)
            return Verdict("A" if ma > mb else "B", f"both successful; equal-weight mean A {ma:.3f} vs B {mb:.3f} ({parts})")
        return tie_break(a, b, instruction)
