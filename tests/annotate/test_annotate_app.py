"""The annotation app without a browser: the answer store, HTTP Range, what is served (and what
never is), and answers that survive a killed server."""

from __future__ import annotations

import http.client
import json
import threading
import time

import pandas as pd
import pytest

from r2s_eval.annotate import AnnotationError, AnswerStore
from r2s_eval.annotate.answers import EXPORT_COLUMNS

from tests.helpers.people import POLICIES, AnnotationServer, export_csv, fetch_json


@pytest.fixture
def store(annotation_set, tmp_path):
    s = AnswerStore(tmp_path / "answers.sqlite", annotation_set["items"])
    yield s
    s.close()


def test_answers_resume_in_each_annotators_own_order(store, annotation_set, tmp_path):
    items = annotation_set["items"]
    for position in range(3):
        store.record("anna", store.item_at("anna", position)["item_id"], "A", seconds=4.5, watched_full=True)
    assert store.progress("anna") == {"annotator": "anna", "answered": 3, "total": len(items), "position": 3}
    assert store.progress("ben")["position"] == 0
    assert store.order("anna") != store.order("ben") and sorted(store.order("anna")) == list(range(len(items)))
    again = AnswerStore(tmp_path / "answers.sqlite", items)  # a restarted server: same order, same answers
    assert again.order("anna") == store.order("anna") and again.progress("anna")["position"] == 3
    again.close()


def test_changing_an_answer_keeps_one_row_and_counts_the_revision(store):
    item = store.item_at("anna", 0)["item_id"]
    store.record("anna", item, "A")
    store.record("anna", item, "b")
    answers = store.answers("anna")
    assert len(answers) == 1 and answers["choice"].iloc[0] == "B" and answers["revisions"].iloc[0] == 2


def test_bad_answers_are_refused_with_a_reason(store):
    item = store.item_at("anna", 0)["item_id"]
    with pytest.raises(AnnotationError, match="choice must be A or B"):
        store.record("anna", item, "C")
    with pytest.raises(AnnotationError, match="no item 'zz'"):
        store.record("anna", "zz", "A")
    with pytest.raises(AnnotationError, match="annotator name"):
        store.record("../anna", item, "A")
    with pytest.raises(AnnotationError, match="outside"):
        store.item_at("anna", 99)


def test_a_database_of_another_set_is_refused(store, annotation_set, tmp_path):
    other = annotation_set["items"].iloc[::-1].reset_index(drop=True)
    other["item_id"] = annotation_set["items"]["item_id"]
    with pytest.raises(AnnotationError, match="answers for another annotation set"):
        AnswerStore(tmp_path / "answers.sqlite", other)


def test_export_has_the_columns_the_audit_reads(store):
    store.record("anna", store.item_at("anna", 0)["item_id"], "B", seconds=3.0)
    out = store.export()
    assert list(out.columns) == list(EXPORT_COLUMNS) and out["choice"].tolist() == ["B"]


# ---------------------------------------------------------------------------- over HTTP


def request(server, path: str, headers: dict | None = None, method: str = "GET", body: bytes | None = None):
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=10)
    conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)  # the path goes out as written
    headers = {"Host": f"127.0.0.1:{server.port}", **(headers or {})}
    if body is not None:
        headers["Content-Length"] = str(len(body))
    for k, v in headers.items():
        conn.putheader(k, v)
    conn.endheaders(body)
    response = conn.getresponse()
    data = response.read()
    conn.close()
    return response, data


@pytest.fixture(scope="module")
def server(annotation_set, tmp_path_factory):
    with AnnotationServer(annotation_set["dir"], tmp_path_factory.mktemp("served") / "answers.sqlite") as s:
        yield s


def test_videos_answer_range_requests(server, annotation_set):
    token = annotation_set["items"]["video_a"].iloc[0]
    whole = (annotation_set["dir"] / "videos" / token).read_bytes()
    r, data = request(server, f"/video/{token}")
    assert r.status == 200 and data == whole and r.getheader("Accept-Ranges") == "bytes"
    r, data = request(server, f"/video/{token}", {"Range": "bytes=0-99"})
    assert r.status == 206 and data == whole[:100] and r.getheader("Content-Range") == f"bytes 0-99/{len(whole)}"
    r, data = request(server, f"/video/{token}", {"Range": f"bytes={len(whole) - 50}-"})
    assert r.status == 206 and data == whole[-50:]
    r, data = request(server, f"/video/{token}", {"Range": "bytes=-64"})  # the last 64 bytes (moov at the end)
    assert r.status == 206 and data == whole[-64:]
    r, _ = request(server, f"/video/{token}", {"Range": f"bytes={len(whole) + 10}-"})
    assert r.status == 416


