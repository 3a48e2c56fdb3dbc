"""The openai judge against a local server that misbehaves on purpose, one fault at a time.

Malformed replies, Retry-After in both forms and past its ceiling, hung requests and the call
deadline, a reserve holding the very comparison it replaces, and the leftovers of a killed run.
"""

from __future__ import annotations

import datetime as dt
import email.utils
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from r2s_eval.errors import JudgeError
from r2s_eval.judge import describe_rollouts, judge_pairs, make_judge
from r2s_eval.judge.base import CRITERIA
from r2s_eval.judge.openai_backend import OpenAIJudge
from r2s_eval.rollout.episode_store import load_episodes


from tests.helpers.chat_server import MALFORMED, ChatServer, kill_when_hanging
from tests.helpers.videos import make_rollouts

SRC = Path(__file__).resolve().parents[2] / "src"
GOOD, BAD = "GoodPolicyAlpha", "BadPolicyBeta"


def judge_cfg(url: str, **kw) -> dict:
    return {"backend": "openai", "base_url": url, "model": "test-vlm", "max_frames": 4,
            "backoff_s": 0.01, "backoff_max_s": 0.05, "timeout_s": 5.0, **kw}


@pytest.fixture
def rollouts(tmp_path):
    """One task, three inits: the good policy bright, the bad one dark; on init 0 the bad video
    is in the server's CONFUSING band (its comparisons are never a letter)."""
    levels = {(GOOD, "lift", i): 0.78 + 0.01 * i for i in range(3)}
    levels.update({(BAD, "lift", 0): 0.50, (BAD, "lift", 1): 0.20, (BAD, "lift", 2): 0.22})
    dirs = make_rollouts(tmp_path / "rollouts", levels)
    return dirs, load_episodes(dirs)


def _ep(episodes: pd.DataFrame, policy: str, init: int) -> str:
    return episodes.loc[(episodes["policy"] == policy) & (episodes["init_id"] == init), "episode_id"].item()


def _comparisons(episodes: pd.DataFrame, rows: list[tuple[int, int, str]]) -> pd.DataFrame:
    """Rows (pair_index, init, policy on side A) of GOOD vs BAD on task lift."""
    out = []
    for pair_index, init, side_a in rows:
        side_b = BAD if side_a == GOOD else GOOD
        out.append({"pair_index": pair_index, "policy_i": BAD, "policy_j": GOOD, "task": "lift", "init_id": init,
                    "episode_a": _ep(episodes, side_a, init), "episode_b": _ep(episodes, side_b, init),
                    "policy_a": side_a, "policy_b": side_b, "first_checkpoint": 1})
    return pd.DataFrame(out)


def _request_cache(cache: Path) -> list[Path]:
    return list((cache / "requests").glob("*/*.json"))


# ------------------------------------------------------------------ malformed replies
@pytest.mark.parametrize("fault", MALFORMED)
def test_malformed_reply_is_retried_and_never_cached(rollouts, tmp_path, fault):
    dirs, episodes = rollouts
    cache = tmp_path / "cache"
    with ChatServer(faults=[fault, fault]) as server:
        out = describe_rollouts(episodes.head(1), ".", make_judge(judge_cfg(server.url)), cache)
    st = out.attrs["stats"]
    assert [e["status"] for e in server.log] == [fault, fault, 200]
    assert st["malformed"] == st["retries"] == 2 and st["calls"] == st["requests"] == 1
    assert out["missing"].item() == "" and out["progress_label"].item() == "failed"
    assert len(_request_cache(cache)) == 1  # only the good reply was kept


