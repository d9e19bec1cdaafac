"""argparse types every command shares: a number is finite and in its range where it enters, or the command
stops with one line naming the option (``argument --baseline: must be a finite number > 0 and <= 10000 mm,
not 'nan'``).

    from stereo_bench.cli.args import board_pattern, finite_float, int_in

    parser.add_argument("--baseline", type=finite_float(min=0, max=10_000, inclusive=(False, True), unit="mm"))
    parser.add_argument("--seed", type=int_in(min=0))
    parser.add_argument("--board", type=board_pattern, metavar="COLSxROWS")   # checked, kept as text

- :func:`finite_float` ``(min=None, max=None, *, inclusive=(True, True), unit="")``: a float type; NaN and
  the infinities never pass. ``inclusive`` says whether each bound itself is allowed.
- :func:`int_in` ``(min=None, max=None, *, unit="")``: an int type with inclusive bounds; accepts ``1e6``
  and ``1_000_000`` when they are whole numbers.
- :func:`board_pattern`: checks ``COLSxROWS`` (at least 2x2, at most
  :data:`stereo_bench.targets.MAX_BOARD_CORNERS` corners) and returns the text as given.
- :func:`output_dir`: an output directory path with no file in the way, where something can be created (returns
  the text).
- :func:`check_range`: a ``MIN MAX`` pair given in order (``--baseline-range 200 50`` is refused).
- :func:`image_size`: ``WxH`` -> (width, height) px, each side 2 .. :data:`MAX_IMAGE_SIDE_PX`.
- :func:`describe_range` for help texts.
- Types for the quantities several commands take, so that each has one range everywhere: ``BASELINE_MM``,
  ``DISTANCE_MM``, ``ALPHA_DEG``, ``TOE_IN_DEG``, ``TILT_DEG``, ``SQUARE_MM``, ``FOCAL_MM``, ``PIXEL_UM``,
  ``PIXEL_SIGMA_PX``, ``SEED``, ``WORKERS``, ``TIME_SCALE``.

Ranges are physical where there is a physical reason (an angle between 0 and 180 degrees) and otherwise
bound the work an input scales (Monte Carlo samples, grid sizes, blur kernels); each bound's reason is
written where the option is defined.
"""

from __future__ import annotations

import argparse
import math
import os
import re
from collections.abc import Callable
from pathlib import Path

from drivers.camera.base import MAX_IMAGE_SIDE_PX  # 20000 x 20000: 400 megapixels, past any camera this bench drives
from stereo_bench.campaign.config import MAX_BASELINE_MM, MAX_DISTANCE_MM, TIME_SCALE_MAX, TIME_SCALE_MIN
from stereo_bench.cli import CliError
from stereo_bench.paths import nearest_existing, probe_writable
from stereo_bench.targets import MAX_BOARD_CORNERS, parse_pattern


def _fmt(value: float) -> str:
    """1000000 rather than 1e+06 for whole numbers a user types; g otherwise."""
    return str(int(value)) if float(value).is_integer() and abs(value) < 1e15 else format(value, "g")


def describe_range(min: float | None = None, max: float | None = None, *, inclusive: tuple[bool, bool] = (True, True),
                   unit: str = "") -> str:
    """``> 0 and <= 10000 mm``, ``in [0, 1)`` style text for a range (``any`` when unbounded)."""
    parts = []
    if min is not None:
        parts.append(f"{'>=' if inclusive[0] else '>'} {_fmt(min)}")
    if max is not None:
        parts.append(f"{'<=' if inclusive[1] else '<'} {_fmt(max)}")
    text = " and ".join(parts) if parts else "any"
    return f"{text} {unit}".rstrip() if unit else text


def _in_range(value: float, min: float | None, max: float | None, inclusive: tuple[bool, bool]) -> bool:
    if min is not None and not (value >= min if inclusive[0] else value > min):
        return False
    return max is None or (value <= max if inclusive[1] else value < max)


def finite_float(min: float | None = None, max: float | None = None, *, inclusive: tuple[bool, bool] = (True, True),
                 unit: str = "") -> Callable[[str], float]:
    """An argparse ``type``: a finite float within [min, max] (each end open when ``inclusive`` says so)."""
    expected = "a finite number" + ("" if min is None and max is None else " " + describe_range(
        min, max, inclusive=inclusive, unit=unit))

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {expected}, not {text!r}") from None
        if not math.isfinite(value) or not _in_range(value, min, max, inclusive):
            raise argparse.ArgumentTypeError(f"must be {expected}, not {text!r}")
        return value

    parse.__name__ = "number"  # argparse names the type in some messages
    return parse


def int_in(min: int | None = None, max: int | None = None, *, unit: str = "") -> Callable[[str], int]:
    """An argparse ``type``: a whole number within [min, max] (``1e6`` is accepted as 1000000)."""
    expected = "a whole number" + ("" if min is None and max is None else " " + describe_range(min, max, unit=unit))

    def parse(text: str) -> int:
        try:
            value = int(text.replace("_", "")) if re.fullmatch(r"\s*[-+]?[\d_]+\s*", text) else None
            if value is None:
                number = float(text)
                value = int(number) if math.isfinite(number) and number == int(number) else None
        except (ValueError, OverflowError):
            value = None
        if value is None or not _in_range(value, min, max, (True, True)):
            raise argparse.ArgumentTypeError(f"must be {expected}, not {text!r}")
        return value

    parse.__name__ = "integer"
    return parse


