"""Stage drivers: blind judge inputs, persistent cache, resumption, and the path to a wins matrix."""

from __future__ import annotations

import json

import numpy as np
import pytest

from r2s_eval.compare import sample_pairs, wins_at_checkpoints
from r2s_eval.errors import DataError
from r2s_eval.judge import Description, KinematicJudge, RolloutInput, Verdict, describe_rollouts, judge_pairs
from r2s_eval.judge.drivers import DESCRIPTION_COLUMNS

CFG = {"backend": "kinematic"}


class CountingJudge(KinematicJudge):
    """The kinematic judge (same identity, so same cache keys) counting calls, optionally failing after k."""

    def __init__(self, cfg=CFG, fail_after: int | None = None):
        super().__init__(cfg)
        self.fail_after = fail_after
        self.describe_calls = 0
        self.compare_calls = 0
        self.seen: list[RolloutInput] = []

    def _tick(self, attr: str) -> None:
        if self.fail_after is not None and getattr(self, attr) >= self.fail_after:
            raise RuntimeError("simulated crash")
        setattr(self, attr, getattr(self, attr) + 1)

    def describe(self, rollout):
        self._tick("describe_calls")
        self.seen.append(rollout)
        return super().describe(rollout)

    def compare(self, a, b, instruction):
        self._tick("compare_calls")
        return super().compare(a, b, instruction)


class SpyVideoJudge(CountingJudge):
    """Reads both recordings, like a video+trajectory VLM backend would."""

    inputs = ("video", "trajectory")


def _specs():
    """Two policies x two tasks x three inits; 'good' is smooth, 'bad' is jerky and stalls on task 'stack'."""
    specs = []
    for task in ("lift", "stack"):
        for init in range(3):
            specs.append({"policy": "GoodPolicyAlpha", "task": task, "init_id": init, "traj": {"steps": 40}})
            bad = {"steps": 40, "noise": 0.01}
            if task == "stack":
                bad["stall_at"] = 0.6
            specs.append({"policy": "BadPolicyBeta", "task": task, "init_id": init, "traj": bad,
                          "success": task != "stack"})
    return specs


@pytest.fixture
def episodes(tmp_path, episode_table):
    root = tmp_path / "episodes"
    return episode_table(root, _specs()), root


def test_judge_describe_rollouts_columns_and_cache(episodes, tmp_path):
    df, root = episodes
    judge = CountingJudge()
    out = describe_rollouts(df, root, judge, tmp_path / "cache", stats_path=tmp_path / "stats.json")
    assert list(out.columns) == list(DESCRIPTION_COLUMNS)
    assert out["episode_id"].tolist() == df["episode_id"].tolist()
    assert (out["missing"] == "").all() and (out["judge"] == judge.name).all()
    for js in out["description"]:
        assert Description.from_json(js).missing == ()
    assert judge.describe_calls == len(df)
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert stats["calls"] == len(df) and stats["cache_hits"] == 0 and stats["wall_s"] >= 0
    # Judge labels come from progress only; the stalled episodes are partially successful.
    stack_bad = df[(df["policy"] == "BadPolicyBeta") & (df["task"] == "stack")]["episode_id"]
    assert set(out.set_index("episode_id").loc[stack_bad, "progress_label"]) == {"partially successful"}

    again = CountingJudge()
    out2 = describe_rollouts(df, root, again, tmp_path / "cache")
    assert again.describe_calls == 0
    assert out2.attrs["stats"]["calls"] == 0 and out2.attrs["stats"]["cache_hits"] == len(df)
    assert out2.equals(out)

    # A different judge config is a different judge: nothing is reused.
    other = CountingJudge({"backend": "kinematic", "impact_jump_n": 5.0})
    describe_rollouts(df, root, other, tmp_path / "cache")
    assert other.describe_calls == len(df)


def test_judge_describe_resumes_after_interruption(episodes, tmp_path):
    df, root = episodes
    k = 5
    with pytest.raises(RuntimeError, match="simulated crash"):
        describe_rollouts(df, root, CountingJudge(fail_after=k), tmp_path / "cache")
    resumed = CountingJudge()
    out = describe_rollouts(df, root, resumed, tmp_path / "cache")
    assert resumed.describe_calls == len(df) - k
    assert out.attrs["stats"]["cache_hits"] == k
    assert not list((tmp_path / "cache" / "inputs").glob("*/*"))  # scratch copies are cleaned up