def test_malformed_description_after_the_last_retry_misses_every_section(rollouts, tmp_path):
    dirs, episodes = rollouts
    cache = tmp_path / "cache"
    cfg = judge_cfg("", max_retries=1)
    with ChatServer(faults=["no_choices", "no_choices"]) as server:
        cfg["base_url"] = server.url
        out = describe_rollouts(episodes.head(2), ".", make_judge(cfg), cache)
        again = describe_rollouts(episodes.head(2), ".", make_judge(cfg), cache)
    st = out.attrs["stats"]
    first = json.loads(out["description"].iloc[0])
    assert out["missing"].iloc[0] == ",".join((*CRITERIA, "summary")) and out["missing"].iloc[1] == ""
    assert first["raw_text"] == "malformed reply: no 'choices'"
    assert st["malformed"] == 2 and st["retries"] == 1 and st["incomplete"] == 1 and st["calls"] == 2
    assert st["requests"] == 1 and len(_request_cache(cache)) == 1
    # Kept like any answer: the rerun asks nothing.
    assert again.attrs["stats"]["calls"] == 0 and again.equals(out)


@pytest.mark.parametrize("mode", ["two_step", "one_step"])
def test_malformed_comparison_after_the_last_retry_is_excluded_and_replaced(rollouts, tmp_path, mode):
    dirs, episodes = rollouts
    cache = tmp_path / "cache"
    pairs = _comparisons(episodes, [(0, 1, GOOD), (1, 2, BAD)])
    reserve = _comparisons(episodes, [(2, 2, GOOD), (3, 1, BAD)])
    cfg = judge_cfg("", max_retries=2, mode=mode)
    with ChatServer() as server:
        cfg["base_url"] = server.url
        desc = describe_rollouts(episodes, ".", make_judge(cfg), cache) if mode == "two_step" else None
        server.faults = ["not_json"] * 3  # every attempt of the first comparison
        out = judge_pairs(pairs, desc, make_judge(cfg), cache, reserve_df=reserve, episodes_df=episodes,
                          episodes_dir=".")
    st = out.attrs["stats"]
    assert st["malformed"] == 3 and st["retries"] == 2
    assert st["excluded"] == st["replacements"] == 1 and out["replaced"].tolist() == [1, 0]
    assert st["exclusions"][0]["replies"] == ["malformed reply: body is not JSON"]
    assert out["source_index"].tolist() == [2, 1] and (out["winner"] == GOOD).all()
    assert st["calls"] + st["cache_hits"] == st["unique_keys"] == 3


# ------------------------------------------------------------------ Retry-After
def _gap(server: ChatServer) -> float:
    return server.log[1]["t"] - server.log[0]["t"]


def test_retry_after_seconds_is_honoured_past_the_backoff_maximum(rollouts, tmp_path):
    dirs, episodes = rollouts
    with ChatServer(faults=[(429, {"Retry-After": "1"})]) as server:
        out = describe_rollouts(episodes.head(1), ".", make_judge(judge_cfg(server.url)), tmp_path / "c")
    assert out.attrs["stats"]["retries"] == 1 and [e["status"] for e in server.log] == [429, 200]
    assert _gap(server) >= 1.0  # backoff_max_s is 0.05 s, but the server asked for 1 s


def test_retry_after_http_date_is_honoured(rollouts, tmp_path):
    dirs, episodes = rollouts

    def in_two_seconds() -> str:  # whole seconds: the server asks for between 1 and 2 s
        return email.utils.format_datetime(dt.datetime.now(dt.timezone.utc) + dt.timedelta(seconds=2), usegmt=True)

    with ChatServer(faults=[(503, {"Retry-After": in_two_seconds})]) as server:
        out = describe_rollouts(episodes.head(1), ".", make_judge(judge_cfg(server.url)), tmp_path / "c")
    assert out.attrs["stats"]["retries"] == 1 and [e["status"] for e in server.log] == [503, 200]
    assert _gap(server) >= 0.99


