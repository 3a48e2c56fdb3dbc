"""Stage: the static results browser, reports/index.html (opens from disk, no server).

The ranking with its intervals per judge, the validation metrics and report cards, the figures,
and per policy pair the compared rollouts with both videos (copied beside the page), both
descriptions and every judge's verdicts; see ``r2s_eval.report.browser``.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from r2s_eval.report.browser import browser_data, figure_links, page_link, write_results_browser
from r2s_eval.stages import _cli
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.utils.io import read_json

READS = ("report.results_browser",)  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    opts = args.cfg["report.results_browser"]
    episodes = load_episodes(args.rollouts)
    data = browser_data(
        fits=_cli.by_judge(args.fits, pd.read_parquet), validations=_cli.by_judge(args.validation, read_json),
        audits=_cli.by_judge(args.audits, read_json),
        verdicts={_judge_of(p): pd.read_parquet(p) for p in args.verdicts},
        descriptions={_judge_of(p): pd.read_parquet(p) for p in args.descriptions or []},
        sim_episodes=episodes, figures=figure_links(args.figures, args.out), page_size=int(opts["page_size"]),
        max_pairs_per_policy_pair=opts["max_pairs_per_policy_pair"], video_dir=page_link(Path(args.media) / "videos", args.out),
    )
    write_results_browser(args.out, args.media, data, episodes)


def _judge_of(path: str) -> str:
    """results/judge/<judge>/<table>.parquet -> <judge>"""
    return Path(path).parent.name


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--fits", nargs="+", required=True)
    p.add_argument("--validation", nargs="+", required=True)
    p.add_argument("--audits", nargs="+", required=True)
    p.add_argument("--verdicts", nargs="+", required=True, help="results/judge/<judge>/verdicts.parquet")
    p.add_argument("--descriptions", nargs="*", help="results/judge/<judge>/descriptions.parquet (two-step judges)")
    p.add_argument("--rollouts", nargs="+", required=True, help="sim rollout folders, one per policy")
    p.add_argument("--figures", nargs="*", default=[], help="PNG figures to show, linked relative to the page")
    p.add_argument("--out", required=True, help="the page (reports/index.html)")
    p.add_argument("--media", required=True, help="folder beside the page for the copied videos")
    _cli.run(main, p)
