"""Stage drivers: describe every rollout, then judge every sampled pair, through the answer cache.

Both drivers ask the judge only for answers the cache lacks and store each answer as soon as it
arrives (``runner.run_cached``), and both report what they cost: judge calls, cache hits, model
requests, retries, re-asks, tokens in/out and wall time (``df.attrs["stats"]``, and
``stats_path`` as JSON when given). Both first clear what killed runs left in the cache folder
(``scratch.clear_leftovers``).

``judge_pairs`` also handles what a real VLM does wrong: a comparison whose answer stays invalid
is excluded and replaced in place from a seeded reserve (``replacement``), and a configurable
share of pairs is asked a second time with the sides swapped (``swap_audit``). Its stats add
``excluded`` (comparisons excluded from a table row; a row's replacement is never a comparison
already excluded in its policy pair and task, so none is counted twice), ``replacements`` (the
sum of ``replaced``: equal to ``excluded``), ``reasked_answers``, ``swap_share``,
``swap_audited``, ``swap_invalid``, ``swap_consistency`` and ``exclusions`` (one record per
excluded comparison, with the replies). ``unique_keys`` counts each distinct question once over
all rounds (planned, replacements, swapped), and ``calls + cache_hits == unique_keys``.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import pandas as pd

from r2s_eval.errors import ConfigError, DataError
from r2s_eval.judge.base import Description, Judge, Verdict
from r2s_eval.judge.cache import AnswerCache, cache_key
from r2s_eval.judge.questions import describe_call, description_questions, episode_files, video_questions
from r2s_eval.judge.replacement import pair_label, replace_invalid
from r2s_eval.judge.cached_runner import Asker, Job, Question, StageStats, finish, require_columns, run_cached
from r2s_eval.judge.scratch import clear_leftovers
from r2s_eval.judge.swap_audit import ask_swapped, swap_columns, swap_stats

log = logging.getLogger(__name__)

EPISODE_COLUMNS = ("episode_id", "instruction", "video_path", "trajectory_path")
PAIR_COLUMNS = ("episode_a", "episode_b", "policy_a", "policy_b")
DESCRIPTION_COLUMNS = (
    "episode_id", "judge", "instruction", "description", "description_sha", "missing", "progress_label", "cache_key",
)
# Added to the pairs table by ``judge_pairs``: verdict ('A'/'B'), winner (the preferred policy),
# rationale, judge (name), cache_key, reasks (0/1), source_index (position in the pair's seeded
# sequence the comparison came from; equals pair_index unless replaced), replaced (how many
# excluded comparisons this slot went through), swap_audited (bool), verdict_swapped ('A'/'B' as
# answered with the sides swapped; "" when not audited or invalid), swap_cache_key.
VERDICT_COLUMNS = (
    "verdict", "winner", "rationale", "judge", "cache_key", "reasks", "source_index", "replaced",
    "swap_audited", "verdict_swapped", "swap_cache_key",
)


def describe_rollouts(episodes_df: pd.DataFrame, episodes_dir: str | Path, judge: Judge, cache_dir: str | Path, *,
                      workers: int | None = None, stats_path: str | Path | None = None) -> pd.DataFrame:
    """Describe every episode with `judge`; one row per episode, in input order.

    Only ``episode_id``, ``instruction`` and the recording paths (relative to `episodes_dir`) are
    read from the episode table; policy, outcome and every other column stay out of the judge's
    sight. Cache key: see ``questions``. `workers` defaults to the judge's ``concurrency``.

    Returns columns ``DESCRIPTION_COLUMNS``: episode_id, judge (name), instruction, description
    (canonical JSON of a ``Description``), description_sha, missing (comma-separated missing
    sections, "" when complete), progress_label, cache_key. The stats add ``incomplete`` (rows
    with missing sections; a description whose server sent only malformed replies misses all).
    """
    t0 = time.perf_counter()
    require_columns(episodes_df, EPISODE_COLUMNS, "episode table")
    ids = episodes_df["episode_id"].astype(str)
    dup = ids[ids.duplicated()].unique().tolist()
    if dup:
        raise DataError(f"episode table has duplicate episode_id values: {dup[:5]}")
    episodes_dir = Path(episodes_dir)
    clear_leftovers(Path(cache_dir), ("describe", "requests"))
    judge.attach_cache(cache_dir)
    stats = StageStats(stage="describe", judge=judge.name, items=len(episodes_df))
    jobs, keys, instructions = _describe_jobs(episodes_df, ids, episodes_dir, judge, Path(cache_dir) / "inputs")
    stats.unique_keys = len(jobs)
    answers = run_cached(jobs, AnswerCache(cache_dir, "describe"), stats, workers or judge.stage_cfg["concurrency"])
    out = _description_table(ids, keys, instructions, answers, judge.name)
    stats.extra["incomplete"] = int((out["missing"] != "").sum())
    if stats.extra["incomplete"]:
        log.warning("%d of %d descriptions miss sections (column 'missing')", stats.extra["incomplete"], len(out))
    return finish(stats, t0, out, stats_path)


def _describe_jobs(episodes_df: pd.DataFrame, ids: pd.Series, episodes_dir: Path, judge: Judge,
                   stage_root: Path) -> tuple[dict[str, Job], list[str], list[str]]:
    """One job per distinct cache key (identical content is described once); each row's key and instruction."""
    identity = judge.identity()
    jobs: dict[str, Job] = {}
    keys, instructions, hashes = [], [], {}
    for eid, row in zip(ids, episodes_df[list(EPISODE_COLUMNS[1:])].itertuples(index=False)):
        instruction = str(row.instruction)
        files = episode_files(eid, row, judge.inputs, episodes_dir, judge, hashes)
        inputs = {"content": {k: sha for k, (_, sha) in files.items()}, "instruction": instruction, "judge": identity}
        key = cache_key(inputs)
        keys.append(key)
        instructions.append(instruction)
        if key not in jobs:
            jobs[key] = (f"episode {eid}", inputs, describe_call(judge, files, instruction, stage_root))
    return jobs, keys, instructions


