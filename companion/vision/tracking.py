"""Obstacles followed across frames: η that does not flip, drop out or false-alarm.

The paper estimates η frame by frame (eq. 10). A rotated obstacle standing in a Manhattan
room has one thing that does not change while the vehicle yaws: its face's angle to the
room's axes, ``rel = wrap90(η − η_room)``, where ``η_room`` is eq. 10 applied to a layout
VP (V1 or V2) and ``wrap90`` folds an angle into (−45°, 45°] (a box's four faces and a
room's four walls are each 90° apart). The track keeps that angle, so that

- a new detection belongs to the track when its ``rel`` agrees within ``gate_deg``, and
  moves the track's ``rel`` by ``smoothing`` of the difference;
- the tracked η is ``rel + η_room`` taken modulo 90° nearest the last η, in every frame:
  where the detection drops out (up to ``max_missed`` of them) it is a prediction, and
  where it shows, the room's VPs (a vote of many segments) carry the vehicle's yaw while
  the obstacle's few edges contribute only their share of ``rel``, so one frame's noisy
  box fit moves the tracked η by ``smoothing`` of its error;
- eq. 9's choice between the obstacle's two OVPs, which flips with noise when the face
  is near 45° to the line of sight, is kept until the other OVP is nearer the frame centre
  by more than ``switch_margin_deg``;
- a detection seen in one frame only is not reported: a track is confirmed after
  ``confirm_hits`` consistent frames among the last ``confirm_window`` (track initiation
  by M-of-N logic: an unconfirmed detection waits for its second frame through one
  frame's drop-out or noise, which does not replace it), unless ``report_pairs`` of the
  frame's corner pairs agree on it (``Obstacle.pairs``): two corners of one frame whose
  legs give the same OVPs are two measurements of them, as two frames are. Such a first
  frame is reported, but the track is still confirmed by frames, so a drop-out is bridged
  only after a second;
- a confirmed track whose detections stop agreeing with it is predicted on for up to
  ``max_missed`` frames, while the disagreeing detection waits beside it as an unconfirmed
  track: confirmed in turn, it takes over at once (two frames that agree on another face
  angle outweigh a prediction), so the tracked η follows the obstacle the frames now show
  (another piece, or the real one after a false pair) without waiting out the coast;
- every obstacle of a frame keeps a track of its own, not only the one that drives the
  frame's η (``find_obstacles``' first): a piece seen beside it is then already
  confirmed when it comes to drive η, and is reported at once, and the reported track is
  measured rather than predicted in a frame whose first obstacle is another. A second
  reading of an obstacle the frame already measured (another hypothesis of one box, within
  ``gate_deg``) starts no track. Only the frame's first obstacle decides which track is
  reported.

Inputs are plain values (the frame's η and the layout's η_room, degrees); the camera's
yaw never has to be known, so a recording is tracked as well as a flight. Pure functions;
:class:`~companion.vision.pipeline.Pipeline` holds the state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

__all__ = ["TrackParams", "Track", "wrap90", "update_track"]


def wrap90(angle_deg: float) -> float:
    """``angle_deg`` folded into (−45°, 45°]."""
    a = (angle_deg + 45.0) % 90.0 - 45.0
    return 45.0 if a == -45.0 else a


@dataclass(frozen=True)
class TrackParams:
    gate_deg: float = 6.0
    """a detection whose face angle to the room differs more is another obstacle"""
    confirm_hits: int = 2
    """consistent frames before a track's η is reported"""
    confirm_window: int = 3
    """... among this many (``confirm_hits``: in a row)"""
    report_pairs: int = 2
    """... or corner pairs of one frame that agree on the detection (0: frames only)"""
    max_missed: int = 3
    """frames a confirmed track is predicted through without a detection"""
    switch_margin_deg: float = 8.0
    """the other OVP takes over as eq. 9's M only when it is this much nearer the centre"""
    smoothing: float = 0.5
    """weight of a new detection in the track's face angle (1: no smoothing)"""


@dataclass(frozen=True)
class Track:
    """``rel_deg``: the obstacle face's angle to the room axes, (−45°, 45°];
    ``eta_deg``: the tracked η it gave in the last frame (on the OVP eq. 9 follows);
    ``hits``: consistent detections so far; ``missed``: frames since the last one;
    ``beside``: the other tracks, kept beside this one (the one reported): obstacles the
    frames read as another face angle, as the frame's obstacle or beside it, each
    confirmed or still waiting for its second frame (``TrackParams.confirm_window``). The
    frame's obstacle replaces this one as soon as its track is confirmed."""

    rel_deg: float
    eta_deg: float
    hits: int = 1
    missed: int = 0
    beside: tuple[Track, ...] = ()

    def confirmed(self, params: TrackParams) -> bool:
        return self.hits >= params.confirm_hits


def _nearest_branch(eta_deg: float, near_deg: float) -> float:
    """``eta_deg`` + k·90° nearest ``near_deg``."""
    return eta_deg + 90.0 * round((near_deg - eta_deg) / 90.0)


