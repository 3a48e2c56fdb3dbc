"""The results browser: one static HTML page (``reports/index.html``) that opens from disk.

It holds the ranking with its intervals per judge beside the reference, the validation metrics,
each judge's report card (human agreement included, where annotations were given), the figures,
and for every policy pair the compared rollouts: both videos, each judge's descriptions of them,
and every judge's verdicts (with the swapped-order answers where audited), filterable by task,
outcome and policy pair. The data is embedded in the page as JSON, the figures are linked where
they lie, and the videos are copied beside the page, so the folder can be moved or zipped. The
page is the researcher's: unlike the annotation app it names policies and outcomes.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path

import pandas as pd

from r2s_eval.annotate.criteria import CRITERIA_TEXT
from r2s_eval.errors import DataError
from r2s_eval.judge.base import Description
from r2s_eval.report.summaries import last_checkpoint
from r2s_eval.stats import outcome_category
from r2s_eval.utils.io import atomic_dir, atomic_path, current_provenance

METRICS = ("spearman", "pearson", "mmrv", "ci_width")


def _num(value) -> float | None:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return value if value == value else None  # NaN -> None (JSON has no NaN)


def _ranking(fit: pd.DataFrame) -> dict:
    last = last_checkpoint(fit).sort_values("score", ascending=False)
    return {"checkpoint": int(last["checkpoint"].iloc[0]),
            "interval": str(last["interval"].iloc[0]) if "interval" in last.columns else "binomial",
            "ci_level": _num(last["ci_level"].iloc[0]) if "ci_level" in last.columns else 0.95,
            "rows": [{"policy": str(p), "score": _num(r["score"]), "ci_low": _num(r["ci_low"]),
                      "ci_high": _num(r["ci_high"])} for p, r in last.iterrows()]}


def _metrics(validation: Mapping) -> dict:
    out = {}
    for at in ("average", "last"):
        block = validation.get(at) or {}
        out[at] = {m: {"value": _num(block.get(m)), "ci_low": _num(block.get(f"{m}_ci_low")),
                       "ci_high": _num(block.get(f"{m}_ci_high"))} for m in METRICS}
    return out


def _card(audit: Mapping) -> dict:
    """The audit's numbers the page shows (the whole JSON stays in results/audit/)."""
    keep = ("n_verdicts", "a_share", "a_share_same_outcome", "n_same_outcome", "swap_consistency", "n_swapped",
            "human_agreement", "n_annotated_pairs", "n_annotations")
    out = {k: audit.get(k) for k in keep}
    for k in ("outcome_agreement", "planted_order_agreement"):
        share = audit.get(k) or {}
        out[k] = {x: share.get(x) for x in ("share", "ci_low", "ci_high", "n_pairs", "n_units")} if share else None
    human = audit.get("human")
    if human:
        def brief(block: Mapping) -> dict:
            return {"n_pairs": block["n_pairs"], "unanimous": block["unanimous"], "fleiss": block["fleiss"],
                    "judge_agreement": block["judge_agreement"]}
        out["human"] = {"n_annotators": human["n_annotators"], "n_unjudged_pairs": human["n_unjudged_pairs"],
                        "n_tied_pairs": human["n_tied_pairs"], **brief(human),
                        "by_category": {c: brief(b) for c, b in human["by_category"].items()}}
    return out


def _descriptions(table: pd.DataFrame) -> dict[str, dict]:
    out = {}
    for episode, text in zip(table["episode_id"].astype(str), table["description"].astype(str)):
        d = Description.from_json(text)
        out[episode] = {"summary": d.summary, "label": d.progress_label,
                        "criteria": [[CRITERIA_TEXT[c][0], n.text] for c, n in d.criteria.items()]}
    return out


def _swapped_letters(verdicts: pd.DataFrame, columns: Sequence[str]) -> list[str | None]:
    column = next((c for c in columns if c in verdicts.columns), None)
    if column is None:
        return [None] * len(verdicts)
    return [str(v).strip().upper() if v is not None and str(v).strip() not in ("", "nan", "None") else None
            for v in verdicts[column]]


def compared_pairs(verdicts: Mapping[str, pd.DataFrame], sim_episodes: pd.DataFrame, *,
                   swapped_columns: Sequence[str] = ("verdict_swapped",),
                   max_per_policy_pair: int | None = None) -> list[dict]:
    """The distinct rollout pairs the judges compared, each with every judge's answers.

    A pair is two videos (unordered); its first episode is policy_i's. Per judge: the verdicts
    on it in the order the judge saw them (which policy was A, the letter, the preferred policy,
    and the swapped-order letter where audited). ``max_per_policy_pair`` keeps the first pairs
    of every policy pair in comparison order (task-balanced by construction)."""
    success = dict(zip(sim_episodes["episode_id"].astype(str), sim_episodes["success"].astype(bool)))
    pairs: dict[frozenset, dict] = {}
    order = []
    for judge in sorted(verdicts):
        v = verdicts[judge].sort_values(["policy_i", "policy_j", "pair_index"], kind="stable")
        swapped = _swapped_letters(v, swapped_columns)
        for row, swap in zip(v.itertuples(index=False), swapped):
            ea, eb = str(row.episode_a), str(row.episode_b)
            for e in (ea, eb):
                if e not in success:
                    raise DataError(f"judge {judge}: verdict on {ea} / {eb} names episode {e}, which has no sim rollout")
            key = frozenset((ea, eb))
            if key not in pairs:
                ei, ej = (ea, eb) if str(row.policy_a) == str(row.policy_i) else (eb, ea)
                pairs[key] = {"policy_i": str(row.policy_i), "policy_j": str(row.policy_j), "task": str(row.task),
                              "init_id": int(row.init_id), "episode_i": ei, "episode_j": ej,
                              "category": outcome_category(success[ei], success[ej]), "verdicts": {}}
                order.append(key)
            letter = str(row.verdict).strip().upper()
            pairs[key]["verdicts"].setdefault(judge, []).append({
                "a": str(row.policy_a), "letter": letter, "winner": str(row.winner), "swapped": swap})
    kept, per_pair = [], {}
    for key in order:
        p = pairs[key]
        n = per_pair.setdefault((p["policy_i"], p["policy_j"]), 0)
        if max_per_policy_pair is None or n < max_per_policy_pair:
            per_pair[(p["policy_i"], p["policy_j"])] = n + 1
            kept.append(p)
    return sorted(kept, key=lambda p: (p["policy_i"], p["policy_j"], p["task"], p["init_id"], p["episode_i"]))


