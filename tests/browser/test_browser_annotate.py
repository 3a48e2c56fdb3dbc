"""The annotation app in a real browser (Debian's chromium, headless, driven by Playwright)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from PIL import Image

from r2s_eval.annotate import AnswerStore
from r2s_eval.config import compose_config
from r2s_eval.utils.io import read_json

from tests.helpers.people import (
    POLICIES,
    AnnotationServer,
    answer_with_keyboard,
    answered,
    browser,
    export_csv,
    open_annotator,
    run_stage,
    screenshot_dir,
    videos_state,
    wait_until,
)

pytestmark = pytest.mark.browser
CONF = Path(__file__).resolve().parents[2] / "conf"


def shown_episodes(page, items: pd.DataFrame) -> tuple[str, str]:
    """The episodes behind the two videos on the page (the test knows the set's key; the page does not)."""
    token = {t: e for side in "ab" for t, e in zip(items[f"video_{side}"], items[f"episode_{side}"])}
    srcs = page.evaluate("[...document.querySelectorAll('video')].map(v => v.getAttribute('src'))")
    return token[srcs[0].rsplit("/", 1)[1]], token[srcs[1].rsplit("/", 1)[1]]


def preference(page, items, sim, contrary: bool = False) -> str:
    """An annotator's letter: the successful rollout, else the earlier policy of the line-up
    (``contrary``: the other one on same-outcome pairs, to leave the vote split)."""
    a, b = shown_episodes(page, items)
    ep = sim.set_index("episode_id")
    key = {e: (bool(ep.at[e, "success"]), -POLICIES.index(ep.at[e, "policy"])) for e in (a, b)}
    better_a = key[a] > key[b]
    if contrary and key[a][0] == key[b][0]:
        better_a = not better_a
    return "A" if better_a else "B"


def test_three_annotators_answer_with_the_keyboard_one_resumes_and_the_export_feeds_the_audit(
        run, annotation_set, tmp_path):
    items, root = annotation_set["items"], run["root"]
    db = tmp_path / "answers.sqlite"
    n = len(items)
    with AnnotationServer(annotation_set["dir"], db) as server, browser() as b:
        for name in ("anna", "ben"):
            page = open_annotator(b, server.url, name)
            for _ in range(n):
                answer_with_keyboard(page, preference(page, items, run["sim"]))
            assert page.get_attribute("body", "data-state") == "done" and answered(page) == n
            page.context.close()
        # cleo answers half, closes the tab, and comes back in a fresh browser context.
        page = open_annotator(b, server.url, "cleo")
        for _ in range(n // 2):
            answer_with_keyboard(page, preference(page, items, run["sim"], contrary=True))
        left_at = int(page.get_attribute("body", "data-position"))
        page.context.close()
        page = open_annotator(b, server.url, "cleo")
        assert answered(page) == n // 2 and int(page.get_attribute("body", "data-position")) == left_at
        assert page.text_content("#progress-text") == f"{n // 2} / {n}"
        for _ in range(n - n // 2):
            answer_with_keyboard(page, preference(page, items, run["sim"], contrary=True))
        assert page.get_attribute("body", "data-state") == "done"
        page.context.close()

    csv = export_csv(annotation_set["dir"], db, root / "annotations.csv")
    assert len(csv) == 3 * n and csv.groupby("annotator").size().to_dict() == {"anna": n, "ben": n, "cleo": n}
    assert set(csv["choice"]) <= {"A", "B"} and (csv["seconds"] > 0).all()

    cfg = compose_config(CONF, experiment="smoke")
    cfg["report"]["judge_audit"]["planted_order"] = list(POLICIES)
    rollouts = run["rollouts"]
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(root)
        run_stage("judge_audit", cfg, "--judge", "kin", "--verdicts", "results/judge/kin/verdicts.parquet",
                  "--rollouts", *rollouts, "--annotations", "annotations.csv", "--out", "results/audit/kin.json")
        audit = read_json("results/audit/kin.json")
        human = audit["human"]
        # anna and ben always pick the successful (else earlier) policy, as the judge does;
        # cleo contradicts them on same-outcome pairs, so those are 2-1 and mixed ones 3-0.
        assert audit["human_agreement"] == 1.0 and audit["n_annotated_pairs"] == n and human["n_annotators"] == 3
        assert human["votes_per_pair"] == {"3": n} and human["fleiss"]["n_raters"] == 3
        assert human["by_category"]["success-failure"]["unanimous"]["share"] == 1.0
        assert human["by_category"]["success-success"]["unanimous"]["share"] == 0.0
        run_stage("realsim_table", cfg, "--validation", "results/validate/kin.json", "--audits",
                  "results/audit/kin.json", "--fits", "results/fit/kin.parquet", "--reference",
                  "results/reference/success.parquet", "--table", "reports/realsim_table.tex",
                  "--ranking", "reports/ranking.txt")
        row = next(line for line in open("reports/realsim_table.tex") if line.startswith("kin &"))
    agreement = row.split("&")[5].strip()
    assert agreement == "1.000", row


def test_annotation_page_plays_both_videos_in_sync_and_shows_what_a_person_needs(
        annotation_set, tmp_path, tmp_path_factory):
    items = annotation_set["items"]
    with AnnotationServer(annotation_set["dir"], tmp_path / "answers.sqlite") as server, browser() as b:
        page = open_annotator(b, server.url, "anna")
        wait_until(page, "[...document.querySelectorAll('video')].every(v => v.currentTime > 0.3)")
        state = videos_state(page)
        assert state["error"] == [None, None] and state["width"] == [128, 128]
        assert min(state["ready"]) >= 2 and state["paused"] == [False, False], state
        assert min(state["advanced"]) > 0.3 and state["gap"] < 0.15, state  # playing, on one clock
        shot = screenshot_dir(tmp_path_factory) / "annotation_page.png"
        page.screenshot(path=str(shot), full_page=True)

        # What a person needs, on screen without scrolling: the instruction, A and B side by side,
        # the answer keys, the four criteria and the progress.
        view = page.viewport_size
        boxes = {s: page.locator(s).bounding_box() for s in ("#instruction", "#video-a", "#video-b", "#choose-a",
                                                              "#choose-b")}
        for s, box in boxes.items():
            assert box and box["y"] >= 0 and box["y"] + box["height"] <= view["height"], (s, box)
        assert abs(boxes["#video-a"]["y"] - boxes["#video-b"]["y"]) < 1 and boxes["#video-a"]["x"] < boxes["#video-b"]["x"]
        assert boxes["#video-a"]["width"] >= 300
        assert page.text_content("#instruction") in set(items["instruction"])
        assert "A is better" in page.text_content("#choose-a") and page.text_content("#choose-a kbd") == "A"
        assert "B is better" in page.text_content("#choose-b") and page.text_content("#choose-b kbd") == "B"
        assert page.locator("#criteria li").count() == 4 and "Force/effort" in page.text_content("#criteria")
        assert page.text_content("#progress-text") == f"0 / {len(items)}"

        # The screenshot shows the two videos' pictures (grey background, coloured square), not black boxes.
        image = Image.open(shot).convert("RGB")
        for s in ("#video-a", "#video-b"):
            box = boxes[s]
            crop = image.crop((int(box["x"]), int(box["y"]), int(box["x"] + box["width"]), int(box["y"] + box["height"])))
            colours = crop.getcolors(maxcolors=1 << 16) or []
            assert crop.getextrema()[0][1] > 200 and len(colours) > 3, s

        # Frame stepping and replay on both videos together.
        page.keyboard.press(" ")
        wait_until(page, "[...document.querySelectorAll('video')].every(v => v.paused)")
        before = page.evaluate("[...document.querySelectorAll('video')].map(v => v.currentTime)")
        page.keyboard.press("ArrowRight")
        after = page.evaluate("[...document.querySelectorAll('video')].map(v => v.currentTime)")
        assert after[0] == pytest.approx(after[1], abs=1e-6) and 0.05 < after[0] - max(before) < 0.15 + 1e-6
        page.keyboard.press("ArrowLeft")
        back = page.evaluate("[...document.querySelectorAll('video')].map(v => v.currentTime)")
        assert back[0] == pytest.approx(after[0] - 0.1, abs=1e-3) and back[0] == pytest.approx(back[1], abs=1e-6)
        assert page.text_content("#frame") == str(round(back[0] * 10))
        page.keyboard.press("r")
        wait_until(page, "[...document.querySelectorAll('video')].every(v => !v.paused)")
        assert max(page.evaluate("[...document.querySelectorAll('video')].map(v => v.currentTime)")) < 1.0
        # Nothing on the page or in its requests names a policy, an outcome or an episode.
        requests = []
        page.on("request", lambda r: requests.append(r.url))
        answer_with_keyboard(page, "A")
        text = (page.content() + " ".join(requests)).lower()
        secrets = [*POLICIES, "success", "failure", *items["episode_a"], *items["episode_b"]]
        assert [s for s in secrets if s.lower() in text] == []


def test_killing_the_server_while_answering_loses_no_submitted_answer(annotation_set, tmp_path):
    items = annotation_set["items"]
    db = tmp_path / "answers.sqlite"
    server = AnnotationServer(annotation_set["dir"], db).start()
    try:
        with browser() as b:
            page = open_annotator(b, server.url, "anna")
            given = ["A", "B", "A"]
            for letter in given:
                answer_with_keyboard(page, letter)
            page.keyboard.press("B")  # the fourth answer is on its way when the server dies
            server.kill()
            store = AnswerStore(db, items)
            order = [store.item_at("anna", p)["item_id"] for p in range(len(items))]
            saved = store.answers("anna").set_index("item_id")["choice"]
            assert [saved[i] for i in order[:3]] == given  # every acknowledged answer is on disk
            store.close()

            # Unless the reply made it out before the kill, the page says the answer was not saved;
            # once the server is back, pressing the key again saves it. If the answer was saved but
            # the next pair could not load, the page says so and N loads it.
            wait_until(page, "['ready', 'stalled'].includes(document.body.dataset.state) && ("
                             "document.querySelector('#status').classList.contains('error')"
                             " || Number(document.body.dataset.answered) === 4)")
            server.start()
            if answered(page) < 4:
                assert "Not saved" in page.text_content("#status")
                answer_with_keyboard(page, "B")
            elif page.get_attribute("body", "data-state") == "stalled":
                assert "next pair did not load" in page.text_content("#status")
                page.keyboard.press("n")
                wait_until(page, "document.body.dataset.state === 'ready'")
            assert answered(page) == 4 and int(page.get_attribute("body", "data-position")) == 4
        store = AnswerStore(db, items)
        saved = store.answers("anna").set_index("item_id")["choice"]
        assert [saved[i] for i in order[:4]] == [*given, "B"] and len(saved) == 4
        store.close()
    finally:
        server.stop()
