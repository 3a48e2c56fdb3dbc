"""Success before style: no built-in judge prefers the run that fails the task to one that
completes it, however either moved, and two failures are a tie (`failures: tie`, the kinematic
judge's default) or decided by how far each got (`failures: progress`, the video judge's), never
by how they moved; asked in both orders."""

from __future__ import annotations

import pytest

from r2s_eval.judge import RolloutInput, make_judge
from tests.helpers.worlds import bundled_tasks

# The words each judge's verdict uses for the rule.
RULE = {"kinematic": "success before style", "video": "success before style"}


def _judge(backend: str, **cfg):
    judge = make_judge({"backend": backend, **cfg})
    judge.know_tasks(bundled_tasks())
    return judge


def _describe(judge, run: dict):
    return judge.describe(RolloutInput(run["instruction"], video_path=run["video_path"],
                                       trajectory_path=run["trajectory_path"]))


@pytest.mark.parametrize("backend", ["kinematic", "video"])
def test_a_shaky_success_beats_a_smooth_failure_in_both_orders(operator_runs, backend):
    judge = _judge(backend)
    shaky_run, smooth_run = operator_runs["jittery"], operator_runs["open_gripper"]
    assert shaky_run["success"] and not smooth_run["success"]
    shaky, smooth = _describe(judge, shaky_run), _describe(judge, smooth_run)
    # The success is read unambiguously, the failure is not taken for one...
    assert shaky.progress_label == "successful" and smooth.progress_label != "successful"
    # ...and the failure is the smoother run: the rule decides, not the motion.
    smoothness = [judge.criterion_score("motion_smoothness", d.criteria["motion_smoothness"].evidence)
                  for d in (shaky, smooth)]
    assert smoothness[1] > smoothness[0] + 0.1
    instruction = shaky_run["instruction"]
    first, second = judge.compare(shaky, smooth, instruction), judge.compare(smooth, shaky, instruction)
    assert (first.letter, second.letter) == ("A", "B")
    assert RULE[backend] in first.rationale and RULE[backend] in second.rationale


@pytest.mark.parametrize("backend", ["kinematic", "video"])
def test_with_failures_tie_two_failures_are_a_tie_however_they_moved(operator_runs, backend):
    judge = _judge(backend, failures="tie")
    smooth_run, shaky_run = operator_runs["open_gripper"], operator_runs["open_gripper_jittery"]
    assert not smooth_run["success"] and not shaky_run["success"]
    smooth, shaky = _describe(judge, smooth_run), _describe(judge, shaky_run)
    assert "successful" not in (smooth.progress_label, shaky.progress_label)
    smoothness = [judge.criterion_score("motion_smoothness", d.criteria["motion_smoothness"].evidence)
                  for d in (smooth, shaky)]
    assert smoothness[0] > smoothness[1] + 0.1  # the jitter is seen...
    instruction = smooth_run["instruction"]
    first, second = judge.compare(smooth, shaky, instruction), judge.compare(shaky, smooth, instruction)
    assert len({first.letter == "A", second.letter == "B"}) == 1  # the same run in both orders...
    # ...as the tie's letter, from the description hashes: no position, no motion decides
    assert all(r.startswith("neither successful") and "a tie" in r for r in (first.rationale, second.rationale))
    assert (first.letter == "A") == (smooth.sha256() < shaky.sha256())


@pytest.mark.parametrize("backend", ["kinematic", "video"])
def test_with_failures_progress_how_far_each_got_decides_not_how_it_moved(operator_runs, backend):
    judge = _judge(backend, failures="progress")
    smooth_run, shaky_run = operator_runs["open_gripper"], operator_runs["open_gripper_jittery"]
    smooth, shaky = _describe(judge, smooth_run), _describe(judge, shaky_run)
    instruction = smooth_run["instruction"]
    first, second = judge.compare(smooth, shaky, instruction), judge.compare(shaky, smooth, instruction)
    winner = {first.letter == "A", second.letter == "B"}
    assert len(winner) == 1  # the same run wins in both orders...
    if backend == "kinematic":  # ...and never by motion: the staged progress is the same, a tie
        assert "tie" in first.rationale and "tie" in second.rationale
    else:  # ...by the task-progress score alone, or a tie where it is equal
        progress = [judge.criterion_score("task_progress", d.criteria["task_progress"].evidence) for d in (smooth, shaky)]
        assert all(r.startswith(("neither successful; task progress", "exact tie")) for r in (first.rationale, second.rationale))
        if progress[0] != progress[1]:
            assert winner == {progress[0] > progress[1]}


@pytest.mark.parametrize("backend", ["kinematic", "video"])
def test_an_unknown_failures_rule_is_refused_by_name(backend):
    with pytest.raises(Exception, match=r"failures must be one of \['tie', 'progress'\], got 'closest'"):
        _judge(backend, failures="closest")
