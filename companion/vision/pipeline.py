"""Frame → :class:`Estimate`: the paper's stages composed, each one timed (Fig. 1).

(lens undone, :mod:`~companion.vision.lens`) → lines (eq. 1) → layout VPs and segment
labels (Fig. 2) → corner projections ranked by Λ (eqs. 2–4) → Table I → obstacles from
corner pairs (eqs. 5–8) → M, η, φ (eqs. 9–11).

The stages are pure functions; :class:`Pipeline` holds the configured line detector
(built once), what a video teaches about its camera (:class:`RunningFocal`,
:class:`RunningLens`) and its obstacle's track, and measures how long each stage took.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from functools import cached_property

import cv2
import numpy as np

from companion.config import Config, VisionConfig, check_lens
from companion.vision.corners import (
    Corners,
    find_corners,
    loose_ends,
    obstacle_legs,
    table1_labels,
    table1_mask,
)
from companion.vision.geometry import focal_from_orthogonal_vps, principal_point
from companion.vision.heading import closest_to_centre, heading_from_vp
from companion.vision.lens import distort_px, half_diagonal, radial_k, undistort_maps
from companion.vision.lines import (
    edge_step_z,
    extend_segments,
    filter_segments,
    make_detector,
    noise_sigma,
    refine_segments,
    to_gray,
)
from companion.vision.obstacles import Obstacle, find_obstacles
from companion.vision.ranging import (
    FloorContact,
    floor_contacts,
    foot_line,
    hidden_extent,
    path_distance,
)
from companion.vision.tracking import Track, update_track
from companion.vision.vanishing import (
    NONE,
    V1,
    V2,
    V3,
    LayoutVPs,
    assign_segments,
    detect_layout_vps,
)

__all__ = ["Estimate", "Pipeline", "RunningFocal", "RunningLens", "STAGES"]

STAGES = ("lines", "vps", "corners", "obstacles", "heading")

SELF_CALIBRATION_TOL = 0.1
"""relative change of the estimated focal length when the VPs are found again with it"""

SELF_CALIBRATION_MARGIN = 0.1
"""a focal length a later guess confirms replaces an earlier guess's only when the VPs
found with it have more than this share more support (V1, V2 and V3 together)"""

SELF_CALIBRATION_GUESSES = (0.5, 0.3, 1.0, 1.5, 2.0)
"""focal-length guesses, in frame widths, each tried in turn (the earlier wins a tie, see
``SELF_CALIBRATION_MARGIN``): horizontal fields of view of 90°, 118°, 53°, 37° and 28°.
A guess far from the truth can pick the wrong V1–V2 pair, so a narrow or a wide lens needs
a guess of its own."""

FOCAL_RANGE = (0.2, 3.0)
"""estimates outside these frame widths (fields of view of 136° and 19°) are discarded"""

REFERENCE_DIAGONAL_PX = 800.0
"""the diagonal of the 640×480 frame the configured sizes in pixels are meant for"""

FOCAL_MEMORY = 31
"""frames of focal-length estimates the running estimate is the median of"""

SETTLED_TOL = 0.15
"""a frame searched with the running estimate alone keeps its layout when the focal length
it implies is within this share of the estimate; else it calibrates itself"""

FOCAL_WARMUP = 5
"""estimates gathered by full per-frame self-calibration before the running estimate is
trusted as the one guess a frame is searched with"""

FOCAL_STEADY = 0.1
"""a video's focal-length estimates whose middle 80 % spans at most this share of their
median are one camera's, seen well: a value worth writing into the configuration"""


LENS_FRAMES = 9
"""frames whose lens estimates (:func:`~companion.vision.lens.radial_k`) the video's lens is
the median of; from the next frame on it is undone, and no longer estimated"""

LENS_MIN_K = 0.03
"""a video's lens whose coefficient is smaller than this is a pinhole: nothing is undone"""


