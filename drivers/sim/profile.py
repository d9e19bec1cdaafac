"""The simulated bench's imperfections: named, documented parameters, grouped in profiles.

Two profiles ship:

- ``ideal``: today's bench. Every camera turns about its own optical centre, the slide is perfect,
  every move lands exactly, the boards are printed flat and to scale, frames are lossless. Frames are
  bit-identical to the bench before profiles existed (for the same seed).
- ``lab``: a bench as one is really built from hobby-grade parts (aluminium-extrusion slide with a
  T8 lead screw, belt-reduction pan heads, board cameras with M12 lenses, a printed target on foam
  board). Every value carries a one-line justification in :data:`LAB_JUSTIFICATIONS`.

Geometry (the bench frame is the nominal rig frame of ``stereo_bench.geometry``: x along the baseline
from left to right, y down, z forward; origin midway between the nominal optical centres of the
parallel rig):

- The slide sets the separation of the two pan axes, ``s = zero_offset_mm + (1 + scale_error) * B``
  (B the commanded baseline), less half the backlash in the direction of approach, plus a random
  landing error of std ``repeatability_mm`` per move. The two carriages move symmetrically along the
  slide direction, which is the rig x axis turned by ``direction_yaw_deg`` about y and
  ``direction_pitch_deg`` about z.
- Each pan head turns its camera about its pan axis (vertical turned by ``axis_tilt_x_deg`` about x
  and ``axis_tilt_z_deg`` about z) by ``zero_offset_deg + (1 + scale_error) * toe_in`` (less half
  the backlash in the direction of approach, plus a random landing error of std
  ``repeatability_deg``), toward the other camera. The optical centre sits ``centre_forward_mm`` in
  front of the axis, ``centre_sideways_mm`` to the right of it (+x) and ``centre_height_mm`` above
  the carriage; the camera is screwed to the head with a small roll (about its optical axis), pitch
  (about its x axis) and yaw (about its y axis).
- Where a rig config drives a camera's tilt (``tilt_*_deg`` mapped to an axis: grblHAL's A/B), the head carries a
  tilt joint between the pan and the camera: it turns the camera about an axis along the camera's x axis turned
  by ``tilt_axis_yaw_deg`` about y and ``tilt_axis_roll_deg`` about z, ``tilt_centre_forward_mm`` behind and
  ``tilt_centre_height_mm`` below the optical centre, by ``tilt_zero_offset_deg + (1 + tilt_scale_error) * tilt``
  (> 0 looks down; less half ``tilt_backlash_deg`` in the direction of approach, plus a landing error of std
  ``tilt_repeatability_deg``). A fixed tilt has no joint: the camera is turned about its own x axis through its
  optical centre by the fixed value, as in the nominal geometry.
- After each move the heads ring: a damped oscillation of the pan angle (``vibration_yaw_deg``) and
  a rocking of the head on its carriage about the rig z axis (``vibration_rock_deg``), frequency
  ``vibration_frequency_hz``, envelope decaying with time constant ``vibration_decay_s``, stopped
  dead by friction once the envelope falls below ``vibration_stop_deg``.
- Boards: the print is ``(1 + print_scale_error)`` times its nominal size and bent into a cylinder
  about its vertical centre line, the centre ``bow_mm`` nearer the cameras than the left and right
  edges of the corner grid (a bent sheet: lengths along the print are kept). A manually placed
  target stands at its nominal distance and yaw plus a random placement error drawn once per
  placement.

- Cameras (issue 22): frames pass through JPEG (MJPG), the sensor adds noise at its gain (read noise and
  shot noise), the lens defocuses, the pattern's image scatters by ``corner_noise_px`` per view (what real
  corners scatter by beyond their image noise), a rolling shutter (``line_time_us``) shears the image of a
  ringing camera; an unsynchronised pair (``synchronised = false``) exposes its right frame a random skew
  after the left one while the hand-held calibration board moves. Every lab figure is measured on one of
  the real sets (docs/SIMULATED_BENCH.md, ``scripts/bench_lab_profile.py --real``).

Random draws (landing errors, placements) come from the campaign seed and what is being done (axis,
position, how often that position was visited; distance and placement count), so a campaign that
resumes draws what one that never stopped would have.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, Strict, ValidationError, model_validator

# strict: no string-to-number or bool-to-number coercion (an int is accepted for a float); no NaN or infinity
_STRICT = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)
# A thin-prism coefficient, in a lax tuple (TOML gives a list): still no "1" or true as a number, and finite (a NaN
# there rendered frames nothing could be measured in); real lenses' are under 0.01, 1 is far past any.
_Real = Annotated[float, Strict(), Field(allow_inf_nan=False, ge=-1, le=1)]


def _f(default: float, description: str, **limits) -> Any:
    return Field(default, allow_inf_nan=False, description=description, **limits)


class SlideErrors(BaseModel):
    """The baseline slide (lead screw + rail) as built."""

    model_config = _STRICT

    direction_yaw_deg: float = _f(0.0, "slide direction turned about the rig y axis: not perpendicular to the "
                                       "parallel optical axes, deg", ge=-5, le=5)
    direction_pitch_deg: float = _f(0.0, "slide direction turned about the rig z axis (one end higher), deg",
                                    ge=-5, le=5)
    scale_error: float = _f(0.0, "relative lead error: separation change = (1 + scale_error) * commanded change",
                            ge=-0.05, le=0.05)
    zero_offset_mm: float = _f(0.0, "pan-axis separation at commanded B = 0 (homing switch and head positions), mm",
                               ge=-20, le=20)
    backlash_mm: float = _f(0.0, "lost motion on reversal; the carriage trails the screw by half of it, mm",
                            ge=0, le=2)
    repeatability_mm: float = _f(0.0, "std of the random landing error of each move, mm", ge=0, le=1)


class PanHeadErrors(BaseModel):
    """One pan head and the camera screwed to it, as built."""

    model_config = _STRICT

    axis_tilt_x_deg: float = _f(0.0, "pan axis turned from vertical about the rig x axis (leans forward/back), deg",
                                ge=-5, le=5)
    axis_tilt_z_deg: float = _f(0.0, "pan axis turned from vertical about the rig z axis (leans sideways), deg",
                                ge=-5, le=5)
    centre_forward_mm: float = _f(0.0, "optical centre in front of the pan axis, mm", ge=-100, le=100)
    centre_sideways_mm: float = _f(0.0, "optical centre to the right (+x) of the pan axis, mm", ge=-50, le=50)
    centre_height_mm: float = _f(0.0, "optical centre above the point where the pan axis meets the carriage, mm "
                                      "(the lever of the head's rocking)", ge=0, le=200)
    mount_roll_deg: float = _f(0.0, "camera turned on the head about its optical axis, deg", ge=-5, le=5)
    mount_pitch_deg: float = _f(0.0, "camera turned on the head about its x axis (> 0 looks down), deg", ge=-5, le=5)
    mount_yaw_deg: float = _f(0.0, "camera turned on the head about its y axis (> 0 toward +x), deg", ge=-5, le=5)
    zero_offset_deg: float = _f(0.0, "pan angle (toward the other camera) at commanded toe-in 0, deg", ge=-5, le=5)
    scale_error: float = _f(0.0, "relative angle error: pan = (1 + scale_error) * commanded toe-in", ge=-0.05,
                            le=0.05)
    backlash_deg: float = _f(0.0, "lost motion on reversal; the head trails the motor by half of it, deg", ge=0, le=2)
    repeatability_deg: float = _f(0.0, "std of the random landing error of each move, deg", ge=0, le=1)
    # The tilt joint: only where a rig config drives the camera's tilt (tilt_*_deg mapped to an axis, grblHAL's A/B);
    # a rig whose tilt is fixed has no joint and these values do nothing (drivers/sim/mechanics.py).
    tilt_axis_yaw_deg: float = _f(0.0, "tilt axis turned from the camera's x axis about its y axis, deg", ge=-5, le=5)
    tilt_axis_roll_deg: float = _f(0.0, "tilt axis then turned about the camera's z axis (one end higher), deg",
                                   ge=-5, le=5)
    tilt_centre_forward_mm: float = _f(0.0, "optical centre in front of the tilt axis, mm", ge=-100, le=100)
    tilt_centre_height_mm: float = _f(0.0, "optical centre above the tilt axis, mm", ge=-100, le=100)
    tilt_zero_offset_deg: float = _f(0.0, "tilt (> 0 looks down) at commanded tilt 0, deg", ge=-5, le=5)
    tilt_scale_error: float = _f(0.0, "relative tilt error: tilt = (1 + scale_error) * commanded tilt", ge=-0.05,
                                 le=0.05)
    tilt_backlash_deg: float = _f(0.0, "lost motion of the tilt on reversal; the camera trails by half of it, deg",
                                  ge=0, le=2)
    tilt_repeatability_deg: float = _f(0.0, "std of the random landing error of each tilt move, deg", ge=0, le=1)


class BoardErrors(BaseModel):
    """A printed board as it really is (and, for the manually placed target, where it really stands)."""

    model_config = _STRICT

    print_scale_error: float = _f(0.0, "relative size error of the print: every length is (1 + error) times "
                                       "nominal", ge=-0.05, le=0.05)
    bow_mm: float = _f(0.0, "cylindrical bend about the board's vertical centre line: centre nearer the cameras "
                            "than the left/right edges of the corner grid, mm", ge=-20, le=20)
    placement_distance_sigma_mm: float = _f(0.0, "std of the operator's distance error per manual placement, mm",
                                            ge=0, le=100)
    placement_yaw_sigma_deg: float = _f(0.0, "std of the operator's yaw error per manual placement, deg", ge=0, le=20)
    hand_held_speed_mm_s: float = _f(0.0, "speed of a hand-held board while the pair captures it, mm/s: it moves "
                                          "between the two exposures of an unsynchronised pair "
                                          "(cameras.synchronised = false); calibration board only", ge=0, le=2000)

    @property
    def flat_and_true(self) -> bool:
        return self.print_scale_error == 0.0 and self.bow_mm == 0.0


class CameraErrors(BaseModel):
    """Image formation beyond the ideal bench: compression, the lens's unmodelled part, vibration."""

    model_config = _STRICT

    jpeg_quality: int | None = Field(None, ge=1, le=100, description="frames pass through JPEG (MJPG) at this "
                                                                     "libjpeg quality; None: lossless")
    radial_high_order_left: float = _f(0.0, "higher-order radial distortion c of the left lens: c r^6 added to the "
                                             "numerator and c r^6 as the denominator of OpenCV's rational model; they "
                                             "cancel to leading order and leave terms from r^8 up", ge=-5, le=5)
    radial_high_order_right: float = _f(0.0, "the same for the right lens", ge=-5, le=5)
    thin_prism_left: tuple[_Real, _Real, _Real, _Real] = Field(
        (0.0, 0.0, 0.0, 0.0), strict=False,
        description="OpenCV thin-prism coefficients s1..s4 of the left lens (not in the 5-coefficient model)")
    thin_prism_right: tuple[_Real, _Real, _Real, _Real] = Field(
        (0.0, 0.0, 0.0, 0.0), strict=False, description="thin-prism coefficients s1..s4 of the right lens")
    vibration_yaw_deg: float = _f(0.0, "amplitude of the pan-angle oscillation right after a move, deg", ge=0, le=1)
    vibration_rock_deg: float = _f(0.0, "amplitude of the head's rocking on its carriage about the rig z axis after "
                                        "a slide move (the stop pushes the camera sideways), deg", ge=0, le=1)
    vibration_frequency_hz: float = _f(15.0, "frequency of the oscillation, Hz", gt=0, le=1000)
    vibration_decay_s: float = _f(0.08, "time constant of the exponential envelope, s", gt=0, le=10)
    vibration_stop_deg: float = _f(0.001, "friction stops the oscillation once its envelope is below this, deg",
                                   ge=0, le=1)
    defocus_sigma_px: float = _f(0.0, "defocus and lens blur beyond the optics' blur, Gaussian sigma in px (added "
                                      "in quadrature)", ge=0, le=20)
    extra_read_noise_dn: float = _f(0.0, "sensor noise at the camera's gain beyond the optics' read noise, 8-bit DN "
                                         "std (added in quadrature)", ge=0, le=50)
    shot_noise_gain: float = _f(0.0, "shot-noise variance per DN of signal (DN^2 / DN) at the camera's gain",
                                ge=0, le=10)
    corner_noise_px: float = _f(0.0, "random displacement of the pattern's image per view (frames of one still "
                                     "view share it), std (px) of each "
                                     "coordinate at nodes corner_noise_scale_px apart: the corner scatter real "
                                     "cameras show beyond their image noise", ge=0, le=10)
    corner_noise_scale_px: int = Field(16, ge=2, le=1024, description="node spacing of the corner-noise field, px")
    line_time_us: float = _f(0.0, "rolling shutter: each row is exposed this much after the one above it, us "
                                  "(0: global shutter); shears the image of a ringing camera", ge=0, le=1000)
    synchronised: bool = Field(True, description="the pair exposes on one trigger (a stereo head); false: two "
                                                 "free-running UVC cameras, each pair's right exposure off the left "
                                                 "one's by a random skew")
    capture_skew_sigma_ms: float = _f(0.0, "std of the left-right exposure skew of an unsynchronised pair, ms",
                                      ge=0, le=1000)

    @property
    def vibrates(self) -> bool:
        return self.vibration_yaw_deg > 0.0 or self.vibration_rock_deg > 0.0

    def lens_terms(self, side: str) -> tuple[float, tuple[float, float, float, float]]:
        """(higher-order radial c, thin prism s1..s4) of the ``side`` lens."""
        if side == "left":
            return self.radial_high_order_left, self.thin_prism_left
        return self.radial_high_order_right, self.thin_prism_right