def update_track(
    track: Track | None,
    eta_deg: float | None,
    eta_room_deg: float | None,
    params: TrackParams | None = None,
    pairs: int = 1,
    others_deg: tuple[float, ...] = (),
) -> tuple[Track | None, float | None]:
    """One frame: the new track and the tracked η in degrees (None: nothing to report).

    ``eta_deg``: this frame's η (eq. 10), None without a detection; ``eta_room_deg``: eq. 10
    of a horizontal layout VP, None when the layout was not seen (the tracks then hold
    their last η while they last); ``pairs``: the corner pairs the detection rests on;
    ``others_deg``: η of the frame's other obstacles, best supported first. Each obstacle
    of the frame keeps a track of its own (the nearest within ``gate_deg``, each track
    taken once), so a piece seen beside the one that drives η is already confirmed when
    it comes to drive it, and the reported track is measured, not predicted, while the
    frame's first obstacle is another. Only the frame's first obstacle decides which track
    is reported.
    """
    p = params or TrackParams()
    if eta_deg is None or eta_room_deg is None:
        if track is None:
            return None, None
        return _predict(track, eta_room_deg, p)
    tracks = () if track is None else (track, *track.beside)
    measured: dict[int, Track] = {}  # index into tracks -> the track a detection renewed
    newcomers: list[Track] = []
    primary: Track | None = None
    for k, eta in enumerate((eta_deg, *others_deg)):
        rel = wrap90(eta - eta_room_deg)
        gap, i = min(((_gap(rel, t), i) for i, t in enumerate(tracks) if i not in measured),
                     default=(math.inf, None))
        if gap <= p.gate_deg:
            measured[i] = renewed = _renew(tracks[i], rel, eta, eta_room_deg, p)
        elif k and any(_gap(rel, t) <= p.gate_deg for t in (*measured.values(), *newcomers)):
            continue  # another reading of an obstacle this frame already measured
        else:
            renewed = Track(rel, eta)
            newcomers.append(renewed)
        if k == 0:
            primary = renewed
    after = [measured.get(i) or _aged(t, eta_room_deg, p) for i, t in enumerate(tracks)]
    old = after[0] if tracks else None  # the reported track, this frame (None: ended)
    # The frame's obstacle is reported once confirmed (or seen twice in the frame), unless
    # a confirmed track goes on beside it, measured beside it or predicted.
    reportable = old is not None and old.confirmed(p)
    main = old if reportable and not primary.confirmed(p) else primary
    # Two corner pairs of one frame that agree are two measurements, as two frames are.
    confirmed = main.confirmed(p) or (main is primary and 0 < p.report_pairs <= pairs)
    rest = tuple(t for t in (*after, *newcomers) if t is not None and t is not main)
    main = replace(main, beside=rest)
    return main, (main.eta_deg if confirmed else None)


def _gap(rel_deg: float, t: Track) -> float:
    """How far a face angle ``rel_deg`` is from track ``t``'s, degrees, modulo 90°."""
    return abs(wrap90(rel_deg - t.rel_deg))


def _renew(t: Track, rel: float, eta_deg: float, eta_room_deg: float, p: TrackParams) -> Track:
    """Track ``t`` measured again at face angle ``rel`` (η ``eta_deg``): its angle moves
    by ``smoothing`` of the difference, and eq. 9's OVP it follows is kept unless the other
    one is clearly nearer the centre."""
    kept = _nearest_branch(eta_deg, t.eta_deg)
    branch = eta_deg if abs(eta_deg) + p.switch_margin_deg < abs(kept) else kept
    new_rel = wrap90(t.rel_deg + p.smoothing * wrap90(rel - t.rel_deg))
    return Track(new_rel, _nearest_branch(new_rel + eta_room_deg, branch), t.hits + 1, 0)


def _aged(t: Track, eta_room_deg: float | None, p: TrackParams) -> Track | None:
    """Track ``t`` a frame without a detection of its own: a confirmed one predicted from
    the room for up to ``max_missed`` frames, an unconfirmed one waiting through at most
    ``confirm_window − confirm_hits`` (the defaults: one); else None."""
    if t.confirmed(p):
        if t.missed >= p.max_missed:
            return None
        eta = t.eta_deg
        if eta_room_deg is not None:
            eta = _nearest_branch(t.rel_deg + eta_room_deg, t.eta_deg)
        return Track(t.rel_deg, eta, t.hits, t.missed + 1)
    if t.missed >= p.confirm_window - p.confirm_hits:
        return None
    return Track(t.rel_deg, t.eta_deg, t.hits, t.missed + 1)


def _predict(track: Track, eta_room_deg: float | None, p: TrackParams
             ) -> tuple[Track | None, float | None]:
    """A frame without a detection: every track predicted from the room, or dropped. The
    reported track goes on while it lasts; after it, the first confirmed track left, else
    the first one waiting (unreported)."""
    kept = [t for t in (_aged(t, eta_room_deg, p) for t in (track, *track.beside)) if t]
    if not kept:
        return None, None
    main = next((t for t in kept if t.confirmed(p)), kept[0])
    main = replace(main, beside=tuple(t for t in kept if t is not main))
    return main, (main.eta_deg if main.confirmed(p) else None)
