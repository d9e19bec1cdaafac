"""The live page's server without a browser (HTTP client): the token, the state it serves (folded from a
recorded session's documents), files confined to the session directory, prompts answered over HTTP,
Server-Sent Events, and previews made only while somebody watches."""

from __future__ import annotations

import json
import os
import threading
import time

import cv2
import httpx
import numpy as np
import pytest

from stereo_bench.campaign.execute import RunControl
from stereo_bench.campaign.operator import CAPTURE_NOW, CONTINUE, Prompt, Ticket
from stereo_bench.campaign.session import SessionReader
from stereo_bench.live.page import LivePage
from stereo_bench.live.preview import Previews
from tests.campaigns import small_config, stop_at_move


@pytest.fixture
def page(small_reference):
    """A page of the small reference session, served on a free port; its run control records what it is asked."""
    control = RunControl()
    page = LivePage.for_campaign(small_config(), session_dir=small_reference, control=control)
    page.control_calls = []
    control.request_pause = lambda: page.control_calls.append("pause")
    control.request_stop = lambda reason="": page.control_calls.append("stop")
    page.start()
    yield page
    page.stop()


def client_of(page) -> httpx.Client:
    return httpx.Client(base_url=f"http://127.0.0.1:{page.server.port}", timeout=10)


def feed(page, session) -> list:
    documents = SessionReader(session).documents()
    for document in documents:
        page.state(document)
    return documents


def test_every_control_needs_the_token(page):
    client = client_of(page)
    page.state.run["status"] = "running"
    for headers in ({}, {"X-Token": "not-the-token"}, {"X-Token": page.token[:-1]}):
        response = client.post("/api/control/stop", headers=headers)
        assert response.status_code == 403 and "token" in response.json()["message"]
    assert page.control_calls == []  # refused: nothing happened
    assert client.post(f"/api/control/stop?token={page.token}").status_code == 200
    assert client.post("/api/control/pause", headers={"X-Token": page.token}).status_code == 200
    assert page.control_calls == ["stop", "pause"]
    assert client.post("/api/control/reboot", headers={"X-Token": page.token}).status_code == 404
    assert client.get("/api/control/stop").status_code == 405  # a GET (a link, an <img>) never acts


def test_the_state_is_the_recorded_stream(page, small_reference):
    documents = feed(page, small_reference)
    page.state.poll_transcript()
    state = client_of(page).get("/api/state").json()
    reader = SessionReader(small_reference)
    rows = {row["config_id"]: row for row in [row.stored() for row in reader.results()]}
    assert [r["config_id"] for r in state["results"]] == [c["config_id"] for c in reader.start().plan]
    for shown in state["results"]:
        assert shown["status"] == rows[shown["config_id"]]["status"]
        if shown["status"] == "measured":
            assert shown["error_mm"] == rows[shown["config_id"]]["error_mm"]
    assert state["plan"]["counts"] == {"total": 4, "measured": 2, "failed": 0, "infeasible": 2, "remaining": 0}
    assert state["plan"]["varying"][0] in ("baseline_mm", "alpha_deg") and state["plan"]["eta_s"] == 0.0
    assert state["run"]["status"] == "success" and state["version"] >= len(documents)
    last_move = reader.events(kind="move")[-1].data.rig
    assert state["rig"]["position"]["baseline_mm"] == pytest.approx(last_move.baseline_mm, abs=1e-3)
    assert any(line.startswith("> $H") for line in state["rig"]["transcript"])  # the session's serial transcript
    per_view = state["calibration"]["per_view"]
    analysis = reader.events(kind="analysis", config_id=state["calibration"]["config_id"])[-1].data
    assert [v["left_px"] for v in per_view] == [e[0] for e in analysis.calibration["per_view_rms_px"]]


def test_files_are_served_from_inside_the_session_only(page, small_reference, tmp_path):
    client = client_of(page)
    response = client.get("/session/results.csv")
    assert response.status_code == 200 and response.text == (small_reference / "results.csv").read_text()
    outside = tmp_path / "secret.txt"
    outside.write_text("not for the page")
    link = small_reference / "link-out"
    os.symlink(outside, link)
    try:
        for path in ("/session/link-out", "/session/..%2Fsmall%2Fresults.csv", f"/session/%2F{outside}",
                     "/session/frames/..%2F..%2Fsecret.txt"):
            response = client.get(path)
            assert response.status_code in (403, 404) and "not for the page" not in response.text, path
        assert client.get("/session/link-out").status_code == 403
    finally:
        link.unlink()
    assert client.get("/session/no-such-file").status_code == 404
    assert client.get("/static/..%2F..%2Fpyproject.toml").status_code == 404
    assert client.get("/static/live.js").status_code == 200
    # Without a session (stereo-bench live) nothing is served from disk at all.
    with LivePage.for_campaign(small_config(), session_dir=None) as bare:
        assert client_of(bare).get("/session/results.csv").status_code == 404


