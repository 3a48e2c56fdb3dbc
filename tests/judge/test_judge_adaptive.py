"""The adaptive judging driver on a scripted judge: a planted order, lazy describing, resumption
after a kill mid-round, no unit asked twice, invalid answers replaced."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pandas as pd
import pytest

from r2s_eval.compare.sequential import unit_order
from r2s_eval.errors import JudgeError
from r2s_eval.judge import CriterionNote, Description, Judge, Verdict, make_judge, register_judge
from r2s_eval.judge.adaptive import judge_adaptively
from r2s_eval.judge.base import InvalidAnswer
from r2s_eval.stats import fit_checkpoints

QUALITY = {"strong": 0.95, "middle": 0.5, "weak": 0.05}
TASKS = ("t0", "t1", "t2")


def _draw(text: str) -> float:
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "big") / 2.0**64


@register_judge("scripted-quality-test")
class ScriptedJudge(Judge):
    """Reads a quality and a tag out of the video bytes (as a VLM would read the picture); prefers
    the better rollout, by a seeded coin weighted by the two qualities. Counts its calls;
    ``fail_after`` simulates a kill, ``invalid_tag`` answers invalidly for one rollout."""

    inputs = ("video",)
    calls: list[tuple[str, str]] = []
    fail_after: int | None = None
    invalid_tag: str | None = None

    def describe(self, rollout):
        q, tag = Path(rollout.video_path).read_text().split()
        type(self).calls.append(("describe", tag))
        return Description(criteria={"task_progress": CriterionNote(q)}, summary=tag, judge=self.name)

    def compare(self, a, b, instruction):
        cls = type(self)
        if cls.fail_after is not None and sum(c[0] == "compare" for c in cls.calls) >= cls.fail_after:
            raise JudgeError("killed")
        cls.calls.append(("compare", f"{a.summary}|{b.summary}"))
        if cls.invalid_tag in (a.summary, b.summary):
            raise InvalidAnswer("no letter", replies=["maybe"])
        qa, qb = float(a.criteria["task_progress"].text), float(b.criteria["task_progress"].text)
        p_a = 0.5 + 0.5 * (qa - qb)
        return Verdict("A" if _draw(f"{a.summary}|{b.summary}") < p_a else "B", "scripted")


@pytest.fixture
def world(tmp_path):
    """Three policies with a planted order, 3 tasks x 24 inits, a video per rollout."""
    rows = []
    for policy in QUALITY:
        for task in TASKS:
            for init in range(24):
                eid = f"{policy}-{task}-{init}"
                video = tmp_path / "videos" / f"{_draw(eid):.12f}.mp4"
                video.parent.mkdir(exist_ok=True)
                video.write_text(f"{QUALITY[policy]} {eid}")
                rows.append({"episode_id": eid, "policy": policy, "task": task, "init_id": init,
                             "instruction": f"do {task}", "video_path": str(video.relative_to(tmp_path)),
                             "trajectory_path": ""})
    episodes = pd.DataFrame(rows)
    units = unit_order(episodes, sorted(QUALITY), seed=0)
    ScriptedJudge.calls, ScriptedJudge.fail_after, ScriptedJudge.invalid_tag = [], None, None
    return episodes, units, tmp_path


def _run(world, cache, **kw):
    episodes, units, root = world
    judge = make_judge({"backend": "scripted-quality-test", **kw.pop("judge", {})})
    return judge_adaptively(units, judge, root / cache, alpha=0.05, budget_per_pair=kw.pop("budget", 60),
                            checkpoints=[20, 40, 60], episodes_df=episodes, episodes_dir=root, **kw)


def test_recovers_the_planted_order_and_describes_lazily(world):
    verdicts, descriptions = _run(world, "cache")
    stats = verdicts.attrs["stats"]
    decided = {(d["policy_i"], d["policy_j"]): d["winner"] for d in stats["pairs"]}
    assert decided[("strong", "weak")] == "strong"
    assert all(w in (None, min(p, key=lambda x: -QUALITY[x])) for p, w in decided.items())
    # No unit twice within a pair, in either orientation.
    units = verdicts.groupby(["policy_i", "policy_j"]).apply(lambda g: list(zip(g.task, g.init_id)), include_groups=False)
    assert all(len(u) == len(set(u)) for u in units)
    # Whole blocks: every pair's count is a multiple of the task count; sequence in judged order.
    assert (verdicts.groupby(["policy_i", "policy_j"]).size() % len(TASKS) == 0).all()
    assert verdicts["sequence_index"].tolist() == list(range(len(verdicts)))
    assert (verdicts["checkpoint_position"] == verdicts["sequence_index"] // 3).all()
    # Lazy: only rollouts some comparison needed were described, each once.
    needed = set(verdicts["episode_a"]) | set(verdicts["episode_b"])
    assert set(descriptions["episode_id"]) == needed
    described = [tag for kind, tag in ScriptedJudge.calls if kind == "describe"]
    assert sorted(described) == sorted(needed)
    assert descriptions.attrs["stats"]["calls"] == len(needed) < len(world[0])
    assert stats["calls"] == sum(kind == "compare" for kind, _ in ScriptedJudge.calls) == len(verdicts)
    # The fit runs on what was judged, at checkpoints that are prefixes of the judged sequence.
    table, _ = fit_checkpoints(verdicts, [20, 40, 60], 50, 0.95, 0)
    last = table[table.checkpoint == 60].set_index("policy")["score"]
    assert last["strong"] > last["weak"]


def test_a_rerun_and_a_resumed_run_make_the_same_choices_without_asking_twice(world):
    first, _ = _run(world, "cache")
    n_compare = sum(kind == "compare" for kind, _ in ScriptedJudge.calls)

    ScriptedJudge.calls = []
    again, _ = _run(world, "cache")  # everything from the cache
    assert ScriptedJudge.calls == []
    pd.testing.assert_frame_equal(first, again)

    ScriptedJudge.calls, ScriptedJudge.fail_after = [], n_compare // 2  # killed mid-way
    with pytest.raises(JudgeError, match="killed"):
        _run(world, "resumed")
    asked_before = [c for c in ScriptedJudge.calls if c[0] == "compare"]
    ScriptedJudge.fail_after = None
    resumed, _ = _run(world, "resumed")
    asked_after = [c for c in ScriptedJudge.calls if c[0] == "compare"][len(asked_before):]
    assert not set(asked_before) & set(asked_after)  # nothing asked twice
    assert len(asked_before) + len(asked_after) == n_compare
    pd.testing.assert_frame_equal(first.drop(columns=["cache_key", "swap_cache_key"]),
                                  resumed.drop(columns=["cache_key", "swap_cache_key"]))


def test_budget_stops_the_run_and_the_report_names_the_open_pairs(world):
    verdicts, _ = _run(world, "cache", budget=4)  # 4 comparisons per pair on average: 4 blocks of 3
    stats = verdicts.attrs["stats"]
    assert len(verdicts) <= 4 * 3 and stats["stop"] == "budget_spent"
    assert stats["undecided"] == [f"{d['policy_i']} vs {d['policy_j']}" for d in stats["pairs"] if not d["decided"]]
    assert stats["undecided"]


def test_an_invalid_answer_is_replaced_by_the_next_unit_of_its_task(world):
    episodes, units, _ = world
    bad = "middle-t1-0"
    ScriptedJudge.invalid_tag = bad
    verdicts, _ = _run(world, "cache")
    stats = verdicts.attrs["stats"]
    assert stats["excluded"] >= 1 and stats["excluded"] == stats["replacements"]
    assert all(bad not in (a, b) for a, b in zip(verdicts["episode_a"], verdicts["episode_b"]))
    replaced = verdicts[verdicts["replaced"] > 0]
    assert (replaced["task"] == "t1").all()
    for r in replaced.itertuples():
        # Same sides as the slot it took over, a unit of the same pair and task never used before.
        slot = units[(units.policy_i == r.policy_i) & (units.policy_j == r.policy_j) & (units.pair_index == r.pair_index)].iloc[0]
        assert r.policy_a == slot.policy_a
        assert r.init_id != slot.init_id
    units_seen = verdicts.groupby(["policy_i", "policy_j"]).apply(lambda g: list(zip(g.task, g.init_id)), include_groups=False)
    assert all(len(u) == len(set(u)) for u in units_seen)


def test_swap_audit_asks_the_other_order_once(world):
    verdicts, _ = _run(world, "cache", judge={"swap_share": 0.5})
    audited = verdicts[verdicts["swap_audited"]]
    assert 0 < len(audited) < len(verdicts)
    assert (audited["verdict_swapped"] != "").all()
    assert verdicts.attrs["stats"]["swap_audited"] == len(audited)