def _room_eta(layout: LayoutVPs, centre: np.ndarray, depth_px: float) -> float | None:
    """Eq. 10 for the observed horizontal layout VP nearest the centre (the room's η, which
    the tracker measures obstacle faces against), None when neither V1 nor V2 was seen."""
    rows = [k for k in (V1, V2) if layout.observed[k]]
    if not rows:
        return None
    vps = layout.vps[rows]
    return heading_from_vp(vps[closest_to_centre(vps, centre)], centre, depth_px).eta_deg


@dataclass(frozen=True)
class RunningFocal:
    """The focal length of one video or camera, estimated from frame to frame.

    ``estimates_px``: the last :data:`FOCAL_MEMORY` per-frame estimates (pixels), oldest
    first. The running estimate is their median, so a frame whose V1–V2 pair was wrong
    cannot move it far. Pure value: :meth:`add` returns a new one.
    """

    estimates_px: tuple[float, ...] = ()

    @cached_property  # read several times a frame; the value never changes
    def focal_px(self) -> float | None:
        """The running estimate in pixels, None before the first frame gave one."""
        return float(np.median(self.estimates_px)) if self.estimates_px else None

    @property
    def settled(self) -> bool:
        """Whether enough frames agreed to search the next frame with this focal alone."""
        return len(self.estimates_px) >= FOCAL_WARMUP

    def add(self, focal_px: float) -> RunningFocal:
        return RunningFocal((self.estimates_px + (float(focal_px),))[-FOCAL_MEMORY:])

    def describe(self, width: int) -> str:
        """One line for a person: what was learnt for frames ``width`` pixels wide, and
        whether it is steady enough to give (``camera.focal_px``) from the first frame on."""
        if not self.estimates_px:
            return ("focal length: not estimated (no frame showed both horizontal room "
                    f"axes); half the width assumed, {width / 2:.0f} px")
        f, n = self.focal_px, len(self.estimates_px)
        lo, hi = np.percentile(self.estimates_px, [10, 90])
        hfov = math.degrees(2 * math.atan(width / 2 / f))
        text = (f"focal length: {f:.0f} px ({hfov:.0f}° across), the median of the last {n} "
                f"frames' estimates (10–90 %: {lo:.0f}–{hi:.0f} px)")
        if n >= FOCAL_WARMUP and hi - lo <= FOCAL_STEADY * f:
            return text + f"; steady: --focal-px {f:.0f} (camera.focal_px) gives it from frame 1"
        return text + ("; not steady enough to give: too few frames, more than one camera, "
                       "or views that do not fix it")


@dataclass(frozen=True)
class RunningLens:
    """The radial distortion of one video's lens, estimated on its first frames.

    ``estimates_k``: per-frame estimates of the half-diagonal normalised coefficient
    (:func:`~companion.vision.lens.radial_k`), oldest first. Their median is the lens once
    :data:`LENS_FRAMES` frames gave one: a single frame holds too little bend to tell,
    but a frame fooled by a curved or cluttered view is one vote among several. Pure
    value: :meth:`add` returns a new one.
    """

    estimates_k: tuple[float, ...] = ()

    @property
    def settled(self) -> bool:
        return len(self.estimates_k) >= LENS_FRAMES

    @cached_property  # read every frame of the video; the value never changes
    def k(self) -> float | None:
        """The lens's coefficient once settled (0.0 for a pinhole), else None."""
        if not self.settled:
            return None
        k = float(np.median(self.estimates_k))
        return k if abs(k) >= LENS_MIN_K else 0.0

    def add(self, k: float) -> RunningLens:
        return RunningLens(self.estimates_k + (float(k),))

    def describe(self) -> str:
        """One line for a person: what was learnt, and whether it is undone."""
        if not self.settled:
            return (f"lens: not learnt, {len(self.estimates_k)} of the {LENS_FRAMES} frames it "
                    "needs; frames taken as they are")
        return (f"lens: radial k {self.k:+.2f} on the half-diagonal, learnt on the first "
                f"{len(self.estimates_k)} frames; "
                + ("undone from there" if self.k else "a pinhole, nothing undone"))