def test_a_prompt_is_answered_once_over_http_and_the_page_refuses_what_it_does_not_accept(page):
    client = client_of(page)
    headers = {"X-Token": page.token}
    assert client.post("/api/control/continue", headers=headers).status_code == 409  # nothing asked
    ticket = Ticket(Prompt("target", "move the target to Z = 450 mm", config_id="B100_Z450_A90"), 2)
    page.operator.offer(ticket)
    assert client.get("/api/state").json()["prompt"]["message"] == "move the target to Z = 450 mm"
    refused = client.post(f"/api/control/{CAPTURE_NOW}", headers=headers)
    assert refused.status_code == 409 and "accepts continue" in refused.json()["message"] and not ticket.done
    assert client.post(f"/api/control/{CONTINUE}", headers=headers).status_code == 200
    assert ticket.answered_by == "live page" and ticket.action == CONTINUE
    assert client.get("/api/state").json()["prompt"] is None
    assert client.post(f"/api/control/{CONTINUE}", headers=headers).status_code == 409
    # The terminal answered first: the page's button does nothing.
    other = Ticket(Prompt("target", "again"), 2)
    page.operator.offer(other)
    other.answer("terminal")
    again = client.post(f"/api/control/{CONTINUE}", headers=headers)
    assert again.status_code == 409 and "terminal" in again.json()["message"]


def test_a_press_meant_for_a_prompt_no_longer_waiting_does_not_answer_the_next(page):
    # The operator presses Continue on prompt A; before the press arrives the terminal answered A and the run
    # asked B. The press names A: B is not answered by it (it would be, by a POST that names no prompt).
    client = client_of(page)
    headers = {"X-Token": page.token}
    first = Ticket(Prompt("target", "move the target to Z = 450 mm"), 2)
    page.operator.offer(first)
    shown = client.get("/api/state").json()["prompt"]["id"]
    first.answer("terminal")
    second = Ticket(Prompt("target", "move the target to Z = 500 mm"), 2)
    page.operator.offer(second)
    assert client.get("/api/state").json()["prompt"]["id"] != shown
    late = client.post(f"/api/control/{CONTINUE}?prompt={shown}", headers=headers)
    assert late.status_code == 409 and "no longer waiting" in late.json()["message"] and not second.done
    assert client.post(f"/api/control/{CONTINUE}?prompt=x", headers=headers).status_code == 400
    current = client.get("/api/state").json()["prompt"]["id"]
    assert client.post(f"/api/control/{CONTINUE}?prompt={current}", headers=headers).status_code == 200
    assert second.answered_by == "live page"


def test_the_per_view_review_is_answered_with_a_threshold_a_view_or_recalibrate_over_http(page):
    from stereo_bench.campaign.review import ReviewState, review_prompt

    client = client_of(page)
    headers = {"X-Token": page.token}
    prompt = review_prompt("B100_Z450_A90", ReviewState(n_views=6))
    for action, value in (("set_threshold", 0.3), ("exclude_view", 4), ("recalibrate", None)):
        ticket = Ticket(prompt, 2)
        page.operator.offer(ticket)
        shown = client.get("/api/state").json()["prompt"]
        assert shown["message"] == prompt.message and "set_threshold" in shown["actions"]
        if value is not None:  # a valued action without its number is refused, and the prompt still waits
            missing = client.post(f"/api/control/{action}", headers=headers)
            assert missing.status_code == 400 and "needs ?value=" in missing.json()["message"] and not ticket.done
        query = "" if value is None else f"?value={value}"
        answered = client.post(f"/api/control/{action}{query}", headers=headers)
        assert answered.status_code == 200, answered.json()
        assert (ticket.action, ticket.value) == (action, None if value is None else float(value))
    # The page has the controls (the buttons the script wires to these actions, with their inputs).
    html = client.get("/").text
    for element in ('id="set_threshold"', 'data-input="review-threshold"', 'id="exclude_view"', 'id="recalibrate"'):
        assert element in html, element


def board_image() -> np.ndarray:
    """A 960x540 grey frame with the small campaign's 9x6 target, square-on (OpenCV detects it)."""
    texture = small_config().target.build().texture(px_per_square=40).image
    frame = np.full((540, 960), 128, np.uint8)
    height, width = texture.shape
    frame[50:50 + height, 100:100 + width] = texture
    return frame