def board_pattern(text: str) -> str:
    """An argparse ``type``: checks ``COLSxROWS`` (2x2 up to :data:`MAX_BOARD_CORNERS` corners), returns ``text``."""
    try:
        parse_pattern(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


def output_dir(text: str) -> str:
    """An argparse ``type`` for an output directory: refuses a path with a file in the way, or where nothing can be
    created (a file is created and removed to tell: ``/proc``, a read-only mount, no permission); returns ``text``.

    What else can go wrong on writing (a full disk) is said by the command's error path when it happens, naming
    the file.
    """
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} exists and is not a directory")
    existing = nearest_existing(path)
    if not existing.is_dir():
        raise argparse.ArgumentTypeError(f"{existing} is a file, so {text} cannot be a directory")
    reason = probe_writable(existing)  # e.g. under /proc, on a read-only mount: refused before anything runs
    if reason is not None:
        raise argparse.ArgumentTypeError(f"{text}: cannot create anything in {existing}: {reason}")
    return text


def check_range(values: tuple[float, float] | list[float] | None, option: str) -> None:
    """A ``MIN MAX`` (or ``NEAR FAR``) pair given in order, else :class:`~stereo_bench.cli.CliError` naming ``option``.

    argparse checks each number; the order of the two is checked here (``--baseline-range 200 50`` is a typo, not
    a range).
    """
    if values is not None and values[0] > values[1]:
        raise CliError(f"{option} {_fmt(values[0])} {_fmt(values[1])}: the first value must not exceed the second "
                       f"(did you mean {_fmt(values[1])} {_fmt(values[0])}?)")


def image_size(text: str) -> tuple[int, int]:
    """An argparse ``type``: ``WxH`` -> (width, height) px, each side from 2 to :data:`MAX_IMAGE_SIDE_PX`."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not match:
        raise argparse.ArgumentTypeError(f"must look like 1920x1080, not {text!r}")
    width, height = int(match.group(1)), int(match.group(2))
    if not (2 <= width <= MAX_IMAGE_SIDE_PX and 2 <= height <= MAX_IMAGE_SIDE_PX):
        raise argparse.ArgumentTypeError(f"each side must be from 2 to {MAX_IMAGE_SIDE_PX} px, not {text!r}")
    return width, height


# ---------------------------------------------------------------------------------------------- shared quantities
# Each range with its reason; a command with a narrower physical range checks that itself.

BASELINE_MM = finite_float(min=0, max=MAX_BASELINE_MM, inclusive=(False, True), unit="mm")  # a 10 m rig is no bench
DISTANCE_MM = finite_float(min=0, max=MAX_DISTANCE_MM, inclusive=(False, True), unit="mm")  # 100 m: a square < 1 px
ALPHA_DEG = finite_float(min=0, max=180, inclusive=(False, False), unit="deg")  # between baseline and optical axis
TOE_IN_DEG = finite_float(min=-90, max=90, inclusive=(False, False), unit="deg")  # alpha = 90 - toe-in in (0, 180)
TILT_DEG = finite_float(min=-90, max=90, inclusive=(False, False), unit="deg")  # +-90: straight down or up
SQUARE_MM = finite_float(min=0, max=1000, inclusive=(False, True), unit="mm")  # a 1 m square is a wall, not a board
FOCAL_MM = finite_float(min=0, max=1000, inclusive=(False, True), unit="mm")  # a 1 m lens is a telescope
PIXEL_UM = finite_float(min=0, max=100, inclusive=(False, True), unit="um")  # sensor pixels are 1-30 um
# Corner noise per image coordinate: detection scatters corners by well under a pixel; 10 px is no detection.
PIXEL_SIGMA_PX = finite_float(min=0, max=10, unit="px")
SEED = int_in(min=0)  # numpy's generators take non-negative seeds
# Local worker processes: the work is CPU-bound, so more than 4 per core only costs memory (~150 MB each).
WORKERS = int_in(min=1, max=4 * (os.cpu_count() or 1))
# Simulated seconds per real second of the simulated rig (campaign run, sim-controller): the campaign config's
# range (campaign/config.py TIME_SCALE_MIN, TIME_SCALE_MAX, where the reason is written).
TIME_SCALE = finite_float(min=TIME_SCALE_MIN, max=TIME_SCALE_MAX, unit="x")


__all__ = ["ALPHA_DEG", "BASELINE_MM", "DISTANCE_MM", "FOCAL_MM", "MAX_BOARD_CORNERS", "MAX_IMAGE_SIDE_PX",
           "PIXEL_SIGMA_PX", "PIXEL_UM", "SEED", "SQUARE_MM", "TILT_DEG", "TIME_SCALE", "TOE_IN_DEG", "WORKERS",
           "board_pattern", "check_range", "describe_range", "finite_float", "image_size", "int_in", "output_dir"]
