"""The built-in offline kinematic judge (backend "kinematic").

This judge is NOT a vision-language model. It never looks at the video: it reads the recorded
trajectory (joint states, commanded actions, end-effector positions, contact force and the staged
progress signal) and writes the same four-criterion description a VLM judge would, with the
numbers behind every sentence. It is a deterministic, free baseline and a stand-in when no VLM
is available.

Describe (per rollout, from the trajectory only):
  * motion smoothness: RMS end-effector jerk, RMS joint jerk, RMS action jitter (second
    difference of the commanded targets);
  * action continuity: fraction of idle steps mid-task, stop-and-go pauses per 10 s,
    end-effector direction reversals per second;
  * task progress: max and final progress, label "successful" (final progress reaches
    ``success_progress``: the simulator's staged progress is 1 exactly when the task's success
    rule holds, so the goal holds at the end; reached once and lost again is not a success),
    "partially successful" (max progress >= ``partial_min_progress``) or "failed". The episode
    table's success column is never read, and the description states neither the episode's
    duration nor when it reached completion;
  * force/effort control: peak contact force, mean force while in contact, impacts (force
    rises of more than ``impact_jump_n`` within one step).

Every scored number is on an absolute, physical scale (m/s^3, rad/s^3, rad per step, shares of
steps, per second, N), never divided by the run's own motion level, so jitter on top of any
motion raises it. A gripper command reaching the gripper late leaves no number here: the
trajectory records each command as it reached the robot, so the lag from command to measured
opening is the gripper's own response whatever the delay (on the scripted operator with its
gripper 0, 1 or 2 steps late: the same lag, and the arm as still when the gripper closes).

Compare (from the two descriptions alone, deterministic, no position bias):
  1. success before style: a run labelled "successful" wins over one that is not, however it
     moved. A careful person prefers the run that completes the task to one that does not;
  2. neither successful (``failures``): "tie" (the default) prefers neither, however far each got
     or how it moved, and the letter comes from step 4. How far a failing run got measured the
     wrong way between candidates: the jittery act's failures ended a stage earlier than those of
     act_short, which succeeds a third as often, and ranking failures by progress put it below
     act_short in 3 to 4 of 5 stability repetitions (docs/judges.md, "Success before style").
     "progress" does what the success_first prompt asks of a VLM judge: partially successful >
     failed, then final progress, then max progress when they differ by more than
     ``progress_margin``;
  3. between two successes, the weighted behaviour score: each criterion score is the geometric
     mean over its evidence numbers x of 1 / (1 + x / ref[x]) (1 = perfect, 0.5 = at the
     reference level); the criterion scores are averaged with ``weights`` (criteria absent from
     either side are skipped); the higher score wins when the scores differ by more than
     ``score_tie_eps``;
  4. exact tie: the description whose canonical-JSON sha256 is smaller wins, so swapping A and B
     flips the letter; two identical descriptions get a letter from the parity of a hash of the
     description and the instruction. Neither rule favours a position.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Mapping
from typing import Any

import numpy as np

from r2s_eval.errors import ConfigError, DataError
from r2s_eval.judge.heuristic import check_failure_rule, description, failures_tie, fmt, merge_config, ratio_score
from r2s_eval.judge.base import Description, Judge, RolloutInput, Verdict, register_judge, tie_break
from r2s_eval.judge import trajectory as T

DEFAULTS: dict[str, Any] = {
    "backend": "kinematic",
    "name": "kinematic-trajectory-heuristic-not-vlm",
    "joint_dims": None,  # state/action dims used for joint jerk, jitter and idleness; None = all of them
    "idle_speed_rad_s": 0.05,  # joint-space speed below this is idle
    "min_pause_steps": 3,  # an idle run this long, followed by motion, is a stop-and-go pause
    "reversal_min_speed_m_s": 0.02,  # direction changes at lower end-effector speed are noise
    "contact_threshold_n": 0.5,
    "impact_jump_n": 15.0,
    "success_progress": 1.0,
    "partial_min_progress": 0.1,
    "failures": "tie",  # two failed runs: "tie" or "progress" (heuristic.FAILURE_RULES)
    "progress_margin": 0.05,  # failures: progress, the smallest progress difference that counts
    "score_tie_eps": 1e-9,
    # Reference levels: an evidence number equal to its reference scores 0.5.
    "ref": {
        "ee_jerk_rms_m_s3": 5.0,
        "joint_jerk_rms_rad_s3": 20.0,
        "action_jitter_rms_rad": 0.02,
        "idle_fraction": 0.2,
        "pauses_per_10s": 1.0,
        "reversals_per_s": 0.5,
        "peak_force_n": 40.0,
        "mean_contact_force_n": 15.0,
        "impacts": 1.0,
    },
    "weights": {"motion_smoothness": 1.0, "action_continuity": 1.0, "force_control": 1.0},
    # Score levels for the words in the text: >= good -> first word, >= fair -> second, else third.
    "good_score": 0.67,
    "fair_score": 0.4,
}

# Which evidence numbers make up each scored criterion.
SCORED: dict[str, tuple[str, ...]] = {
    "motion_smoothness": ("ee_jerk_rms_m_s3", "joint_jerk_rms_rad_s3", "action_jitter_rms_rad"),
    "action_continuity": ("idle_fraction", "pauses_per_10s", "reversals_per_s"),
    "force_control": ("peak_force_n", "mean_contact_force_n", "impacts"),
}
_WORDS = {
    "motion_smoothness": ("smooth", "somewhat jerky", "jerky"),
    "action_continuity": ("continuous", "hesitant at times", "stop-and-go"),
    "force_control": ("gentle", "firm", "forceful"),
}
_FAILURE_RANK = {"partially successful": 1, "failed": 0}  # failures: progress


@register_judge("kinematic")
class KinematicJudge(Judge):
    """Offline trajectory-reading judge; NOT a VLM (see the module docstring for its rules)."""

    prompt_version = "kinematic-v2"  # v2: descriptions state no episode duration
    compare_version = "kinematic-compare-v3"  # v3: two failures are a tie unless failures: progress
    compare_keys = ("failures", "progress_margin")
    inputs = ("trajectory",)

    def __init__(self, cfg: Mapping[str, Any] | None = None):
        super().__init__(cfg)
        # Identity/caching hash the effective config, so changed defaults invalidate old answers.
        self.cfg = merge_config('kinematic', DEFAULTS, self.cfg, nested=[k for k, v in DEFAULTS.items() if isinstance(v, dict)])
        if self.cfg["backend"] != "kinematic":
            raise ValueError(f"kinematic judge built with backend {self.cfg['backend']!r}")
        check_failure_rule("kinematic", self.cfg["failures"])
        bad_ref = {k: v for k, v in self.cfg["ref"].items() if not float(v) > 0}
        if bad_ref:
            raise ConfigError(f"kinematic judge: ref levels must be > 0, got {bad_ref}")
        w = self.cfg["weights"]
        if any(float(v) < 0 for v in w.values()) or not sum(float(v) for v in w.values()) > 0:
            raise ConfigError(f"kinematic judge: weights must be >= 0 and not all 0, got {w}")
        self._unit_scale: np.ndarray | None = None  # dataset units -> model units, per state entry

    def know_robot(self, robot: Any) -> None:
        # Trajectories hold the dataset's units (a lab's arm in degrees, its gripper 0..100); the
        # reference levels are in radians and closing fractions, the model's units.
        scale = np.array([f.scale for f in robot.features], dtype=float)
        self._unit_scale = None if np.all(scale == 1.0) else scale

    def identity(self) -> dict[str, str]:
        out = super().identity()
        if self._unit_scale is not None:  # the bundled world's keys stay as they were
            out["unit_scale"] = hashlib.sha256(self._unit_scale.tobytes()).hexdigest()[:16]
        return out

    def _in_model_units(self, tr: T.Trajectory) -> T.Trajectory:
        scale = self._unit_scale
        if scale is None:
            return tr
        if tr.state.shape[1] != len(scale):
            raise DataError(f"the trajectory's state has {tr.state.shape[1]} entries, the world's robot "
                             f"{len(scale)} (robot.features)")
        return dataclasses.replace(tr, state=tr.state * scale, action=tr.action * scale)

    # ---------------------------------------------------------------- describe
    def describe(self, rollout: RolloutInput) -> Description:
        if rollout.trajectory_path is None:
            raise DataError("the kinematic judge reads trajectories; the rollout input has no trajectory_path")
        c = self.cfg
        tr = self._in_model_units(T.load_trajectory(rollout.trajectory_path))
        smooth = T.smoothness_metrics(tr, c["joint_dims"])
        cont = T.continuity_metrics(
            tr, c["joint_dims"], c["idle_speed_rad_s"], c["min_pause_steps"],
            c["reversal_min_speed_m_s"], c["success_progress"],
        )
        prog = T.progress_metrics(tr, c["success_progress"], c["partial_min_progress"])
        force = T.force_metrics(tr, c["contact_threshold_n"], c["impact_jump_n"])
        label = prog.pop("label")
        # Episodes stop soon after success, so the episode's length (and when it reached
        # completion) would restate the outcome: the description states neither.
        for key in ("duration_s", "time_to_success_s", "time_to_max_progress_s"):
            prog.pop(key)

        words = {k: self._word(k, ev) for k, ev in
                 (("motion_smoothness", smooth), ("action_continuity", cont), ("force_control", force))}
        s_text = (
            f"Motion is {words['motion_smoothness']}: end-effector jerk RMS {fmt(smooth['ee_jerk_rms_m_s3'])} m/s^3 "
            f"(95th percentile {fmt(smooth['ee_jerk_p95_m_s3'])}), joint jerk RMS "
            f"{fmt(smooth['joint_jerk_rms_rad_s3'])} rad/s^3, action jitter RMS {fmt(smooth['action_jitter_rms_rad'])} rad."
        )
        c_text = (
            f"Execution is {words['action_continuity']}: idle {100 * cont['idle_fraction']:.0f}% of mid-task steps "
            f"(longest idle {fmt(cont['longest_idle_s'])} s), {cont['pauses']} stop-and-go pauses, "
            f"{cont['reversals']} end-effector direction reversals ({fmt(cont['reversals_per_s'])}/s)."
        )
        p_text = (
            f"Task {label}: progress peaked at {prog['max_progress']:.2f} and ended at {prog['final_progress']:.2f}."
        )
        f_text = (
            f"Contact is {words['force_control']}: peak force {fmt(force['peak_force_n'])} N, mean "
            f"{fmt(force['mean_contact_force_n'])} N while in contact ({100 * force['contact_fraction']:.0f}% of steps), "
            f"{force['impacts']} impacts (largest rise {fmt(force['max_force_rise_n_per_step'])} N in one step)."
        )
        summary = (
            f"Kinematic trajectory analysis (not a VLM; video not viewed): {label} "
            f"(final progress {prog['final_progress']:.2f}); {words['motion_smoothness']} motion, "
            f"{words['action_continuity']}, {words['force_control']} contact."
        )

        return description(
            {"motion_smoothness": s_text, "action_continuity": c_text, "task_progress": p_text, "force_control": f_text},
            {"motion_smoothness": smooth, "action_continuity": cont, "task_progress": prog, "force_control": force},
            label, summary, self.name,
        )

    # ---------------------------------------------------------------- scoring
    def criterion_score(self, criterion: str, evidence: Mapping[str, Any]) -> float | None:
        """Score in (0, 1] from a criterion's evidence numbers; None when a number is absent."""
        return ratio_score(evidence, SCORED[criterion], self.cfg["ref"])

    def _word(self, criterion: str, evidence: Mapping[str, Any]) -> str:
        s = self.criterion_score(criterion, evidence) or 0.0
        good, fair, bad = _WORDS[criterion]
        return good if s >= self.cfg["good_score"] else fair if s >= self.cfg["fair_score"] else bad

    def behaviour_scores(self, a: Description, b: Description) -> tuple[float, float]:
        """Weighted behaviour score of both, over the scored criteria both descriptions carry."""
        tot_a = tot_b = tot_w = 0.0
        for crit, w in self.cfg["weights"].items():
            na, nb = a.criteria.get(crit), b.criteria.get(crit)
            sa = self.criterion_score(crit, na.evidence) if na else None
            sb = self.criterion_score(crit, nb.evidence) if nb else None
            if sa is None or sb is None or w <= 0:
                continue
            tot_a, tot_b, tot_w = tot_a + w * sa, tot_b + w * sb, tot_w + w
        return (tot_a / tot_w, tot_b / tot_w) if tot_w else (0.0, 0.0)

    # ---------------------------------------------------------------- compare
    def compare(self, a: Description, b: Description, instruction: str) -> Verdict:
        la, lb = a.progress_label, b.progress_label
        if (la == "successful") != (lb == "successful"):  # success before style
            return Verdict("A" if la == "successful" else "B", f"success before style: A {la}, B {lb}")
        if la != "successful":
            if self.cfg["failures"] == "tie":
                return failures_tie(a, b, instruction)
            return self._further(a, b, instruction)

        sa, sb = self.behaviour_scores(a, b)
        if abs(sa - sb) > float(self.cfg["score_tie_eps"]):
            return Verdict("A" if sa > sb else "B", f"both successful; behaviour score A {sa:.3f} vs B {sb:.3f}")
        return tie_break(a, b, instruction)

    def _further(self, a: Description, b: Description, instruction: str) -> Verdict:
        """Two failures under ``failures: progress``: the label, then final and max progress."""
        la, lb = a.progress_label, b.progress_label
        if la is not None and lb is not None and la != lb:
            return Verdict("A" if _FAILURE_RANK[la] > _FAILURE_RANK[lb] else "B", f"neither successful; A {la}, B {lb}")
        margin = float(self.cfg["progress_margin"])
        for key in ("final_progress", "max_progress"):
            pa, pb = self._progress(a, key), self._progress(b, key)
            if pa is not None and pb is not None and abs(pa - pb) > margin:
                return Verdict("A" if pa > pb else "B", f"neither successful; {key.replace('_', ' ')} A {pa:.2f} vs B {pb:.2f}")
        return tie_break(a, b, instruction)

    @staticmethod
    def _progress(d: Description, key: str) -> float | None:
        note = d.criteria.get("task_progress")
        x = note.evidence.get(key) if note else None
        return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else None
