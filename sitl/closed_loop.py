"""The paper's loop in simulation (Fig. 6, Fig. 11, Table IV): ``companion sim``.

Every camera tick the renderer draws the room from the mock autopilot's current heading,
with that frame's own sensor noise, the companion pipeline computes η, Table II turns it
into a yaw rate, and the offboard controller sends it over real MAVLink (MAVSDK → UDP on
127.0.0.1 → :mod:`sitl.autopilot`), which integrates it into the heading the next frame
is drawn from. The vehicle moves in lock-step with the camera, as in
:mod:`sitl.approach`: the autopilot flies one camera period of simulated time per frame
and the companion runs on that clock, so the machine's speed decides nothing (drawing a
frame costs no flight time, as a real camera's exposure does not) and a start flown again
flies the same way. The MAVLink exchange itself (setpoints, modes, telemetry) is real.

The start: a box 30° off the room's axes, ahead of the camera, and the camera turned so
that η = ``eta0_deg``. Since M is the obstacle VP nearest the image centre (eq. 9), its
true bearing is at most 45°, so with D = f (eq. 10) |η| never exceeds 45°. The paper's
Table IV reports η up to 76° because its D (240 px on a 2 MP camera) is well below the
focal length. The simulation does the same: D = f / 4, so η0 = ±75° is a bearing of ±43°.

``python -m sitl.closed_loop --eta0 60 75 -75`` or ``companion sim`` prints a Table IV-style
table per start and writes a PNG of η and the yaw rate over time.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from companion.config import CameraConfig, Config, MavlinkConfig
from companion.control.offboard import OffboardController, SentSetpoint
from companion.control.policy import TurnHistory, decide_frame
from companion.vision.pipeline import Pipeline
from sitl.approach import CAMERA_HZ
from sitl.scene import (
    EAST,
    NORTH,
    RENDERERS,
    WEST,
    Box,
    Camera,
    Room,
    Scene,
    WallRect,
    render,
)

__all__ = ["LoopFrame", "LoopRun", "fly_alongside", "format_table", "hovering_autopilot",
           "loop_scene", "run_closed_loop", "sitl_link", "write_plot", "STARTS_DEG"]

STARTS_DEG = (30.0, -30.0, 60.0, -60.0, 75.0, -75.0)
BOX_YAW_DEG = 30.0  # the obstacle's yaw against the room: clearly non-Manhattan
DEPTH_OVER_FOCAL = 0.25  # D = f / 4 (see the module docstring)


@dataclass(frozen=True)
class LoopFrame:
    """One camera tick while offboard was active."""

    frame: int  # 1-based, as Table IV
    t_s: float  # since the first active frame
    heading_deg: float  # the autopilot's heading when the frame was drawn
    m_x_px: float | None  # eq. 9, centred, right positive
    eta_deg: float | None  # measured (eq. 10)
    true_eta_deg: float  # eq. 10 on the true M with the same D
    action: str
    yaw_rate_deg_s: float  # what Table II asked for
    latency_ms: float  # pipeline time


@dataclass(frozen=True)
class LoopRun:
    eta0_deg: float
    deadband_deg: float
    frames: list[LoopFrame]
    setpoints: list[tuple[float, float]]  # (t_s since first active frame, yaw rate) received
    converged_at: int | None  # first frame from which |η| stayed within the deadband
    overshoot_deg: float  # furthest the true η went past 0, on the far side of η0
    sign_changes: int  # of the measured η outside the deadband: 0 means no oscillation
    events: list[str] = field(default_factory=list)

    @property
    def converged(self) -> bool:
        return self.converged_at is not None


def loop_scene(eta0_deg: float, width: int = 640, height: int = 480,
               hfov_deg: float = 60.0) -> tuple[Scene, Camera, float]:
    """The room, the camera's starting pose and D (px) for a start at ``eta0_deg``.

    The camera sees the box's face at bearing ``az = atan(D tan η0 / f)``; the box stands
    3.5 m ahead along the middle of the turn, so it stays in view all the way.
    """
    room = Room(x_min=0.0, x_max=10.0, y_min=-5.0, y_max=5.0, height=2.8, tile_m=0.5,
                decorations=(WallRect(NORTH, -1.5, 0.9, 0.0, 2.05, (0.35, 0.45, 0.6)),
                             WallRect(NORTH, 2.0, 1.4, 0.9, 2.0, (0.75, 0.65, 0.5)),
                             WallRect(EAST, 6.0, 0.9, 0.0, 2.05, (0.3, 0.35, 0.45)),
                             WallRect(WEST, 4.0, 0.8, 1.3, 1.8, (0.3, 0.5, 0.35))))
    cam = Camera(width=width, height=height, hfov_deg=hfov_deg, x=2.5, y=-1.0, height_m=1.3)
    depth = DEPTH_OVER_FOCAL * cam.focal_px
    az = math.degrees(math.atan(depth * math.tan(math.radians(eta0_deg)) / cam.focal_px))
    cam = replace(cam, yaw_deg=BOX_YAW_DEG - az)
    toward = math.radians(BOX_YAW_DEG - az / 2.0)
    box = Box(x=cam.x + 3.5 * math.cos(toward), y=cam.y + 3.5 * math.sin(toward),
              yaw_deg=BOX_YAW_DEG, length=1.2, width=0.7, height=1.0,
              albedo=(0.3, 0.35, 0.55))
    scene = Scene(room=room, boxes=(box,), noise_sigma=2.0, blur_sigma=0.6, seed=11)
    return scene, cam, depth


def loop_config(cam: Camera, depth_px: float, port: int, base: Config | None = None) -> Config:
    """The companion's config for the simulation: the camera's focal length, D, offboard on,
    the mock's URL.

    With D = f / k, η is the bearing of M magnified (tan η = k tan bearing). The policy is
    rescaled so the vehicle behaves as the shipped defaults do with D = f: the deadband is
    the same bearing (3° → 11.8° of η), and ``max_turn_deg`` (up to 90°) and ``turn_time_s``
    are k times larger, so the yaw rate per degree of bearing is about the shipped one.
    Timeouts and rate limits are as shipped. The vehicle hovers (forward speed 0), as in
    the paper's Table IV.
    """
    cfg = base or Config()
    k = cam.focal_px / depth_px
    deadband = math.degrees(math.atan(k * math.tan(math.radians(cfg.policy.deadband_deg))))
    return sitl_link(replace(
        cfg,
        offboard=replace(cfg.offboard, forward_speed_m_s=0.0),
        camera=replace(cfg.camera, focal_px=cam.focal_px),
        heading=replace(cfg.heading, depth_px=depth_px),
        policy=replace(cfg.policy, deadband_deg=deadband,
                       max_turn_deg=min(cfg.policy.max_turn_deg * k, 90.0),
                       turn_time_s=cfg.policy.turn_time_s * k),
    ), port)


def sitl_link(base: Config, port: int, **offboard) -> Config:
    """``base`` flying the mock autopilot on 127.0.0.1:``port``: offboard enabled, further
    ``offboard`` keys replaced."""
    return replace(base,
                   mavlink=MavlinkConfig(url=f"udpin://127.0.0.1:{port}", connect_timeout_s=10.0),
                   offboard=replace(base.offboard, enabled=True, **offboard))


def hovering_autopilot(port: int, **params):
    """The mock PX4, armed and hovering, sending to ``port`` where MAVSDK listens (udpin);
    ``params`` replace further :class:`sitl.autopilot.AutopilotParams`.

    Imported here, not at the top: `companion --help` and the dry-run build the `sim`
    parser from this module, and need not load MAVLink to do so.
    """
    from sitl.autopilot import AutopilotParams, MockAutopilot

    return MockAutopilot(port, AutopilotParams(**{"boot_in_air": True, "arm_ready_s": 0.2,
                                                  **params}))


def fly_alongside(controller: OffboardController, camera: Callable[[], None],
                  linger_s: float = 0.0, session_over: threading.Event | None = None) -> None:
    """Run ``controller``'s MAVSDK session while ``camera`` runs in a thread; ``linger_s``
    after the camera returns, stop the session and wait for its safe stop. Raises what the
    session raised. ``session_over`` is set when the session ends, so that a camera can
    stop when it ends first (no autopilot answered)."""
    async def fly() -> None:
        stop = asyncio.Event()
        session = asyncio.ensure_future(controller.run(stop))
        if session_over is not None:
            session.add_done_callback(lambda _: session_over.set())
        await asyncio.to_thread(camera)
        await asyncio.sleep(linger_s)
        stop.set()
        await session

    asyncio.run(fly())


EXPOSURE_LEAD_S = 0.001
"""s: a frame's timestamp precedes the clock reading at which it is decided on"""