def test_judge_describe_parallel_workers_match_serial(episodes, tmp_path):
    df, root = episodes
    serial = describe_rollouts(df, root, CountingJudge(), tmp_path / "c1")
    judge = CountingJudge()
    parallel = describe_rollouts(df, root, judge, tmp_path / "c2", workers=4)
    assert judge.describe_calls == len(df)
    assert parallel.equals(serial)


def test_judge_sees_no_policy_name_outcome_or_file_name(episodes, tmp_path):
    df, root = episodes
    spy = SpyVideoJudge()
    describe_rollouts(df, root, spy, tmp_path / "cache")
    assert len(spy.seen) == len(df)
    for r in spy.seen:
        visible = " ".join(str(v) for v in (r.instruction, r.video_path, r.trajectory_path))
        for secret in ("GoodPolicyAlpha", "BadPolicyBeta", "SUCCESS", "FAILURE", "ep000", "episodes"):
            assert secret not in visible, visible
        # Files are named by their content hash only.
        assert len(r.video_path.stem) == 64 and r.video_path.suffix == ".mp4"
        assert len(r.trajectory_path.stem) == 64 and r.trajectory_path.suffix == ".parquet"


def test_judge_identical_recordings_are_described_once(tmp_path, episode_table):
    specs = [{"policy": p, "init_id": 0, "traj": {"offset": 0.0}} for p in ("P1", "P2", "P3")]
    df = episode_table(tmp_path / "episodes", specs)
    judge = CountingJudge()
    out = describe_rollouts(df, tmp_path / "episodes", judge, tmp_path / "cache")
    assert judge.describe_calls == 1 and out["description_sha"].nunique() == 1
    assert out.attrs["stats"]["unique_keys"] == 1 and out.attrs["stats"]["items"] == 3


def test_judge_describe_errors_name_the_episode(episodes, tmp_path):
    df, root = episodes
    broken = df.copy()
    broken.loc[3, "trajectory_path"] = "gone/missing.parquet"
    with pytest.raises(FileNotFoundError, match=r"episode ep0003.*missing\.parquet"):
        describe_rollouts(broken, root, CountingJudge(), tmp_path / "cache")
    with pytest.raises(ValueError, match="duplicate episode_id"):
        describe_rollouts(df.assign(episode_id="same"), root, CountingJudge(), tmp_path / "cache")


def test_judge_pairs_cache_resume_and_wins(episodes, tmp_path):
    df, root = episodes
    desc = describe_rollouts(df, root, CountingJudge(), tmp_path / "cache")
    policies, checkpoints = ["GoodPolicyAlpha", "BadPolicyBeta"], [4, 8, 12]
    pairs = sample_pairs(df, policies, checkpoints, seed=3)

    k = 4
    with pytest.raises(RuntimeError, match=r"pair row \d+ \(\w+ vs \w+"):
        judge_pairs(pairs, desc, CountingJudge(fail_after=k), tmp_path / "cache")
    judge = CountingJudge()
    judged = judge_pairs(pairs, desc, judge, tmp_path / "cache", stats_path=tmp_path / "pstats.json")
    n_keys = judged["cache_key"].nunique()
    assert judge.compare_calls == n_keys - k
    assert set(judged.columns) >= {*pairs.columns, "verdict", "winner", "rationale", "judge"}
    assert set(judged["verdict"]) <= {"A", "B"}
    assert (judged["winner"] == np.where(judged["verdict"] == "A", judged["policy_a"], judged["policy_b"])).all()

    rerun = CountingJudge()
    again = judge_pairs(pairs, desc, rerun, tmp_path / "cache")
    assert rerun.compare_calls == 0 and again["winner"].tolist() == judged["winner"].tolist()

    # The smooth, always-successful policy wins every comparison, from either side.
    assert (judged["winner"] == "GoodPolicyAlpha").all()
    assert set(judged["policy_a"]) == set(policies)
    wins = wins_at_checkpoints(judged, policies, checkpoints)
    assert wins[:, 0, 1].tolist() == checkpoints and wins[:, 1, 0].tolist() == [0, 0, 0]