class SimProfile(BaseModel):
    """Every imperfection of the simulated bench; the default instance is the ideal bench."""

    model_config = _STRICT

    name: str = Field("ideal", description="profile name, recorded with the truth")
    slide: SlideErrors = Field(default_factory=SlideErrors)
    left_head: PanHeadErrors = Field(default_factory=PanHeadErrors)
    right_head: PanHeadErrors = Field(default_factory=PanHeadErrors)
    target: BoardErrors = Field(default_factory=BoardErrors, description="the measured board")
    calibration_board: BoardErrors = Field(default_factory=BoardErrors, description="the calibration board")
    cameras: CameraErrors = Field(default_factory=CameraErrors)

    @model_validator(mode="after")
    def _check(self) -> SimProfile:
        if self.target.hand_held_speed_mm_s:
            raise ValueError("target: hand_held_speed_mm_s applies to the calibration board only (the measured "
                             "target stands where the operator placed it)")
        if self.calibration_board.placement_distance_sigma_mm or self.calibration_board.placement_yaw_sigma_deg:
            raise ValueError("calibration_board: placement errors apply to the manually placed target only "
                             "(calibration views are free poses, estimated per view)")
        return self

    def head(self, side: str) -> PanHeadErrors:
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', not {side!r}")
        return self.left_head if side == "left" else self.right_head

    @property
    def mechanically_ideal(self) -> bool:
        """No slide or head error: the cameras stand exactly where the nominal geometry puts them."""
        return (self.slide == SlideErrors() and self.left_head == PanHeadErrors()
                and self.right_head == PanHeadErrors() and not self.cameras.vibrates)

    @property
    def moves_need_history(self) -> bool:
        """Backlash, landing errors or vibration: the bench must watch the axes move."""
        s, left, right = self.slide, self.left_head, self.right_head
        return bool(s.backlash_mm or s.repeatability_mm or left.backlash_deg or left.repeatability_deg
                    or right.backlash_deg or right.repeatability_deg or self.cameras.vibrates
                    or left.tilt_backlash_deg or left.tilt_repeatability_deg or right.tilt_backlash_deg
                    or right.tilt_repeatability_deg)

    def rows(self) -> list[tuple[str, Any, str]]:
        """(dotted name, value, description) of every parameter, in declaration order."""
        out = []
        for section in ("slide", "left_head", "right_head", "target", "calibration_board", "cameras"):
            model = getattr(self, section)
            for name, field in type(model).model_fields.items():
                out.append((f"{section}.{name}", getattr(model, name), field.description or ""))
        return out


