"""The static results browser, opened from disk in a real browser."""

from __future__ import annotations

from pathlib import Path

import pytest
from PIL import Image

from r2s_eval.annotate import AnswerStore
from r2s_eval.config import compose_config

from tests.helpers.people import POLICIES, browser, run_stage, screenshot_dir, videos_state, wait_until

pytestmark = pytest.mark.browser
CONF = Path(__file__).resolve().parents[2] / "conf"


@pytest.fixture(scope="module")
def page_built(run, annotation_set, tmp_path_factory):
    """The run's judge audit (with three annotators' answers) and its results browser."""
    root = run["root"]
    store = AnswerStore(tmp_path_factory.mktemp("db") / "answers.sqlite", annotation_set["items"])
    for k, name in enumerate(("anna", "ben", "cleo")):
        for position in range(len(store.items)):
            store.record(name, store.item_at(name, position)["item_id"], "AB"[(position + k) % 2 if k else 0])
    store.export().to_csv(root / "annotations.csv", index=False)
    store.close()
    cfg = compose_config(CONF, experiment="smoke", overrides=["report.results_browser.page_size=4"])
    cfg["report"]["judge_audit"]["planted_order"] = list(POLICIES)
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(root)
        run_stage("judge_audit", cfg, "--judge", "kin", "--verdicts", "results/judge/kin/verdicts.parquet",
                  "--rollouts", *run["rollouts"], "--annotations", "annotations.csv", "--out", "results/audit/kin.json")
        run_stage("results_browser", cfg, "--fits", "results/fit/kin.parquet", "--validation",
                  "results/validate/kin.json", "--audits", "results/audit/kin.json", "--verdicts",
                  "results/judge/kin/verdicts.parquet", "--descriptions", "results/judge/kin/descriptions.parquet",
                  "--rollouts", *run["rollouts"], "--figures", "reports/bt_convergence.png",
                  "reports/win_rate_matrix_kin.png", "--out", "reports/index.html", "--media", "reports/browser")
    return root / "reports" / "index.html"


def test_results_browser_from_disk(page_built, tmp_path_factory):
    with browser() as b:
        page = b.new_page(viewport={"width": 1280, "height": 900})
        errors = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(page_built.as_uri())
        page.wait_for_selector("body[data-ready='true']")
        # The ranking with its intervals, best first, beside the reference.
        rows = page.locator("#judges tbody").first.locator("tr")
        assert rows.count() == 3 and rows.nth(0).text_content().startswith("alpha60.0 [55.0, 65.0]")
        assert "100.0" in rows.nth(0).text_content()  # alpha's reference success %
        # Figures load from their relative links.
        assert page.evaluate("[...document.querySelectorAll('#figure-list img')].map(i => i.naturalWidth > 0)") == [
            True, True]
        # Human agreement: the annotators among themselves and the judge against their majority.
        human = page.text_content("#human-body")
        assert "3 annotators" in human and "Fleiss" in human and "Judge kin agrees with the majority" in human
        # 24 distinct rollout pairs, 4 per page; each card shows two videos, two descriptions, the verdicts.
        assert page.text_content("#pair-count") == "24 of 24 distinct rollout pairs"
        cards = page.locator("#pair-list article")
        assert cards.count() == 4
        first = cards.nth(0)
        assert first.locator("video").count() == 2 and first.locator(".desc dl").count() == 2
        assert "moves smoothly" in first.text_content() and first.locator(".verdicts tbody tr").count() == 1
        first.locator("button.play-both").click()
        wait_until(page, "[...document.querySelectorAll('#pair-list article')][0]"
                         ".querySelectorAll('video')[1].currentTime > 0.3")
        state = videos_state(page)
        assert min(state["ready"]) >= 2 and state["paused"] == [False, False] and min(state["advanced"]) > 0.3
        page.evaluate("window.scrollTo(0, 0)")
        shot = screenshot_dir(tmp_path_factory) / "results_browser.png"
        page.screenshot(path=str(shot), full_page=True)
        assert Image.open(shot).size[0] == 1280  # nothing wider than the window

        # Pages of page_size pairs.
        assert page.text_content("#pager span") == "page 1 of 6"
        shown = page.locator("#pair-list article").all_text_contents()
        page.click("#pager button >> text=next")
        assert page.text_content("#pager span") == "page 2 of 6"
        assert page.locator("#pair-list article").all_text_contents() != shown

        # Filters: outcome, task, policy pair; the swapped-order answers show where audited.
        page.select_option("#f-outcome", "failure-failure")
        assert page.text_content("#pair-count") == "4 of 24 distinct rollout pairs"
        assert set(page.evaluate("[...document.querySelectorAll('#pair-list article')].map(a => a.dataset.category)")) == {
            "failure-failure"}
        page.select_option("#f-outcome", "")
        page.select_option("#f-task", "cup_on_plate")
        page.select_option("#f-pair", "alpha vs gamma")
        assert page.text_content("#pair-count") == "4 of 24 distinct rollout pairs"
        texts = page.locator("#pair-list article").all_text_contents()
        assert all("alpha vs gamma" in t and "cup_on_plate" in t for t in texts)
        assert any("swapped: 1 of 1 consistent" in t for t in texts)
        assert page.text_content("#pager span") == "page 1 of 1" and page.locator("#pager button").last.is_disabled()
        assert errors == []
