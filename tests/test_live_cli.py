"""`stereo-bench live` (previews with no campaign) on the simulated bench, and the --ui options' errors."""

from __future__ import annotations

import argparse
import json
import re
import signal
import socket
import subprocess
import sys
import time

import httpx
import pytest

from stereo_bench.cli import main
from stereo_bench.cli.campaign_run import start_live_page
from stereo_bench.cli.live import live_config
from stereo_bench.live.page import LivePage
from stereo_bench.live.server import LiveServerError
from tests.campaigns import small_config


def test_live_previews_the_simulated_bench_and_ends_on_ctrl_c():
    process = subprocess.Popen(
        [sys.executable, "-m", "stereo_bench", "live", "--ui-host", "127.0.0.2", "--ui-port", "0",
         "--time-scale", "50", "--distance", "450"],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        lines, url = [], None
        deadline = time.monotonic() + 60
        while url is None and time.monotonic() < deadline:
            lines.append(process.stderr.readline())
            match = re.search(r"live page: (http://\S+)", lines[-1])
            url = match.group(1) if match else None
        assert url is not None, "".join(lines)
        # 127.0.0.2 is not this machine's usual local name: the page says it may be seen from elsewhere.
        assert any(line.startswith("warning: the live page listens on 127.0.0.2") for line in lines)
        base = url.split("/?")[0]
        with httpx.stream("GET", f"{base}/api/events", timeout=30) as stream:  # somebody watches: previews
            preview, event = None, "state"
            for line in stream.iter_lines():
                if line.startswith("event: "):
                    event = line[7:]
                elif line.startswith("data: ") and event == "preview":  # the newest preview's meta
                    preview = json.loads(line[6:])
                    if preview["corners"]["left"]:
                        break
        state = httpx.get(f"{base}/api/state").json()
        assert state["run"]["status"] == "live preview"
        assert preview["source"] == "live" and preview["board"] == "target"
        assert preview["in_both"] == 54  # the simulated target at 450 mm, whole in both views
        assert state["preview"]["version"] >= preview["version"]  # the state carries the newest preview too
        assert state["rig"]["position"]["baseline_mm"] == pytest.approx(100.0, abs=0.01)  # homed and moved
        assert httpx.get(f"{base}/preview/right.jpg").headers["content-type"] == "image/jpeg"
        control = httpx.post(url.replace("/?token=", "/api/control/stop?token="))
        assert control.status_code == 409 and "no campaign" in control.json()["message"]
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=30) == 0
    finally:
        if process.poll() is None:
            process.kill()
        process.communicate()


def test_a_taken_port_is_one_line_naming_it_and_leaves_nothing_running():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        page = LivePage.for_campaign(small_config(), session_dir=None, host="127.0.0.1", port=port)
        with pytest.raises(LiveServerError, match=f"cannot serve on 127.0.0.1:{port}: the port is in use"):
            start_live_page(page, write=lambda _: pytest.fail("no URL for a page that is not served"))
        assert not page.previews._threads  # the previews never started


def test_live_refuses_a_simulated_rig_with_real_cameras(capsys):
    assert main(["live", "--cameras", "usb-port:1-2", "usb-port:1-3", "--ui-port", "0"]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and "cameras" in error[0] and "rig" in error[0]


def test_live_takes_the_first_configuration_of_a_campaign_given_in_toe_ins(tmp_path):
    # A campaign file may give its angles as toe_in_deg; live sets alpha_deg, and the plan refuses both.
    campaign = tmp_path / "toe.toml"
    campaign.write_text('name = "t"\n[plan]\nbaseline_mm = [120]\ndistance_mm = [600]\ntoe_in_deg = [10, 20]\n')
    options = dict(campaign=str(campaign), port=None, rig_config=None, time_scale=None, cameras=None, baseline=None,
                   distance=None, alpha=None)
    plan = live_config(argparse.Namespace(**options)).plan
    assert (plan.baseline_mm, plan.distance_mm, plan.alpha_deg, plan.toe_in_deg) == ([120.0], [600.0], [80.0], None)
    assert live_config(argparse.Namespace(**{**options, "alpha": 70.0})).plan.alpha_deg == [70.0]