IDEAL = SimProfile()

LAB = SimProfile(
    name="lab",
    slide=SlideErrors(
        direction_yaw_deg=0.25, direction_pitch_deg=0.10, scale_error=6.0e-4, zero_offset_mm=0.40,
        backlash_mm=0.04, repeatability_mm=0.003,
    ),
    left_head=PanHeadErrors(
        axis_tilt_x_deg=0.30, axis_tilt_z_deg=-0.15, centre_forward_mm=22.0, centre_sideways_mm=1.8,
        centre_height_mm=40.0, mount_roll_deg=0.40, mount_pitch_deg=-0.25, mount_yaw_deg=0.30,
        zero_offset_deg=0.15, scale_error=2.0e-3, backlash_deg=0.03, repeatability_deg=0.002,
        tilt_axis_yaw_deg=0.25, tilt_axis_roll_deg=-0.15, tilt_centre_forward_mm=12.0, tilt_centre_height_mm=8.0,
        tilt_zero_offset_deg=0.20, tilt_scale_error=2.5e-3, tilt_backlash_deg=0.02, tilt_repeatability_deg=0.002,
    ),
    right_head=PanHeadErrors(
        axis_tilt_x_deg=-0.20, axis_tilt_z_deg=0.25, centre_forward_mm=22.8, centre_sideways_mm=-2.6,
        centre_height_mm=40.6, mount_roll_deg=-0.30, mount_pitch_deg=0.35, mount_yaw_deg=-0.20,
        zero_offset_deg=-0.10, scale_error=-1.5e-3, backlash_deg=0.03, repeatability_deg=0.002,
        tilt_axis_yaw_deg=-0.20, tilt_axis_roll_deg=0.20, tilt_centre_forward_mm=12.7, tilt_centre_height_mm=7.4,
        tilt_zero_offset_deg=-0.15, tilt_scale_error=-2.0e-3, tilt_backlash_deg=0.02, tilt_repeatability_deg=0.002,
    ),
    target=BoardErrors(print_scale_error=8.0e-4, bow_mm=0.6, placement_distance_sigma_mm=2.0,
                       placement_yaw_sigma_deg=1.0),
    calibration_board=BoardErrors(hand_held_speed_mm_s=50.0),
    cameras=CameraErrors(
        jpeg_quality=50, radial_high_order_left=0.6, radial_high_order_right=0.45,
        vibration_yaw_deg=0.02, vibration_rock_deg=0.01, vibration_frequency_hz=15.0, vibration_decay_s=0.08,
        vibration_stop_deg=0.001, defocus_sigma_px=0.57, extra_read_noise_dn=1.5, shot_noise_gain=0.03,
        corner_noise_px=0.2, corner_noise_scale_px=16, line_time_us=29.0, synchronised=True,
        capture_skew_sigma_ms=6.2,
    ),
)