def _description_table(ids: pd.Series, keys: list[str], instructions: list[str],
                       answers: dict[str, dict[str, Any]], judge_name: str) -> pd.DataFrame:
    rows = []
    for eid, key, instruction in zip(ids, keys, instructions):
        desc = Description.from_dict(answers[key])
        rows.append({
            "episode_id": eid,
            "judge": judge_name,
            "instruction": instruction,
            "description": desc.to_json(),
            "description_sha": desc.sha256(),
            "missing": ",".join(desc.missing),
            "progress_label": desc.progress_label or "",
            "cache_key": key,
        })
    return pd.DataFrame(rows, columns=list(DESCRIPTION_COLUMNS))


def judge_pairs(pairs_df: pd.DataFrame, descriptions_df: pd.DataFrame | None, judge: Judge, cache_dir: str | Path, *,
                workers: int | None = None, stats_path: str | Path | None = None,
                reserve_df: pd.DataFrame | None = None, episodes_df: pd.DataFrame | None = None,
                episodes_dir: str | Path | None = None, swap_share: float | None = None) -> pd.DataFrame:
    """Ask `judge` which side of every pair is better.

    `pairs_df` is ``r2s_eval.compare.sample_pairs`` output (needs episode_a, episode_b, policy_a,
    policy_b; policy_i, policy_j, task, pair_index when comparisons may be replaced or audited).
    With ``mode: two_step`` (the judge's stage option) the judge sees description A, description
    B (`descriptions_df`, ``describe_rollouts`` output) and the task instruction; with ``mode:
    one_step`` both videos (`episodes_df` with episode_id, instruction, video_path relative to
    `episodes_dir`), under content-hash names. Cache keys: see ``questions``.

    A comparison whose answer is invalid (``InvalidAnswer``) is excluded and replaced in place by
    the next unused row of `reserve_df` (``sample_reserve`` output) with the same policy pair and
    task, oriented so that the same policy is A. Rows with ``swap_audited(..., swap_share)`` are
    asked again with A and B swapped; `swap_share` and `workers` default to the judge's stage
    options.

    Returns `pairs_df` (with episode_a/episode_b/init_id of replacements) plus ``VERDICT_COLUMNS``
    (described there); the stats it adds are described in this module's docstring.
    """
    t0 = time.perf_counter()
    require_columns(pairs_df, PAIR_COLUMNS, "pairs table")
    mode = judge.stage_cfg["mode"]
    share = float(judge.stage_cfg["swap_share"] if swap_share is None else swap_share)
    clear_leftovers(Path(cache_dir), ("compare", "compare_videos", "requests"))
    judge.attach_cache(cache_dir)
    stats = StageStats(stage="compare", judge=judge.name, items=len(pairs_df))
    question, cache = _comparisons(mode, judge, cache_dir, descriptions_df, episodes_df, episodes_dir)
    ask = Asker(question, cache, stats, workers or judge.stage_cfg["concurrency"])
    rows = _planned_rows(pairs_df)
    labels = [pair_label(n, r) for n, r in enumerate(rows)]
    keys = ask([(labels[n], r["episode_a"], r["episode_b"]) for n, r in enumerate(rows)])
    exclusions = replace_invalid(rows, labels, keys, ask, reserve_df)
    audited, swap_key_of = ask_swapped(rows, labels, share, ask)
    out = _verdict_table(pairs_df, rows, keys, ask, judge.name, swap_columns(audited, swap_key_of, ask))
    stats.extra.update({
        "mode": mode, "excluded": len(exclusions), "replacements": int(out["replaced"].sum()),
        "reasked_answers": int(out["reasks"].sum()), "swap_share": share, **swap_stats(out),
        "exclusions": exclusions,
    })
    return finish(stats, t0, out, stats_path)


