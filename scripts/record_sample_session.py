"""Record the small sample session shipped in calib_data/sample_session (used by the replay tests).

A campaign on the simulated rig with cameras of half the default resolution (960x540, 6 um pixels,
the same 4 mm lens, so the same field of view), so that three configurations with their
calibration views fit in ~10 MB of lossless PNG: B = 100 and 150 mm at alpha = 90 deg, Z = 450 mm,
measured; and both at alpha = 35 deg, infeasible (recorded with the reason).

    python scripts/record_sample_session.py [--out calib_data/sample_session]
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from stereo_bench.campaign.config import campaign_from_dict
from stereo_bench.campaign.documents import ResultDocument
from stereo_bench.campaign.execute import run_campaign

SAMPLE = {
    "name": "sample-session",
    "description": "small recorded session for the replay tests (scripts/record_sample_session.py)",
    "seed": 2024,
    "rig": {"time_scale": 50.0},
    "cameras": {"optics": {"width_px": 960, "height_px": 540, "pixel_um": 6.0}},
    "calibration_board": {"kind": "checkerboard", "cols": 9, "rows": 6, "square_mm": 25.0},
    "capture": {"calibration_views": 7, "frames_per_config": 2, "settle_s": 0.2},
    "sim": {"profile": "ideal"},  # the sample session was recorded on the ideal bench
    "plan": {"baseline_mm": [100, 150], "distance_mm": [450], "alpha_deg": [90, 35]},
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "calib_data" / "sample_session"))
    parser.add_argument("--replace", action="store_true", help="delete an existing sample session first")
    args = parser.parse_args()
    out = Path(args.out)
    if out.exists():
        if not args.replace:
            print(f"{out} exists: pass --replace to record it again", file=sys.stderr)
            return 2
        shutil.rmtree(out)
    config = campaign_from_dict(SAMPLE)
    def show(document) -> None:  # a subscriber: one line per result
        if isinstance(document, ResultDocument):
            print(document.config_id, document.row.status, document.row.square_mean_mm)

    summary = run_campaign(config, out, yes=True, subscribers=[show])
    size_mb = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6
    print(f"{summary.exit_status}: {summary.counts()}, {size_mb:.1f} MB in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