# One line per value of the lab profile: where the number comes from.
LAB_JUSTIFICATIONS: dict[str, str] = {
    "slide.direction_yaw_deg": "rail squared to the camera plate by eye and a try-square on an extrusion frame: "
                               "+-0.3 deg typical",
    "slide.direction_pitch_deg": "extrusion mounting surfaces flat to ~0.5 mm over 300 mm: ~0.1 deg",
    "slide.scale_error": "rolled T8 trapezoidal lead screw, lead accuracy of class C10 (0.21 mm per 300 mm = 0.07 %)",
    "slide.zero_offset_mm": "homing micro-switch and head plates placed at assembly to ~0.5 mm "
                            "(the switch itself repeats to ~0.01 mm)",
    "slide.backlash_mm": "anti-backlash (spring-loaded POM) nut on a T8 screw: 0.02-0.05 mm lost motion",
    "slide.repeatability_mm": "unidirectional repeatability of a stepper lead-screw slide +-0.01 mm (~3 sigma)",
    "left_head.axis_tilt_x_deg": "bearing seat and plate perpendicularity of a hobby pan-tilt head: a few tenths "
                                 "of a degree",
    "left_head.axis_tilt_z_deg": "as axis_tilt_x_deg, the other direction",
    "left_head.centre_forward_mm": "entrance pupil of an M12 lens on a board camera centred on the head's 1/4\" "
                                   "screw: 15-30 mm ahead of the pan axis (issue 11)",
    "left_head.centre_sideways_mm": "camera centred on the head's screw by eye: a few mm",
    "left_head.centre_height_mm": "lens axis 40 mm above the carriage (head design height)",
    "left_head.mount_roll_deg": "board camera on M2 screws in clearance holes 20 mm apart: +-0.5 deg",
    "left_head.mount_pitch_deg": "as mount_roll_deg (plate flatness, screw clearance)",
    "left_head.mount_yaw_deg": "as mount_roll_deg",
    "left_head.zero_offset_deg": "pan homing switch placed at assembly to ~0.1-0.2 deg (repeats to ~0.01 deg)",
    "left_head.scale_error": "GT2 belt reduction: effective pitch radius 0.1-0.3 % off nominal (tension, tooth "
                             "engagement)",
    "left_head.backlash_deg": "tensioned GT2 belt reduction: 0.02-0.05 deg at the output",
    "left_head.repeatability_deg": "microstepped stepper through a tensioned belt: unidirectional +-0.005 deg "
                                   "(~2.5 sigma)",
    "left_head.tilt_axis_yaw_deg": "tilt bracket's bearing bores drilled and squared to the camera plate by hand: "
                                   "a few tenths of a degree, as the pan axis",
    "left_head.tilt_axis_roll_deg": "as tilt_axis_yaw_deg, the other direction (one bearing seat higher)",
    "left_head.tilt_centre_forward_mm": "tilt bracket pivots at the camera board; the M12 lens's entrance pupil "
                                        "stands 10-15 mm in front of the board",
    "left_head.tilt_centre_height_mm": "pivot screws through the bracket's lower holes, ~8 mm under the lens axis "
                                       "of a 32 mm board camera",
    "left_head.tilt_zero_offset_deg": "tilt homing switch placed at assembly to ~0.1-0.2 deg, as the pan's",
    "left_head.tilt_scale_error": "GT2 belt reduction, as the pan, on a smaller pulley: 0.2-0.3 % off nominal",
    "left_head.tilt_backlash_deg": "the camera's weight ahead of the pivot preloads the belt one way: less lost "
                                   "motion than the pans' 0.03 deg",
    "left_head.tilt_repeatability_deg": "microstepped stepper through a tensioned belt, as the pan: +-0.005 deg "
                                        "(~2.5 sigma)",
    "right_head.axis_tilt_x_deg": "as left_head (a different head, a different error)",
    "right_head.axis_tilt_z_deg": "as left_head",
    "right_head.centre_forward_mm": "as left_head; the same head and camera mounted again land ~1 mm apart",
    "right_head.centre_sideways_mm": "as left_head",
    "right_head.centre_height_mm": "as left_head; 0.6 mm from the plates' thickness tolerance",
    "right_head.mount_roll_deg": "as left_head",
    "right_head.mount_pitch_deg": "as left_head",
    "right_head.mount_yaw_deg": "as left_head",
    "right_head.zero_offset_deg": "as left_head",
    "right_head.scale_error": "as left_head",
    "right_head.backlash_deg": "as left_head",
    "right_head.repeatability_deg": "as left_head",
    "right_head.tilt_axis_yaw_deg": "as left_head",
    "right_head.tilt_axis_roll_deg": "as left_head",
    "right_head.tilt_centre_forward_mm": "as left_head; the same bracket and camera mounted again land ~1 mm apart",
    "right_head.tilt_centre_height_mm": "as left_head; 0.6 mm from the bracket holes' clearance",
    "right_head.tilt_zero_offset_deg": "as left_head",
    "right_head.tilt_scale_error": "as left_head",
    "right_head.tilt_backlash_deg": "as left_head",
    "right_head.tilt_repeatability_deg": "as left_head",
    "target.print_scale_error": "office laser/inkjet print: +-0.1 % scale from the paper feed",
    "target.bow_mm": "A3 print laminated on 5 mm foam board: 0.5-1 mm out of flat over 300 mm",
    "target.placement_distance_sigma_mm": "operator sets the distance with a tape measure: ~2 mm",
    "target.placement_yaw_sigma_deg": "target squared to the rig by eye: ~1 deg",
    "target.hand_held_speed_mm_s": "0: the measured target stands where the operator placed it",
    "calibration_board.print_scale_error": "the calibration board is the bench's length reference (rigid, "
                                           "certified to ~0.01 mm): taken as exact",
    "calibration_board.bow_mm": "rigid (aluminium/glass) calibration board: flat to <0.05 mm, taken as flat",
    "calibration_board.placement_distance_sigma_mm": "calibration views are free poses, estimated per view",
    "calibration_board.placement_yaw_sigma_deg": "calibration views are free poses, estimated per view",
    "calibration_board.hand_held_speed_mm_s": "caliscope_charuco_2cam (hand-held ChArUco, two webcams): median "
                                              "board speed between consecutive frames 46 / 57 mm/s (cam 0 / 1, "
                                              "p90 97 / 109); used only by unsynchronised captures",
    "cameras.jpeg_quality": "opencv_sample: its JPEGs' luma quantisation table is libjpeg quality 50 (present_cjn's "
                            "95 is OpenCV's imwrite default, not the camera's); with the noise below it gives "
                            "opencv_sample's flat-square noise",
    "cameras.radial_high_order_left": "cheap M12 lens: stereo_bench's calibration fits its views to 0.006 px but "
                                      "misses the lens by 0.4 px RMS, 2.6 px at the image corners (measured, 1080p)",
    "cameras.radial_high_order_right": "as radial_high_order_left, a different lens",
    "cameras.thin_prism_left": "0: to first order a thin prism is a turn of the camera frame (2 s1 rad) plus "
                               "tangential terms and a principal-point shift, which the calibration absorbs into its "
                               "frame: it would only make the true R ambiguous by ~0.1 deg (kept for experiments)",
    "cameras.thin_prism_right": "as thin_prism_left",
    "cameras.vibration_yaw_deg": "50 g camera on a plastic pan head (~5 N m/rad) stopped at 200 mm/s^2 plus "
                                 "stepper ringing: ~0.02 deg",
    "cameras.vibration_rock_deg": "the head rocking on its carriage after a slide stop: half the pan ringing",
    "cameras.vibration_frequency_hz": "first mode of a small pan-tilt head with a camera: 10-20 Hz",
    "cameras.vibration_decay_s": "damping ratio ~0.13 at 15 Hz: rings for a fraction of a second",
    "cameras.vibration_stop_deg": "bearing and belt friction stop the last ~0.001 deg (3.6 arcsec) dead",
    "cameras.defocus_sigma_px": "opencv_sample: median edge width (sigma of the gradient across the squares' edges) "
                                "1.24 / 1.25 px (left / right); the lab's frames measured the same way: 1.03 px "
                                "before, 1.20 px with 0.57 px in quadrature with the optics' 0.7 px",
    "cameras.extra_read_noise_dn": "opencv_sample: noise inside its squares after JPEG (plane removed) 1.05 / 1.75 DN "
                                   "dark / light (left); the lab's frames at quality 50 measured the same way: "
                                   "1.03 / 1.64 DN with 2.5 DN read noise (the optics' 2.0 and 1.5 in quadrature)",
    "cameras.shot_noise_gain": "opencv_sample: the light squares' noise above the dark ones' (1.75 vs 1.05 DN after "
                               "JPEG): 0.03 DN^2 / DN before JPEG reproduces it",
    "cameras.corner_noise_px": "opencv_sample: stereo calibration RMS 0.217 px (mono 0.195 / 0.207), its image noise "
                               "explains ~0.05 px (the lab's frames with its noise, blur and JPEG: 0.045 px); "
                               "0.2 px at the field's nodes gives the lab bench 0.21 px",
    "cameras.corner_noise_scale_px": "below the corner spacing of every view (>= 25 px): neighbouring corners "
                                     "move nearly independently, as the real sets' residuals do (per-view RMS "
                                     "uniform: median 0.196 / 0.208 px against 0.195 / 0.207 overall, opencv_sample)",
    "cameras.line_time_us": "not measurable from the sets (no known motion during a frame): a 1080p30 UVC sensor "
                            "reads 1080 rows in ~31 ms of its 33 ms frame: 29 us a row",
    "cameras.synchronised": "the lab bench is a stereo head on one trigger; false gives two free-running webcams "
                            "(caliscope_charuco_2cam's kind)",
    "cameras.capture_skew_sigma_ms": "caliscope_charuco_2cam's timestamps.csv: cam 1 - cam 0 per synchronised "
                                     "frame, 111 frames: mean +1.2 ms, std 6.2 ms, |max| 36 ms, p95 13 ms",
}