def _support(layout: LayoutVPs) -> float:
    """How strongly the segments back a layout: the support of its observed VPs (pixels)."""
    return float(np.sum(layout.support_px[np.array(layout.observed)]))


def _orthogonal_focal(layout: LayoutVPs, centre: np.ndarray) -> float | None:
    """The focal length that makes the observed V1 and V2 orthogonal, None without both."""
    if not (layout.observed[V1] and layout.observed[V2]):
        return None
    return focal_from_orthogonal_vps(layout.vps[V1], layout.vps[V2], centre)


def _plausible(focal_px: float | None, width: int) -> bool:
    """Whether an estimate is a focal length at all: within ``FOCAL_RANGE`` frame widths."""
    return focal_px is not None and FOCAL_RANGE[0] * width <= focal_px <= FOCAL_RANGE[1] * width


@dataclass(frozen=True)
class Estimate:
    """What one frame says.

    ``eta_deg``, ``phi_deg``: eq. 10 for the primary obstacle (the best supported, see
    :func:`~companion.vision.obstacles.find_obstacles`), None if none.
    ``m_px``: its M in centred coordinates (y up), None if none or at infinity.
    ``obstacles``: every obstacle found, primary first. ``layout``: V1, V2, V3.
    ``segments`` N×4, those corners are built from (validated, grown to their junctions),
    and their ``labels`` N (V1 0, V2 1, V3 2, none −1); ``corners``: the
    top-K corner projections; ``obstacle_corners``: those passing Table I.
    ``stage_ms``: wall time per stage in milliseconds (keys :data:`STAGES`).
    ``focal_px``: the focal length the layout rests on, ``focal_source`` where it came from
    (given, estimated, assumed); ``depth_px``: D of eq. 10 (configured, else the given
    focal length, else the video's running estimate of it, else half the width).
    ``eta_tracked_deg``: η of the obstacle tracked across this video's frames
    (:mod:`~companion.vision.tracking`), None while the tracker reports nothing (no
    confirmed track, and no first frame that two corner pairs agree on).
    ``obstacle_contacts``: per obstacle, its floor contacts (range and bearing,
    :mod:`~companion.vision.ranging`), empty without the camera height
    (``camera_height_m``) or a vertical edge whose foot is seen; ``contact``, ``range_m``:
    the primary obstacle's nearest.
    ``noise_segments`` K×4: unassigned segments dropped before the corners for not
    standing out of the frame's noise (``vision.min_step_z``); drawn, never used.
    ``noise_sigma``: that noise, grey levels, measured on the frame as captured (0.0 when
    the step test is off).
    """

    eta_deg: float | None
    phi_deg: float | None
    m_px: tuple[float, float] | None
    obstacles: tuple[Obstacle, ...]
    layout: LayoutVPs
    segments: np.ndarray
    labels: np.ndarray
    corners: Corners
    obstacle_corners: Corners
    width: int
    height: int
    focal_px: float
    depth_px: float
    focal_source: str = "given"  # given | estimated (from V1 ⟂ V2) | assumed (width / 2)
    stage_ms: dict[str, float] = field(default_factory=dict)
    eta_tracked_deg: float | None = None
    obstacle_contacts: tuple[tuple[FloorContact, ...], ...] = ()
    camera_height_m: float | None = None
    noise_segments: np.ndarray = field(default_factory=lambda: np.empty((0, 4)))
    noise_sigma: float = 0.0

    @property
    def contact(self) -> FloorContact | None:
        """The primary obstacle's nearest floor contact, None if not measured."""
        first = self.obstacle_contacts[0] if self.obstacle_contacts else ()
        return min(first, key=lambda c: c.range_m) if first else None

    @property
    def contacts_ahead_right_m(self) -> tuple[tuple[float, float], ...]:
        """Every obstacle's floor contacts, each (m ahead of the camera, m to its right);
        empty when none is measured."""
        return tuple(c.ahead_right_m for contacts in self.obstacle_contacts for c in contacts)

    def footprint_ahead_right_m(self, hidden_depth_m: float = 0.0
                                ) -> tuple[tuple[float, float], ...]:
        """:attr:`contacts_ahead_right_m`, the floor between an obstacle's neighbouring
        contacts (:func:`~companion.vision.ranging.foot_line`), and with ``hidden_depth_m``
        > 0 the floor each obstacle is taken to cover behind them
        (:func:`~companion.vision.ranging.hidden_extent`); each (m ahead of the camera, m
        to its right)."""
        if not any(self.obstacle_contacts):
            return ()
        between = (p for contacts in self.obstacle_contacts for p in foot_line(contacts))
        if hidden_depth_m <= 0.0:
            return self.contacts_ahead_right_m + tuple(between)
        centre = principal_point(self.width, self.height)
        behind = (p for o, contacts in zip(self.obstacles, self.obstacle_contacts, strict=True)
                  for p in hidden_extent(o.corners_px, contacts, o.ovps, self.layout.vps[V3],
                                         self.layout.focal_px, centre, self.camera_height_m,
                                         hidden_depth_m))
        return self.contacts_ahead_right_m + tuple(between) + tuple(behind)

    @property
    def range_m(self) -> float | None:
        """Horizontal distance to the primary obstacle's floor contact, metres."""
        return None if self.contact is None else self.contact.range_m

    def path_m(self, half_width_m: float) -> float | None:
        """Distance (m) to the nearest measured floor contact in a corridor of
        ``half_width_m`` ahead (:func:`~companion.vision.ranging.path_distance`); inf when
        nothing measured is in it or no obstacle is seen; None when obstacles are seen but
        none could be measured (no camera height, or no foot in view)."""
        if not self.obstacles:
            return math.inf if self.camera_height_m else None
        if not any(self.obstacle_contacts):
            return None
        return path_distance(self.obstacle_contacts, half_width_m)

    @property
    def latency_ms(self) -> float:
        """Total processing time of the frame, milliseconds."""
        return float(sum(self.stage_ms.values()))

    @property
    def scene_understood(self) -> bool:
        """Whether the room's layout was seen: a vertical and a horizontal VP (the layout
        the obstacle stage needs), or both horizontal VPs, as in a view of a bare wall
        and the floor that holds no vertical edge at all."""
        observed = self.layout.observed
        return self.layout.found or bool(observed[V1] and observed[V2])


