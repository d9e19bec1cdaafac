"""Paths to the real image sets in calib_data/real (see its README for sources and licences)."""

from pathlib import Path

REAL = Path(__file__).resolve().parents[1] / "calib_data" / "real"
OPENCV_SAMPLE = REAL / "opencv_sample"
PRESENT_CJN = REAL / "present_cjn"
OPENCV_FORMAT = REAL / "opencv_stereo_calib_format"