PROFILES: dict[str, SimProfile] = {"ideal": IDEAL, "lab": LAB}


def profile_named(name: str) -> SimProfile:
    if name not in PROFILES:
        raise ValueError(f"unknown simulated-bench profile {name!r}; known: {', '.join(PROFILES)}")
    return PROFILES[name]


class SimSettings(BaseModel):
    """The ``[sim]`` table of a campaign: a profile and optional overrides of its values.

    ::

        [sim]
        profile = "lab"          # or "ideal": today's perfect bench
        [sim.slide]
        backlash_mm = 0.0        # any value of the profile, by section
        [sim.cameras]
        jpeg_quality = 95
    """

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

    profile: Literal["lab", "ideal"] = Field("lab", description="imperfections of the simulated bench: 'lab' (a "
                                                                "bench as built, the default) or 'ideal'")
    slide: dict[str, Any] | None = Field(None, description="overrides of the profile's slide values")
    left_head: dict[str, Any] | None = Field(None, description="overrides of the left pan head's values")
    right_head: dict[str, Any] | None = Field(None, description="overrides of the right pan head's values")
    target: dict[str, Any] | None = Field(None, description="overrides of the measured board's values")
    calibration_board: dict[str, Any] | None = Field(None, description="overrides of the calibration board's values")
    cameras: dict[str, Any] | None = Field(None, description="overrides of the cameras' values")
    presenter: Literal["still", "hand"] | None = Field(
        None, description="who presents the calibration board: still (a still board at each view's pose, placed "
                          "when the view is taken) or hand (a simulated operator carrying it by hand: "
                          "drivers/sim/hand.py). Default: hand when views are taken automatically, else still")
    hand_fps: float = Field(10.0, gt=0, le=60, description="the simulated hand: frames per second (bench clock) the "
                                                            "cameras stream while views are taken automatically")

    @model_validator(mode="after")
    def _check(self) -> SimSettings:
        self.resolve()
        return self

    def overrides(self) -> dict[str, dict[str, Any]]:
        return {section: values for section in ("slide", "left_head", "right_head", "target", "calibration_board",
                                                "cameras")
                if (values := getattr(self, section))}

    def resolve(self) -> SimProfile:
        """The profile with the overrides applied, validated (ValueError naming ``section.key``)."""
        base = profile_named(self.profile)
        overrides = self.overrides()
        if not overrides:
            return base
        data = base.model_dump()
        for section, values in overrides.items():
            data[section] = {**data[section], **values}
        data["name"] = f"{self.profile}+overrides"
        try:
            return SimProfile.model_validate(data)
        except ValidationError as error:
            first = error.errors()[0]
            where = ".".join(str(p) for p in first.get("loc", ()))
            message = first.get("msg", "invalid").removeprefix("Value error, ")
            if first.get("type") == "extra_forbidden":
                section = str(first["loc"][0])
                known = type(getattr(base, section)).model_fields
                message = f"unknown key; known: {', '.join(known)}"
            raise ValueError(f"{where}: {message}" if where else message) from None