def browser_data(*, fits: Mapping[str, pd.DataFrame], validations: Mapping[str, dict], audits: Mapping[str, dict],
                 verdicts: Mapping[str, pd.DataFrame], descriptions: Mapping[str, pd.DataFrame],
                 sim_episodes: pd.DataFrame, figures: Sequence[dict], page_size: int,
                 max_pairs_per_policy_pair: int | None = None, video_dir: str = "browser/videos") -> dict:
    """Everything the page shows, as plain JSON-able data (videos referenced under ``video_dir``)."""
    judges = sorted(fits)
    pairs = compared_pairs(verdicts, sim_episodes, max_per_policy_pair=max_pairs_per_policy_pair)
    shown = sorted({e for p in pairs for e in (p["episode_i"], p["episode_j"])})
    ep = sim_episodes.assign(episode_id=sim_episodes["episode_id"].astype(str)).set_index("episode_id")
    reference = next((validations[j].get("reference") for j in sorted(validations)
                      if validations[j].get("reference")), None) or {}
    rate = reference.get("success_rate", {})
    policies = sorted(set(sim_episodes["policy"].astype(str)), key=lambda p: (-(rate.get(p) or 0.0), p))
    return {
        "page_size": int(page_size),
        "policies": policies,
        "tasks": sorted(set(sim_episodes["task"].astype(str))),
        "instructions": {str(t): str(i) for t, i in sim_episodes.groupby("task")["instruction"].first().items()}
        if "instruction" in sim_episodes.columns else {},
        "reference": {p: {"rate": _num(rate.get(p)), "ci_low": _num(reference.get("ci_low", {}).get(p)),
                          "ci_high": _num(reference.get("ci_high", {}).get(p))} for p in policies},
        "reference_definition": reference.get("definition"),
        "judges": {j: {"ranking": _ranking(fits[j]), "metrics": _metrics(validations.get(j, {})),
                       "card": _card(audits.get(j, {}))} for j in judges},
        "figures": list(figures),
        "episodes": {e: {"policy": str(ep.at[e, "policy"]), "task": str(ep.at[e, "task"]),
                         "init_id": int(ep.at[e, "init_id"]), "success": bool(ep.at[e, "success"]),
                         "length": int(ep.at[e, "length"]) if "length" in ep.columns else None,
                         "video": f"{video_dir}/{e}.mp4"} for e in shown},
        "descriptions": {j: {e: d for e, d in _descriptions(descriptions[j]).items() if e in set(shown)}
                         for j in sorted(descriptions)},
        "pairs": pairs,
    }


def _asset(name: str) -> str:
    return resources.files("r2s_eval.report").joinpath("browser_assets", name).read_text()


def render_page(data: dict, title: str = "r2s-eval results") -> str:
    """The page: template, style, script and the data (as JSON that cannot close its tag)."""
    blob = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)
    blob = blob.replace("<", "\\u003c")  # no "</script>" or "<!--" inside the data block
    return (_asset("index.html").replace("{{TITLE}}", title).replace("{{CSS}}", _asset("browser.css"))
            .replace("{{JS}}", _asset("browser.js")).replace("{{DATA}}", blob))


def write_results_browser(out_html: str | Path, media_dir: str | Path, data: dict, sim_episodes: pd.DataFrame) -> None:
    """Copy the shown videos to ``media_dir/videos/<episode>.mp4`` and write the page."""
    source = dict(zip(sim_episodes["episode_id"].astype(str), sim_episodes["video_path"].astype(str)))
    with atomic_dir(media_dir) as tmp:
        (tmp / "videos").mkdir()
        for episode in sorted(data["episodes"]):
            src = Path(source[episode])
            if not src.is_file():
                raise DataError(f"episode {episode}: video {src} is missing")
            shutil.copyfile(src, tmp / "videos" / f"{episode}.mp4")
    with atomic_path(out_html) as tmp:  # the embedded data records what made the page
        tmp.write_text(render_page({**data, "provenance": current_provenance()}), encoding="utf-8")


FIGURE_TITLES = {"bt_convergence": "Bradley-Terry scores over the checkpoints",
                 "overall_ranking": "Judge-averaged score beside the reference",
                 "hardware_effort": "Operator effort of hardware trials"}


def _figure_title(stem: str) -> str:
    for prefix, title in (("win_rate_matrix_", "Win rates, judge {}"), ("case_study_", "Case study, judge {}")):
        if stem.startswith(prefix):
            return title.format(stem[len(prefix):])
    return FIGURE_TITLES.get(stem, stem.replace("_", " "))


def page_link(path: str | Path, page: str | Path) -> str:
    """``path`` as a link relative to the folder of ``page``."""
    return Path(os.path.relpath(path, Path(page).parent)).as_posix()


def figure_links(paths: Sequence[str | Path], page: str | Path) -> list[dict]:
    """Figures as {title, src} with src relative to the page, in the given order."""
    return [{"title": _figure_title(Path(p).stem), "src": page_link(p, page)} for p in paths]