class Pipeline:
    """The configured pipeline. ``Pipeline(config)(frame) → Estimate``."""

    def __init__(self, config: Config | None = None):
        self.config = config or Config()
        check_lens(self.config.camera)  # a Config built in code skips from_mapping's check
        self._detectors: dict[tuple[int, int], tuple[object, float]] = {}
        self.running_focal = RunningFocal()
        self.track: Track | None = None
        self._vision: dict[tuple[int, int], VisionConfig] = {}
        self._lens_maps: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        self.running_lens = RunningLens()
        self._lens_size: tuple[int, int] | None = None
        self._last_lens: tuple[float, tuple[float, ...]] | None = None
        self._focal_size: tuple[int, int] | None = None
        vp = self.config.vision.vanishing
        self._known_focal_vp = replace(
            vp, orthogonal_tol_deg=vp.known_focal_orthogonal_tol_deg,
            orthogonal_sigma_deg=vp.known_focal_orthogonal_sigma_deg)

    def detector_for(self, width: int, height: int):
        """The configured line detector for frames of ``width``×``height`` (built once per
        frame size) and its minimum segment length in pixels (``min_segment_frac`` of the
        diagonal)."""
        if (width, height) not in self._detectors:
            min_len = self.config.vision.min_segment_frac * math.hypot(width, height)
            self._detectors[width, height] = make_detector(
                self.config.vision.detector, min_len, self.config.vision.edge_threshold,
                self.config.vision.validate_segments), min_len
        return self._detectors[width, height]

    def _layout(self, segments: np.ndarray, w: int, h: int) -> tuple[LayoutVPs, str]:
        """Layout VPs, and where the focal length they rest on came from.

        ``given``: configured. With a given focal length V1 ⟂ V2 is checked with the
        tighter ``known_focal_orthogonal_tol_deg``.

        Otherwise self-calibration: V1 and V2 are orthogonal in space, so when both are
        finite they fix ``f`` (:func:`focal_from_orthogonal_vps`), and each frame's
        estimate joins the video's :class:`RunningFocal`. Until that has settled, each
        frame calibrates itself (:meth:`_calibrate`). Once it has, a frame is searched with
        the running estimate alone (``estimated``): one VP search per frame instead of
        several.

        A settled video's frame whose VPs under the running estimate imply another focal
        length (beyond ``SETTLED_TOL``), or show no V1–V2 pair, still calibrates itself
        and its estimate joins the running one, so that a video whose first frames misled
        it recovers. But its layout stays the one found with the running estimate, if that
        found V1: one frame's fixed point can pair V1 with a rotated obstacle's edges at
        twice the true focal length, and the median of the video's frames is the better
        evidence.
        """
        vp = self.config.vision.vanishing
        if self.config.camera.focal_px:
            return detect_layout_vps(segments, w, h, self.config.camera.focal_px,
                                     self._known_focal_vp), "given"
        if self._focal_size != (w, h):  # another camera: its lens is another question
            self._focal_size, self.running_focal = (w, h), RunningFocal()

        guesses = [g * w for g in SELF_CALIBRATION_GUESSES]
        if not self.running_focal.settled:
            layout, source = self._calibrate(segments, w, h, guesses)
            if source == "estimated":
                self.running_focal = self.running_focal.add(layout.focal_px)
            return layout, source

        f_run = self.running_focal.focal_px
        layout = detect_layout_vps(segments, w, h, f_run, vp)
        f = _orthogonal_focal(layout, principal_point(w, h))
        if _plausible(f, w) and abs(f - f_run) <= SETTLED_TOL * f_run:
            self.running_focal = self.running_focal.add(f)
            return layout, "estimated"
        # This frame disagrees with the video's focal length, or shows no V1–V2 pair
        # under it: it calibrates itself, starting from the running estimate, and votes.
        own, source = self._calibrate(segments, w, h, [f_run, *guesses], found=layout)
        if source == "estimated":
            self.running_focal = self.running_focal.add(own.focal_px)
        return (layout, "estimated") if layout.observed[V1] else (own, source)

    def _calibrate(self, segments: np.ndarray, w: int, h: int, guesses: list[float],
                   found: LayoutVPs | None = None) -> tuple[LayoutVPs, str]:
        """One frame's self-calibration: its layout, ``estimated`` or ``assumed``.

        VPs found with each focal length of ``guesses`` (pixels) in turn give ``f``
        (V1 ⟂ V2, kept within ``FOCAL_RANGE``), and the VPs are found again with it. An
        estimate the VPs found with it give back (within ``SELF_CALIBRATION_TOL``) is
        confirmed; of several confirmed, the earliest guess's, unless a later one's VPs
        have clearly more support (``SELF_CALIBRATION_MARGIN``). Without a confirmed
        estimate, the first unconfirmed one; without any, the first guess's VPs
        (``assumed``). The layout's ``focal_px`` is the focal length it was found with.
        ``found``: the VPs already found with the first guess, not searched again.
        """
        vp = self.config.vision.vanishing
        centre = principal_point(w, h)
        first = unconfirmed = best = None
        for k, guess in enumerate(guesses):
            layout = found if k == 0 and found is not None else detect_layout_vps(
                segments, w, h, guess, vp)
            first = first or layout
            f = _orthogonal_focal(layout, centre)
            if not _plausible(f, w):
                continue
            again = detect_layout_vps(segments, w, h, f, vp)
            f_again = _orthogonal_focal(again, centre)
            # A frame picked under a wrong guess can imply a focal length under which a
            # different frame wins; a true estimate is a fixed point. A frame can have more
            # than one (an obstacle's edges paired with V1 instead of the room's far wall):
            # the one whose VPs the segments back clearly better wins, else the earlier.
            if f_again is not None and abs(f_again - f) <= SELF_CALIBRATION_TOL * f:
                if best is None or _support(again) > (1 + SELF_CALIBRATION_MARGIN) * _support(
                        best):
                    best = again
                continue
            unconfirmed = unconfirmed or again
        if best is not None:
            return best, "estimated"
        if unconfirmed is not None:
            return unconfirmed, "estimated"
        return first, "assumed"

    def describe_focal(self) -> str:
        """One line for a person: the focal length this video taught, for the frame size
        it was learnt at (:meth:`RunningFocal.describe`); a given one is never learnt."""
        width = self._focal_size[0] if self._focal_size else 0
        return self.running_focal.describe(width) if width else "focal length: no frame seen"

    def focal_for(self, width: int) -> float:
        """The focal length in pixels: given, else this video's running estimate, else half
        the width."""
        return self.config.camera.focal_px or self.running_focal.focal_px or width / 2.0

    def depth_for(self, width: int) -> float:
        """D of eq. 10 in pixels: ``heading.depth_px`` if set, else the focal length
        (:meth:`focal_for`). Only with D = f is η the bearing of the obstacle face."""
        return self.config.heading.depth_px or self.focal_for(width)

    def _undone_lens(self, w: int, h: int) -> tuple[float, tuple[float, ...]] | None:
        """The lens undone in frames of ``w``×``h`` (focal length and OpenCV's coefficients
        it is written with), None when they are taken as they are: ``camera.distortion``
        when given (``[0]``: a pinhole), else this video's :class:`RunningLens` once it has
        settled."""
        cam = self.config.camera
        if cam.distortion is not None:
            return (cam.focal_px, tuple(cam.distortion)) if any(cam.distortion) else None
        k = self.running_lens.k if self._lens_size == (w, h) else None
        return (half_diagonal(w, h), (k,)) if k else None

    def pinhole(self, frame: np.ndarray) -> np.ndarray:
        """The frame as every stage sees it: the lens's distortion undone
        (:mod:`~companion.vision.lens`; same size and focal length), else the frame
        itself. The lens is ``camera.distortion`` when given (``[0]``: a pinhole), else
        this video's :class:`RunningLens` once it has settled. Pixel positions in an
        :class:`Estimate` are positions in this picture (:meth:`frame_px` maps them back)."""
        h, w = frame.shape[:2]
        lens = self._last_lens = self._undone_lens(w, h)
        if lens is None:
            return frame
        key = (w, h, lens)
        if key not in self._lens_maps:
            self._lens_maps[key] = undistort_maps(w, h, *lens)
        mx, my = self._lens_maps[key]
        return cv2.remap(frame, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def frame_px(self, points_px: np.ndarray, width: int, height: int) -> np.ndarray:
        """Positions in the last frame's pinhole picture (N×2 pixels, as its
        :class:`Estimate` gives them) → where the ``width``×``height`` frame itself shows
        them (N×2): the lens :meth:`pinhole` undid in it put back (a video's lens is
        learnt during its first frames, so the next frame's may differ)."""
        pts = np.asarray(points_px, dtype=float).reshape(-1, 2)
        lens = self._last_lens
        return pts if lens is None else distort_px(pts, width, height, *lens)

    @property
    def learning_lens(self) -> bool:
        """Whether the next frame (of the size seen last) still adds to this video's lens
        estimate: its lines stage then also searches the lens (``lens.radial_k``, about
        three times the stage's cost), as on the first :data:`LENS_FRAMES` frames."""
        return self.config.camera.distortion is None and not self.running_lens.settled

    def _learn_lens(self, segments: np.ndarray, w: int, h: int) -> None:
        """Add this frame's estimate to the video's lens, while it is being estimated: the
        lens was not given and has not settled. Segments as detected in the raw frame."""
        if self._lens_size != (w, h):  # another camera
            self._lens_size, self.running_lens = (w, h), RunningLens()
        if not self.learning_lens:
            return
        k = radial_k(segments, w, h, self.focal_for(w), self.config.vision.vanishing)
        if k is not None:
            self.running_lens = self.running_lens.add(k)

    def segments(self, frame: np.ndarray) -> np.ndarray:
        """Stage 1: the frame's line segments (N×4 pixels), filtered and capped."""
        return self._segments(self.pinhole(to_gray(frame)))[0]

    def _segments(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every segment, for the layout VPs, and those that pass the a-contrario test
        (``vision.validate_segments``), for corners and obstacles; each filtered and capped.

        The layout VPs are a vote of hundreds of segments, in which a chance segment is
        one outlier among many and a faint true one still adds support; a corner is built
        from two or three segments, and one chance segment is enough to make a wrong one.
        With ``vision.refine_segments`` each is moved onto its edge, sub-pixel.
        """
        h, w = gray.shape[:2]
        detect, min_len = self.detector_for(w, h)
        segments, validated = detect(gray)
        cap = self.config.vision.max_segments
        every = filter_segments(segments, min_len, cap)
        chosen = every if validated.all() else filter_segments(segments[validated], min_len, cap)
        if self.config.vision.refine_segments:
            refined = refine_segments(gray, every)
            chosen = refined if chosen is every else refine_segments(gray, chosen)
            every = refined
        return every, chosen

    def _drop_noise(self, gray: np.ndarray, sigma: float, segments: np.ndarray,
                    labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The segments and labels without the unassigned segments that are not clearly
        edges (``vision.min_step_z``), and those dropped (K×4). ``sigma``: the frame's
        noise in grey levels, measured on the frame as captured (:func:`noise_sigma`).

        Sensor noise on a plain wall makes short chance segments at every angle, and one
        of them at a vertical edge is the corner of an obstacle that is not there. A
        segment the room's VPs claim needs no such test: chance does not line it up with
        a VP, and a faint one (a box's edge between two faces lit alike) still counts.
        """
        min_z = self.config.vision.min_step_z
        unassigned = np.flatnonzero(labels == NONE)
        if min_z <= 0 or len(unassigned) == 0:
            return segments, labels, segments[:0]
        z = edge_step_z(gray, segments[unassigned], sigma)
        keep = np.ones(len(segments), bool)
        keep[unassigned[z < min_z]] = False
        return segments[keep], labels[keep], segments[~keep]

    def layout(self, frame: np.ndarray) -> tuple[LayoutVPs, str]:
        """Stages 1–2 alone, frame → layout VPs and the focal length's source (given,
        estimated, assumed): what a vanishing-point detector returns."""
        h, w = frame.shape[:2]
        return self._layout(self.segments(frame), w, h)

    def vision_for(self, width: int, height: int) -> VisionConfig:
        """The vision settings for frames of ``width``×``height``: the sizes of things in
        the picture (corner radius, leg growth, shortest obstacle edge) are configured
        for a 640×480 frame and scale with the diagonal, as the picture does; tolerances
        for pixel noise (residuals, λ1) stay in pixels."""
        key = (width, height)
        if key not in self._vision:
            vc = self.config.vision
            s = float(np.hypot(width, height)) / REFERENCE_DIAGONAL_PX
            self._vision[key] = replace(
                vc,
                corners=replace(vc.corners, radius_px=vc.corners.radius_px * s,
                                leg_growth_px=vc.corners.leg_growth_px * s),
                obstacles=replace(vc.obstacles, min_edge_px=vc.obstacles.min_edge_px * s))
        return self._vision[key]

    def __call__(self, frame: np.ndarray, camera_height_m: float | None = None) -> Estimate:
        """Run every stage on a BGR or grey ``frame`` (H×W[×3] uint8). With the camera's
        height above the floor (``camera_height_m``, else ``camera.height_m``) the
        primary obstacle's range is measured too."""
        vc = self.vision_for(frame.shape[1], frame.shape[0])
        h, w = frame.shape[:2]
        centre = principal_point(w, h)
        ms: dict[str, float] = {}

        t0 = time.perf_counter()
        captured = to_gray(frame)
        gray = self.pinhole(captured)
        all_segments, segments = self._segments(gray)
        self._learn_lens(all_segments, w, h)
        t1 = time.perf_counter()
        ms["lines"] = (t1 - t0) * 1e3

        # The layout rests on every segment, corners and obstacles on the validated ones,
        # less the unassigned ones that do not stand out of the frame's noise.
        layout, focal_source = self._layout(all_segments, w, h)
        labels, _ = assign_segments(segments, layout.vps, vc.vanishing)
        # The noise is measured before the lens is undone: the remap's interpolation
        # averages neighbouring pixels, which hides about a third of the noise from the
        # estimator but much less of it from the step test along a segment.
        sigma = noise_sigma(captured) if self.config.vision.min_step_z > 0 else 0.0
        segments, labels, noise_segments = self._drop_noise(gray, sigma, segments, labels)
        t2 = time.perf_counter()
        ms["vps"] = (t2 - t1) * 1e3

        # Labels are judged on the detected segments; corners and pairs are built from the
        # same segments grown to the junctions the detector stopped short of.
        strict_labels = table1_labels(segments, layout.vps, vc.corners)
        free_legs = obstacle_legs(labels, strict_labels)
        ends = loose_ends(segments, vc.corners.radius_px, among=free_legs | (labels == V3))
        segments = extend_segments(gray, segments, max_px=vc.corners.leg_growth_px, ends=ends)
        corners = find_corners(segments, labels, vc.corners)
        obstacle_corners = corners.take(table1_mask(corners, labels, free_legs))
        t3 = time.perf_counter()
        ms["corners"] = (t3 - t2) * 1e3

        obstacles = (
            find_obstacles(
                segments,
                obstacle_corners,
                layout,
                free_legs,
                labels,
                vc.obstacles,
                radius_px=vc.corners.radius_px,
                leg_gap_frac=vc.corners.leg_gap_frac,
                min_leg_angle_deg=vc.corners.min_leg_angle_deg,
                noise_px=vc.corners.manhattan_leg_noise_px,
                focal_settled=focal_source == "estimated" and self.running_focal.settled,
            )
            if layout.found
            else []
        )
        t4 = time.perf_counter()
        ms["obstacles"] = (t4 - t3) * 1e3

        depth = self.depth_for(w)
        headings = [heading_from_vp(o.ovps[:2][closest_to_centre(o.ovps[:2], centre)], centre,
                                    depth) for o in obstacles]
        eta = phi = m = None
        pairs = 0
        if obstacles:
            eta, phi, m = headings[0].eta_deg, headings[0].phi_deg, headings[0].m_px
            pairs = obstacles[0].pairs
        # Every obstacle of the frame keeps its own track; the first one's is reported.
        self.track, eta_tracked = update_track(
            self.track, eta, _room_eta(layout, centre, depth), pairs=pairs,
            others_deg=tuple(hd.eta_deg for hd in headings[1:]))
        height = camera_height_m or self.config.camera.height_m
        contacts: tuple[tuple[FloorContact, ...], ...] = ()
        if obstacles and height and layout.observed[V3]:
            contacts = tuple(tuple(floor_contacts(o.corners_px, layout.vps[V3],
                                                  layout.focal_px, centre, height))
                             for o in obstacles)
        ms["heading"] = (time.perf_counter() - t4) * 1e3

        return Estimate(
            eta_deg=eta,
            phi_deg=phi,
            m_px=m,
            obstacles=tuple(obstacles),
            layout=layout,
            segments=segments,
            labels=labels,
            corners=corners,
            obstacle_corners=obstacle_corners,
            width=w,
            height=h,
            focal_px=layout.focal_px,
            focal_source=focal_source,
            depth_px=depth,
            stage_ms=ms,
            eta_tracked_deg=eta_tracked,
            obstacle_contacts=contacts,
            camera_height_m=height or None,
            noise_segments=noise_segments,
            noise_sigma=sigma,
        )
