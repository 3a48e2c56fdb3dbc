"""People in the loop on the smoke run: three annotators answer its annotation set in the browser
(one closes the tab halfway and comes back), the export feeds the judge audit, the realsim
table's agreement column shows a number, and the results browser shows it all."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest

from tests.helpers.people import (
    AnnotationServer,
    answer_with_keyboard,
    answered,
    browser,
    export_csv,
    open_annotator,
    screenshot_dir,
    videos_state,
    wait_until,
)

from .conftest import planned_jobs, snakemake

pytestmark = pytest.mark.slow
LINE_UP = ["act", "act_hesitant", "act_subset", "act_weak"]  # the smoke line-up, best first by construction


@pytest.fixture(scope="module")
def workdir(smoke_run, tmp_path_factory) -> Path:
    """A copy of the smoke run (times kept, so Snakemake plans nothing there), so the annotations
    change nothing the other tests see. A full copy, not hard links: DVC treats linked files
    differently, and the DVC round trip runs on the original."""
    copy = tmp_path_factory.mktemp("people") / "run"
    shutil.copytree(smoke_run.workdir, copy, symlinks=True)
    return copy


def letter(page, items: pd.DataFrame, contrary: bool) -> str:
    """The successful rollout, else the better policy of the line-up (``contrary``: the other one on
    same-outcome pairs, to split the vote). The test knows the set's key; the page does not."""
    srcs = page.evaluate("[...document.querySelectorAll('video')].map(v => v.getAttribute('src').split('/').pop())")
    row = items[(items["video_a"] == srcs[0]) & (items["video_b"] == srcs[1])].iloc[0]
    better_a = (row["success_a"], -LINE_UP.index(row["policy_a"])) > (row["success_b"], -LINE_UP.index(row["policy_b"]))
    if contrary and row["success_a"] == row["success_b"]:
        better_a = not better_a
    return "A" if better_a else "B"


def test_three_annotators_feed_the_audit_and_the_realsim_table(workdir, tmp_path_factory):
    set_dir = workdir / "results" / "annotate"
    items = pd.read_parquet(set_dir / "set.parquet")
    summary = json.loads((set_dir / "summary.json").read_text())
    for category, c in summary["categories"].items():  # balanced where the pool allows, shortfall recorded
        assert c["drawn"] == min(c["target"], c["available"]) and c["shortfall"] == c["target"] - c["drawn"]
        assert (items["category"] == category).sum() == c["drawn"]
    n = len(items)
    assert n == summary["n_items"] > 0
    shots = screenshot_dir(tmp_path_factory)
    db = tmp_path_factory.mktemp("answers") / "answers.sqlite"
    with AnnotationServer(set_dir, db) as server, browser() as b:
        for name in ("anna", "ben"):
            page = open_annotator(b, server.url, name)
            if name == "anna":
                wait_until(page, "[...document.querySelectorAll('video')].every(v => v.currentTime > 0.3)")
                state = videos_state(page)
                assert state["width"] == [448, 448] and state["paused"] == [False, False], state
                assert min(state["advanced"]) > 0.2 and state["gap"] < 0.15, state
                page.screenshot(path=str(shots / "annotation_page_smoke.png"))
            for _ in range(n):
                answer_with_keyboard(page, letter(page, items, contrary=False))
            page.context.close()
        page = open_annotator(b, server.url, "cleo")
        for _ in range(n // 2):
            answer_with_keyboard(page, letter(page, items, contrary=True))
        page.context.close()  # the tab is closed halfway
        page = open_annotator(b, server.url, "cleo")
        assert answered(page) == n // 2
        for _ in range(n - n // 2):
            answer_with_keyboard(page, letter(page, items, contrary=True))
        assert page.get_attribute("body", "data-state") == "done"
    csv = export_csv(set_dir, db, workdir / "annotations.csv")
    assert len(csv) == 3 * n

    overrides = ["report.judge_audit.human_annotations=annotations.csv"]
    planned = {rule for rule, _ in planned_jobs(snakemake(workdir, "-n", overrides=overrides).stdout)}
    assert {"judge_audit", "realsim_table", "results_browser"} <= planned and "fit" not in planned
    snakemake(workdir, "-j", "2", overrides=overrides)
    for judge in ("kinematic", "video"):
        audit = json.loads((workdir / "results" / "audit" / f"{judge}.json").read_text())
        human = audit["human"]
        assert audit["n_annotated_pairs"] == n and human["n_annotators"] == 3 and human["votes_per_pair"] == {"3": n}
        assert 0.0 <= audit["human_agreement"] <= 1.0
        if "success-failure" in human["by_category"]:  # everyone picked the successful rollout
            mixed = human["by_category"]["success-failure"]
            assert mixed["unanimous"]["share"] == 1.0
            if judge == "kinematic":  # and so does this judge on every mixed pair (its outcome agreement)
                assert mixed["judge_agreement"]["share"] == audit["outcome_agreement"]["share"] == 1.0
    table = (workdir / "reports" / "realsim_table.tex").read_text()
    for judge in ("kinematic", "video"):
        row = next(line for line in table.splitlines() if line.startswith(f"{judge} &"))
        agreement = row.split("&")[5].strip()
        assert agreement != "--" and 0.0 <= float(agreement) <= 1.0, row

    with browser() as b:
        page = b.new_page(viewport={"width": 1280, "height": 900})
        page.goto((workdir / "reports" / "index.html").as_uri())
        page.wait_for_selector("body[data-ready='true']")
        assert "3 annotators" in page.text_content("#human-body")
        page.locator("#pair-list article").first.locator("button.play-both").click()
        wait_until(page, "[...document.querySelectorAll('video')].slice(0, 2).every(v => v.currentTime > 0.3)")
        assert videos_state(page)["width"] == [448, 448]
        page.evaluate("window.scrollTo(0, 0)")
        page.screenshot(path=str(shots / "results_browser_smoke.png"), full_page=True)
