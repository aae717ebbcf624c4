"""The turning rule of the paper's Table II, as a pure function.

| D_t      | action                     |
|----------|----------------------------|
| D_t < 0  | turn left by  |D_t|        |
| D_t > 0  | turn right by |D_t|        |
| D_t = 0  | go forward                 |

with ``D_t ≈ η_t`` (eq. 11). Additions a vehicle needs: the turn per decision is capped
at a maximum turning angle (the paper's preset maximum), ``|η|`` within a deadband counts
as ``D_t = 0`` (η never is exactly 0 on real images), and the turn is executed as a yaw
rate ``turn / turn_time_s`` capped at ``max_yaw_rate_deg_s``. Sign: positive yaw rate turns
right (body FRD / NED, as PX4 and MAVSDK use).

Across frames, :func:`confirm_reversal` adds one more rule: a turn against the last turn
made needs two frames in a row asking for it. Near convergence a single frame can read M
on the wrong side of the centre; alone it must not swing the vehicle back.

In forward flight the same rule is flown as a heading (:func:`avoidance_heading`): the
heading the frame was taken at plus η, its turn capped at ``max_turn_deg``, held in closed
loop on the heading the autopilot reports (:func:`heading_rate`). Additions beyond the
paper, each measured in ``companion sim --scenario approach`` (docs/flight.md):

- a pass-off angle: the heading is at least ``min_avoid_deg`` off the course, on the
  face's side. A face only 12°–18° off the course gains too little room when the vehicle
  aligns with it, and the vehicle clipped the obstacle;
- the side kept: once a pass-off has been taken on one side of the course, a frame that
  would take it on the other side is not acted on until the vehicle is back on the
  course (without ``resume_course``: until the obstacle is passed) and, if an obstacle's
  foot was measured, has flown past it along the course, unless the frame measures an
  obstacle in the flight path (:func:`keeps_side`). Beside a box just passed, one wrong
  reading (a rug's corner over a floor seam, read as the box's foot) otherwise turned
  the vehicle across the course into it; and a vehicle that lost the box from view while
  turning away resumed the course short of it, saw its other face, and turned into it;
- optionally (``unconfirmed: ranged``), a detection confirmed: a frame's η the tracker has
  not confirmed sets no heading until its obstacle's floor contact is measured
  (:func:`turns_for`); it still counts as an obstacle in view, so the course does not
  resume toward it. Half the turns for one-frame false alarms (a striped rug, a shadow)
  go, but an obstacle seen on scattered frames is turned for late or never, so the
  default flies every frame's η, as the paper;
- the course resumed: Table II aligns the heading with the face, up to 45° off the course
  the pilot set, and nothing in the paper ever turns back, so the vehicle left the
  obstacle behind and flew on into the side wall. Once no obstacle has been in view for
  ``resume_after_s`` (and, flying slower, for as far as full speed covers in that time:
  ``supervisor.supervise``), the heading goes back to the course (the heading offboard
  engaged with) at most ``resume_max_rate_deg_s``;
- the least turn (``least_turn``): once an obstacle's feet are measured, the heading
  flown to pass it is the one nearest the course, but at least ``min_avoid_deg`` off it,
  whose straight path keeps ``resume_clearance_m`` from them (:func:`clearing_heading`),
  when that is nearer the course than the face's. Aligned with a face 42° off the
  course, the vehicle carried on across the room into furniture beside the path after
  it had cleared the obstacle.

Range, when the camera height is known (:mod:`~companion.vision.ranging`, not in the
paper): an obstacle whose floor contact is measured beyond ``act_within_m`` is not turned
for (:func:`obstacle_matters`): far away, its face says little about the path the vehicle
will fly; and the forward speed is scaled by :func:`path_speed_scale` from the distance to
the nearest obstacle in the flight path, down to a stop at ``stop_within_m``, so that a
late detection is turned away from rather than flown into.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from companion.config import PolicyConfig

__all__ = ["TurnCommand", "TurnHistory", "avoidance_heading", "clearing_heading",
           "confirm_reversal", "decide_frame", "decide_turn", "heading_rate", "keeps_side",
           "obstacle_matters", "pass_side", "path_speed_scale", "resume_path_clearance_m",
           "steering_eta", "turns_for", "wrap_deg"]

Action = Literal["left", "right", "forward", "hold"]


@dataclass(frozen=True)
class TurnCommand:
    """One decision: ``action``, the signed ``turn_deg`` it asks for (right positive), and
    the ``yaw_rate_deg_s`` that executes it."""

    action: Action
    turn_deg: float
    yaw_rate_deg_s: float


def steering_eta(eta_deg: float | None, eta_tracked_deg: float | None,
                 policy: PolicyConfig, range_m: float | None = None) -> float | None:
    """The η to steer by, or None: the frame's (eq. 10), or with ``steer_by_track`` the
    tracked one (it holds eq. 9's choice of face and bridges dropouts); then a detection
    the tracker has not confirmed is steered by only as :func:`turns_for` says (without
    ``steer_by_track`` the supervisor applies that rule in forward flight)."""
    if eta_tracked_deg is not None:  # confirmed
        return eta_tracked_deg if policy.steer_by_track else eta_deg
    if eta_deg is None or not policy.steer_by_track:
        return eta_deg
    return eta_deg if turns_for(False, range_m, policy) else None


def turns_for(confirmed: bool, range_m: float | None, policy: PolicyConfig) -> bool:
    """Whether a detection is turned for: one the tracker has ``confirmed`` (a second
    frame, or a second corner pair of its frame, agrees on it) always; one it has not as
    ``unconfirmed`` says: ``fly`` always, as the paper does; ``ranged`` once its floor
    contact is measured (``range_m``, m; :func:`obstacle_matters` still applies
    ``act_within_m``); ``wait`` never. Most one-frame false alarms had no foot measured,
    and flown they turn the vehicle off its course (docs/flight.md)."""
    return (confirmed or policy.unconfirmed == "fly"
            or (policy.unconfirmed == "ranged" and range_m is not None))


def obstacle_matters(range_m: float | None, policy: PolicyConfig) -> bool:
    """Whether an obstacle whose floor contact is ``range_m`` away (m; None: not measured)
    is to be turned for: unless it is measured beyond ``act_within_m`` (0: always)."""
    return range_m is None or policy.act_within_m <= 0.0 or range_m <= policy.act_within_m


def path_speed_scale(path_m: float | None, policy: PolicyConfig) -> float:
    """The share (0..1) of the forward speed to fly with the nearest obstacle in the flight
    path ``path_m`` ahead (m; None or inf: none known): 1 from ``slow_within_m`` on, falling
    linearly to 0 at ``stop_within_m``. ``slow_within_m`` 0 turns the rule off."""
    if path_m is None or not math.isfinite(path_m) or policy.slow_within_m <= 0.0:
        return 1.0
    if path_m <= policy.stop_within_m:
        return 0.0
    span = policy.slow_within_m - policy.stop_within_m
    return 1.0 if span <= 0.0 else min(1.0, (path_m - policy.stop_within_m) / span)


def decide_turn(
    eta_deg: float | None, policy: PolicyConfig, scene_understood: bool = True,
    range_m: float | None = None,
) -> TurnCommand:
    """Table II: η (degrees, right positive, or None) → :class:`TurnCommand`.

    - no scene understanding (no layout found, e.g. a blank or blurred frame) → ``hold``:
      nothing to act on, yaw rate 0;
    - no non-Manhattan obstacle (``eta_deg is None``), one measured farther than
      ``act_within_m`` (``range_m``, :func:`obstacle_matters`), or ``|η| <= deadband``
      → ``forward``;
    - otherwise turn toward η's side by ``min(|η|, max_turn_deg)``.
    """
    if not scene_understood or (eta_deg is not None and not math.isfinite(eta_deg)):
        return TurnCommand("hold", 0.0, 0.0)
    if not obstacle_matters(range_m, policy):
        eta_deg = None
    if eta_deg is None or abs(eta_deg) <= policy.deadband_deg:
        return TurnCommand("forward", 0.0, 0.0)
    turn = math.copysign(min(abs(eta_deg), policy.max_turn_deg), eta_deg)
    rate = turn / policy.turn_time_s
    rate = math.copysign(min(abs(rate), policy.max_yaw_rate_deg_s), turn)
    return TurnCommand("right" if turn > 0 else "left", turn, rate)


def wrap_deg(angle_deg: float) -> float:
    """An angle in degrees, wrapped to [-180, 180)."""
    return (angle_deg + 180.0) % 360.0 - 180.0


def pass_side(eta_deg: float, heading_deg: float, course_deg: float) -> int:
    """The side of the course (+1 right, -1 left) an obstacle face seen at bearing
    ``eta_deg`` from a frame taken at ``heading_deg`` is passed on: where the face points
    (:func:`avoidance_heading`); +1 for a face along the course."""
    return 1 if wrap_deg(heading_deg + eta_deg - course_deg) >= 0.0 else -1


def keeps_side(side: int, kept_side: int, path_m: float | None,
               policy: PolicyConfig) -> bool:
    """Whether a frame that would pass on ``side`` (:func:`pass_side`) is held back, the
    pass-off having been taken on ``kept_side`` (0: none since the course was last flown
    past the obstacle, ``supervisor.supervise``):
    with ``keep_pass_side``, a frame asking for the other side is held back unless it
    measures an obstacle in the flight path near enough to slow the vehicle
    (``path_m``, m; None: not measured; :func:`path_speed_scale`). The pass-off side was
    chosen while the obstacle was ahead; beside it, the view is of its flank and of what
    lies past it, and a reading there that turned across the course would turn into it
    (module docstring)."""
    if not policy.keep_pass_side or kept_side == 0 or side == kept_side:
        return False
    return path_speed_scale(path_m, policy) >= 1.0  # nothing slows it: the side holds


def avoidance_heading(eta_deg: float, heading_deg: float, course_deg: float,
                      policy: PolicyConfig) -> float:
    """The heading (deg, right positive) to fly for an obstacle face seen at bearing
    ``eta_deg`` from a frame taken at ``heading_deg``, on a flight along ``course_deg``.

    Table II (eq. 11) turns by η: toward ``heading + η``, at most ``max_turn_deg`` per
    decision. Beyond the paper, the heading is held at least ``min_avoid_deg`` off the
    course, on the side the face points to (module docstring).
    """
    face = wrap_deg(heading_deg + eta_deg - course_deg)  # the face's direction off course
    offset = pass_side(eta_deg, heading_deg, course_deg) * max(abs(face), policy.min_avoid_deg)
    turn = wrap_deg(course_deg + offset - heading_deg)
    turn = math.copysign(min(abs(turn), policy.max_turn_deg), turn)
    return wrap_deg(heading_deg + turn)


RESUME_HORIZON_S = 8.0
"""How far ahead :func:`resume_path_clearance_m` predicts the resume at least: from 45° off
the course at ``resume_max_rate_deg_s`` (10°/s) the heading is back on it in about 5 s; the
rest is the straight flight after it. Beyond it, the prediction goes on until it is past
every contact along the course, for at most :data:`RESUME_HORIZON_MAX_S`."""

RESUME_HORIZON_MAX_S = 60.0


def resume_path_clearance_m(contacts_m: tuple[tuple[float, float], ...], along_m: float,
                            across_m: float, heading_off_deg: float, speed_m_s: float,
                            policy: PolicyConfig, horizon_s: float = RESUME_HORIZON_S,
                            dt_s: float = 0.1) -> float:
    """The nearest the resume would pass to a remembered floor contact (m; inf: none).

    ``contacts_m``: floor contacts seen earlier, each (metres along the course, metres
    right of it) in the frame whose origin is where offboard engaged; the vehicle is at
    (``along_m``, ``across_m``) with its heading ``heading_off_deg`` right of the course.
    The resume is predicted as :func:`heading_rate` flies it back to the course, at most
    ``resume_max_rate_deg_s``, at ``speed_m_s``, for ``horizon_s`` and on until it is
    ``resume_clearance_m`` past the farthest contact along the course (a foot on the
    course far ahead is met however late), the position sampled every ``dt_s``. Not in
    the paper: a vehicle that lost an obstacle from view while turning away from it
    resumed the course into it, where its feet had been measured (docs/flight.md).
    """
    if not contacts_m:
        return math.inf
    path = [(along_m, across_m)]
    heading = heading_off_deg
    past = max(c[0] for c in contacts_m) + policy.resume_clearance_m
    least, most = max(1, round(horizon_s / dt_s)), round(RESUME_HORIZON_MAX_S / dt_s)
    while len(path) <= least or (along_m < past and len(path) <= most):
        heading += heading_rate(0.0, heading, policy, policy.resume_max_rate_deg_s) * dt_s
        h = math.radians(heading)
        along_m += speed_m_s * dt_s * math.cos(h)
        across_m += speed_m_s * dt_s * math.sin(h)
        path.append((along_m, across_m))
    gaps = np.asarray(path)[:, None, :] - np.asarray(contacts_m, float)[None, :, :]
    return float(np.sqrt((gaps ** 2).sum(axis=2)).min())


def clearing_heading(contacts_m: tuple[tuple[float, float], ...], along_m: float,
                     across_m: float, course_deg: float, target_deg: float,
                     policy: PolicyConfig, step_deg: float = 1.0) -> float:
    """The heading (deg, right positive) nearest the course, from ``min_avoid_deg`` off it
    to ``target_deg``, whose straight path keeps ``resume_clearance_m`` from every floor
    contact remembered (a contact already nearer is not to be neared); ``target_deg`` if
    none does.

    ``contacts_m`` and the vehicle's position (``along_m``, ``across_m``) are as in
    :func:`resume_path_clearance_m`; headings are tried every ``step_deg`` off the course,
    on the side of ``target_deg``. Not in the paper: Table II aligns the vehicle with the
    obstacle's face, up to 45° off the course, however little of that turn its feet need;
    the vehicle then drifted across the room into furniture beside the path
    (docs/flight.md). With the feet measured, no more of that turn is flown than passes
    them, and never less than the pass-off angle: the feet one view measures need not be
    all of the piece (a face seen whole, its neighbour hidden), and flown by the least
    turn alone, a vehicle passed at half the clearance and met pieces measured in part.
    The straight path is a fair test: from a heading farther off the course, the turn
    toward it swings the vehicle wide of the course, away from the feet it passes.
    """
    target_off = wrap_deg(target_deg - course_deg)
    least = min(policy.min_avoid_deg, abs(target_off))
    if not contacts_m or policy.resume_clearance_m <= 0.0 or abs(target_off) <= least:
        return target_deg
    n = int((abs(target_off) - least) // step_deg)
    offsets = np.append(least + np.arange(n + 1) * step_deg, abs(target_off))
    angles = np.radians(math.copysign(1.0, target_off) * offsets)
    heading = np.stack([np.cos(angles), np.sin(angles)], axis=1)  # H×2, along and across
    gaps = np.asarray(contacts_m, float) - (along_m, across_m)  # C×2
    now = np.hypot(gaps[:, 0], gaps[:, 1])
    ahead = np.maximum(gaps @ heading.T, 0.0)  # C×H: how far along each path it is nearest
    nearest = np.hypot(gaps[:, 0, None] - ahead * heading[:, 0],
                       gaps[:, 1, None] - ahead * heading[:, 1])
    clear = (nearest >= np.minimum(now, policy.resume_clearance_m)[:, None] - 1e-9).all(axis=0)
    first = int(np.argmax(clear))
    if not clear[first]:
        return target_deg
    return wrap_deg(course_deg + float(np.degrees(angles[first])))


def heading_rate(target_deg: float, heading_deg: float, policy: PolicyConfig,
                 max_rate_deg_s: float | None = None) -> float:
    """Yaw rate (deg/s, right positive) from ``heading_deg`` toward ``target_deg``: the
    error over ``turn_time_s`` (Table II's rate), capped at ``max_rate_deg_s`` (default
    ``max_yaw_rate_deg_s``); 0 within the deadband."""
    error = wrap_deg(target_deg - heading_deg)
    if abs(error) <= policy.deadband_deg:
        return 0.0
    cap = policy.max_yaw_rate_deg_s if max_rate_deg_s is None else max_rate_deg_s
    rate = error / policy.turn_time_s
    return math.copysign(min(abs(rate), cap), rate)


@dataclass(frozen=True)
class TurnHistory:
    """What :func:`confirm_reversal` remembers: the last turn made (``left``/``right``) and
    what the previous frame asked for, before confirmation."""

    last_turn: Action | None = None
    previous: Action | None = None


def confirm_reversal(command: TurnCommand, history: TurnHistory
                     ) -> tuple[TurnCommand, TurnHistory]:
    """The frame's command after the reversal rule, and the history for the next frame.

    A ``left``/``right`` opposite to ``history.last_turn`` is flown only when the previous
    frame asked for the same; otherwise this frame goes ``forward`` (yaw rate 0).
    """
    asked = command.action
    if (asked in ("left", "right") and history.last_turn not in (None, asked)
            and history.previous != asked):
        command = TurnCommand("forward", 0.0, 0.0)
    turned = command.action if command.action in ("left", "right") else history.last_turn
    return command, TurnHistory(last_turn=turned, previous=asked)


def decide_frame(eta_deg: float | None, eta_tracked_deg: float | None, policy: PolicyConfig,
                 history: TurnHistory, scene_understood: bool = True,
                 range_m: float | None = None
                 ) -> tuple[float | None, TurnCommand, TurnHistory]:
    """One frame's decision, as every caller makes it: the η to steer by
    (:func:`steering_eta`), Table II on it (:func:`decide_turn`), then the reversal rule
    (:func:`confirm_reversal`). Returns that η, the command and the history for the next
    frame."""
    eta = steering_eta(eta_deg, eta_tracked_deg, policy, range_m)
    command, history = confirm_reversal(decide_turn(eta, policy, scene_understood, range_m),
                                        history)
    return eta, command, history