@pytest.mark.parametrize("status, retry_after, limit, match", [
    (429, "3600", {"retry_after_max_s": 2},
     r"HTTP 429.*retry after 3600 s.*retry_after_max_s \(2 s\); raise retry_after_max_s"),
    (503, "30", {"call_deadline_s": 2}, r"HTTP 503; the retry in 30.0 s would pass call_deadline_s \(2 s\)"),
], ids=["past_the_ceiling", "past_the_call_deadline"])
def test_retry_after_past_a_limit_fails_at_once_saying_so(rollouts, tmp_path, status, retry_after, limit, match):
    # A Retry-After beyond retry_after_max_s, or beyond what is left of call_deadline_s, ends the
    # retries at once, with an error naming the limit.
    dirs, episodes = rollouts
    t0 = time.monotonic()
    with ChatServer(faults=[(status, {"Retry-After": retry_after})]) as server:
        with pytest.raises(JudgeError, match=r"episode \S+: .*" + match):
            describe_rollouts(episodes.head(1), ".", make_judge(judge_cfg(server.url, **limit)), tmp_path / "c")
    # At once: well under the 30 s a wait would take at the least, on a loaded or slow machine too.
    assert len(server.log) == 1 and time.monotonic() - t0 < 15


# ------------------------------------------------------------------ hung requests, deadline
def test_hung_request_times_out_and_is_retried(rollouts, tmp_path):
    dirs, episodes = rollouts
    t0 = time.monotonic()
    with ChatServer(faults=["hang"]) as server:
        out = describe_rollouts(episodes.head(1), ".", make_judge(judge_cfg(server.url, timeout_s=0.5)),
                                tmp_path / "c")
    assert out.attrs["stats"]["retries"] == 1 and out["missing"].item() == ""
    # Under the server's 10 s hang, with room for a loaded or slow machine.
    assert [e["status"] for e in server.log] == ["hang", 200] and time.monotonic() - t0 < 9


def test_hung_requests_end_at_the_call_deadline_naming_the_pair(rollouts, tmp_path):
    dirs, episodes = rollouts
    pairs = _comparisons(episodes, [(0, 1, GOOD)])
    # The request timeout (30 s) is longer than the whole call may take (1 s): the deadline wins.
    cfg = judge_cfg("", mode="one_step", timeout_s=30.0, call_deadline_s=1.0, max_retries=50)
    with ChatServer(faults=["hang"] * 50) as server:
        cfg["base_url"] = server.url
        t0 = time.monotonic()
        with pytest.raises(JudgeError, match=r"compare: judge 'test-vlm' failed on pair row 0 .*"
                                             r"call_deadline_s \(1 s\)"):
            judge_pairs(pairs, None, make_judge(cfg), tmp_path / "c", episodes_df=episodes, episodes_dir=".")
        took = time.monotonic() - t0
    assert 1.0 <= took < 9.0  # the deadline, not the server's 10 s hang (room for a slow machine)


def test_defaults_bound_one_call_and_stay_out_of_the_cache_identity():
    d = OpenAIJudge.DEFAULTS
    assert d["timeout_s"] <= d["call_deadline_s"] and d["retry_after_max_s"] <= d["call_deadline_s"]
    base = make_judge({"backend": "openai", "model": "m"}).identity()
    other = make_judge({"backend": "openai", "model": "m", "timeout_s": 5, "call_deadline_s": 60,
                        "retry_after_max_s": 10}).identity()
    assert other == base
    with pytest.raises(ValueError, match="call_deadline_s must be a number of seconds > 0"):
        make_judge({"backend": "openai", "model": "m", "call_deadline_s": 0})