@pytest.mark.parametrize("path", [
    "/video/../set.parquet", "/video/..%2fset.parquet", "/video/%2e%2e/set.parquet", "/static/../server.py",
    "/static/..%2f..%2fstore.py", "/static/index.html", "/set.parquet", "/results/annotate/set.parquet",
    "/videos/{token}", "/video/{token}/../../set.parquet", "/video/0123456789abcdef0123.mp4", "//etc/passwd",
    "/static/%2e%2e/%2e%2e/server.py",
])
def test_only_the_sets_files_are_served(server, annotation_set, path):
    token = annotation_set["items"]["video_a"].iloc[0]
    r, data = request(server, path.format(token=token))
    assert r.status in (400, 404), (path, r.status)
    assert b"PAR1" not in data and b"import" not in data and b"root:" not in data


def test_requests_for_another_host_are_refused(server):
    r, _ = request(server, "/api/info", {"Host": "attacker.example:80"})
    assert r.status == 421


def test_nothing_served_names_a_policy_an_outcome_or_an_episode(server, annotation_set):
    items = annotation_set["items"]
    secrets = [*POLICIES, "success", "failure", "fail", *items["episode_a"], *items["episode_b"]]
    texts = [request(server, p)[1].decode() for p in ("/", "/static/app.js", "/static/app.css", "/api/info")]
    texts.append(request(server, "/api/progress?annotator=anna")[1].decode())
    for position in range(len(items)):
        item = fetch_json(f"{server.url}/api/item?annotator=anna&position={position}")
        assert set(item) == {"position", "total", "answered", "instruction", "video_a", "video_b", "fps_a", "fps_b",
                             "choice"}
        texts.append(json.dumps(item))
        body = json.dumps({"annotator": "anna", "position": position, "choice": "A"}).encode()
        texts.append(request(server, "/api/answer", {"Content-Type": "application/json"}, "POST", body)[1].decode())
    blob = "\n".join(texts).lower()
    assert [s for s in secrets if s.lower() in blob] == []


def test_a_bad_answer_gets_a_reason_not_a_crash(server):
    r, data = request(server, "/api/answer", {"Content-Type": "application/json"}, "POST", b'{"annotator": "anna"}')
    assert r.status == 400 and "annotator, position and choice" in json.loads(data)["error"]
    body = json.dumps({"annotator": "anna", "position": 0, "choice": "maybe"}).encode()
    r, data = request(server, "/api/answer", {"Content-Type": "application/json"}, "POST", body)
    assert r.status == 400 and "choice must be A or B" in json.loads(data)["error"]


def test_killing_the_server_mid_burst_loses_no_acknowledged_answer(annotation_set, tmp_path):
    """Three annotators post answers as fast as they can; the server is SIGKILLed in the middle.
    Every answer it acknowledged is in the database afterwards, and the export has them all."""
    db = tmp_path / "answers.sqlite"
    server = AnnotationServer(annotation_set["dir"], db).start()
    acked: list[tuple[str, int, str]] = []
    lock = threading.Lock()

    def annotate(name: str) -> None:
        for position in range(len(annotation_set["items"])):
            choice = "AB"[(position + len(name)) % 2]
            body = json.dumps({"annotator": name, "position": position, "choice": choice}).encode()
            try:
                r, _ = request(server, "/api/answer", {"Content-Type": "application/json"}, "POST", body)
            except OSError:
                return  # the server is gone
            if r.status == 200:
                with lock:
                    acked.append((name, position, choice))

    threads = [threading.Thread(target=annotate, args=(n,)) for n in ("anna", "ben", "cleo")]
    for t in threads:
        t.start()
    deadline = time.monotonic() + 60
    while len(acked) < 8 and time.monotonic() < deadline:
        time.sleep(0.001)
    server.kill()
    for t in threads:
        t.join()
    assert 8 <= len(acked) < 3 * len(annotation_set["items"])
    store = AnswerStore(db, annotation_set["items"])
    answers = store.answers()
    stored = {(r.annotator, r.item_id): r.choice for r in answers.itertuples()}
    for name, position, choice in acked:
        assert stored[(name, store.item_at(name, position)["item_id"])] == choice
    store.close()
    csv = export_csv(annotation_set["dir"], db, tmp_path / "annotations.csv")
    assert len(csv) == len(answers) >= len(acked)
    assert set(pd.unique(csv["annotator"])) <= {"anna", "ben", "cleo"}


def test_command_line_status_and_export(annotation_set, tmp_path, capsys):
    from r2s_eval.annotate.__main__ import main

    db = tmp_path / "answers.sqlite"
    store = AnswerStore(db, annotation_set["items"])
    for position in range(2):
        store.record("anna", store.item_at("anna", position)["item_id"], "A")
    store.close()
    args = ["--set", str(annotation_set["dir"]), "--db", str(db)]
    assert main(["status", *args]) == 0
    assert f"anna{'':<20}    2 / {len(annotation_set['items'])}" in capsys.readouterr().out
    assert main(["export", *args, "--out", str(tmp_path / "a.csv")]) == 0
    assert pd.read_csv(tmp_path / "a.csv")["annotator"].tolist() == ["anna", "anna"]
    assert main(["status", "--set", str(tmp_path / "nowhere"), "--db", str(db)]) == 1
    assert "set.parquet does not exist" in capsys.readouterr().err
