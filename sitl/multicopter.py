"""How a PX4 multicopter answers velocity and yaw-rate setpoints: a pure response model.

Fitted to what a real PX4 (SIH quadrotor, ``../shared/PX4-NOTES.md``) did:

- yaw rate: ~0.25 s dead time, then a first-order rise (17 of 20 °/s after ~0.6 s) to a
  steady 95 % of the command (18–19.5 °/s for 20 °/s);
- horizontal velocity: ~0.3 s dead time, then a fast and a slow first-order part
  (0.57 m/s after 1 s, 0.76 after 2 s, 0.9 only after ~4 s for a 1 m/s step: PX4's
  acceleration and jerk limits). The model gives 0.60 / 0.79 / 0.92. Vertical velocity
  follows the fast part alone (PX4 holds altitude tightly);
- the body tilts with the acceleration (nose down to speed up, into a turn), as a
  multicopter must: pitch = −atan(a_forward / g), roll = atan(a_right / g), reached
  with a 0.1 s lag. A camera fixed to the body sees the room tilt with it.

No sockets, clocks or MAVLink here: :class:`Motion` holds the state, :func:`step`
advances it by ``dt`` for a command already delayed by the caller. ``sitl/autopilot.py``
keeps the setpoint history and calls this.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from companion.control.policy import wrap_deg

__all__ = ["Motion", "Response", "step"]

G_M_S2 = 9.81


@dataclass(frozen=True)
class Response:
    """Response constants (PX4-NOTES.md, SIH quadrotor)."""

    velocity_dead_s: float = 0.3
    velocity_fast_share: float = 0.55
    velocity_fast_tau_s: float = 0.35
    velocity_slow_tau_s: float = 2.2
    yaw_dead_s: float = 0.25
    yaw_tau_s: float = 0.15
    yaw_gain: float = 0.95
    tilt_tau_s: float = 0.1


@dataclass
class Motion:
    """Position (NED, m), velocity in two response parts (NED, m/s), heading (deg from
    north, right positive), yaw rate (deg/s) and tilt (deg) of the vehicle."""

    north_m: float = 0.0
    east_m: float = 0.0
    down_m: float = 0.0
    v_fast: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    v_slow: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    yaw_deg: float = 0.0
    yaw_rate_deg_s: float = 0.0
    roll_deg: float = 0.0
    pitch_deg: float = 0.0

    def velocity(self, response: Response) -> tuple[float, float, float]:
        """The vehicle's velocity (NED, m/s): the blend of the two response parts."""
        s = response.velocity_fast_share
        return tuple(s * f + (1.0 - s) * w for f, w in zip(self.v_fast, self.v_slow, strict=True))


def step(m: Motion, cmd_ned_m_s: tuple[float, float, float], cmd_yaw_rate_deg_s: float,
         dt: float, response: Response, move: bool = True) -> None:
    """Advance ``m`` by ``dt`` seconds toward the command (already past its dead time).

    ``move`` False (on the ground) keeps the position and zeroes the motion.
    """
    r = response
    if not move:
        m.v_fast = [0.0, 0.0, 0.0]
        m.v_slow = [0.0, 0.0, 0.0]
        m.yaw_rate_deg_s = m.roll_deg = m.pitch_deg = 0.0
        return
    before = m.velocity(r)
    a_fast = min(1.0, dt / r.velocity_fast_tau_s)
    a_slow = min(1.0, dt / r.velocity_slow_tau_s)
    for i in range(3):
        m.v_fast[i] += (cmd_ned_m_s[i] - m.v_fast[i]) * a_fast
        m.v_slow[i] += (cmd_ned_m_s[i] - m.v_slow[i]) * a_slow
    m.v_slow[2] = m.v_fast[2]
    after = m.velocity(r)
    m.north_m += after[0] * dt
    m.east_m += after[1] * dt
    m.down_m = min(0.0, m.down_m + after[2] * dt)
    m.yaw_rate_deg_s += (cmd_yaw_rate_deg_s * r.yaw_gain - m.yaw_rate_deg_s) * min(
        1.0, dt / r.yaw_tau_s)
    m.yaw_deg = wrap_deg(m.yaw_deg + m.yaw_rate_deg_s * dt)
    # Tilt from the horizontal acceleration in the body frame.
    yaw = math.radians(m.yaw_deg)
    an, ae = ((a - b) / dt for a, b in zip(after[:2], before[:2], strict=True))
    a_fwd = math.cos(yaw) * an + math.sin(yaw) * ae
    a_right = -math.sin(yaw) * an + math.cos(yaw) * ae
    a_tilt = min(1.0, dt / r.tilt_tau_s)
    m.pitch_deg += (-math.degrees(math.atan2(a_fwd, G_M_S2)) - m.pitch_deg) * a_tilt
    m.roll_deg += (math.degrees(math.atan2(a_right, G_M_S2)) - m.roll_deg) * a_tilt