def test_a_new_compare_rule_asks_every_comparison_anew_and_keeps_the_descriptions(episodes, tmp_path):
    df, root = episodes
    desc = describe_rollouts(df, root, CountingJudge(), tmp_path / "cache")
    pairs = sample_pairs(df, ["GoodPolicyAlpha", "BadPolicyBeta"], [4], seed=2)
    before = judge_pairs(pairs, desc, CountingJudge(), tmp_path / "cache")

    class NewRule(CountingJudge):
        compare_version = CountingJudge.compare_version + "-next"

    judge = NewRule()
    again = describe_rollouts(df, root, judge, tmp_path / "cache")
    assert judge.describe_calls == 0 and again["cache_key"].tolist() == desc["cache_key"].tolist()
    after = judge_pairs(pairs, desc, judge, tmp_path / "cache")
    assert judge.compare_calls == after["cache_key"].nunique() > 0
    assert not set(after["cache_key"]) & set(before["cache_key"])


@pytest.mark.parametrize("backend, compare_only, describing", [
    ("kinematic", {"failures": "progress", "progress_margin": 0.2}, {"ref": {"impacts": 2.0}}),
    ("video", {"failures": "tie", "progress_margin": 0.1, "style_margin": 0.0}, {"end_s": 0.5}),
])
def test_a_compare_key_keeps_the_descriptions_and_asks_comparisons_anew(backend, compare_only, describing):
    from r2s_eval.judge import make_judge
    from tests.helpers.worlds import bundled_tasks

    def judge(**cfg):
        made = make_judge({"backend": backend, **cfg})
        made.know_tasks(bundled_tasks())
        return made

    base = judge()
    for key, value in compare_only.items():
        other = judge(**{key: value})
        assert other.identity() == base.identity()  # the descriptions' keys
        assert other.compare_identity() != base.compare_identity()
    assert judge(**describing).identity() != base.identity()


def test_judge_pairs_errors_name_the_pair(episodes, tmp_path):
    df, root = episodes
    desc = describe_rollouts(df, root, CountingJudge(), tmp_path / "cache")
    pairs = sample_pairs(df, ["GoodPolicyAlpha", "BadPolicyBeta"], [2], seed=0)
    gone = pairs["episode_b"].iloc[1]
    with pytest.raises(DataError, match=rf"pair row 1 .*episode {gone} has no description"):
        judge_pairs(pairs, desc[desc["episode_id"] != gone], CountingJudge(), tmp_path / "cache")


def test_judge_pairs_key_is_order_sensitive(episodes, tmp_path):
    df, root = episodes
    desc = describe_rollouts(df, root, CountingJudge(), tmp_path / "cache")
    pairs = sample_pairs(df, ["GoodPolicyAlpha", "BadPolicyBeta"], [6], seed=1)
    swapped = pairs.rename(columns={"episode_a": "episode_b", "episode_b": "episode_a",
                                    "policy_a": "policy_b", "policy_b": "policy_a"})
    j1, j2 = judge_pairs(pairs, desc, CountingJudge(), tmp_path / "cache"), CountingJudge()
    out2 = judge_pairs(swapped, desc, j2, tmp_path / "cache")
    # Swapped order = new questions (unless the same two episodes already came up swapped).
    assert j2.compare_calls == len(set(out2["cache_key"]) - set(j1["cache_key"])) > 0
    assert out2["winner"].tolist() == j1["winner"].tolist()  # ... with consistent answers
    assert (out2["verdict"] != j1["verdict"]).all()


def test_judge_custom_backend_plugs_in(episodes, tmp_path):
    """A backend only has to implement describe/compare; the drivers do the rest."""
    from r2s_eval.judge import CriterionNote, Judge, make_judge, register_judge

    @register_judge("constant-test")
    class Constant(Judge):
        inputs = ("video",)

        def describe(self, rollout):
            return Description(criteria={"motion_smoothness": CriterionNote("fine")}, summary="ok", judge=self.name)

        def compare(self, a, b, instruction):
            return Verdict("A", "always A")

    df, root = episodes
    judge = make_judge({"backend": "constant-test"})
    out = describe_rollouts(df, root, judge, tmp_path / "cache")
    assert (out["missing"] == "action_continuity,task_progress,force_control").all()
    assert (out["progress_label"] == "").all()