def _comparisons(mode: str, judge: Judge, cache_dir: str | Path, descriptions_df: pd.DataFrame | None,
                 episodes_df: pd.DataFrame | None, episodes_dir: str | Path | None) -> tuple[Question, AnswerCache]:
    """The comparisons `mode` asks for, and the cache of their answers."""
    identity = judge.compare_identity()
    if mode == "two_step":
        if descriptions_df is None:
            raise ConfigError(f"judge {judge.name!r} compares descriptions (mode two_step): give the descriptions table")
        return description_questions(descriptions_df, judge, identity), AnswerCache(cache_dir, "compare")
    if episodes_df is None or episodes_dir is None:
        raise ConfigError(f"judge {judge.name!r} compares videos (mode one_step): give the episode table and folder")
    question = video_questions(episodes_df, Path(episodes_dir), judge, identity, Path(cache_dir) / "inputs")
    return question, AnswerCache(cache_dir, "compare_videos")


def _planned_rows(pairs_df: pd.DataFrame) -> list[dict[str, Any]]:
    """The table's rows as planned: each comparison from its own position, not replaced yet."""
    rows = pairs_df.reset_index(drop=True).to_dict("records")
    for r in rows:
        r["source_index"] = int(r.get("pair_index", -1))
        r["replaced"] = 0
    return rows


def _verdict_table(pairs_df: pd.DataFrame, rows: list[dict[str, Any]], keys: list[str], ask: Asker,
                   judge_name: str, swap: dict[str, list[Any]]) -> pd.DataFrame:
    """`rows` (the planned table after replacements) with the ``VERDICT_COLUMNS``."""
    out = pd.DataFrame(rows)
    verdicts = [Verdict.from_dict(ask.answers[k]) for k in keys]
    columns = {
        "verdict": [v.letter for v in verdicts],
        "winner": [r["policy_a"] if v.letter == "A" else r["policy_b"] for v, r in zip(verdicts, rows)],
        "rationale": [v.rationale for v in verdicts],
        "judge": judge_name,
        "cache_key": keys,
        "reasks": [int(ask.answers[k].get("usage", {}).get("reasks", 0)) for k in keys],
        **swap,
    }
    for name, values in columns.items():
        out[name] = values
    out = out[[*pairs_df.columns, *VERDICT_COLUMNS]]
    return out.astype({"source_index": "int64", "replaced": "int64", "reasks": "int64", "swap_audited": bool})