ENGAGE_WAIT_S = 5.0
"""s of real time the lock-stepped clock waits for offboard to engage (MAVSDK gives up on
a mode switch the heartbeat does not show within about 3 s)"""


def step_vehicle(mock, controller: OffboardController, period_s: float) -> None:
    """Lock-step: fly ``mock`` one camera period of simulated time, then wait until MAVSDK
    has delivered the pose it sent at the new time (asked for again if a callback was
    dropped), so the next frame is drawn and decided on where the vehicle now is."""
    if controller.pose is None:  # MAVSDK not listening yet: nothing to wait for
        mock.advance(period_s)
        return
    n = controller.pose.position_updates
    target_us = int(round(mock.advance(period_s) * 1e6)) - 1000
    t0 = time.monotonic()
    resent = t0
    while time.monotonic() < t0 + 5.0:
        pose = controller.pose
        if pose is not None and pose.position_updates > n and pose.attitude_t_us >= target_us:
            return
        if time.monotonic() > resent + 0.25:  # MAVSDK can drop a callback under load
            mock.send_pose()
            resent = time.monotonic()
        time.sleep(0.0005)
    raise TimeoutError("no telemetry from the autopilot after a lock-step")


def _wait_engaged(controller: OffboardController, t_frame: float,
                  session_over: threading.Event) -> None:
    """Lock-stepped, with the simulated clock held: until the supervisor has ticked on the
    decision on the frame taken at ``t_frame`` and any engagement that began is over,
    either way, or :data:`ENGAGE_WAIT_S` of real time passed.

    Engaging offboard is MAVSDK's and the autopilot's real-time exchange; holding the
    clock meanwhile makes the vehicle start to act at the same frame however long it takes.
    """
    t0 = time.monotonic()
    while not session_over.is_set() and time.monotonic() - t0 < ENGAGE_WAIT_S:
        name = controller.state.name
        if name == "active" or (name != "engaging" and controller.ticked_t_s == t_frame):
            return
        time.sleep(0.001)