# ------------------------------------------------------------------ replacements and counts
def test_replacement_is_never_the_comparison_it_replaces(rollouts, tmp_path):
    dirs, episodes = rollouts
    cache = tmp_path / "cache"
    pairs = _comparisons(episodes, [(0, 0, BAD), (1, 1, BAD)])  # row 0 is never answered with a letter
    # The reserve holds the excluded comparison itself, then the same pair swapped, then the
    # comparison of row 1 (answered already: a replacement reuses it without asking again).
    reserve = _comparisons(episodes, [(2, 0, BAD), (3, 0, GOOD), (4, 1, BAD)])
    cfg = judge_cfg("")
    with ChatServer() as server:
        cfg["base_url"] = server.url
        desc = describe_rollouts(episodes, ".", make_judge(cfg), cache)
        out = judge_pairs(pairs, desc, make_judge(cfg), cache, reserve_df=reserve)
        compare_requests = [e for e in server.log if e["kind"] == "compare"]
        again = judge_pairs(pairs, desc, make_judge(cfg), cache, reserve_df=reserve)
    st = out.attrs["stats"]
    assert out["source_index"].tolist() == [4, 1] and out["replaced"].tolist() == [1, 0]
    assert out["episode_a"].tolist() == [_ep(episodes, BAD, 1)] * 2 and (out["winner"] == GOOD).all()
    assert st["excluded"] == st["replacements"] == len(st["exclusions"]) == 1
    assert st["unique_keys"] == st["calls"] == 2 and st["cache_hits"] == 0
    assert len(compare_requests) == 3  # the confusing one and its re-ask, and row 1's
    ast = again.attrs["stats"]
    assert ast["calls"] == 0 and ast["cache_hits"] == ast["unique_keys"] == 2 and ast["excluded"] == 1
    assert again.equals(out)


def test_no_replacement_but_the_excluded_comparison_fails_naming_the_option(rollouts, tmp_path):
    dirs, episodes = rollouts
    pairs = _comparisons(episodes, [(0, 0, BAD)])
    reserve = _comparisons(episodes, [(1, 0, BAD), (2, 0, GOOD)])
    with ChatServer() as server:
        cfg = judge_cfg(server.url)
        desc = describe_rollouts(episodes, ".", make_judge(cfg), tmp_path / "c")
        with pytest.raises(JudgeError, match="no reserve comparison is left .*raise the judge's 'reserve' option"):
            judge_pairs(pairs, desc, make_judge(cfg), tmp_path / "c", reserve_df=reserve)


# ------------------------------------------------------------------ a killed run
_DESCRIBE = """
import sys
from r2s_eval.judge import describe_rollouts, make_judge
from r2s_eval.rollout.episode_store import load_episodes
cfg = {"backend": "openai", "base_url": sys.argv[1], "model": "test-vlm", "max_frames": 4, "concurrency": 3}
describe_rollouts(load_episodes(sys.argv[3:]), ".", make_judge(cfg), sys.argv[2])
"""


def test_killed_describe_leaves_nothing_a_rerun_trips_over(rollouts, tmp_path):
    dirs, episodes = rollouts
    cache = tmp_path / "cache"
    with ChatServer(hold_after=1) as server:
        proc = subprocess.Popen([sys.executable, "-c", _DESCRIBE, server.url, str(cache), *dirs],
                                env={**os.environ, "PYTHONPATH": str(SRC)}, cwd=tmp_path,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        # Kill while requests hang on the server: their scratch folders are in use.
        kill_when_hanging(proc, server, cache, stored=1, requests=4)
        left = list((cache / "inputs").iterdir())
        assert left and all(p.name.startswith(f"in-{proc.pid}-") for p in left)

        # What else a kill (or a live neighbour) leaves: a temporary file of an atomic write,
        # stale or fresh, and the scratch folder of a live process sharing the cache.
        shard = next((cache / "describe").iterdir())
        stale, fresh = shard / ".abc.json.k1x2.tmp", shard / ".def.json.k3x4.tmp"
        stale.write_text("{")
        fresh.write_text("{")
        hour_ago = time.time() - 3700
        os.utime(stale, (hour_ago, hour_ago))
        live = cache / "inputs" / f"in-{os.getpid()}-{socket.gethostname()}-live0000"
        live.mkdir()

        server.release()
        server.hold_after = None
        out = describe_rollouts(episodes, ".", make_judge(judge_cfg(server.url, concurrency=3)), cache)
    assert len(out) == len(episodes) and (out["missing"] == "").all()
    assert out.attrs["stats"]["cache_hits"] >= 1
    assert list((cache / "inputs").iterdir()) == [live]
    assert not stale.exists() and fresh.exists()
