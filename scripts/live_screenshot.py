"""The screenshot of the live page in docs/LIVE.md: a simulated campaign with --ui, mid-way, waiting for the operator.

Runs ``stereo-bench campaign run PLAN --ui`` (1920x1080 simulated cameras; the target distance is set
by hand, so the operator is asked at each new Z), answers the prompts through the page's API until
``--results`` configurations have results, then takes a screenshot with headless Chromium (Debian's
``chromium``, driven by Playwright) at the next prompt, and stops the campaign.

    python scripts/live_screenshot.py [--out docs/live-page.png] [--results 5]
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

PLAN = """
name = "exp1-live"
seed = 3
[rig]
time_scale = 10
[capture]
calibration_views = 10
frames_per_config = 2
settle_s = 0.2
[plan]
baseline_mm = [50, 100, 150, 200]
distance_mm = [400, 500, 600]
alpha_deg = [90]
"""
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/live-page.png")
    parser.add_argument("--results", type=int, default=5, help="results to wait for before the screenshot")
    args = parser.parse_args()
    from playwright.sync_api import sync_playwright

    workdir = Path(tempfile.mkdtemp(prefix="live-screenshot-"))
    plan = workdir / "plan.toml"
    plan.write_text(PLAN)
    process = subprocess.Popen([sys.executable, "-m", "stereo_bench", "campaign", "run", str(plan), "--out",
                                str(workdir / "session"), "--ui", "--ui-port", "0", "--quiet"],
                               stdin=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = None
        while url is None:
            match = re.search(r"live page: (http://\S+)", process.stderr.readline())
            url = match.group(1) if match else None
        base, token = url.split("/?token=")
        client = httpx.Client(base_url=base, headers={"X-Token": token}, timeout=30)
        while True:
            state = client.get("/api/state").json()
            if state["prompt"] is not None:
                # The analyses run behind the captures: let the results of the configurations before this
                # prompt arrive before deciding whether this is the prompt to photograph.
                settled = time.monotonic() + 3.0
                while time.monotonic() < settled and len(state["results"]) < args.results:
                    time.sleep(0.2)
                    state = client.get("/api/state").json()
                if len(state["results"]) >= args.results:
                    break
                client.post("/api/control/continue")
            time.sleep(0.2)
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=shutil.which("chromium"), args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1400, "height": 1300})
            page.goto(url)
            page.wait_for_function("Number(document.querySelector('#img-right').dataset.version || 0) > 2")
            time.sleep(1.0)
            page.screenshot(path=args.out, full_page=True)
            browser.close()
        client.post("/api/control/stop")
        client.post("/api/control/continue")
        process.wait(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
        shutil.rmtree(workdir, ignore_errors=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