OVERTAKE_S = 0.01
"""s of real time the setpoint of a frame's decision must stay the mock's newest before the
clock moves on. MAVSDK's 20 Hz resend copies the setpoint under a lock and sends it after
the lock is released, so a resend of the previous setpoint can leave just after the new
one and arrive after it; held as the newest, it would fly the next step."""


def _carries(setpoint, sent: SentSetpoint) -> bool:
    """Whether a setpoint as the mock received it carries what ``sent`` handed to MAVSDK
    (float32 on the wire, the yaw rate in rad/s)."""
    return (abs(setpoint.vx_m_s - sent.forward_m_s) <= 1e-4
            and abs(setpoint.yaw_rate_deg_s - sent.yaw_rate_deg_s) <= 1e-4)


def _wait_sent(controller: OffboardController, mock, t_frame: float) -> float | None:
    """Until the decision on the frame taken at ``t_frame`` is in a setpoint and, with a
    ``mock``, the mock's newest setpoint carries it and still does :data:`OVERTAKE_S`
    later; at most 2 s. Returns the ``time.monotonic()`` it was sent, or None."""
    deadline = time.monotonic() + 2.0
    newest_since = None
    while time.monotonic() < deadline:
        sent = controller.sent
        if sent is not None and sent.t_s == t_frame:
            if mock is None:
                return sent.monotonic_s
            if mock.setpoints and _carries(mock.setpoints[-1], sent):
                newest_since = newest_since or time.monotonic()
                if time.monotonic() - newest_since >= OVERTAKE_S:
                    return sent.monotonic_s
            else:
                newest_since = None
        time.sleep(0.0002)
    return None


