"""Where the mechanics really put the cameras, downstream of what the controller reports.

The GRBL emulator reports what the steppers were told (commanded, step-quantised axis positions);
this module turns those reported values into the true poses of the two cameras, through the
mechanical errors of a :class:`~drivers.sim.profile.SimProfile` (see that module for the geometry):

    separation = zero_offset + (1 + scale_error) * B        - approach * backlash / 2 + landing error
    pan        = zero_offset + (1 + scale_error) * toe_in   - approach * backlash / 2 + landing error
    T_bench_cam = Trans(carriage point) @ R_z(rock) @ Rot(pan axis, +-(pan + ringing))
                  @ Trans(optical centre on the head) @ R_mount @ R_x(-tilt)           (a fixed tilt)
    tilt       = zero_offset + (1 + scale_error) * tilt     - approach * backlash / 2 + landing error
    T_bench_cam = Trans(carriage point) @ R_z(rock) @ Rot(pan axis, +-(pan + ringing))
                  @ Rot(tilt axis, -tilt) @ Trans(optical centre on the head) @ R_mount   (a driven tilt)

A tilt is a joint only where the rig drives it (``tilting``: the ``tilt_*_deg`` quantities a rig config maps to
an axis, grblHAL's A/B); a fixed tilt turns the camera about its own x axis through its optical centre, as the
nominal geometry does, and a rig without a tilt axis is the bench it was before tilt joints existed.

``approach`` is the sign of the last motion of the quantity (+1 toward larger values): the driven
part trails the motor by half the backlash. Landing errors are drawn once per move, at rest.

:class:`MoveHistory` keeps, per quantity, the direction of approach, the landing error and when the
last move ended (for the ringing); the bench feeds it every motion the emulator reports as ended
(its motion events: exact end times on the bench clock, no sampling).

The bench frame is the nominal rig frame of ``stereo_bench.geometry`` (origin midway between the
nominal optical centres of the parallel rig, x toward the right camera, y down, z forward). This is
a simulator: it imports only the leaf module ``stereo_bench.geometry``, and it is deliberately
written independently of ``stereo_bench.kinematics`` (the estimator), so a test that the estimator
recovers these parameters tests both.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from drivers.sim.profile import CameraErrors, PanHeadErrors, SimProfile, SlideErrors
from stereo_bench.geometry import make_transform, rotation_deg

SIDES = ("left", "right")
# The quantities whose motion the mechanics model on every rig; a tilt moves only where a rig drives it (TILTS).
MOVED = ("baseline_mm", "toe_in_left_deg", "toe_in_right_deg")
TILTS = ("tilt_left_deg", "tilt_right_deg")


def rotation_about(axis: np.ndarray, deg: float) -> np.ndarray:
    """(3, 3) right-handed rotation by ``deg`` about the unit vector ``axis`` (Rodrigues' formula)."""
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    a = math.radians(deg)
    return np.eye(3) + math.sin(a) * K + (1.0 - math.cos(a)) * (K @ K)


def slide_direction(slide: SlideErrors) -> np.ndarray:
    """(3,) unit vector along which the right carriage moves away from the left one (bench frame)."""
    return (rotation_deg("y", slide.direction_yaw_deg) @ rotation_deg("z", slide.direction_pitch_deg)
            @ np.array([1.0, 0.0, 0.0]))


def pan_axis(head: PanHeadErrors) -> np.ndarray:
    """(3,) unit direction of a head's pan axis (nominally the rig's +y, i.e. down)."""
    return (rotation_deg("x", head.axis_tilt_x_deg) @ rotation_deg("z", head.axis_tilt_z_deg)
            @ np.array([0.0, 1.0, 0.0]))


def tilt_axis(head: PanHeadErrors) -> np.ndarray:
    """(3,) unit direction of a head's tilt axis in its camera's frame (nominally the camera's +x)."""
    return (rotation_deg("y", head.tilt_axis_yaw_deg) @ rotation_deg("z", head.tilt_axis_roll_deg)
            @ np.array([1.0, 0.0, 0.0]))


def mount_rotation(head: PanHeadErrors) -> np.ndarray:
    """(3, 3) camera orientation on the head: yaw (about y, > 0 toward +x), pitch (> 0 down), roll (about z)."""
    return (rotation_deg("y", head.mount_yaw_deg) @ rotation_deg("x", -head.mount_pitch_deg)
            @ rotation_deg("z", head.mount_roll_deg))


def true_separation_mm(slide: SlideErrors, baseline_mm: float, *, approach: int = 0, landing_mm: float = 0.0) -> float:
    """Pan-axis separation the slide really sets for a reported baseline (mm)."""
    return (slide.zero_offset_mm + (1.0 + slide.scale_error) * baseline_mm - approach * slide.backlash_mm / 2.0
            + landing_mm)


def true_pan_deg(head: PanHeadErrors, toe_in_deg: float, *, approach: int = 0, landing_deg: float = 0.0) -> float:
    """Pan angle (toward the other camera, deg) a head really turns to for a reported toe-in."""
    return (head.zero_offset_deg + (1.0 + head.scale_error) * toe_in_deg - approach * head.backlash_deg / 2.0
            + landing_deg)


def true_tilt_deg(head: PanHeadErrors, tilt_deg: float, *, approach: int = 0, landing_deg: float = 0.0) -> float:
    """Tilt (> 0 looks down, deg) a head's tilt joint really turns to for a reported tilt."""
    return (head.tilt_zero_offset_deg + (1.0 + head.tilt_scale_error) * tilt_deg
            - approach * head.tilt_backlash_deg / 2.0 + landing_deg)


def camera_pose(
    profile: SimProfile, side: str, *, separation_mm: float, pan_deg: float, tilt_deg: float = 0.0,
    ringing_deg: float = 0.0, rock_deg: float = 0.0, tilt_joint: bool = False,
) -> np.ndarray:
    """T_bench_cam (4x4, mm) of the ``side`` camera for a true slide separation and pan angle.

    ``ringing_deg`` adds to the pan angle (the head's oscillation about its pan axis), ``rock_deg``
    turns the head about the rig z axis through the point where its pan axis meets the carriage.
    A fixed tilt (``tilt_joint`` False) turns the camera about its own x axis through its optical centre
    (> 0 looks down), as in the nominal geometry. With ``tilt_joint``, ``tilt_deg`` is the true angle of the
    head's tilt joint (:func:`true_tilt_deg`), which turns the camera about the head's tilt axis
    (:func:`tilt_axis`, ``tilt_centre_*`` off the optical centre).
    """
    if side not in SIDES:
        raise ValueError(f"side must be 'left' or 'right', not {side!r}")
    head = profile.head(side)
    sign = -1.0 if side == "left" else 1.0  # where the carriage is along the slide
    toward = 1.0 if side == "left" else -1.0  # a pan toward the other camera turns about +y for the left one
    # The slide line lies below and behind the optical centres so that the bench frame's origin is
    # midway between the nominal centres of the parallel rig.
    height = 0.5 * (profile.left_head.centre_height_mm + profile.right_head.centre_height_mm)
    forward = 0.5 * (profile.left_head.centre_forward_mm + profile.right_head.centre_forward_mm)
    carriage = sign * separation_mm / 2.0 * slide_direction(profile.slide) + np.array([0.0, height, -forward])
    centre_on_head = np.array([head.centre_sideways_mm, -head.centre_height_mm, head.centre_forward_mm])
    R_pan = rotation_about(pan_axis(head), toward * (pan_deg + ringing_deg))
    R_rock = rotation_deg("z", rock_deg)
    if not tilt_joint:
        R = R_rock @ R_pan @ mount_rotation(head) @ rotation_deg("x", -tilt_deg)
        return make_transform(R, carriage + R_rock @ R_pan @ centre_on_head)
    # On the head (pan frame): the camera at tilt 0 stands at centre_on_head as mounted; the tilt axis runs along
    # the camera's (turned) x axis, behind and below its optical centre.
    M = mount_rotation(head)
    pivot = centre_on_head + M @ np.array([0.0, head.tilt_centre_height_mm, -head.tilt_centre_forward_mm])
    R_tilt = rotation_about(M @ tilt_axis(head), -tilt_deg)
    centre = pivot + R_tilt @ (centre_on_head - pivot)
    return make_transform(R_rock @ R_pan @ R_tilt @ M, carriage + R_rock @ R_pan @ centre)


def ringing_deg(cameras: CameraErrors, amplitude_deg: float, since_s: float) -> tuple[float, float]:
    """(angle deg, angular rate deg/s) of a damped oscillation ``since_s`` seconds after it was excited.

    ``amplitude_deg * exp(-t / decay) * cos(2 pi f t)``; zero before the excitation and once the envelope
    has fallen below ``vibration_stop_deg`` (friction holds the head).
    """
    if amplitude_deg <= 0.0 or not math.isfinite(since_s) or since_s < 0.0:
        return 0.0, 0.0
    envelope = amplitude_deg * math.exp(-since_s / cameras.vibration_decay_s)
    if envelope < cameras.vibration_stop_deg:
        return 0.0, 0.0
    w = 2.0 * math.pi * cameras.vibration_frequency_hz
    phase = w * since_s
    angle = envelope * math.cos(phase)
    rate = -envelope * (math.cos(phase) / cameras.vibration_decay_s + w * math.sin(phase))
    return angle, rate


def ringing_duration_s(cameras: CameraErrors) -> float:
    """How long after a move the heads ring (s): until friction stops the larger of the pan and rocking ringing."""
    amplitude = max(cameras.vibration_yaw_deg, cameras.vibration_rock_deg)
    if amplitude <= cameras.vibration_stop_deg:
        return 0.0
    return cameras.vibration_decay_s * math.log(amplitude / cameras.vibration_stop_deg)


@dataclass
class AxisHistory:
    """What the mechanics remember of one quantity's motion."""

    value: float | None = None  # where the last move ended (reported value)
    approach: int = 0  # sign of the last motion (+1 toward larger values), 0 = never moved
    move_end_s: float = -math.inf  # bench-clock time the last move ended
    landing: float = 0.0  # random landing error of the last move (mm or deg)


class MoveHistory:
    """Per moved quantity: direction of approach, landing error and end time of the last move.

    Fed with every motion that ends (:meth:`moved`; the bench passes on the emulator's motion events),
    so end times are the motion model's, on the bench clock. Each landing error is drawn from
    ``(seed, quantity, key)``, with a key the caller gives per quantity that names the move (the
    simulated bench in a campaign: the configuration the axis arrived at in the plan and which move
    there, see ``BenchSimulator.begin_configuration``), so that a resumed campaign draws the same
    errors for the same moves however the moves before them went. Without keys, a move is named by
    its position and the visits of that position so far (in the order they happen).
    """

    def __init__(self, profile: SimProfile, seed: int = 0, *, quantities: Sequence[str] = MOVED):
        """``quantities``: what moves (``MOVED``, and the tilts a rig drives, of ``TILTS``)."""
        unknown = [q for q in quantities if q not in MOVED + TILTS]
        if unknown:
            raise ValueError(f"quantities: {', '.join(unknown)} not of {', '.join(MOVED + TILTS)}")
        self.profile = profile
        self.seed = int(seed) & 0xFFFFFFFF
        self.axes = {q: AxisHistory() for q in quantities}
        self._visits: Counter = Counter()

    def _sigma(self, quantity: str) -> float:
        if quantity == "baseline_mm":
            return self.profile.slide.repeatability_mm
        if quantity in TILTS:
            return self.profile.head("left" if quantity == "tilt_left_deg" else "right").tilt_repeatability_deg
        side = "left" if quantity == "toe_in_left_deg" else "right"
        return self.profile.head(side).repeatability_deg

    def landing_draw(self, quantity: str, key: Sequence[int]) -> float:
        """The landing error (mm or deg) of the move ``key`` names: a pure function of (seed, quantity, key)."""
        sigma = self._sigma(quantity)
        if sigma <= 0.0:
            return 0.0
        rng = np.random.default_rng([self.seed, 0x1A9D, (MOVED + TILTS).index(quantity),
                                     *(int(k) & 0xFFFFFFFF for k in key)])
        return float(rng.normal(0.0, sigma))

    def moved(self, end: Mapping[str, float], *, end_s: float, approach: Mapping[str, int],
              keys: Mapping[str, Sequence[int]] | None = None) -> None:
        """A motion ended at bench time ``end_s`` with the quantities in ``approach`` (+1/-1: the direction each
        arrived in) at ``end`` (reported values); ``keys[quantity]`` names the move for its landing draw
        (None: by position and visits, see the class docstring)."""
        for quantity, direction in approach.items():
            axis = self.axes.get(quantity)
            if axis is None or not direction:
                continue
            axis.value = float(end[quantity])
            axis.approach = 1 if direction > 0 else -1
            axis.move_end_s = float(end_s)
            if keys is None:
                position = int(round(axis.value * 1e4)) & 0xFFFFFFFF
                key = (position, self._visits[(quantity, position)])
                self._visits[(quantity, position)] += 1
            else:
                key = keys[quantity]
            axis.landing = self.landing_draw(quantity, key)

    def excited_since(self, side: str) -> tuple[float, float]:
        """(bench time the ``side`` head's pan ringing was last excited, time its rocking was)."""
        slide = self.axes["baseline_mm"]
        pan = self.axes["toe_in_left_deg" if side == "left" else "toe_in_right_deg"]
        return max(slide.move_end_s, pan.move_end_s), slide.move_end_s

    def snapshot(self) -> dict[str, dict]:
        """JSON-ready: per quantity its direction of approach and landing error."""
        return {q: {"approach": a.approach, "landing": a.landing} for q, a in self.axes.items()}


@dataclass(frozen=True)
class PairState:
    """The true state of the pair at one instant."""

    T_bench_left: np.ndarray
    T_bench_right: np.ndarray
    separation_mm: float
    pan_left_deg: float
    pan_right_deg: float
    ringing_deg: dict[str, float]  # per side: pan ringing angle at the instant
    ringing_rate_deg_s: dict[str, float]
    rock_deg: dict[str, float]
    tilt_deg: dict[str, float] = field(default_factory=dict)  # per side with a tilt joint: its true angle

    def T_bench_cam(self, side: str) -> np.ndarray:
        return self.T_bench_left if side == "left" else self.T_bench_right


def pair_state(
    profile: SimProfile, reported: Mapping[str, float], *, history: MoveHistory | None = None,
    now_s: float = math.inf, tilting: Sequence[str] = (),
) -> PairState:
    """True camera poses for reported physical values (``baseline_mm``, ``toe_in_*_deg``, ``tilt_*_deg``).

    With ``history``, backlash follows each quantity's direction of approach, landing errors are added
    and the heads ring according to the time since the last move ended (``now_s``, simulated seconds).
    Without it, the poses are the mechanics' at rest with no backlash or landing error (approach 0).
    ``tilting``: the tilts (of ``TILTS``) the rig drives, through the heads' tilt joints; any other tilt is fixed.
    """
    def state(quantity: str) -> AxisHistory:
        return history.axes.get(quantity, AxisHistory()) if history is not None else AxisHistory()

    b, tl, tr = state("baseline_mm"), state("toe_in_left_deg"), state("toe_in_right_deg")
    separation = true_separation_mm(profile.slide, reported["baseline_mm"], approach=b.approach, landing_mm=b.landing)
    pans = {
        "left": true_pan_deg(profile.left_head, reported["toe_in_left_deg"], approach=tl.approach,
                             landing_deg=tl.landing),
        "right": true_pan_deg(profile.right_head, reported["toe_in_right_deg"], approach=tr.approach,
                              landing_deg=tr.landing),
    }
    ringing, rates, rocks, poses, tilts = {}, {}, {}, {}, {}
    for side in SIDES:
        quantity = f"tilt_{side}_deg"
        tilt = float(reported.get(quantity, 0.0))
        if quantity in tilting:
            moved = state(quantity)
            tilt = tilts[side] = true_tilt_deg(profile.head(side), tilt, approach=moved.approach,
                                               landing_deg=moved.landing)
        yaw_since, rock_since = history.excited_since(side) if history is not None else (-math.inf, -math.inf)
        cams = profile.cameras
        ringing[side], rates[side] = ringing_deg(cams, cams.vibration_yaw_deg, now_s - yaw_since)
        rocks[side] = ringing_deg(cams, cams.vibration_rock_deg, now_s - rock_since)[0]
        poses[side] = camera_pose(profile, side, separation_mm=separation, pan_deg=pans[side], tilt_deg=tilt,
                                  ringing_deg=ringing[side], rock_deg=rocks[side], tilt_joint=quantity in tilting)
    return PairState(T_bench_left=poses["left"], T_bench_right=poses["right"], separation_mm=separation,
                     pan_left_deg=pans["left"], pan_right_deg=pans["right"], ringing_deg=ringing,
                     ringing_rate_deg_s=rates, rock_deg=rocks, tilt_deg=tilts)


def kinematic_parameters(profile: SimProfile, reference_baseline_mm: float, *,
                         tilting: Sequence[str] = ()) -> dict[str, float]:
    """The profile's mechanics in the parametrisation of ``stereo_bench.kinematics`` (same names and units).

    That model's frame S is the left camera at toe-in 0; pan axes are given in their own camera's
    frame at toe-in 0 (direction as tilts of the camera's y axis about x then z; position where the
    axis crosses the camera's y = 0 plane); the slide direction in S; the right camera's pose at
    ``reference_baseline_mm`` and toe-in 0 in S. The truth a fitted model is compared with: derived
    here from the simulator's own chain, not from the estimator's code.

    ``tilting``: the tilts the rig drives (of ``TILTS``). Each camera's frame is then the one at commanded tilt 0
    as well, and its tilt joint is given in it: direction (the camera's x axis turned about y, then z), where
    it crosses the camera's x = 0 plane (y, z), its scale and backlash.
    """
    separation = true_separation_mm(profile.slide, reference_baseline_mm)
    joint = {side: f"tilt_{side}_deg" in tilting for side in SIDES}
    poses = {side: camera_pose(profile, side, separation_mm=separation,
                               pan_deg=true_pan_deg(profile.head(side), 0.0),
                               tilt_deg=true_tilt_deg(profile.head(side), 0.0) if joint[side] else 0.0,
                               tilt_joint=joint[side]) for side in SIDES}
    height = 0.5 * (profile.left_head.centre_height_mm + profile.right_head.centre_height_mm)
    forward = 0.5 * (profile.left_head.centre_forward_mm + profile.right_head.centre_forward_mm)
    out: dict[str, float] = {}
    for side in SIDES:
        sign = -1.0 if side == "left" else 1.0
        carriage = sign * separation / 2.0 * slide_direction(profile.slide) + np.array([0.0, height, -forward])
        R, t = poses[side][:3, :3], poses[side][:3, 3]
        direction = R.T @ pan_axis(profile.head(side))
        point = R.T @ (carriage - t)
        crossing = point - point[1] / direction[1] * direction
        out[f"{side}_axis_tilt_x_deg"] = math.degrees(math.atan2(direction[2], direction[1]))
        out[f"{side}_axis_tilt_z_deg"] = -math.degrees(math.asin(direction[0]))
        out[f"{side}_axis_x_mm"] = float(crossing[0])
        out[f"{side}_axis_z_mm"] = float(crossing[2])
        out[f"{side}_angle_scale"] = 1.0 + profile.head(side).scale_error
        if joint[side]:
            head = profile.head(side)
            # The tilt axis at pan 0 in the bench frame (a rotation about it leaves it where it is), then in the
            # camera's frame at commanded tilt 0.
            M = mount_rotation(head)
            centre_on_head = np.array([head.centre_sideways_mm, -head.centre_height_mm, head.centre_forward_mm])
            pivot_head = centre_on_head + M @ np.array([0.0, head.tilt_centre_height_mm, -head.tilt_centre_forward_mm])
            R_pan = rotation_about(pan_axis(head), (1.0 if side == "left" else -1.0) * true_pan_deg(head, 0.0))
            direction = R.T @ (R_pan @ M @ tilt_axis(head))
            point = R.T @ (carriage + R_pan @ pivot_head - t)
            crossing = point - point[0] / direction[0] * direction
            out[f"{side}_tilt_axis_yaw_deg"] = math.degrees(math.atan2(-direction[2], direction[0]))
            out[f"{side}_tilt_axis_roll_deg"] = math.degrees(math.asin(direction[1]))
            out[f"{side}_tilt_axis_y_mm"] = float(crossing[1])
            out[f"{side}_tilt_axis_z_mm"] = float(crossing[2])
            out[f"{side}_tilt_scale"] = 1.0 + head.tilt_scale_error
            out[f"{side}_tilt_backlash_deg"] = head.tilt_backlash_deg / (1.0 + head.tilt_scale_error)
    d = poses["left"][:3, :3].T @ slide_direction(profile.slide)
    out["slide_yaw_deg"] = math.degrees(math.atan2(-d[2], d[0]))
    out["slide_pitch_deg"] = math.degrees(math.asin(d[1]))
    out["slide_scale"] = 1.0 + profile.slide.scale_error
    T_S_R0 = np.linalg.inv(poses["left"]) @ poses["right"]
    angle = math.acos(max(-1.0, min(1.0, (np.trace(T_S_R0[:3, :3]) - 1.0) / 2.0)))
    R = T_S_R0[:3, :3]
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    rvec = axis / (2.0 * math.sin(angle)) * angle if angle > 1e-12 else axis / 2.0
    for k, name in enumerate(("x", "y", "z")):
        out[f"right_rot_{name}_deg"] = math.degrees(rvec[k])
        out[f"right_{name}_mm"] = float(T_S_R0[k, 3])
    # The model corrects the commanded value (B' = B - a b / 2, then scaled); the mechanics lose the backlash after
    # the scale: the model's backlash is the mechanics' in commanded units (0.2 % apart on the lab heads).
    out["slide_backlash_mm"] = profile.slide.backlash_mm / (1.0 + profile.slide.scale_error)
    out["left_backlash_deg"] = profile.left_head.backlash_deg / (1.0 + profile.left_head.scale_error)
    out["right_backlash_deg"] = profile.right_head.backlash_deg / (1.0 + profile.right_head.scale_error)
    return out
