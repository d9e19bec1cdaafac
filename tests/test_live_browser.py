"""The live page in a real browser: headless Chromium (Debian's ``chromium``; .ci/run installs it) driven by
Playwright with the system browser as its executable (no browser download). Skipped, not failed, without it.

A simulated campaign runs as ``stereo-bench campaign run PLAN --out DIR --ui`` (no --yes: the target distance
is set by hand, so the operator is prompted). In the page the test watches the previews update while the
operator is asked, answers the prompt with Continue, sees the first result row appear (a second tab too),
presses Pause (recorded once the run holds) and Stop, and finds the session resumable; a control request
without the URL's token is refused. Resumed without the page, the session measures exactly what a run that
never had a page measures: the page changed nothing that was recorded.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest

from stereo_bench.campaign.config import campaign_from_dict
from stereo_bench.campaign.execute import run_campaign
from stereo_bench.campaign.session import SessionReader
from tests.campaigns import SMALL, numbers

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
playwright = pytest.importorskip("playwright.sync_api", reason="Playwright is not installed")
pytestmark = [pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium is not installed "
                                                          "(Debian: apt-get install chromium)"),
              pytest.mark.slow]
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]
SCREENSHOT = os.environ.get("STEREO_BENCH_LIVE_SCREENSHOT")  # a path: keep a screenshot of the page mid-campaign

# The small campaign at two target distances, so that the operator is asked twice.
PLAN = SMALL.split("[plan]")[0] + "[plan]\nbaseline_mm = [100, 150]\ndistance_mm = [400, 450]\nalpha_deg = [90]\n"


def launch(plan: Path, out: Path) -> tuple[subprocess.Popen, str]:
    """The campaign with --ui in its own process (stdin kept open: the terminal operator stays, silent)."""
    process = subprocess.Popen(
        [sys.executable, "-m", "stereo_bench", "campaign", "run", str(plan), "--out", str(out), "--ui",
         "--ui-port", "0", "--quiet"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    seen = []
    while time.monotonic() < deadline:
        line = process.stderr.readline()
        seen.append(line)
        match = re.search(r"live page: (http://\S+)", line)
        if match:
            return process, match.group(1)
        if process.poll() is not None:
            break
    process.kill()
    raise AssertionError(f"no URL printed: {''.join(seen)}")


def preview_version(page) -> int:
    return int(page.get_attribute("#img-left", "data-version") or 0)


def test_a_campaign_followed_and_steered_from_the_live_page(tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN)
    out = tmp_path / "session"
    process, url = launch(plan, out)
    assert url.startswith("http://127.0.0.1:") and "token=" in url
    base = url.split("/?")[0]
    try:
        with playwright.sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1400, "height": 1400})
            page.goto(url)
            second = browser.new_page()  # a second tab, without the token: sees everything, controls nothing
            second.goto(base + "/")

            # The first prompt: the operator moves the target. Meanwhile the previews are live.
            page.wait_for_selector("#prompt:not([hidden])", timeout=60_000)
            assert "Z = 400 mm" in page.inner_text("#prompt-message")
            # The second tab draws the prompt from its own event stream, when that delivers it: wait for it there.
            second.wait_for_selector("#prompt:not([hidden])", timeout=30_000)
            assert second.is_visible("#prompt") and second.is_disabled("#continue")
            page.wait_for_function("Number(document.querySelector('#img-left').dataset.version || 0) > 0")
            # The previews keep updating while the operator is asked (a count of new frames, not a rate:
            # how many a second is the machine's load's business).
            first = preview_version(page)
            page.wait_for_function(f"Number(document.querySelector('#img-left').dataset.version || 0) >= {first + 5}",
                                   timeout=30_000)
            assert page.is_visible("#prompt")
            # A preview whose next frame is still loading has no width yet: wait for a loaded one.
            page.wait_for_function("document.querySelector('#img-left').naturalWidth === 640", timeout=30_000)

            # Refused without the token: the same request the buttons make, from this browser.
            refused = page.request.post(base + "/api/control/stop")
            assert refused.status == 403

            page.click("#continue")
            page.wait_for_selector("#prompt", state="hidden", timeout=30_000)

            # The second prompt (Z = 450 mm): by then the first configuration's result has been published.
            page.wait_for_selector("#prompt:not([hidden])", timeout=120_000)
            assert "Z = 450 mm" in page.inner_text("#prompt-message")
            page.wait_for_selector("#results-table tr[data-status='measured']", timeout=60_000)
            row = page.inner_text("#results-table tr[data-config='B100_Z400_A90']")
            assert row.startswith("B100_Z400_A90")
            second.wait_for_selector("#results-table tr[data-config='B100_Z400_A90']", timeout=30_000)
            assert second.inner_text("#results-table tr[data-config='B100_Z400_A90']") == row
            page.wait_for_selector(".cov canvas", timeout=30_000)  # the coverage of the kept views
            # The results plot's series legend sits below the plot, clear of the error bars (it overlapped them).
            # Checked in the page in one go: the plot is drawn anew with each result, so boxes read one after the
            # other from here could belong to two drawings (the legend's of a drawing already replaced).
            page.wait_for_function("""() => {
                const svg = document.querySelector('#plot svg'), legend = document.querySelector('#plot .legend');
                if (!svg || !legend || !legend.getClientRects().length) return false;
                return legend.getBoundingClientRect().top >= svg.getBoundingClientRect().bottom - 0.5;
            }""", timeout=30_000)
            assert "Z = 400 mm" in page.inner_text("#plot .legend")
            if SCREENSHOT:
                page.screenshot(path=SCREENSHOT, full_page=True)

            # Pause while the operator is asked: the run holds after the answer, and says so.
            page.click("#pause")
            page.click("#continue")
            page.wait_for_function("document.querySelector('#status').textContent === 'paused'", timeout=60_000)
            assert page.inner_text("#pause") == "Resume"
            paused_at = preview_version(page)
            page.wait_for_function(f"Number(document.querySelector('#img-left').dataset.version) > {paused_at}",
                                   timeout=30_000)  # paused: the cameras are the page's again

            page.click("#stop")
            page.wait_for_function("document.querySelector('#status').textContent === 'interrupted'",
                                   timeout=60_000)
            assert "--resume" in page.inner_text("#step")
            browser.close()
        assert process.wait(timeout=60) == 130  # interrupted: resumable
    finally:
        if process.poll() is None:
            process.kill()
        process.communicate()

    reader = SessionReader(out)
    assert reader.stops()[-1].exit_status == "interrupted"
    controls = [e.data.action for e in reader.events(kind="run_control")]
    assert controls == ["pause"]
    answered = [e.data.answered_by for e in reader.events(kind="prompt")]
    assert answered == ["live page", "live page"]
    done = reader.completed_config_ids()
    assert "B100_Z400_A90" in done and len(done) < 4

    # Resume it (no page) to the end; a run that never had a page records the same numbers.
    config = campaign_from_dict(tomllib.loads(PLAN))
    assert run_campaign(config, out, resume=True, yes=True).exit_status == "success"
    reference = tmp_path / "reference"
    assert run_campaign(config, reference, yes=True).exit_status == "success"
    assert numbers(out) == numbers(reference)
