"""The openai backend end to end against a real chat-completions server on 127.0.0.1."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pandas as pd
import pytest

from r2s_eval.compare import wins_at_checkpoints
from r2s_eval.compare.sampling import sample_pairs, sample_reserve
from r2s_eval.judge import describe_rollouts, judge_pairs, make_judge
from tests.helpers.worlds import bundled_world
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.stats import order_swap_consistency


from tests.helpers.chat_server import ChatServer, kill_when_hanging
from tests.helpers.videos import INSTRUCTIONS, make_rollouts, scene

SRC = Path(__file__).resolve().parents[2] / "src"


def judge_cfg(url: str, **kw) -> dict:
    return {"backend": "openai", "base_url": url, "model": "test-vlm", "backoff_s": 0.01, "max_frames": 8, **kw}


@pytest.fixture
def rollouts(tmp_path):
    dirs = make_rollouts(tmp_path / "rollouts", scene())
    return dirs, load_episodes(dirs)


def test_openai_two_step_retries_reasks_excludes_audits_and_never_pays_twice(rollouts, tmp_path):
    dirs, episodes = rollouts
    cache = tmp_path / "cache"
    policies, checkpoints = ["BadPolicyBeta", "GoodPolicyAlpha"], [8, 16]
    pairs = sample_pairs(episodes, policies, checkpoints, seed=5)
    reserve = sample_reserve(episodes, policies, checkpoints, seed=5, n_reserve=40)
    cfg = judge_cfg("", concurrency=4, swap_share=1.0)

    with ChatServer(fail_plan=[500, 429, 502]) as server:
        cfg["base_url"] = server.url
        desc = describe_rollouts(episodes, ".", make_judge(cfg), cache)
        st = desc.attrs["stats"]
        # Three transient failures were retried; every video was described by exactly one answer.
        assert [e["status"] for e in server.log[:3]] == [500, 429, 502] and st["retries"] == 3
        assert st["calls"] == st["requests"] == len(episodes) == len(server.ok_requests("describe"))
        assert st["tokens_in"] > 0 and st["tokens_out"] > 0
        assert {(e["model"], e["temperature"], e["max_tokens"]) for e in server.log} == {("test-vlm", 0.0, 1024)}
        policy_of = dict(zip(episodes["episode_id"], episodes["policy"]))
        labels = {p: set(desc.loc[desc["episode_id"].map(policy_of) == p, "progress_label"]) for p in policies}
        assert labels == {"GoodPolicyAlpha": {"successful"}, "BadPolicyBeta": {"failed"}}
        flagged = desc[desc["missing"] != ""]
        assert flagged["missing"].tolist() == ["force_control"] and st["incomplete"] == 1

        out = judge_pairs(pairs, desc, make_judge(cfg), cache, reserve_df=reserve)
        st = out.attrs["stats"]
        n_log = len(server.log)

        # Second full run: everything from the cache, not one request.
        again_desc = describe_rollouts(episodes, ".", make_judge(cfg), cache)
        again = judge_pairs(pairs, again_desc, make_judge(cfg), cache, reserve_df=reserve)
        assert len(server.log) == n_log
        assert again_desc.attrs["stats"]["calls"] == again.attrs["stats"]["calls"] == 0
        assert again.equals(out)

    init_of = episodes.set_index("episode_id")["init_id"]
    bad_init = lambda row: init_of[row.episode_a if row.policy_a == "BadPolicyBeta" else row.episode_b]  # noqa: E731
    planned_confusing = {r.pair_index for r in pairs.itertuples() if bad_init(r) == 0 and r.pair_index is not None}
    # Excluded exactly where a confusing video was planned; replaced in place from the reserve,
    # same task, same sides, pair_index 0..n-1 intact.
    assert set(out.loc[out["replaced"] > 0, "pair_index"]) == planned_confusing
    assert st["excluded"] == st["replacements"] == int(out["replaced"].sum()) >= len(planned_confusing) > 0
    replaced = out[out["replaced"] > 0]
    assert (replaced["source_index"] >= max(checkpoints)).all()
    assert (out["task"] == pairs["task"]).all() and (out["policy_a"] == pairs["policy_a"]).all()
    assert not any(bad_init(r) == 0 for r in out.itertuples())
    assert all(e["replies"] == ["They look about the same to me."] * 2 for e in st["exclusions"])
    # Hesitant answers were asked once more and then counted.
    hesitant = [r.pair_index for r in out.itertuples() if bad_init(r) == 1]
    assert hesitant and (out.set_index("pair_index").loc[hesitant, "reasks"] == 1).all()
    assert st["reasked_answers"] == len(hesitant)
    # The better policy wins everywhere, in both orders (the audit covers every pair).
    assert (out["winner"] == "GoodPolicyAlpha").all()
    assert out["swap_audited"].all() and st["swap_consistency"] == 1.0
    assert order_swap_consistency(out["verdict"], out["verdict_swapped"]) == 1.0
    wins = wins_at_checkpoints(out, policies, checkpoints)
    assert wins[:, 1, 0].tolist() == checkpoints


def test_openai_prompts_carry_no_identity(rollouts, tmp_path):
    dirs, episodes = rollouts
    pairs = sample_pairs(episodes, ["BadPolicyBeta", "GoodPolicyAlpha"], [6], seed=1)
    with ChatServer() as server:
        cfg = judge_cfg(server.url, concurrency=2)
        desc = describe_rollouts(episodes, ".", make_judge(cfg), tmp_path / "c")
        judge_pairs(pairs, desc, make_judge(judge_cfg(server.url, mode="one_step")), tmp_path / "c",
                    episodes_df=episodes, episodes_dir=".")
    kinds = Counter(e["kind"] for e in server.log)
    assert kinds["describe"] == len(episodes) and kinds["compare_videos"] == len(pairs)
    for e in server.log:
        for secret in ("GoodPolicyAlpha", "BadPolicyBeta", "Good", "Bad", "SUCCESS", "FAILURE", "ep0", "videos/",
                       ".mp4", "rollouts", "test-vlm"):
            assert secret not in e["text"], (secret, e["text"][:300])
        assert any(i in e["text"] for i in INSTRUCTIONS.values())


def test_openai_one_step_mode_compares_videos(rollouts, tmp_path):
    dirs, episodes = rollouts
    pairs = sample_pairs(episodes, ["BadPolicyBeta", "GoodPolicyAlpha"], [6], seed=2)
    with ChatServer() as server:
        judge = make_judge(judge_cfg(server.url, mode="one_step", swap_share=0.5))
        out = judge_pairs(pairs, None, judge, tmp_path / "c", episodes_df=episodes, episodes_dir=".")
        n = len(server.log)
        again = judge_pairs(pairs, None, make_judge(judge_cfg(server.url, mode="one_step", swap_share=0.5)),
                            tmp_path / "c", episodes_df=episodes, episodes_dir=".")
        assert len(server.log) == n and again.attrs["stats"]["calls"] == 0
    assert (out["winner"] == "GoodPolicyAlpha").all()
    assert 0 < out["swap_audited"].sum() < len(out)
    audited = out[out["swap_audited"]]
    assert (audited["verdict"] != audited["verdict_swapped"]).all()
    assert (out.loc[~out["swap_audited"], "verdict_swapped"] == "").all()
    # One request per distinct question (a pair may recur, or recur swapped); no describe requests.
    assert n == len((set(out["cache_key"]) | set(out["swap_cache_key"])) - {""})


def test_openai_api_key_comes_from_the_named_variable_and_is_never_stored(rollouts, tmp_path, monkeypatch):
    dirs, episodes = rollouts
    with ChatServer() as server:
        monkeypatch.delenv("R2S_TEST_JUDGE_KEY", raising=False)
        with pytest.raises(RuntimeError, match="R2S_TEST_JUDGE_KEY"):
            describe_rollouts(episodes.head(1), ".", make_judge(judge_cfg(server.url, api_key_env="R2S_TEST_JUDGE_KEY")),
                              tmp_path / "c")
        monkeypatch.setenv("R2S_TEST_JUDGE_KEY", "sk-very-secret-value")
        describe_rollouts(episodes.head(2), ".", make_judge(judge_cfg(server.url, api_key_env="R2S_TEST_JUDGE_KEY")),
                          tmp_path / "c", stats_path=tmp_path / "stats.json")
    stored = [p.read_text() for p in (tmp_path / "c").rglob("*.json")] + [(tmp_path / "stats.json").read_text()]
    assert stored and not any("sk-very-secret-value" in s for s in stored)


def test_openai_client_errors_fail_at_once_naming_the_episode(rollouts, tmp_path):
    dirs, episodes = rollouts
    with ChatServer(fail_plan=[400]) as server:
        with pytest.raises(RuntimeError, match=r"episode BadPolicyBeta-ep000: .*HTTP 400 after 1 attempt"):
            describe_rollouts(episodes.head(1), ".", make_judge(judge_cfg(server.url)), tmp_path / "c")
        assert len(server.log) == 1


def test_openai_stage_killed_mid_run_resumes_without_repeating_a_request(rollouts, tmp_path):
    dirs, episodes = rollouts
    cache, out = tmp_path / "cache", tmp_path / "judge" / "descriptions.parquet"
    with ChatServer(hold_after=5) as server:
        world = bundled_world()
        cfg = json.dumps({"judge": judge_cfg(server.url, concurrency=2), "name": "vlm",
                          "world.objects": world["objects"], "world.tasks": world["tasks"],
                          "world.robot": world["robot"]})
        cmd = [sys.executable, "-m", "r2s_eval.stages.describe", "--cfg", cfg, "--rollouts", *dirs,
               "--cache", str(cache), "--out", str(out)]
        env = {**os.environ, "PYTHONPATH": str(SRC)}
        proc = subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        # Kill once the five answered requests are stored and the next ones hang on the server.
        kill_when_hanging(proc, server, cache, stored=5, requests=7)
        server.release()
        assert not out.exists()
        held = [e for e in server.log if e["status"] != 200]

        server.hold_after = None
        done = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr[-2000:]

    answered = server.ok_requests()
    assert len(answered) == len(episodes) and len(held) >= 1
    assert max(Counter(e["sha"] for e in answered).values()) == 1  # no request answered twice
    stats = json.loads(out.with_name("describe_stats.json").read_text())
    assert stats["cache_hits"] == 5 and stats["calls"] == len(episodes) - 5
    assert len(pd.read_parquet(out)) == len(episodes)


def test_openai_stage_entry_points_write_verdicts_and_costs(rollouts, tmp_path, monkeypatch, capsys):
    """compare_pairs -> describe -> judge_pairs through their command lines, as the workflow runs them."""
    from r2s_eval.stages import _cli
    from r2s_eval.stages import compare_pairs as cp_stage
    from r2s_eval.stages import describe as d_stage
    from r2s_eval.stages import judge_pairs as jp_stage

    dirs, episodes = rollouts
    monkeypatch.chdir(tmp_path)
    pairs = tmp_path / "pairs.parquet"
    cfg_pairs = {"compare.checkpoints": {"start": 4, "stop": 8, "step": 4}, "compare.allocation": "fixed", "seed": 3}
    _cli.run(cp_stage.main, _add(cp_stage, ["--rollouts", "--out"]),
             ["--cfg", json.dumps(cfg_pairs), "--rollouts", *dirs, "--out", str(pairs)])
    with ChatServer() as server:
        judge = {"judge": judge_cfg(server.url, reserve=30, swap_share=0.5), "name": "vlm", "seed": 3}
        desc, verdicts = tmp_path / "j" / "descriptions.parquet", tmp_path / "j" / "verdicts.parquet"
        world = bundled_world()
        judge.update({"world.objects": world["objects"], "world.tasks": world["tasks"], "world.robot": world["robot"]})
        describe_cfg = judge
        _cli.run(d_stage.main, _add(d_stage, ["--rollouts", "--cache", "--transport", "--out", "--stats"]),
                 ["--cfg", json.dumps(describe_cfg), "--rollouts", *dirs, "--cache", "cache", "--out", str(desc)])
        _cli.run(jp_stage.main, _add(jp_stage, JP_FLAGS),
                 ["--cfg", json.dumps(judge), "--pairs", str(pairs), "--rollouts", *dirs,
                  "--descriptions", str(desc), "--cache", "cache", "--out", str(verdicts)])
    out = pd.read_parquet(verdicts)
    assert len(out) == len(pd.read_parquet(pairs)) and (out["winner"] == "GoodPolicyAlpha").all()
    stats = json.loads(verdicts.with_name("compare_stats.json").read_text())
    assert stats["excluded"] > 0 and stats["swap_audited"] == int(out["swap_audited"].sum())
    for key in ("calls", "cache_hits", "requests", "retries", "reasks", "tokens_in", "tokens_out", "wall_s"):
        assert key in stats and key in json.loads(verdicts.with_name("describe_stats.json").read_text())

    # Pairs that do not come from these rollouts and seed are refused, not silently replaced.
    judge["seed"] = 4
    with pytest.raises(SystemExit) as stop:
        _cli.run(jp_stage.main, _add(jp_stage, JP_FLAGS),
                 ["--cfg", json.dumps(judge), "--pairs", str(pairs), "--rollouts", *dirs,
                  "--descriptions", str(desc), "--cache", "cache", "--out", str(verdicts)])
    assert stop.value.code == _cli.EXIT_EXPECTED
    assert "was not sampled from these rollouts with seed 4" in capsys.readouterr().err


# The flags of the judge_pairs stage, as its __main__ block adds them.
def test_openai_adaptive_stage_describes_on_the_way_and_never_pays_twice(rollouts, tmp_path, monkeypatch):
    """compare_pairs (adaptive) -> judge_adaptive through their command lines, against a chat
    server: a rollout is described when a comparison first needs it, describe and compare
    requests are counted apart, a never-a-letter comparison is replaced, and a rerun asks nothing."""
    from r2s_eval.stages import _cli
    from r2s_eval.stages import compare_pairs as cp_stage

    dirs, episodes = rollouts
    monkeypatch.chdir(tmp_path)
    checkpoints = {"start": 4, "stop": 8, "step": 4}
    pairs = tmp_path / "pairs.parquet"
    _cli.run(cp_stage.main, _add(cp_stage, ["--rollouts", "--out"]),
             ["--cfg", json.dumps({"compare.checkpoints": checkpoints, "compare.allocation": "adaptive", "seed": 3}),
              "--rollouts", *dirs, "--out", str(pairs)])
    world = bundled_world()
    verdicts, desc = tmp_path / "j" / "verdicts.parquet", tmp_path / "j" / "descriptions.parquet"
    with ChatServer() as server:
        cfg = {"judge": judge_cfg(server.url, swap_share=0.5), "name": "vlm", "compare.checkpoints": checkpoints,
               "compare.budget": None, "compare.alpha": 0.05, "world.objects": world["objects"],
               "world.tasks": world["tasks"], "world.robot": world["robot"]}
        command = [sys.executable, "-m", "r2s_eval.stages.judge_adaptive", "--cfg", json.dumps(cfg), "--pairs", str(pairs),
                   "--rollouts", *dirs, "--cache", "cache", "--out", str(verdicts), "--descriptions-out", str(desc)]
        first = subprocess.run(command, capture_output=True, text=True)
        assert first.returncode == 0, first.stderr[-3000:]
        answered = server.answered
        stats = json.loads(verdicts.with_name("compare_stats.json").read_text())
        made = json.loads(verdicts.with_name("describe_stats.json").read_text())
        out = pd.read_parquet(verdicts)
        again = subprocess.run(command, capture_output=True, text=True)
        assert again.returncode == 0 and server.answered == answered  # the rerun asks nothing
    pd.testing.assert_frame_equal(pd.read_parquet(verdicts), out)
    assert json.loads(verdicts.with_name("describe_stats.json").read_text())["requests"] == 0
    assert (out["winner"] == "GoodPolicyAlpha").all() and len(set(zip(out["task"], out["init_id"]))) == len(out)
    assert stats["allocation"] == "adaptive" and stats["excluded"] > 0
    assert made["requests"] > 0 and stats["requests"] > 0 and made["requests"] + stats["requests"] == answered
    assert stats["describe_requests"] == made["requests"]
    described = pd.read_parquet(desc)["episode_id"]
    assert set(described) <= set(episodes["episode_id"].astype(str))
    assert set(out["episode_a"]) | set(out["episode_b"]) <= set(described)


JP_FLAGS = ["--pairs", "--rollouts", "--descriptions", "--cache", "--transport", "--out"]


def _add(stage, flags: list[str]):
    """The stage's own argument parser, as in its __main__ block."""
    from r2s_eval.stages import _cli

    p = _cli.parser(stage.__doc__)
    for f in flags:
        if f == "--transport":
            p.add_argument(f, default="{}", help="JSON: the judge's transport keys")
        elif f == "--stats":
            p.add_argument(f, default=None)
        else:
            p.add_argument(f, nargs="+" if f == "--rollouts" else None, required=f != "--descriptions")
    return p