class Doc:
    """The attributes of a recorded measurement_frame document the preview reads."""

    kind = "measurement_frame"
    config_id = "B100_Z450_A90"

    class data:  # noqa: N801 - stands in for the document's data model
        index = 0
        dt_s = 0.0012


def test_previews_are_made_only_while_watched_and_the_newest_frame_wins():
    encoded = []
    previews = Previews({"target": small_config().target.build()}, on_encoded=encoded.append).start()
    try:
        image = board_image()
        previews.captured(Doc(), {"left": image, "right": image})
        time.sleep(0.3)
        assert encoded == []  # nobody watches: nothing encoded
        for _ in range(3):  # three frames before the worker runs: two are dropped, never queued
            previews.captured(Doc(), {"left": image, "right": image})
        previews.watchers(+1)
        deadline = time.monotonic() + 5
        while not encoded and time.monotonic() < deadline:
            time.sleep(0.02)
        assert len(encoded) == 1 and previews.stats["dropped"] == 3
        meta = encoded[0].meta
        assert meta["corners"] == {"left": 54, "right": 54} and meta["in_both"] == 54
        assert meta["skew_ms"] == pytest.approx(1.2) and meta["board"] == "target"
        jpeg = cv2.imdecode(np.frombuffer(encoded[0].jpeg["left"], np.uint8), cv2.IMREAD_COLOR)
        assert jpeg.shape == (360, 640, 3)
        # The corners are drawn in green (seen by both cameras) onto the grey frame.
        green = (jpeg[:, :, 1] > 150) & (jpeg[:, :, 0] < 120) & (jpeg[:, :, 2] < 120)
        assert green.sum() > 54 * 10
    finally:
        previews.stop()


def test_server_sent_events_and_a_second_tab_see_the_same_state_and_leaving_changes_nothing(small_reference):
    page = LivePage.for_campaign(small_config(), session_dir=small_reference, control=RunControl()).start()
    try:
        feed(page, small_reference)
        while page.state.poll_transcript():  # the whole (finished) transcript read: the state stands still
            pass
        ticket = Ticket(Prompt("target", "move the target to Z = 450 mm"), 2)
        page.operator.offer(ticket)
        base = f"http://127.0.0.1:{page.server.port}"

        def first_state() -> dict:
            with httpx.stream("GET", f"{base}/api/events", timeout=10) as stream:
                for line in stream.iter_lines():
                    if line.startswith("data: "):
                        assert page.previews.watched  # a connected browser makes previews start
                        return json.loads(line[6:])
            raise AssertionError("no state event")

        states = []
        tabs = [threading.Thread(target=lambda: states.append(first_state())) for _ in range(2)]
        for tab in tabs:
            tab.start()
        for tab in tabs:
            tab.join(15)
        assert len(states) == 2
        for state in states:
            state["run"].pop("elapsed_s")
        assert states[0] == states[1] and states[0]["prompt"]["message"] == "move the target to Z = 450 mm"
        deadline = time.monotonic() + 5
        while page.previews.watched and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not page.previews.watched  # both tabs closed: previews stop ...
        assert not ticket.done and httpx.get(f"{base}/api/state").json()["prompt"] is not None  # ... nothing else
        assert page.url.startswith(f"http://127.0.0.1:{page.server.port}/?token=")
    finally:
        page.stop()


def test_a_resumed_campaign_shows_the_plan_and_the_results_recorded_before(tmp_path):
    from stereo_bench.campaign.execute import run_campaign
    from stereo_bench.live.state import LiveState

    out, control = tmp_path / "resumed", RunControl()
    assert run_campaign(small_config(), out, yes=True, control=control,
                        bench_factory=stop_at_move(control, 2)).exit_status == "interrupted"
    before = {row.config_id for row in SessionReader(out).results()}
    state = LiveState(session_dir=out)
    assert run_campaign(small_config(), out, resume=True, yes=True, subscribers=[state]).exit_status == "success"
    snapshot = state.snapshot()
    assert snapshot["run"]["attempt"] == 2 and snapshot["plan"]["counts"]["remaining"] == 0
    assert before <= {row["config_id"] for row in snapshot["results"]} and len(snapshot["results"]) == 4
    assert any("resumed (attempt 2)" in entry["text"] for entry in snapshot["log"])


