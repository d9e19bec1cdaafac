"""The report of two recorded sessions (an experiment-1-like grid and an experiment-2-like alpha sweep on the
simulated rig) and of a session with the structure and uncertainty records (built with the typed models), opened in
headless Chromium with no network: every image loads and the page renders.

Chromium is the Debian package ``chromium`` (.ci/run installs it); without it the test is skipped.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from report_sessions import GRID, SWEEP, write_structured_session

from stereo_bench.campaign.config import campaign_from_dict
from stereo_bench.campaign.execute import run_campaign
from stereo_bench.report.build import build_report

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium is not installed "
                                                         "(Debian: apt-get install chromium)")

TINY = {
    "seed": 11, "rig": {"time_scale": 50},
    "cameras": {"optics": {"width_px": 960, "height_px": 540, "pixel_um": 6.0}},
    "calibration_board": {"cols": 9, "rows": 6, "square_mm": 25},
    "capture": {"calibration_views": 6, "frames_per_config": 1, "settle_s": 0.05},
}
EXP1 = {**TINY, "name": "tiny-exp1", "plan": {"baseline_mm": [100, 150], "distance_mm": [400, 500], "alpha_deg": [90]}}
# alpha = 35 deg at B = 100 mm, Z = 500 mm: the views do not overlap on the target (infeasible, marked)
EXP2 = {**TINY, "name": "tiny-exp2", "plan": {"baseline_mm": [100], "distance_mm": [500], "alpha_deg": [35, 80, 90]}}

# Written into a copy of the page (the report itself has no script): after load, record every image's size.
CHECK_SCRIPT = """<script>
window.addEventListener('load', function () {
  var images = document.images, bad = [], sizes = [];
  for (var i = 0; i < images.length; i++) {
    images[i].setAttribute('data-natural-width', String(images[i].naturalWidth));
    sizes.push([images[i].getAttribute('src'), images[i].naturalWidth, images[i].naturalHeight]);
    if (!(images[i].complete && images[i].naturalWidth > 0)) bad.push(images[i].getAttribute('src'));
  }
  var out = document.createElement('pre');
  out.id = 'image-check';
  out.textContent = JSON.stringify({total: images.length, bad: bad, sizes: sizes,
                                    tables: document.querySelectorAll('table').length});
  document.body.appendChild(out);
});
</script>
"""


def chromium(profile: Path, *args: str) -> subprocess.CompletedProcess:
    command = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               "--hide-scrollbars", f"--user-data-dir={profile}", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=90, check=False)


def image_check(report: Path, profile: Path, extra: str = "") -> dict:
    """Load a copy of the page with CHECK_SCRIPT; return what the script recorded."""
    page = (report / "index.html").read_text(encoding="utf-8")
    check = report / "check.html"
    check.write_text(page.replace("</body>", extra + CHECK_SCRIPT + "</body>"), encoding="utf-8")
    try:
        result = chromium(profile, "--virtual-time-budget=15000", "--dump-dom", check.as_uri())
    finally:
        check.unlink()
    match = re.search(r'<pre id="image-check">([^<]*)</pre>', result.stdout)
    assert match, f"no image check in the dumped DOM (exit {result.returncode}): {result.stderr[-500:]}"
    return json.loads(match.group(1).replace("&quot;", '"').replace("&amp;", "&"))


def test_report_renders_in_headless_chromium(tmp_path):
    sessions = []
    for config in (EXP1, EXP2):
        summary = run_campaign(campaign_from_dict(config), tmp_path / config["name"], yes=True)
        assert summary.exit_status == "success"
        sessions.append(tmp_path / config["name"])
    sessions.append(write_structured_session(tmp_path / "nominal", "built-nominal", "nominal", GRID + SWEEP))
    report = tmp_path / "report"
    summary = build_report(sessions, report)
    assert summary.counts() == {"measured": 6 + len(GRID + SWEEP), "infeasible": 1}
    srcs = [f for f in summary.files if f.endswith((".png", ".jpg"))]
    for expected in ("figures/s1-tiny-exp1_fig8_A90.png", "figures/s1-tiny-exp1_fig9_A90.png",
                     "figures/s2-tiny-exp2_fig11.png", "figures/s1-tiny-exp1_comparison.png",
                     "figures/s2-tiny-exp2_calibration.png", "images/s2-tiny-exp2/B100_Z500_A80_rectified.jpg",
                     "figures/s1-tiny-exp1_structure.png", "figures/s3-built-nominal_normalised.png",
                     "figures/structural_fig8_A90.png", "figures/structural_fig11.png"):
        assert expected in srcs
    # the simulated sessions record the truth beside each measurement (the structure event)
    tiny = summary.sessions[0].configs[0].structure
    assert tiny.origin["truth"] == "structure event" and tiny.square_true_mm is not None

    profile = tmp_path / "chromium-profile"
    checked = image_check(report, profile)
    assert checked["bad"] == []
    assert checked["total"] == len(srcs)  # every figure and image file is on the page, and loaded
    assert all(width > 0 and height > 0 for _, width, height in checked["sizes"])
    # Tables 1 and 2, per session the comparison, calibration and structure tables, a budget table per session
    # (every session records budgets), the extrinsics side by side in each measured configuration's block, and on
    # the first screen the paper's Table 1 beside ours in the two sessions that measured cells of its grid
    page = (report / "index.html").read_text(encoding="utf-8")
    paper_tables = page.count('<table class="paper">')
    assert paper_tables >= 2
    expected = (1 + 1) + (1 + 1) + 3 * 3 + 3 + 6 + len(GRID + SWEEP) + paper_tables
    assert checked["tables"] == page.count("<table") == expected

    # the check does catch an image that does not load
    broken = image_check(report, profile, extra='<img src="figures/missing.png" alt="missing">')
    assert broken["bad"] == ["figures/missing.png"]

    shot = tmp_path / "shot.png"
    result = chromium(profile, f"--screenshot={shot}", "--window-size=1400,3000", (report / "index.html").as_uri())
    assert shot.is_file(), result.stderr[-500:]
    image = cv2.imread(str(shot))
    assert image.shape[:2] == (3000, 1400)
    assert float(np.std(image)) > 20  # text, tables and figures, not a blank page
