"""Stage: frames of two rollouts with the same outcome where the judge prefers one."""

from __future__ import annotations

import logging

import pandas as pd

from r2s_eval.report import case_study_figure, pick_case_study, sample_frames, save_figure
from r2s_eval.stages import _cli
from r2s_eval.rollout.episode_store import load_episodes

READS = ("report.case_study",)  # config paths the --cfg slice holds (see _reads.py)

log = logging.getLogger("r2s_eval.case_study")


def main(args) -> None:
    opts = args.cfg["report.case_study"]
    case = pick_case_study(pd.read_parquet(args.verdicts), load_episodes(args.rollouts), opts["outcomes"], opts["rank"])
    rows = []
    for role in ("preferred", "other"):
        ep = case[role]
        frames, times = sample_frames(ep["video_path"], int(opts["n_frames"]))
        outcome = "success" if ep["success"] else "failure"
        rows.append((f"{role}\n{ep['policy']} ({outcome})", frames, times))
    v = case["verdict"]
    both = {"success": "both succeed", "failure": "both fail"}.get(case["outcome"], "same outcome")
    title = f"Judge {args.judge}, task {v['task']}, init {v['init_id']}: {both}, the judge prefers {case['preferred']['policy']}"
    save_figure(case_study_figure(rows, title, str(v.get("rationale") or ""), opts), args.pdf, args.png, dpi=opts["dpi"])
    log.info("case study (%s) from %d candidate pairs: preferred %s, other %s", case["outcome"], case["n_candidates"],
             case["preferred"]["episode_id"], case["other"]["episode_id"])


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--judge", required=True)
    p.add_argument("--verdicts", required=True)
    p.add_argument("--rollouts", nargs="+", required=True, help="sim rollout folders, one per policy")
    p.add_argument("--pdf", required=True)
    p.add_argument("--png", required=True)
    _cli.run(main, p)