def submit_frame(controller: OffboardController, mock, command, eta_deg: float | None,
                 session_over: threading.Event, **fields) -> tuple[float, bool, float | None]:
    """Hand one frame's decision to ``controller`` (``fields``: further
    :meth:`~companion.control.offboard.OffboardController.submit` arguments), stamped
    :data:`EXPOSURE_LEAD_S` before now on its clock: the frame was exposed a moment before
    it is decided on, and in lock-step the offset also keeps a frame's age off the
    supervisor's thresholds (whole numbers of camera periods), where the clock's rounding
    would decide the comparison. Lock-stepped (``mock`` given), the clock is held while
    offboard engages; once active, until the decision is in a setpoint (at the mock).

    Returns the frame's time on the controller's clock, whether it waited for offboard to
    engage, and the ``time.monotonic()`` its setpoint was sent (None: not seen sent)."""
    t_frame = controller.clock() - EXPOSURE_LEAD_S
    controller.submit(command, eta_deg, t_s=t_frame, **fields)
    engaging = mock is not None and controller.state.name != "active"
    if engaging:
        _wait_engaged(controller, t_frame, session_over)
    sent = _wait_sent(controller, mock, t_frame) if controller.state.name == "active" else None
    return t_frame, engaging, sent


def _true_eta_deg(truth, depth_px: float) -> float:
    m = truth.obstacles[0].m_px
    return math.degrees(math.atan2(m[0], depth_px)) if m is not None else math.nan


