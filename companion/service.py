"""``companion run``: capture → pipeline → policy → offboard controller, as a service.

Three threads of control, each simple:

- the capture thread (:class:`~companion.capture.LatestFrame`) keeps only the newest
  frame and reopens a camera that disappears;
- the vision thread takes the newest frame, runs the pipeline and the Table II policy and
  hands the decision to the controller;
- the asyncio loop runs the MAVSDK session (:mod:`companion.control.offboard`) and, once a
  second, talks to systemd: ``READY=1`` once frames are decided and the autopilot is
  connected, ``WATCHDOG=1`` only while decisions keep coming, ``STATUS=`` with fps, η and
  the offboard state.

stdout gets one line per state change and a periodic health line, never a line per frame;
per-frame decisions go to a size-rotated JSON-lines file when configured. SIGTERM/SIGINT
run the controller's safe stop (yaw rate 0, Hold) and exit 0.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import logging.handlers
import signal
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np

from companion.capture import LatestFrame, is_camera, open_source
from companion.config import Config
from companion.control.obstacle_distance import from_estimate
from companion.control.offboard import AutopilotNotFound, OffboardController
from companion.control.policy import TurnHistory, decide_frame
from companion.notify import notify
from companion.report import log_record
from companion.vision.pipeline import FOCAL_MEMORY, Pipeline

log = logging.getLogger("companion")

__all__ = ["run_service"]

EXIT_NO_AUTOPILOT = 3


class _Health:
    """Counters the vision thread updates and the loop reads (floats: atomic enough)."""

    def __init__(self) -> None:
        self.decisions = 0
        self.last_decision_s = 0.0
        self.eta_deg: float | None = None
        self.latency_ms: deque[float] = deque(maxlen=300)
        self.decided_at: deque[float] = deque(maxlen=300)

    def fps(self, now_s: float) -> float:
        recent = [t for t in self.decided_at if now_s - t <= 5.0]
        return len(recent) / 5.0 if recent else 0.0


def _decision_log(config: Config) -> logging.Logger | None:
    path = config.service.decision_log
    if not path:
        return None
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    handler = logging.handlers.RotatingFileHandler(
        path, maxBytes=int(config.service.decision_log_max_mb * 1e6),
        backupCount=config.service.decision_log_backups)
    handler.setFormatter(logging.Formatter("%(message)s"))
    logger = logging.getLogger("companion.decisions")
    logger.propagate = False
    logger.handlers[:] = [handler]
    logger.setLevel(logging.INFO)
    return logger


def _vision_loop(config: Config, frames: LatestFrame, controller: OffboardController,
                 health: _Health, stop: threading.Event, decisions: logging.Logger | None):
    pipeline = Pipeline(config)
    history = TurnHistory()
    lens_told = False
    focal_told = False  # a given focal length gathers no estimates: never told
    while not stop.is_set():
        frame = frames.get(timeout_s=0.2)
        if frame is None:
            if frames.ended.is_set():
                return
            continue
        est = pipeline(frame.image, camera_height_m=controller.camera_height_m())
        if pipeline.running_lens.settled and not lens_told:
            log.info("%s", pipeline.running_lens.describe())
            lens_told = True
        if len(pipeline.running_focal.estimates_px) >= FOCAL_MEMORY and not focal_told:
            log.info("%s", pipeline.describe_focal())  # once its memory is full
            focal_told = True
        eta, cmd, history = decide_frame(est.eta_deg, est.eta_tracked_deg, config.policy,
                                         history, est.scene_understood, est.range_m)
        controller.submit(cmd, eta, t_s=frame.captured_s,
                          obstacle_distance=from_estimate(
                              est, config.mavlink.obstacle_distance_increment_deg),
                          range_m=est.range_m,
                          path_m=est.path_m(config.policy.path_half_width_m),
                          confirmed=est.eta_tracked_deg is not None,
                          contacts_m=est.footprint_ahead_right_m(config.policy.hidden_depth_m))
        now = time.monotonic()
        health.decisions += 1
        health.last_decision_s = now
        health.eta_deg = est.eta_deg
        health.latency_ms.append((now - frame.captured_s) * 1e3)
        health.decided_at.append(now)
        if decisions is not None:
            record = log_record(frame.index, frame.t_s, est, cmd, est.latency_ms)
            decisions.info(json.dumps(record))


def run_service(config: Config, source: str | None = None) -> int:
    """Run until SIGTERM/SIGINT (or the end of a recording used as the camera).

    ``source``: a video file, image folder or camera; default ``camera.device``.
    Returns the exit code: 0 after a clean stop, 3 if no autopilot answered.
    Raises :class:`~companion.capture.CaptureError` for a recording that cannot be read.
    """
    cam = config.camera
    spec = source if source is not None else cam.device

    def open_frames():
        return open_source(spec, (cam.width, cam.height), cam.fps, cam.fourcc)

    if not is_camera(spec):
        open_frames().close()  # a recording: a bad path is a one-line error now, not later
    frames = LatestFrame(open_frames, realtime=True, on_event=lambda text: log.warning(
        "capture: %s", text))
    controller = OffboardController(config)
    health = _Health()
    return asyncio.run(_main(config, frames, controller, health))


async def _main(config: Config, frames: LatestFrame, controller: OffboardController,
                health: _Health) -> int:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    vision_stop = threading.Event()
    frames.start()
    vision = threading.Thread(
        target=_vision_loop, name="vision", daemon=True,
        args=(config, frames, controller, health, vision_stop, _decision_log(config)))
    vision.start()
    session = asyncio.ensure_future(controller.run(stop))
    code = 0
    try:
        await _supervise(config, frames, controller, health, stop, session)
    finally:
        stop.set()
        try:
            await session
        except AutopilotNotFound as exc:
            log.error("%s", exc)
            code = EXIT_NO_AUTOPILOT
        vision_stop.set()
        frames.stop()
        vision.join(timeout=1.0)
        notify("STOPPING=1")
    log.info("stopped: %d decisions", health.decisions)
    return code


async def _supervise(config, frames, controller, health, stop, session) -> None:
    """Once a second: systemd notifications, and a health line every health_every_s."""
    svc = config.service
    ready = False
    next_health = time.monotonic() + svc.health_every_s
    while not stop.is_set() and not session.done():
        now = time.monotonic()
        flowing = health.decisions > 0 and now - health.last_decision_s <= svc.max_frame_gap_s
        if frames.ended.is_set() and not flowing:
            log.info("recording ended")
            stop.set()
            break
        eta = "none" if health.eta_deg is None else f"{health.eta_deg:+.1f}°"
        status = (f"STATUS={health.fps(now):.1f} fps, eta {eta}, "
                  f"offboard {controller.state.name}")
        lines = [status]
        if not ready and flowing and controller.connected:
            ready = True
            lines.append("READY=1")
            log.info("ready: camera delivering, autopilot connected")
        if flowing:
            lines.append("WATCHDOG=1")  # only while decisions keep coming
        notify(*lines)
        if now >= next_health:
            next_health = now + svc.health_every_s
            lat = np.percentile(health.latency_ms, 50) if health.latency_ms else float("nan")
            log.info("health: %.1f fps, latency %.0f ms, eta %s, offboard %s, dropped %d",
                     health.fps(now), lat, eta, controller.state.name, frames.dropped)
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), timeout=1.0)