def _format(value: Any) -> str:
    if isinstance(value, tuple):
        return "(" + ", ".join(f"{v:g}" for v in value) + ")"
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def lab_table_markdown() -> str:
    """The lab profile as the markdown table of docs/SIMULATED_BENCH.md: parameter, value, why."""
    lines = ["| parameter | lab | why |", "|---|---|---|"]
    lines += [f"| `{name}` | {_format(value)} | {LAB_JUSTIFICATIONS[name]} |" for name, value, _ in LAB.rows()]
    return "\n".join(lines) + "\n"


def drawn_build(base: SimProfile, sigmas: Mapping[str, float], rng: Any) -> SimProfile:
    """``base`` with its as-built geometry drawn from a rig's stated tolerances: one sample of the class of
    benches the tolerances describe (``campaign.config.RigTolerances``: standard uncertainties keyed
    ``baseline_zero_mm``, ``baseline_scale``, ``slide_direction_deg``, ``centre_forward_mm``,
    ``centre_forward_each_mm``, ``centre_sideways_mm``, ``centre_height_mm``, ``yaw_deg``, ``pitch_deg``,
    ``roll_deg``, ``axis_tilt_deg``, ``pan_scale``).

    Each deviation is normal with its sigma, independent per camera, except the optical centres' offset
    ahead of the pan axes: 15-30 mm (uniform, shared by both: the same lens and head), which the ideal
    geometry ignores, plus each camera's own offset. The pan zero and the camera's mount yaw are one
    yaw. Backlash, repeatability, lenses and boards stay ``base``'s. ``rng``: a numpy Generator.
    """
    s = sigmas

    def head(errors: PanHeadErrors, forward: float) -> PanHeadErrors:
        return errors.model_copy(update={
            "axis_tilt_x_deg": rng.normal(0.0, s["axis_tilt_deg"]),
            "axis_tilt_z_deg": rng.normal(0.0, s["axis_tilt_deg"]),
            "centre_forward_mm": forward + rng.normal(0.0, s["centre_forward_each_mm"]),
            "centre_sideways_mm": rng.normal(0.0, s["centre_sideways_mm"]),
            "centre_height_mm": 40.0 + rng.normal(0.0, s["centre_height_mm"]),
            "mount_roll_deg": rng.normal(0.0, s["roll_deg"]), "mount_pitch_deg": rng.normal(0.0, s["pitch_deg"]),
            "mount_yaw_deg": rng.normal(0.0, s["yaw_deg"]), "zero_offset_deg": 0.0,
            "scale_error": rng.normal(0.0, s["pan_scale"])})

    forward = float(rng.uniform(15.0, 30.0))
    slide = base.slide.model_copy(update={
        "direction_yaw_deg": rng.normal(0.0, s["slide_direction_deg"]),
        "direction_pitch_deg": rng.normal(0.0, s["slide_direction_deg"]),
        "scale_error": rng.normal(0.0, s["baseline_scale"]),
        "zero_offset_mm": rng.normal(0.0, s["baseline_zero_mm"])})
    return base.model_copy(update={"name": f"{base.name} (drawn build)", "slide": slide,
                                   "left_head": head(base.left_head, forward),
                                   "right_head": head(base.right_head, forward)})