def run_closed_loop(eta0_deg: float, port: int, *, width: int = 640, height: int = 480,
                    max_frames: int = 80, settle_frames: int = 10, timeout_s: float = 120.0,
                    frame_period_s: float = 0.2, config: Config | None = None) -> LoopRun:
    """Fly one start to convergence (``settle_frames`` frames in the deadband) or to
    ``max_frames`` active frames; the mock autopilot listens on 127.0.0.1:``port``.

    The camera delivers a frame every ``frame_period_s`` of vehicle time (5 frames/s by
    default, a slow companion board). The vehicle moves in lock-step with it: each frame is
    drawn and decided on where the vehicle is, its setpoint reaches the autopilot, and the
    autopilot then flies one frame period. ``timeout_s`` bounds the run in real time.
    """
    scene, cam0, depth = loop_scene(eta0_deg, width, height)
    cfg = loop_config(cam0, depth, port, config)
    pipeline = Pipeline(cfg)
    deadband = cfg.policy.deadband_deg
    frames: list[LoopFrame] = []
    t_first: list[float] = []
    session_over = threading.Event()

    with hovering_autopilot(port, lockstep=True) as mock:
        controller = OffboardController(cfg, clock=lambda: mock.sim_time_s)

        def camera() -> None:
            in_band = tick = 0
            history = TurnHistory()
            deadline = time.monotonic() + timeout_s
            # The first frame once the companion has heard the hovering vehicle for a
            # second: how long MAVSDK takes to connect in real time decides nothing.
            heard_at = None
            while time.monotonic() < deadline and not session_over.is_set():
                step_vehicle(mock, controller, frame_period_s)
                if controller.pose is None or not controller.connected:
                    continue
                heard_at = mock.sim_time_s if heard_at is None else heard_at
                if mock.sim_time_s >= heard_at + 1.0:
                    break
            while time.monotonic() < deadline and not session_over.is_set():
                tick += 1
                heading = mock.yaw_deg
                image, truth = render(scene, replace(cam0, yaw_deg=cam0.yaw_deg + heading),
                                      supersample=1, frame=tick)
                est = pipeline(image)
                eta, cmd, history = decide_frame(est.eta_deg, est.eta_tracked_deg, cfg.policy,
                                                 history, est.scene_understood)
                t_frame, _, _ = submit_frame(controller, mock, cmd, eta, session_over)
                if controller.state.name == "active":
                    if not t_first:
                        t_first.append(t_frame)
                    row = LoopFrame(
                        frame=len(frames) + 1, t_s=t_frame - t_first[0], heading_deg=heading,
                        m_x_px=None if est.m_px is None else est.m_px[0], eta_deg=est.eta_deg,
                        true_eta_deg=_true_eta_deg(truth, depth), action=cmd.action,
                        yaw_rate_deg_s=cmd.yaw_rate_deg_s, latency_ms=est.latency_ms)
                    frames.append(row)
                    in_band = in_band + 1 if row.action == "forward" else 0
                    if in_band >= settle_frames or len(frames) >= max_frames:
                        break
                elif t_first:  # released after it was active: the run is over
                    break
                step_vehicle(mock, controller, frame_period_s)

        fly_alongside(controller, camera, session_over=session_over)
        t0 = t_first[0] if t_first else 0.0
        setpoints = [(s.sim_t_s - t0, s.yaw_rate_deg_s) for s in mock.setpoints
                     if s.sim_t_s >= t0]
    return _score(eta0_deg, deadband, frames, setpoints, controller.events)


def _score(eta0_deg, deadband, frames, setpoints, events) -> LoopRun:
    measured = [f.eta_deg if f.action != "forward" else 0.0 for f in frames]
    converged_at = None
    for i in range(len(frames)):
        if all(f.action == "forward" for f in frames[i:]):
            converged_at = frames[i].frame
            break
    side = math.copysign(1.0, eta0_deg)
    past = [-side * f.true_eta_deg for f in frames if math.isfinite(f.true_eta_deg)]
    overshoot = max([0.0, *past])
    signs = [math.copysign(1.0, e) for e in measured if e]
    changes = sum(a != b for a, b in zip(signs, signs[1:], strict=False))
    return LoopRun(eta0_deg, deadband, frames, setpoints, converged_at, overshoot, changes,
                   list(events))


def format_table(run: LoopRun) -> list[str]:
    """Table IV's columns (frame, M_x, η, action) plus the true η and the yaw rate."""
    out = [f"η0 = {run.eta0_deg:+.0f}°",
           f"{'frame':>5} {'t (s)':>6} {'M_x (px)':>9} {'η (°)':>7} {'true η':>7}"
           f" {'action':>8} {'yaw rate':>9}"]
    for f in run.frames:
        mx = "—" if f.m_x_px is None else f"{f.m_x_px:.1f}"
        eta = "—" if f.eta_deg is None else f"{f.eta_deg:+.2f}"
        out.append(f"{f.frame:>5} {f.t_s:>6.2f} {mx:>9} {eta:>7} {f.true_eta_deg:>+7.2f}"
                   f" {f.action:>8} {f.yaw_rate_deg_s:>+8.1f}°/s")
    verdict = (f"converged at frame {run.converged_at}" if run.converged
               else "NOT converged")
    out.append(f"{verdict}; overshoot {run.overshoot_deg:.1f}°; "
               f"sign changes outside the deadband {run.sign_changes}")
    return out


