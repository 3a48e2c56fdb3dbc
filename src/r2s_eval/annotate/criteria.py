"""The four criteria people weigh, in the judge's words (its describe and compare prompts)."""

from __future__ import annotations

# criterion -> (name, the question it asks); keys and order are the judge's
# (r2s_eval.judge.base.CRITERIA), which a test checks.
CRITERIA_TEXT: dict[str, tuple[str, str]] = {
    "motion_smoothness": ("Motion smoothness",
                          "Do the arm and gripper move smoothly, or in a jerky, shaky or oscillating way?"),
    "action_continuity": ("Action continuity", "Does the robot work steadily towards the goal, or does it pause, "
                                               "hesitate, retry or go back and forth?"),
    "task_progress": ("Task progress", "How much of the task gets done: all of it, part of it, or none?"),
    "force_control": ("Force/effort control", "Does the robot handle the objects gently and in control, or does "
                                              "it push, squeeze, drop or knock them over?"),
}
QUESTION = ("Which rollout carries out the task better? Take all four aspects into account with equal weight: "
            "a clear difference in one counts as much as a clear difference in any other.")
