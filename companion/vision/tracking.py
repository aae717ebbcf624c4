"""One obstacle followed across frames: η that does not flip, drop out or false-alarm.

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
  (another piece, or the real one after a false pair) without waiting out the coast.

Inputs are plain values (the frame's η and the layout's η_room, degrees); the camera's
yaw never has to be known, so a recording is tracked as well as a flight. Pure functions;
:class:`~companion.vision.pipeline.Pipeline` holds the state.
"""

from __future__ import annotations

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
    ``earlier``: unconfirmed tracks of the last frames that this one disagreed with, each
    still waiting for its second frame (``TrackParams.confirm_window``); the first to get
    it replaces this one."""

    rel_deg: float
    eta_deg: float
    hits: int = 1
    missed: int = 0
    earlier: tuple[Track, ...] = ()

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
) -> tuple[Track | None, float | None]:
    """One frame: the new track and the tracked η in degrees (None: nothing to report).

    ``eta_deg``: this frame's η (eq. 10), None without a detection; ``eta_room_deg``: eq. 10
    of a horizontal layout VP, None when the layout was not seen (the track then holds its
    last η while it lasts); ``pairs``: the corner pairs the detection rests on.
    """
    p = params or TrackParams()
    if eta_deg is not None and eta_room_deg is not None:
        rel = wrap90(eta_deg - eta_room_deg)
        # The track, and the unconfirmed ones still waiting before or beside it.
        waiting = () if track is None else (track, *track.earlier)

        def gap(t: Track) -> float:
            return abs(wrap90(rel - t.rel_deg))

        t = min(waiting, key=gap, default=None)
        if t is not None and gap(t) <= p.gate_deg:
            # The same obstacle: keep the OVP being followed unless the other one is
            # clearly nearer the centre.
            kept = _nearest_branch(eta_deg, t.eta_deg)
            branch = eta_deg if abs(eta_deg) + p.switch_margin_deg < abs(kept) else kept
            new_rel = wrap90(t.rel_deg + p.smoothing * wrap90(rel - t.rel_deg))
            eta = _nearest_branch(new_rel + eta_room_deg, branch)
            track = Track(new_rel, eta, t.hits + 1, 0)
        elif track is not None and track.confirmed(p) and track.missed < p.max_missed:
            # Another obstacle, a false alarm, or this track was the false one: it is
            # predicted on, and the newcomer waits beside it for a second frame.
            coasting, eta = _predict(track, eta_room_deg, p)
            return replace(coasting, earlier=(Track(rel, eta_deg), *coasting.earlier)), eta
        else:
            track = Track(rel, eta_deg, earlier=_waiting(waiting, p))
        measured_twice = 0 < p.report_pairs <= pairs
        return track, (track.eta_deg if track.confirmed(p) or measured_twice else None)
    if track is None:
        return None, None
    return _predict(track, eta_room_deg, p)


def _waiting(tracks: tuple[Track, ...], p: TrackParams) -> tuple[Track, ...]:
    """Unconfirmed ``tracks`` a frame older: each waits through at most ``confirm_window
    − confirm_hits`` frames without it (the defaults: one)."""
    return tuple(replace(t, missed=t.missed + 1, earlier=()) for t in tracks
                 if not t.confirmed(p) and t.missed < p.confirm_window - p.confirm_hits)


def _predict(track: Track, eta_room_deg: float | None, p: TrackParams
             ) -> tuple[Track | None, float | None]:
    """A frame without a consistent detection: predict from the room, or drop the track
    (an unconfirmed one waits on, unreported, while it can still be confirmed; so do the
    newcomers waiting beside a confirmed one)."""
    if not track.confirmed(p) or track.missed >= p.max_missed:
        waiting = _waiting((track, *track.earlier), p)  # a confirmed track is not among them
        return (replace(waiting[0], earlier=waiting[1:]) if waiting else None), None
    eta = track.eta_deg
    if eta_room_deg is not None:
        eta = _nearest_branch(track.rel_deg + eta_room_deg, track.eta_deg)
    track = Track(track.rel_deg, eta, track.hits, track.missed + 1, _waiting(track.earlier, p))
    return track, eta
