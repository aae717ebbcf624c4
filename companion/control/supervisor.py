"""When the companion may command the vehicle, and what it sends: a pure state machine.

No MAVSDK, sockets or clocks here: :func:`supervise` takes the previous state, what the
vehicle reports, the newest vision decision and the time, and returns the next state, the
setpoint to stream and the offboard request to make. ``control/offboard.py`` is the shell
that feeds it and carries its answers out over MAVLink.

States::

    disabled ──enable()──► waiting ──armed, in air, vision fresh──► engaging ──OFFBOARD in
       ▲                     ▲  ▲                                      │       heartbeat
       │                     │  └──not confirmed in confirm_timeout_s──┘          ▼
       └── pilot/failsafe left OFFBOARD, vision stalled > hold_after_s,  ◄──── active
           link lost while engaged (needs enable() again: never a silent resume)

``link_lost`` is entered from any state while the autopilot is not connected.

What ``active`` streams is a body-frame velocity setpoint: forward speed and yaw rate,
vertical velocity 0 (PX4 holds the altitude; vision never commands it):

- yaw rate, hovering (``forward_speed_m_s`` 0): Table II's turn per decision
  (:func:`yaw_rate_setpoint`), as in the paper's Table IV;
- yaw rate, flying forward: toward the heading Table II asks for, at least
  ``policy.min_avoid_deg`` off the course (the heading offboard engaged with), on the
  side first taken until the vehicle is back on the course and past the last obstacle
  foot measured, if any (``policy.keep_pass_side``),
  and back to the course once no obstacle has been seen for ``policy.resume_after_s``
  (:func:`~companion.control.policy.avoidance_heading`, ``heading_rate``), unless the
  path back (predicted by ``policy.resume_path_clearance_m``) would pass within
  ``policy.resume_clearance_m`` of a floor contact measured earlier, of the floor between
  two of an obstacle's contacts, or of the floor taken to be covered behind them
  (``policy.hidden_depth_m``, :func:`remembered_contacts`): then the pass-off heading is
  flown, held off the course or, back on it with such a foot ahead, turned to again;
  with ``policy.least_turn`` that heading is the least turn off the course (at least
  ``policy.min_avoid_deg``) whose straight path keeps ``resume_clearance_m`` from the
  contacts remembered, when that is less than the face's
  (:func:`~companion.control.policy.clearing_heading`).
  With ``policy.resume_in_view``, an obstacle still in view whose feet the newest frame
  that saw it measured holds the vehicle off the course only while that path back does
  not clear them: it neither flies on away from the course once clear of it, nor turns
  for a piece whose measured feet leave the course clear. A frame whose scene
  is not understood (``hold``) stops the vehicle but not this turn, which rests on
  earlier frames and the reported heading: stopped and still, the view would never change;
- forward speed (:func:`forward_speed_setpoint`): ``offboard.forward_speed_m_s`` while
  the scene is understood, also during a turn (less ``turn_slowdown`` × the share of
  ``max_turn_deg`` still to turn, when that is set: 0 by default, docs/flight.md); 0 at
  once on ``hold`` (scene not understood) and when vision is older than
  ``stale_after_s``. With range, it is scaled by ``policy.path_speed_scale`` from the
  distance to the nearest obstacle in the path (:func:`path_ahead`), and an obstacle
  measured beyond ``policy.act_within_m`` sets no heading to pass it. The course resumes
  only once the distance full speed covers in ``resume_after_s`` has also been flown.
  Speed rises no faster than ``forward_accel_m_s2`` (from 0 on engaging, and after every
  stop), and falls at once: PX4's own acceleration limits shape the braking, the
  companion never delays it. Until the autopilot has reported a heading, the yaw rate is
  the hovering one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from companion.config import OffboardConfig, PolicyConfig
from companion.control.policy import (
    TurnCommand,
    avoidance_heading,
    clearing_heading,
    heading_rate,
    keeps_side,
    obstacle_matters,
    pass_side,
    path_speed_scale,
    resume_path_clearance_m,
    turns_for,
    wrap_deg,
)

__all__ = [
    "Decision", "Step", "SupervisorState", "VehicleStatus", "enable", "forward_speed_setpoint",
    "initial_state", "path_ahead", "remembered_contacts", "supervise", "turn_ends_at",
    "yaw_rate_setpoint",
]

StateName = Literal["disabled", "waiting", "engaging", "active", "link_lost"]
# start: zero setpoint, then ask for OFFBOARD. stop: zero, then ask for Hold.
# release: stop streaming without any mode change (the pilot or a failsafe owns the mode).
Request = Literal["start", "stop", "release"] | None


@dataclass(frozen=True)
class VehicleStatus:
    """What the autopilot reports (heartbeat and EXTENDED_SYS_STATE)."""

    connected: bool
    armed: bool = False
    in_air: bool = False
    offboard: bool = False  # the heartbeat's mode is OFFBOARD
    yaw_deg: float | None = None  # heading (ATTITUDE), right positive; None if not known


@dataclass(frozen=True)
class Decision:
    """The newest turn decision from the vision pipeline, made at ``t_s`` (monotonic s)."""

    t_s: float
    command: TurnCommand
    eta_deg: float | None = None
    heading_deg: float | None = None  # the vehicle's heading when the frame was taken
    range_m: float | None = None  # to the obstacle's floor contact; None: not measured
    path_m: float | None = None  # to the nearest obstacle in the path; inf: none; None: not
    #                              measured (ranging.path_distance)
    confirmed: bool = True  # the tracker confirms the obstacle (policy.turns_for)
    contacts_m: tuple[tuple[float, float], ...] = ()  # the obstacles' floor contacts, and
    #   the floor taken to be covered behind them (policy.hidden_depth_m), m ahead and
    #   right of the camera (Estimate.footprint_ahead_right_m)


@dataclass(frozen=True)
class SupervisorState:
    name: StateName
    enabled: bool  # the latch: cleared by every release, set again only by enable()
    vision_fresh: bool = False
    start_t_s: float | None = None  # when offboard was last requested
    engaged_before_loss: bool = False
    forward_m_s: float = 0.0  # the forward speed last streamed (the ramp starts from it)
    tick_t_s: float | None = None  # when it was streamed
    course_deg: float | None = None  # the heading when offboard engaged: the pilot's course
    obstacle_t_s: float | None = None  # when a decision last saw an obstacle
    seen_ranged: bool = False  # and whether that decision measured its floor contact
    target_deg: float | None = None  # the heading flown to pass it
    target_from_t_s: float | None = None  # the decision that set it
    pass_side: int = 0  # the side of the course it passes on (+1 right, -1 left; 0: none)
    path_m: float | None = None  # the nearest obstacle in the path, dead-reckoned to now
    path_t_s: float | None = None  # the decision that measured it
    flown_since_seen_m: float = 0.0  # forward distance streamed since obstacle_t_s
    course_progress_m: float = 0.0  # flown along the course since offboard engaged
    foot_abeam_m: float | None = None  # course_progress_m at which the last obstacle foot
    #                                   measured is abeam at the latest (its range ahead)
    course_offset_m: float = 0.0  # flown right of the course since offboard engaged
    contacts_m: tuple[tuple[float, float], ...] = ()  # floor contacts measured and not yet
    #                  passed: (course_progress_m, course_offset_m) of each, dead-reckoned
    contacts_t_s: float | None = None  # the decision that last added to them


@dataclass(frozen=True)
class Step:
    """One tick's answer: the next state, whether to stream a setpoint and which (yaw rate,
    forward speed), an offboard start/stop to request, and the state-change messages for
    the pilot."""

    state: SupervisorState
    stream: bool
    yaw_rate_deg_s: float
    request: Request
    events: tuple[str, ...]
    forward_m_s: float = 0.0


def initial_state(config: OffboardConfig) -> SupervisorState:
    return SupervisorState("waiting" if config.enabled else "disabled", config.enabled)


def yaw_rate_setpoint(decision: Decision | None, now_s: float, stale_after_s: float,
                      policy: PolicyConfig) -> float:
    """Yaw rate (deg/s, right positive) to fly at ``now_s`` for the newest decision.

    The decision's rate, clamped to ``max_yaw_rate_deg_s``, flown only until its turn
    (clamped to ``max_turn_deg``, Table II's cap) is complete; then 0. A decision older
    than ``stale_after_s`` gives 0 at once, so a stalled camera never leaves a turn flying.
    """
    if decision is None or now_s - decision.t_s > stale_after_s:
        return 0.0
    end_s = turn_ends_at(decision, policy)
    if end_s is None or not now_s < end_s:  # no turn, or it is complete
        return 0.0
    rate = decision.command.yaw_rate_deg_s
    return math.copysign(min(abs(rate), policy.max_yaw_rate_deg_s), rate)


def turn_ends_at(decision: Decision | None, policy: PolicyConfig) -> float | None:
    """When (monotonic s) the decision's turn, at its rate clamped to ``max_yaw_rate_deg_s``,
    reaches its angle clamped to ``max_turn_deg`` (Table II's cap): from then
    :func:`yaw_rate_setpoint` gives 0. None if it asks for no turn. The shell ticks then,
    so the cap holds to the millisecond rather than to the next setpoint tick."""
    if decision is None:
        return None
    rate = decision.command.yaw_rate_deg_s
    if rate == 0.0 or not math.isfinite(rate):
        return None
    rate = min(abs(rate), policy.max_yaw_rate_deg_s)
    return decision.t_s + min(abs(decision.command.turn_deg), policy.max_turn_deg) / rate


def forward_speed_setpoint(decision: Decision | None, now_s: float, prev_m_s: float,
                           dt_s: float, config: OffboardConfig) -> float:
    """Body-frame forward speed (m/s) to fly at ``now_s`` for the newest decision.

    ``config.forward_speed_m_s`` while the decision is fresh and the scene understood (any
    action but ``hold``), reached from ``prev_m_s`` (streamed ``dt_s`` ago) at no more
    than ``forward_accel_m_s2``; 0 at once for ``hold``, no decision, or one older than
    ``stale_after_s``.
    """
    if (decision is None or now_s - decision.t_s > config.stale_after_s
            or decision.command.action == "hold"):
        return 0.0
    ramped = max(prev_m_s, 0.0) + config.forward_accel_m_s2 * max(dt_s, 0.0)
    return min(config.forward_speed_m_s, ramped)


def supervise(prev: SupervisorState, vehicle: VehicleStatus, decision: Decision | None,
              now_s: float, config: OffboardConfig, policy: PolicyConfig) -> Step:
    """Advance the state machine by one tick (module docstring has the diagram)."""
    events: list[str] = []
    age_s = math.inf if decision is None else now_s - decision.t_s
    fresh = age_s <= config.stale_after_s
    engaged = prev.name in ("engaging", "active")
    if fresh != prev.vision_fresh and (engaged or fresh):
        events.append("vision recovered" if fresh else "vision stalled: stop, yaw rate 0")
    state = replace(prev, vision_fresh=fresh)

    def step(name: StateName, stream=False, rate=0.0, request: Request = None, **kw) -> Step:
        if name != prev.name and name in ("waiting", "disabled") and prev.name == "link_lost":
            events.append("autopilot link restored" + (
                ": offboard stays off until re-enabled" if name == "disabled" else ""))
        return Step(replace(state, name=name, forward_m_s=0.0, tick_t_s=now_s, **kw), stream,
                    rate, request, tuple(events))

    def fly(name: StateName) -> Step:
        """Stream the yaw rate (module docstring) and the forward speed, ramping from the
        last tick's."""
        engaged_now = prev.name != "active"
        was = 0.0 if engaged_now else prev.forward_m_s
        dt = 0.0 if prev.tick_t_s is None else now_s - prev.tick_t_s
        flown_m = max(was, 0.0) * max(dt, 0.0)  # since the last tick, at the speed streamed
        forward = forward_speed_setpoint(decision, now_s, was, dt, config)
        course = vehicle.yaw_deg if engaged_now else prev.course_deg
        # An engagement starts with nothing seen: what an earlier one saw, the heading it
        # flew to pass it and its side belong to another course and place in the room.
        mem = replace(prev, **_FORGOTTEN_ON_ENGAGING) if engaged_now else prev
        keep = {"obstacle_t_s": mem.obstacle_t_s, "seen_ranged": mem.seen_ranged,
                "target_deg": mem.target_deg,
                "target_from_t_s": mem.target_from_t_s, "pass_side": mem.pass_side,
                "foot_abeam_m": mem.foot_abeam_m}
        if config.forward_speed_m_s > 0.0:
            path, path_t = path_ahead(mem, decision, fresh, now_s, flown_m)
            keep = {**keep, "path_m": path, "path_t_s": path_t}
            forward = min(forward, config.forward_speed_m_s * path_speed_scale(path, policy))
        if config.forward_speed_m_s > 0.0 and course is not None and vehicle.yaw_deg is not None:
            off_course = wrap_deg(vehicle.yaw_deg - course)
            progress = mem.course_progress_m + flown_m * math.cos(math.radians(off_course))
            offset = mem.course_offset_m + flown_m * math.sin(math.radians(off_course))
            keep["course_progress_m"], keep["course_offset_m"] = progress, offset
            keep["contacts_m"], keep["contacts_t_s"] = remembered_contacts(
                mem, decision, fresh, course, progress, offset, policy)
            keep = _pass_target(keep, decision, fresh, course, policy)
            target, seen_t = keep.get("target_deg"), keep.get("obstacle_t_s")
            flown = 0.0 if seen_t != mem.obstacle_t_s else mem.flown_since_seen_m + flown_m
            keep["flown_since_seen_m"] = flown
            # The course resumes resume_after_s after the obstacle left the view, and once
            # as far has been flown as that takes at full speed: a vehicle slowed by range
            # has not yet passed what it last saw beside it.
            left_view = seen_t is None or (
                now_s - seen_t >= policy.resume_after_s
                and flown >= policy.resume_after_s * config.forward_speed_m_s - 1e-9)
            # Still in view, once its feet are measured: the vehicle need not fly on away
            # from the course after the path back is seen to be clear of them.
            guarded = policy.resume_course and policy.resume_clearance_m > 0.0
            in_view = (guarded and policy.resume_in_view and not left_view
                       and keep["seen_ranged"] and bool(keep["contacts_m"]))
            clearance = (resume_path_clearance_m(keep["contacts_m"], progress, offset,
                                                 off_course, config.forward_speed_m_s, policy)
                         if guarded and (left_view or in_view) else math.inf)
            passed = left_view or (in_view and clearance >= policy.resume_clearance_m)
            # ... and not onto a path that passes an obstacle foot measured earlier: the
            # obstacle left the view, not the room.
            blocked = passed and clearance < policy.resume_clearance_m
            foot = keep.get("foot_abeam_m")
            if (passed and (foot is None or progress >= foot)
                    and (not policy.resume_course
                         or abs(wrap_deg(course - vehicle.yaw_deg)) <= policy.deadband_deg)):
                # Back on the course and past the last foot measured: the next obstacle
                # picks anew. A vehicle that turned away lost the obstacle from view before
                # passing it, and back on the course it may see the obstacle's other face.
                keep["pass_side"], keep["foot_abeam_m"] = 0, None
            rate = 0.0
            if fresh:  # also in hold: the heading comes from telemetry, not this frame
                if policy.resume_course and passed and not blocked:
                    rate = heading_rate(course, vehicle.yaw_deg, policy,
                                        policy.resume_max_rate_deg_s)
                elif target is not None:
                    if guarded and policy.least_turn:
                        target = clearing_heading(keep["contacts_m"], progress, offset,
                                                  course, target, policy)
                    rate = heading_rate(target, vehicle.yaw_deg, policy)
                    to_turn = abs(wrap_deg(target - vehicle.yaw_deg)) / policy.max_turn_deg
                    # A cap, not a factor on the streamed speed: multiplied in every tick,
                    # it would compound into a crawl set by the tick rate.
                    forward = min(forward, config.forward_speed_m_s
                                  * (1.0 - config.turn_slowdown * min(1.0, to_turn)))
        else:  # hovering: Table II per decision, as in the paper's Table IV
            rate = yaw_rate_setpoint(decision, now_s, config.stale_after_s, policy)
        answer = step(name, stream=True, rate=rate)
        return replace(answer, forward_m_s=forward, state=replace(
            answer.state, forward_m_s=forward, course_deg=course, **keep))

    if not vehicle.connected:
        if prev.name == "link_lost":
            return step("link_lost")
        events.append("autopilot link lost")
        # Stop MAVSDK's own resending; never resume silently after the link returns.
        return step("link_lost", request="release" if engaged else None,
                    enabled=prev.enabled and not engaged, engaged_before_loss=engaged)
    if prev.name == "link_lost":
        return step("waiting" if prev.enabled else "disabled", engaged_before_loss=False)

    if prev.name == "active":
        if not vehicle.offboard:
            events.append("offboard left by pilot or failsafe: released until re-enabled")
            return step("disabled", request="release", enabled=False)
        if not vehicle.in_air:
            events.append("landed: offboard released")
            return step("waiting", request="stop")
        if age_s > config.hold_after_s:
            events.append("vision stalled: Hold, released until re-enabled")
            return step("disabled", request="stop", enabled=False)
        return fly("active")

    if prev.name == "engaging":
        if vehicle.offboard:
            events.append("offboard engaged")
            return fly("active")
        waited = now_s - (prev.start_t_s if prev.start_t_s is not None else now_s)
        if waited > config.confirm_timeout_s or not (vehicle.armed and vehicle.in_air):
            events.append("offboard not confirmed by the autopilot; will retry")
            return step("waiting", request="release")
        return step("engaging", stream=True)  # zero until OFFBOARD shows in the heartbeat

    if prev.name == "waiting":
        if not prev.enabled:
            return step("disabled")
        retry_ok = prev.start_t_s is None or now_s - prev.start_t_s >= config.retry_after_s
        if vehicle.armed and vehicle.in_air and fresh and retry_ok:
            events.append("requesting offboard")
            return step("engaging", stream=True, request="start", start_t_s=now_s)
        return step("waiting")

    return step("waiting" if prev.enabled else "disabled")


_FORGOTTEN_ON_ENGAGING = {"obstacle_t_s": None, "seen_ranged": False, "target_deg": None,
                          "target_from_t_s": None,
                          "pass_side": 0, "path_m": None, "path_t_s": None,
                          "flown_since_seen_m": 0.0, "course_progress_m": 0.0,
                          "foot_abeam_m": None, "course_offset_m": 0.0, "contacts_m": (),
                          "contacts_t_s": None}


def _pass_target(keep: dict, decision: Decision | None, fresh: bool, course_deg: float,
                 policy: PolicyConfig) -> dict:
    """The heading target, when an obstacle was last seen and where its foot, if measured,
    is abeam (``foot_abeam_m``, in ``course_progress_m``), after a new decision.

    A decision that turns (or sees the face aligned, within the deadband) sets the target
    from its η and heading; one whose turn the reversal rule held back (``forward`` with
    η outside the deadband), or that asks to pass on the other side of the course than
    the pass-off taken (:func:`~companion.control.policy.keeps_side`), or that the tracker
    has not confirmed (:func:`~companion.control.policy.turns_for`), leaves the target as
    it was.
    """
    if (not fresh or decision is None or decision.eta_deg is None
            or not obstacle_matters(decision.range_m, policy)):
        return keep
    if decision.range_m is not None and decision.t_s != keep.get("obstacle_t_s"):
        # A foot range_m away is abeam once that far has been flown along the course.
        keep = {**keep, "foot_abeam_m": keep.get("course_progress_m", 0.0) + decision.range_m}
    keep = {**keep, "obstacle_t_s": decision.t_s, "seen_ranged": decision.range_m is not None}
    if (decision.heading_deg is None or decision.t_s == keep.get("target_from_t_s")
            or not turns_for(decision.confirmed, decision.range_m, policy)):
        return keep  # seen, so the course does not resume toward it, but not turned for
    action, eta = decision.command.action, decision.eta_deg
    if action in ("left", "right") or (action == "forward" and abs(eta) <= policy.deadband_deg):
        side = pass_side(eta, decision.heading_deg, course_deg)
        if keeps_side(side, keep.get("pass_side", 0), decision.path_m, policy):
            return keep
        keep["target_deg"] = avoidance_heading(eta, decision.heading_deg, course_deg, policy)
        keep["target_from_t_s"] = decision.t_s
        keep["pass_side"] = side
    return keep


CONTACT_MEMORY = 1024
"""At most this many floor contacts are remembered, the newest: with
:data:`CONTACT_MERGE_M` a piece's feet and the floor behind them
(``policy.hidden_depth_m``) are a few dozen points each."""

CONTACT_MERGE_M = 0.1
"""A contact remembered this near a new one is replaced by it: a foot seen on every frame
is one point, measured from ever nearer, however fast the camera."""


def remembered_contacts(prev: SupervisorState, decision: Decision | None, fresh: bool,
                        course_deg: float, along_m: float, across_m: float,
                        policy: PolicyConfig
                        ) -> tuple[tuple[tuple[float, float], ...], float | None]:
    """The floor contacts to remember at this tick, each (metres along the course, metres
    right of it) from where offboard engaged, and the decision that last added to them.

    The vehicle is at (``along_m``, ``across_m``), dead-reckoned. A new fresh decision
    taken at a known heading adds its contacts (``Decision.contacts_m``), those within
    ``act_within_m`` (nearer ones are measured better: the range error grows with its
    square), each replacing those remembered within :data:`CONTACT_MERGE_M` of it; a
    contact farther behind the vehicle than ``resume_clearance_m`` is forgotten, as no
    path ahead can pass nearer to it, and so is one the vehicle has come within half
    ``resume_clearance_m`` of: flown over, it was no piece reaching the flight height (a
    frame that misread a box leaves contacts along the very path flown, which would
    otherwise hold the vehicle off its course); at most :data:`CONTACT_MEMORY`.
    """
    kept = [c for c in prev.contacts_m if c[0] >= along_m - policy.resume_clearance_m
            and math.hypot(c[0] - along_m, c[1] - across_m) >= 0.5 * policy.resume_clearance_m]
    since = prev.contacts_t_s
    if (fresh and decision is not None and decision.t_s != since
            and decision.heading_deg is not None):
        since = decision.t_s
        b = math.radians(wrap_deg(decision.heading_deg - course_deg))
        new = [(along_m + ahead * math.cos(b) - right * math.sin(b),
                across_m + ahead * math.sin(b) + right * math.cos(b))
               for ahead, right in decision.contacts_m
               if policy.act_within_m <= 0.0 or math.hypot(ahead, right) <= policy.act_within_m]
        if new and kept:
            gaps = np.asarray(kept)[:, None, :] - np.asarray(new)[None, :, :]
            near = ((gaps ** 2).sum(axis=2) < CONTACT_MERGE_M ** 2).any(axis=1)
            kept = [c for c, n in zip(kept, near.tolist(), strict=True) if not n]
        kept.extend(new)
    return tuple(kept[-CONTACT_MEMORY:]), since


PATH_MEMORY_S = 2.0
"""How long a path distance is dead-reckoned without a new measurement: a close
obstacle's foot drops below the view (1.5 m at 1 m height and a 90° lens), yet it is
still there; after this the vehicle, stopped and turning, goes on."""


def path_ahead(prev: SupervisorState, decision: Decision | None, fresh: bool, now_s: float,
               flown_m: float) -> tuple[float | None, float | None]:
    """The distance (m) to the nearest obstacle in the flight path at ``now_s`` and the
    decision time it was measured at: a new decision's measurement (``path_m``, inf when
    the path is clear); else the last one less ``flown_m`` (flown since the last tick),
    while frames still see an obstacle, for at most :data:`PATH_MEMORY_S`; else None (not
    known)."""
    if not fresh or decision is None:
        return None, None
    if decision.path_m is not None and decision.t_s != prev.path_t_s:
        return decision.path_m, decision.t_s
    last, since = prev.path_m, prev.path_t_s
    if last is None or since is None or not math.isfinite(last):
        return (last, since) if decision.t_s == since else (None, None)
    if (decision.t_s != since and decision.eta_deg is None) or now_s - since > PATH_MEMORY_S:
        return None, None  # a newer frame sees no obstacle, or the measurement is too old
    return last - flown_m, since


def enable(state: SupervisorState) -> SupervisorState:
    """Re-arm the latch after a release (pilot's or operator's explicit act)."""
    if state.enabled:
        return state
    return replace(state, enabled=True,
                   name="waiting" if state.name == "disabled" else state.name)