def test_the_resume_document_carries_what_a_page_shows_without_reading_the_session(tmp_path):
    """A page that sees only the stream (no session directory) shows a resumed run's plan and earlier rows."""
    from stereo_bench.campaign.execute import run_campaign
    from stereo_bench.live.state import LiveState

    out, control = tmp_path / "resumed", RunControl()
    assert run_campaign(small_config(), out, yes=True, control=control,
                        bench_factory=stop_at_move(control, 2)).exit_status == "interrupted"
    before = SessionReader(out).results()
    assert before  # the interruption came after a result: there is something to carry
    state = LiveState(session_dir=None)
    assert run_campaign(small_config(), out, resume=True, yes=True, subscribers=[state]).exit_status == "success"
    reader = SessionReader(out)
    (resume,) = reader.resumes()
    start = reader.start()
    assert (resume.config, resume.plan, resume.bench) == (start.config, start.plan, start.bench)
    assert [row.stored() for row in resume.results] == [row.stored() for row in before]
    snapshot = state.snapshot()
    assert snapshot["run"]["bench"] == start.bench and snapshot["plan"]["counts"]["remaining"] == 0
    assert len(state.plan) == 4
    assert {row.config_id for row in before} <= {row["config_id"] for row in snapshot["results"]}


def test_previews_reach_the_page_as_their_own_events_unthrottled_and_change_no_state(monkeypatch):
    """Live previews come 6 a second: each is a small ``preview`` event, not a whole state (those stay <= 5/s).

    The stream's clock stands still once the first state is sent: a second state would wait for it forever (at most
    5 a second), a preview goes at once. Each preview is set when the one before has arrived: every one must come,
    however slowly a loaded machine delivers them (no arrival times are compared)."""
    from types import SimpleNamespace

    from stereo_bench.live import server as server_module

    page = LivePage.for_campaign(small_config(), session_dir=None, control=RunControl()).start()
    frozen = SimpleNamespace(monotonic=lambda: 1000.0, sleep=time.sleep)  # after start(): it waits on the clock
    monkeypatch.setattr(server_module, "time", frozen)
    states, previews = [], []
    try:
        def listen():
            with httpx.stream("GET", f"http://127.0.0.1:{page.server.port}/api/events", timeout=30) as stream:
                event = None
                for line in stream.iter_lines():
                    if line.startswith("event: "):
                        event = line[7:]
                    elif line.startswith("data: "):
                        (states if event == "state" else previews).append(json.loads(line[6:]))
                        if previews and previews[-1]["version"] == 10:
                            return

        def arrived(condition, what: str) -> None:
            deadline = time.monotonic() + 30
            while not condition():
                assert time.monotonic() < deadline and listener.is_alive(), f"never received {what}"
                time.sleep(0.01)

        listener = threading.Thread(target=listen, daemon=True)
        listener.start()
        arrived(lambda: states, "the first state")
        version = page.state.version
        for n in range(1, 11):
            page.state.set_preview({"version": n, "source": "live", "corners": {"left": 54, "right": 54}})
            arrived(lambda n=n: previews and previews[-1]["version"] == n, f"preview {n} (the clock stands still)")
        listener.join(30)
    finally:
        page.stop()
    assert page.state.version == version and len(states) == 1  # the previews changed nothing else
    assert [p["version"] for p in previews] == list(range(1, 11))  # each its own event, none held
    assert previews[-1] == {"version": 10, "source": "live", "corners": {"left": 54, "right": 54}}


def test_the_pages_eta_is_the_terminals(small_reference):
    """The page's ETA comes from the same tracker as the status line's (campaign/eta.py), fed the same events on
    the same clock: the plan's time model corrected by what was measured, not a rate of its own."""
    from stereo_bench.campaign.documents import MoveEvent, PromptEvent, StartDocument
    from stereo_bench.campaign.eta import EtaTracker, forecast_groups
    from stereo_bench.campaign.execute import CampaignPlan
    from stereo_bench.campaign.recorded import RecordedStart
    from stereo_bench.live.state import LiveState

    now = [100.0]
    state = LiveState(clock=lambda: now[0])
    tracker = None
    moves = 0
    for document in SessionReader(small_reference).documents():
        now[0] += 7.0  # every document a little later, on both sides
        state(document)
        if isinstance(document, StartDocument):
            recorded = RecordedStart.of(document)
            config = recorded.campaign
            plan = CampaignPlan.of(config, recorded.configurations, recorded.visits)
            tracker = EtaTracker(forecast_groups(config, plan.steps), start_s=now[0])
        elif isinstance(document, MoveEvent):
            tracker.moved(document.config_id, now[0])
            moves += 1
        elif isinstance(document, PromptEvent):
            tracker.prompt_answered(document.data.waited_s)
        if moves == 2:
            break
    assert moves == 2 and state.eta_tracker is not None
    eta = state._eta()
    assert eta["eta_s"] == pytest.approx(tracker.shown(now[0])) and eta["eta_s"] > 0
    assert "as the terminal's" in eta["basis"]
