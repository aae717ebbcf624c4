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

Beyond the paper, :func:`resume_course_rate`: Table II aligns the heading with the
obstacle's face, up to 45° off the course the pilot set, and nothing in the paper ever
turns back, so in flight the vehicle left the obstacle behind and went on into the side
wall (docs/flight.md has the figures). Once no obstacle has been in view for
``resume_after_s``, the vehicle steers back to its course (the heading it had when offboard
engaged), proportionally and at most ``resume_max_rate_deg_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from companion.config import PolicyConfig

__all__ = ["TurnCommand", "TurnHistory", "confirm_reversal", "decide_turn",
           "resume_course_rate"]

Action = Literal["left", "right", "forward", "hold"]


@dataclass(frozen=True)
class TurnCommand:
    """One decision: ``action``, the signed ``turn_deg`` it asks for (right positive), and
    the ``yaw_rate_deg_s`` that executes it."""

    action: Action
    turn_deg: float
    yaw_rate_deg_s: float


def decide_turn(
    eta_deg: float | None, policy: PolicyConfig, scene_understood: bool = True
) -> TurnCommand:
    """Table II: η (degrees, right positive, or None) → :class:`TurnCommand`.

    - no scene understanding (no layout found, e.g. a blank or blurred frame) → ``hold``:
      nothing to act on, yaw rate 0;
    - no non-Manhattan obstacle (``eta_deg is None``) or ``|η| <= deadband`` → ``forward``;
    - otherwise turn toward η's side by ``min(|η|, max_turn_deg)``.
    """
    if not scene_understood or (eta_deg is not None and not math.isfinite(eta_deg)):
        return TurnCommand("hold", 0.0, 0.0)
    if eta_deg is None or abs(eta_deg) <= policy.deadband_deg:
        return TurnCommand("forward", 0.0, 0.0)
    turn = math.copysign(min(abs(eta_deg), policy.max_turn_deg), eta_deg)
    rate = turn / policy.turn_time_s
    rate = math.copysign(min(abs(rate), policy.max_yaw_rate_deg_s), turn)
    return TurnCommand("right" if turn > 0 else "left", turn, rate)


def resume_course_rate(heading_deg: float, course_deg: float, policy: PolicyConfig) -> float:
    """Yaw rate (deg/s, right positive) back toward ``course_deg`` from ``heading_deg``:
    ``resume_gain_per_s`` × the heading error (wrapped to ±180°), capped at
    ``resume_max_rate_deg_s``; 0 when ``resume_course`` is off or within the deadband."""
    error = (course_deg - heading_deg + 180.0) % 360.0 - 180.0
    if not policy.resume_course or abs(error) <= policy.deadband_deg:
        return 0.0
    rate = policy.resume_gain_per_s * error
    return math.copysign(min(abs(rate), policy.resume_max_rate_deg_s), rate)


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