def write_plot(runs: Sequence[LoopRun], path: str | Path, width: int = 900,
               panel_h: int = 260) -> None:
    """η (measured: dots, true: line) and the yaw rate the autopilot received, over time.

    Drawn with OpenCV so the simulation needs nothing beyond the runtime's packages.
    """
    colours = [(200, 80, 30), (30, 140, 230), (60, 170, 60), (40, 40, 200), (150, 60, 150),
               (20, 150, 150)]
    left, right, top = 60, 20, 30
    img = np.full((2 * panel_h + 2 * top, width, 3), 255, np.uint8)
    t_max = max([f.t_s for r in runs for f in r.frames] + [1.0])
    panels = [("eta (deg)", 80.0, top), ("yaw rate (deg/s)", 35.0, 2 * top + panel_h)]

    def xy(t, v, vmax, y0):
        x = left + (width - left - right) * t / t_max
        y = y0 + panel_h / 2 - (panel_h / 2 - 5) * max(-1.0, min(1.0, v / vmax))
        return int(round(x)), int(round(y))

    for label, vmax, y0 in panels:
        cv2.rectangle(img, (left, y0), (width - right, y0 + panel_h), (0, 0, 0), 1)
        cv2.line(img, xy(0, 0, vmax, y0), xy(t_max, 0, vmax, y0), (160, 160, 160), 1)
        cv2.putText(img, label, (left + 5, y0 - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1)
        for v in (vmax, -vmax):
            cv2.putText(img, f"{v:+.0f}", (5, xy(0, v, vmax, y0)[1] + 5),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    cv2.putText(img, f"time (s), 0 .. {t_max:.1f}", (width // 2 - 60, img.shape[0] - 8),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    for k, run in enumerate(runs):
        c = colours[k % len(colours)]
        (_, vmax, y0), (_, rmax, y1) = panels
        pts = [xy(f.t_s, f.true_eta_deg, vmax, y0) for f in run.frames
               if math.isfinite(f.true_eta_deg)]
        if len(pts) > 1:
            cv2.polylines(img, [np.array(pts, np.int32)], False, c, 1, cv2.LINE_AA)
        for f in run.frames:
            if f.eta_deg is not None:
                cv2.circle(img, xy(f.t_s, f.eta_deg, vmax, y0), 2, c, -1)
        rate = [xy(t, r, rmax, y1) for t, r in run.setpoints if 0.0 <= t <= t_max]
        if len(rate) > 1:
            cv2.polylines(img, [np.array(rate, np.int32)], False, c, 1, cv2.LINE_AA)
        cv2.putText(img, f"eta0 {run.eta0_deg:+.0f}", (width - right - 90, top + 15 + 15 * k),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, c, 1)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"cannot write {path}")


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``companion sim`` (also ``python -m sitl.closed_loop``)."""
    ap.add_argument("--scenario", choices=("turn", "approach"), default="turn",
                    help="turn: hover and turn until η converges (the paper's Table IV, "
                         "default); approach: fly past a rotated obstacle, randomized runs")
    ap.add_argument("--eta0", type=float, nargs="+", default=list(STARTS_DEG),
                    metavar="DEG", help="turn: starting η values (default: ±30 ±60 ±75)")
    ap.add_argument("--plot", metavar="PATH",
                    help="PNG: turn, η and yaw rate over time (default "
                         "out/closed_loop.png); approach, the runs' top-down trajectories")
    ap.add_argument("--width", type=int, default=CameraConfig.width)
    ap.add_argument("--height", type=int, default=CameraConfig.height)
    ap.add_argument("--port", type=int, default=14561,
                    help="turn: UDP port on 127.0.0.1 for the MAVLink link (default 14561; "
                         "approach picks a free port per run)")
    ap.add_argument("--runs", type=int, default=20, help="approach: runs (default 20)")
    ap.add_argument("--seed", type=int, default=0, help="approach: seed of the run set")
    ap.add_argument("--policy", choices=("paper", "none", "oracle"), default="paper",
                    help="approach: paper (the pipeline, default), none (fly straight), "
                         "oracle (the turn rule fed the renderer's true η)")
    ap.add_argument("--autopilot", metavar="URL",
                    help="approach: fly an autopilot that is already running (e.g. PX4 SITL: "
                         "udpin://127.0.0.1:14540) in real time instead of the mock")
    ap.add_argument("--camera-hz", type=float, default=CAMERA_HZ,
                    help=f"approach: camera frames per second of flight (default {CAMERA_HZ:g})")
    ap.add_argument("--workers", type=int, default=2,
                    help="approach: runs side by side against the mock (default 2)")
    ap.add_argument("--no-focal", action="store_true",
                    help="approach: do not give the pipeline the camera's focal length")
    ap.add_argument("--speed", type=float, default=None, metavar="M_S",
                    help="approach: fly every run at this forward speed (default: drawn, "
                         "0.4-0.8 m/s)")
    ap.add_argument("--lens", type=float, default=0.0, metavar="K1",
                    help="approach: the camera's radial distortion, OpenCV's k1 on "
                         "coordinates normalised by the focal length (< 0 barrel; default "
                         "0, a pinhole): every frame is taken through it")
    ap.add_argument("--renderer", choices=RENDERERS, default="scene",
                    help="approach: who draws the camera's view: scene (flat-shaded, fast, "
                         "default) or pathtraced (the same room path-traced by Mitsuba 3: "
                         "shadows, textures, noise, yaw blur and a lens of its own; about "
                         "3 s a frame; needs companion[render])")
    ap.add_argument("--spp", type=int, default=8,
                    help="approach, pathtraced: samples per pixel (default 8)")
    ap.add_argument("--eye-level", action="store_true",
                    help="approach: the same runs with the obstacle's top 0.1-0.25 m above "
                         "the hover altitude, seen nearly edge-on all the way in (furniture "
                         "at the height the vehicle cruises at)")
    ap.add_argument("--manhattan", action="store_true",
                    help="approach: the same runs with the obstacle square to the room and "
                         "against a side wall: nothing to avoid, so every turn is a false "
                         "alarm flown (the report counts the runs that left the course)")
    ap.add_argument("--json", metavar="PATH", help="approach: write the figures as JSON")
    ap.add_argument("--config", metavar="PATH", dest="sim_config",
                    help="approach: YAML config for the companion (policy, offboard ...)")


def simulate(args: argparse.Namespace) -> int:
    """Fly every start, print its table, write the plot; 0 if every start converged."""
    if args.scenario == "approach":
        from sitl.approach import simulate_approach

        return simulate_approach(args)
    if args.renderer != "scene":
        raise ValueError("--renderer pathtraced goes with --scenario approach")
    for flag, given in (("--eye-level", args.eye_level), ("--manhattan", args.manhattan)):
        if given:
            raise ValueError(f"{flag} goes with --scenario approach")
    if args.sim_config:
        raise ValueError("--config goes with --scenario approach")
    runs = []
    for eta0 in args.eta0:
        if not -89.0 < eta0 < 89.0:
            raise ValueError(f"--eta0 {eta0:g}: must be between -89 and 89 degrees")
        run = run_closed_loop(eta0, args.port, width=args.width, height=args.height)
        runs.append(run)
        for line in format_table(run):
            print(line, flush=True)
        print()
    plot = Path(args.plot or "out/closed_loop.png")
    plot.parent.mkdir(parents=True, exist_ok=True)
    write_plot(runs, plot)
    ok = all(r.converged for r in runs)
    print(f"{sum(r.converged for r in runs)}/{len(runs)} starts converged; plot: {plot}")
    return 0 if ok else 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sitl.closed_loop",
                                 description=__doc__.splitlines()[0])
    add_arguments(ap)
    return simulate(ap.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
