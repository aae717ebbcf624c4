"""Randomized approaches to a rotated obstacle: ``companion sim --scenario approach``.

Each run draws a room and one obstacle rotated 12°–45° off the room's axes standing in the
flight path, then flies it with the service's own pieces: the renderer draws the camera's
view from the pose the autopilot reports over MAVLink (MAVSDK's ``position_velocity_ned``
and ``attitude_euler``), the pipeline and Table II decide, the offboard controller streams
the setpoints over real MAVLink, and the autopilot moves. The run ends as

- **collision**: the vehicle's body, a cylinder of radius :data:`BODY_RADIUS_M` reaching
  :data:`BODY_HALF_HEIGHT_M` above and below its altitude, touches the obstacle, a wall or
  other furniture;
- **passed**: it crossed the line :data:`PASS_MARGIN_M` beyond the obstacle's far side
  (measured along the original course) without a collision;
- **timeout**: neither within the run's time limit.

What is drawn, per run (all from ``numpy.random.default_rng([seed, run])``):

=====================  =====================================================
room                   14–18 m along the course, 10–14 m across, 2.7–3.2 m high,
                       doors, windows and pictures; tilted pictures and a rotated
                       rug (non-Manhattan clutter, no vertical edges) half the time
start                  1.5 m from the near wall, within ±1 m of the room's middle;
                       the course is a room axis ±5°
obstacle               centre 3–7 m ahead, within ±0.5 m of the line of flight,
                       rotated 12°–45° off the room's axes (either way), 0.8–1.6 m
                       by 0.5–1.0 m, 0.4–1.0 m taller than the flight altitude
                       (``--eye-level``: 0.1–0.25 m taller, :meth:`Approach.at_eye_level`;
                       ``--manhattan``: square to the room, against a side wall,
                       :meth:`Approach.aside`)
furniture              0–3 aligned (Manhattan) boxes along the side walls
flight                 takeoff altitude 0.8–1.3 m requested (the harness reads the
                       altitude the autopilot levels off at), forward speed
                       0.4–0.8 m/s, camera field of view 60°–90° (horizontal)
=====================  =====================================================

Policies: ``paper`` (the pipeline on the rendered frame, the default), ``none`` (fly
straight: how hard the scenario is), ``oracle`` (the same turn rule fed the renderer's true
η while the obstacle is in view: the policy's own ceiling).

Renderers: ``scene`` (:mod:`sitl.scene`, flat-shaded, the default) or ``pathtraced`` (the
same room path-traced by :mod:`sitl.pathtraced`, :func:`pathtraced_room`: soft shadows,
textured floors and walls, glossy reflections, exposure error, vignetting, sensor noise
drawn afresh every frame, the blur of the vehicle's own yaw rate, and a radial lens the
pipeline is not told of). The geometry, and so the collisions and the oracle, are the same.

Time. Against the mock autopilot (the default) the vehicle moves in lock-step with the
camera: each frame, the mock flies one camera period of simulated time and the companion
runs on that clock, so a frame that takes 0.12 s to draw (3 s path-traced) costs no
flight time, as with a real camera. The clock also waits while offboard engages (MAVSDK's
real-time exchange with the autopilot), so that the vehicle starts to act at the same frame
whenever a run is flown again (the rest of a run repeats too, nearly always: the
supervisor still ticks in real time; docs/flight.md). Against another autopilot
(``--autopilot URL``, e.g. PX4 SITL) everything runs in real time and the harness assumes
nothing of it: it maps the autopilot's local frame (origin, heading) onto the room where
the vehicle hovers when the run begins, and renders at the altitude the vehicle actually
reports.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from companion.config import CameraConfig, Config, MavlinkConfig
from companion.control.policy import TurnHistory, decide_frame, wrap_deg
from companion.report import closing_line
from companion.vision.lens import distort_maps
from sitl.scene import (
    RENDERERS,
    Box,
    Camera,
    Room,
    Scene,
    random_colour,
    random_decorations,
    render_image,
    scene_truth,
    striped_rug,
)
from sitl.workers import SPAWN

__all__ = ["Approach", "RunResult", "draw_approach", "fly_approach", "first_contact",
           "format_report", "run_approaches", "summarize", "write_trajectories"]

POLICIES = ("paper", "none", "oracle")
CAMERA_HZ = 5.0
"""camera frames per second of flight, unless ``--camera-hz`` says otherwise"""
BODY_RADIUS_M = 0.25
BODY_HALF_HEIGHT_M = 0.1  # frame, props and camera: 0.2 m from the skids to the props' tips
PASS_MARGIN_M = 1.0
ROOM_LENGTH_M = (14.0, 18.0)
ROOM_WIDTH_M = (10.0, 14.0)
ROOM_HEIGHT_M = (2.7, 3.2)
START_FROM_WALL_M = 1.5
START_OFF_MIDDLE_M = 1.0
COURSE_OFF_AXIS_DEG = 5.0
OBSTACLE_AHEAD_M = (3.0, 7.0)
OBSTACLE_OFF_LINE_M = 0.5
OBSTACLE_REL_YAW_DEG = (12.0, 45.0)
OBSTACLE_LENGTH_M = (0.8, 1.6)
OBSTACLE_WIDTH_M = (0.5, 1.0)
OBSTACLE_ABOVE_FLIGHT_M = (0.4, 1.0)
OBSTACLE_ABOVE_EYE_LEVEL_M = (0.1, 0.25)  # --eye-level: Approach.at_eye_level
FURNITURE = (0, 3)
WALL_GAP_M = 0.15  # furniture along a side wall stands at least this far from it
ALTITUDE_M = (0.8, 1.3)
SPEED_M_S = (0.4, 0.8)
HFOV_DEG = (60.0, 90.0)
TURNED_DEG = 10.0  # --manhattan: a run whose heading left the course by more turned for nothing
SLACK_S = 15.0  # time limit: twice the straight flight to the pass line, plus this


@dataclass(frozen=True)
class Approach:
    """One drawn run, in the room's frame (x along the room's length, y across, metres;
    headings in degrees, right positive). ``boxes[0]`` is the obstacle; its height and the
    room's are set from the flight altitude by :meth:`at_altitude`."""

    run: int
    room: Room
    boxes: tuple[Box, ...]
    start_x_m: float
    start_y_m: float
    course_deg: float
    altitude_m: float  # requested at takeoff
    speed_m_s: float
    hfov_deg: float
    obstacle_ahead_m: float
    obstacle_off_line_m: float
    obstacle_rel_yaw_deg: float  # off the room's axes, signed
    obstacle_above_m: float  # how much taller than the flight altitude
    noise_sigma: float = 2.0
    blur_sigma: float = 0.6
    scene_seed: int = 0

    def course_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit vectors along the course and to its right (room x, y)."""
        c = math.radians(self.course_deg)
        return np.array([math.cos(c), math.sin(c)]), np.array([-math.sin(c), math.cos(c)])

    def pass_distance_m(self) -> float:
        """How far along the course, from the start, the pass line lies."""
        u, _ = self.course_axes()
        start = np.array([self.start_x_m, self.start_y_m])
        far = max(float((c[:2] - start) @ u) for c in self.boxes[0].footprint())
        return far + PASS_MARGIN_M

    def at_altitude(self, altitude_m: float) -> Approach:
        """The scene for a vehicle flying at ``altitude_m``: the obstacle stands
        ``obstacle_above_m`` above it (so it cannot be overflown), the room above that."""
        height = altitude_m + self.obstacle_above_m
        room = self.room
        if room.height < height + 0.3:
            room = replace(room, height=height + 0.3)
        return replace(self, room=room, boxes=(replace(self.boxes[0], height=height),
                                               *self.boxes[1:]))

    def at_eye_level(self) -> Approach:
        """The same run with the obstacle's top :data:`OBSTACLE_ABOVE_EYE_LEVEL_M` above the
        hover altitude: once PX4's altitude creep in offboard (0.2 m, PX4-NOTES.md) has
        lifted the vehicle, the camera flies 0.25 m below to 0.1 m above the top and sees
        it within a few degrees of edge-on, along the horizon, all the way in, and the
        body still cannot clear it. The height is the drawn one scaled into that range,
        so every other draw, and the room, is the run's own."""
        lo, hi = OBSTACLE_ABOVE_FLIGHT_M
        elo, ehi = OBSTACLE_ABOVE_EYE_LEVEL_M
        return replace(self, obstacle_above_m=elo + (ehi - elo)
                       * (self.obstacle_above_m - lo) / (hi - lo))

    def aside(self) -> Approach:
        """The same run with nothing to avoid: the obstacle turned square to the room and
        moved across the room to the side wall on its side of the course, as far along
        the room as it stood (so the run ends near its pass line). A Manhattan room, its
        clutter and side furniture: whatever the vehicle turns for is a false alarm. The
        obstacle's reported offsets are those of where it now stands."""
        box = self.boxes[0]
        side = 1.0 if self.obstacle_off_line_m >= 0.0 else -1.0
        wall = self.room.y_max if side > 0 else self.room.y_min
        square = replace(box, yaw_deg=0.0, y=wall - side * (WALL_GAP_M + 0.5 * box.width))
        u, v = self.course_axes()
        to_box = np.array([square.x - self.start_x_m, square.y - self.start_y_m])
        return replace(self, boxes=(square, *self.boxes[1:]), obstacle_rel_yaw_deg=0.0,
                       obstacle_ahead_m=float(to_box @ u), obstacle_off_line_m=float(to_box @ v))

    def scene(self) -> Scene:
        return Scene(room=self.room, boxes=self.boxes, noise_sigma=self.noise_sigma,
                     blur_sigma=self.blur_sigma, seed=self.scene_seed)


def draw_approach(seed: int, run: int, eye_level: bool = False,
                  manhattan: bool = False) -> Approach:
    """Run ``run`` of the scenario set ``seed`` (the ranges in the module docstring);
    ``eye_level``: the same run with the obstacle's top near the flight altitude
    (:meth:`Approach.at_eye_level`); ``manhattan``: with nothing to avoid
    (:meth:`Approach.aside`)."""
    rng = np.random.default_rng([seed, run])
    u = rng.uniform
    length, width = u(*ROOM_LENGTH_M), u(*ROOM_WIDTH_M)
    room0 = Room(x_min=0.0, x_max=length, y_min=-width / 2, y_max=width / 2,
                 height=u(*ROOM_HEIGHT_M), tile_m=float(rng.choice([0.3, 0.4, 0.5, 0.6])),
                 floor_albedo=random_colour(rng, 0.4, 0.75),
                 wall_albedo=random_colour(rng, 0.6, 0.85))
    sx, sy = START_FROM_WALL_M, u(-START_OFF_MIDDLE_M, START_OFF_MIDDLE_M)
    course = u(-COURSE_OFF_AXIS_DEG, COURSE_OFF_AXIS_DEG)
    ahead, off = u(*OBSTACLE_AHEAD_M), u(-OBSTACLE_OFF_LINE_M, OBSTACLE_OFF_LINE_M)
    rel = u(*OBSTACLE_REL_YAW_DEG) * rng.choice([-1.0, 1.0])
    c = math.radians(course)
    obstacle = Box(sx + ahead * math.cos(c) - off * math.sin(c),
                   sy + ahead * math.sin(c) + off * math.cos(c),
                   float(rel + 90.0 * rng.integers(0, 4)), u(*OBSTACLE_LENGTH_M),
                   u(*OBSTACLE_WIDTH_M), 1.0, random_colour(rng, 0.15, 0.6))
    boxes = [obstacle]
    for _ in range(int(rng.integers(FURNITURE[0], FURNITURE[1] + 1))):
        side = rng.choice([-1.0, 1.0])
        b = Box(u(2.0, length - 1.0), 0.0, float(90.0 * rng.integers(0, 2)), u(0.5, 1.4),
                u(0.4, 0.8), u(0.5, 2.0), random_colour(rng, 0.15, 0.6))
        reach = b.radius()
        b = replace(b, y=side * (width / 2 - WALL_GAP_M - reach - u(0.0, 0.5)))
        if all(math.hypot(b.x - o.x, b.y - o.y) > reach + o.radius() + 0.3 for o in boxes):
            boxes.append(b)
    clutter = bool(rng.random() < 0.5)
    rug = None
    if clutter:
        rug = striped_rug(rng, u(3.0, length - 2.0), u(-width / 4, width / 4))
    room = replace(room0, decorations=random_decorations(rng, room0, clutter), rug=rug)
    drawn = Approach(
        run=run, room=room, boxes=tuple(boxes), start_x_m=sx, start_y_m=sy, course_deg=course,
        altitude_m=u(*ALTITUDE_M), speed_m_s=u(*SPEED_M_S), hfov_deg=u(*HFOV_DEG),
        obstacle_ahead_m=ahead, obstacle_off_line_m=off, obstacle_rel_yaw_deg=rel,
        obstacle_above_m=u(*OBSTACLE_ABOVE_FLIGHT_M), noise_sigma=u(1.5, 4.0),
        blur_sigma=u(0.4, 0.9), scene_seed=int(rng.integers(0, 2**31 - 1)))
    drawn = drawn.at_eye_level() if eye_level else drawn
    return drawn.aside() if manhattan else drawn


def pathtraced_room(ap: Approach, spp: int = 8):
    """The run's room as :mod:`sitl.pathtraced` draws it (a :class:`~sitl.pathtraced.Room3D`):
    the same geometry, so that collisions and the truth stay the run's (each piece of
    furniture's bounding box is the run's box; the obstacle and the side furniture are plain
    boxes or cabinets on a plinth, which fill their boxes), and a look drawn from the run's
    seed: floor, walls, lamps and daylight, exposure, lens distortion, vignetting and
    noise (:func:`~sitl.pathtraced.random_look`). The furniture's heights are the flown
    ones: call it on :meth:`Approach.at_altitude`'s scene."""
    from sitl import pathtraced

    rng = np.random.default_rng([ap.scene_seed, 3])
    pieces = []
    for box in ap.boxes:
        kind = str(rng.choice(["box", "cabinet"]))
        material = "wood" if kind == "cabinet" and rng.random() < 0.5 else str(
            rng.choice(["paint", "wood", "gloss"]))
        pieces.append(pathtraced.Furniture(kind, box.x, box.y, box.yaw_deg, box.length,
                                           box.width, box.height, box.albedo, material))
    return pathtraced.Room3D(ap.room, tuple(pieces), pathtraced.random_look(rng, spp))


def _draw_frame(renderer: str, scene: Scene, r3, cam: Camera, frame: int,
                yaw_rate_deg_s: float) -> np.ndarray:
    """The camera's picture of the run's room, with this frame's sensor noise:
    :mod:`sitl.scene`'s, or path-traced (``r3``: :func:`pathtraced_room`) with the blur of
    the vehicle's own yaw rate too."""
    if renderer == "scene":
        return render_image(scene, cam, supersample=1, frame=frame + 1)
    from sitl import pathtraced

    look = replace(r3.look, frame=frame + 1, yaw_rate_deg_s=yaw_rate_deg_s)
    return pathtraced.render(replace(r3, look=look), cam)[0]


# --------------------------------------------------------------------------- geometry


def _box_clearance_m(box: Box, x: float, y: float) -> float:
    """Distance (m) from the point to the box's footprint; 0 inside."""
    a1, a2 = box.axes()
    d = np.array([x - box.x, y - box.y])
    lu = max(abs(float(d @ a1[:2])) - box.length / 2, 0.0)
    lv = max(abs(float(d @ a2[:2])) - box.width / 2, 0.0)
    return math.hypot(lu, lv)


def first_contact(room: Room, boxes: Sequence[Box], x: float, y: float, altitude_m: float,
                  radius_m: float = BODY_RADIUS_M, half_height_m: float = BODY_HALF_HEIGHT_M
                  ) -> str | None:
    """What a body, a cylinder of ``radius_m`` reaching ``half_height_m`` above and below
    (x, y, ``altitude_m`` above the floor), touches: ``"wall"``, ``"obstacle"``
    (``boxes[0]``), ``"furniture"`` (the other boxes, when the body clears their top), or
    None. The height matters when a top is near the flight altitude: a body of no height
    would slip over a box its underside scrapes."""
    if (x - radius_m <= room.x_min or x + radius_m >= room.x_max or y - radius_m <= room.y_min
            or y + radius_m >= room.y_max):
        return "wall"
    for k, box in enumerate(boxes):
        if altitude_m - half_height_m <= box.height and _box_clearance_m(box, x, y) <= radius_m:
            return "obstacle" if k == 0 else "furniture"
    return None


@dataclass(frozen=True)
class FrameMap:
    """The autopilot's local NED frame → the room's: the vehicle's pose when the run began
    (``north0``, ``east0``, ``yaw0``) is the run's start pose."""

    north0_m: float
    east0_m: float
    yaw0_deg: float
    start_x_m: float
    start_y_m: float
    course_deg: float

    def to_room(self, north_m: float, east_m: float, yaw_deg: float
                ) -> tuple[float, float, float]:
        """(x, y, heading) in the room for a local (north, east, heading)."""
        turn = math.radians(self.course_deg - self.yaw0_deg)
        dn, de = north_m - self.north0_m, east_m - self.east0_m
        x = self.start_x_m + math.cos(turn) * dn - math.sin(turn) * de
        y = self.start_y_m + math.sin(turn) * dn + math.cos(turn) * de
        heading = wrap_deg(yaw_deg + self.course_deg - self.yaw0_deg)
        return x, y, heading


# --------------------------------------------------------------------------- one run


class FrameDecision(NamedTuple):
    """One frame of a run, as decided (rounded; in the ``--json`` document a list in this
    order, named by its ``decision_fields``)."""

    t_s: float  # simulated time since the first frame
    heading_deg: float  # in the room's frame
    eta_steered_deg: float | None  # the η Table II was applied to (policy.steering_eta)
    action: str
    range_m: float | str | None  # to the obstacle's floor contact; None: not measured
    path_m: float | str | None  # to the nearest obstacle in the path; "inf": clear
    eta_deg: float | None  # the frame's own η (eq. 10)
    eta_tracked_deg: float | None  # the tracker's; None: no confirmed track
    rule: str | None  # the obstacle stage's rule that read the frame's obstacle


@dataclass
class RunResult:
    """One run: how it ended and what it flew. Times in simulated (vehicle) seconds from
    the first frame; ``path`` in room metres."""

    run: int
    outcome: str  # passed | collision | timeout | error
    hit: str | None  # for a collision: obstacle | wall | furniture
    time_s: float
    frames: int
    min_clearance_m: float  # closest the body's centre came to the obstacle's footprint
    max_turn_deg: float  # largest heading change from the course
    altitude_m: float  # the altitude the vehicle flew at (as reported)
    decision_ms: list[float] = field(default_factory=list)
    setpoint_ms: list[float] = field(default_factory=list)
    path: list[tuple[float, float]] = field(default_factory=list)
    decisions: list[FrameDecision] = field(default_factory=list)  # one per frame
    detail: str = ""
    # how far the obstacle's top stood above the camera, lowest and highest over the frames
    top_above_camera_m: tuple[float, float] = (math.inf, -math.inf)


def _policy_config(base: Config, ap: Approach, camera: Camera, focal_given: bool,
                   url: str) -> Config:
    return replace(
        base,
        camera=replace(base.camera, width=camera.width, height=camera.height,
                       focal_px=camera.focal_px if focal_given else None),
        mavlink=MavlinkConfig(url=url, connect_timeout_s=15.0),
        offboard=replace(base.offboard, enabled=True, sim_arm_and_takeoff=True,
                         sim_takeoff_altitude_m=ap.altitude_m, forward_speed_m_s=ap.speed_m_s))


def fly_approach(ap: Approach, policy: str = "paper", *, port: int | None = None,
                 autopilot_url: str | None = None, camera_hz: float = CAMERA_HZ, width: int = 640,
                 height: int = 480, base: Config | None = None, focal_given: bool = True,
                 lens_k1: float = 0.0, renderer: str = "scene", spp: int = 8) -> RunResult:
    """Fly one drawn approach; against the lock-step mock on 127.0.0.1:``port``, or, with
    ``autopilot_url``, against an autopilot that is already running (real time). With
    ``lens_k1`` every frame is taken through that radial lens (OpenCV's k1, focal length
    normalised). ``renderer``: ``scene`` (:mod:`sitl.scene`) or ``pathtraced`` (the same
    room path-traced at ``spp`` samples per pixel, :func:`pathtraced_room`; its own lens)."""
    from companion.control.offboard import OffboardController
    from companion.vision.pipeline import Pipeline
    from sitl.closed_loop import fly_alongside, step_vehicle, submit_frame

    if policy not in POLICIES:
        raise ValueError(f"--policy {policy}: must be one of {', '.join(POLICIES)}")
    if renderer not in RENDERERS:
        raise ValueError(f"--renderer {renderer}: must be one of {', '.join(RENDERERS)}")
    cam0 = Camera(width=width, height=height, hfov_deg=ap.hfov_deg)
    lens = distort_maps(width, height, cam0.focal_px, (lens_k1,)) if lens_k1 else None
    mock = None
    if autopilot_url is None:
        from sitl.autopilot import AutopilotParams, MockAutopilot

        rng = np.random.default_rng([ap.scene_seed, 1])
        # What a real PX4 does that a harness must not assume away (PX4-NOTES.md): its own
        # heading and origin, a takeoff that levels off above the request, heading drift.
        mock = MockAutopilot(port, AutopilotParams(
            lockstep=True, arm_ready_s=1.0, boot_yaw_deg=float(rng.uniform(-180.0, 180.0)),
            takeoff_overshoot_m=float(rng.uniform(0.0, 0.3)), yaw_drift_deg_s=1.0,
            offboard_climb_m_s=0.03))
        url = f"udpin://127.0.0.1:{port}"
    else:
        url = autopilot_url
    cfg = _policy_config(base or Config(), ap, cam0, focal_given, url)
    pipeline = Pipeline(cfg) if policy == "paper" else None
    clock = (lambda: mock.sim_time_s) if mock is not None else time.monotonic
    controller = OffboardController(cfg, clock=clock)
    period_s = 1.0 / camera_hz
    result = RunResult(ap.run, "error", None, 0.0, 0, math.inf, 0.0, math.nan)
    next_frame = [time.monotonic()]

    def advance() -> None:
        """One camera period of vehicle time: lock-step the mock, else wait it out."""
        if mock is not None:
            step_vehicle(mock, controller, period_s)
            return
        next_frame[0] = max(next_frame[0] + period_s, time.monotonic())
        time.sleep(max(0.0, next_frame[0] - time.monotonic()))

    def hover_pose():
        """Wait until the vehicle hovers after takeoff (its altitude steady to 2 cm for a
        second); its pose then."""
        deadline = time.monotonic() + 90.0
        recent: deque[float] = deque(maxlen=max(1, round(1.0 / period_s)) + 1)  # 1 s of frames
        while time.monotonic() < deadline and not session_over.is_set():
            advance()
            pose = controller.pose
            if pose is None or -pose.down_m < 0.5 or controller.state.name != "waiting":
                recent.clear()
                continue
            recent.append(pose.down_m)
            if len(recent) == recent.maxlen and max(recent) - min(recent) < 0.02:
                return pose
        raise TimeoutError("the vehicle did not take off and hover")

    session_over = threading.Event()  # the MAVSDK session ended (no autopilot, or an error)

    def camera() -> None:
        pose = hover_pose()
        alt = -pose.down_m
        flown = ap.at_altitude(alt)
        scene = flown.scene()
        r3 = pathtraced_room(flown, spp) if renderer == "pathtraced" else None
        last_heading = None
        frame_map = FrameMap(pose.north_m, pose.east_m, pose.yaw_deg, ap.start_x_m,
                             ap.start_y_m, ap.course_deg)
        u, _ = ap.course_axes()
        start = np.array([ap.start_x_m, ap.start_y_m])
        pass_at = ap.pass_distance_m()
        limit_s = 2.0 * pass_at / ap.speed_m_s + SLACK_S
        history = TurnHistory()
        t_start = controller.clock()
        result.altitude_m = alt
        prev_xy = None
        while not session_over.is_set():
            pose = controller.pose
            x, y, heading = frame_map.to_room(pose.north_m, pose.east_m, pose.yaw_deg)
            alt = -pose.down_m
            above = flown.boxes[0].height - alt
            result.top_above_camera_m = (min(result.top_above_camera_m[0], above),
                                         max(result.top_above_camera_m[1], above))
            result.path.append((round(x, 3), round(y, 3)))
            result.frames += 1
            result.time_s = controller.clock() - t_start
            result.max_turn_deg = max(result.max_turn_deg,
                                      abs(wrap_deg(heading - ap.course_deg)))
            # The body between the last pose and this one, so a fast frame cannot skip a wall.
            samples = [(x, y)] if prev_xy is None else [
                (prev_xy[0] + s * (x - prev_xy[0]), prev_xy[1] + s * (y - prev_xy[1]))
                for s in (0.25, 0.5, 0.75, 1.0)]
            prev_xy = (x, y)
            for sx, sy in samples:
                result.min_clearance_m = min(result.min_clearance_m,
                                             _box_clearance_m(flown.boxes[0], sx, sy))
                hit = first_contact(flown.room, flown.boxes, sx, sy, alt)
                if hit is not None:
                    result.outcome, result.hit = "collision", hit
                    return
            if float((np.array([x, y]) - start) @ u) >= pass_at:
                result.outcome = "passed"
                return
            if result.time_s > limit_s:
                result.outcome = "timeout"
                return
            cam = replace(cam0, x=x, y=y, height_m=alt, yaw_deg=heading,
                          pitch_deg=pose.pitch_deg, roll_deg=pose.roll_deg)
            yaw_rate = 0.0 if last_heading is None else wrap_deg(heading - last_heading) * camera_hz
            last_heading = heading
            image = (_draw_frame(renderer, scene, r3, cam, result.frames, yaw_rate)
                     if policy == "paper" else None)
            if image is not None and lens is not None:
                image = cv2.remap(image, *lens, cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_REPLICATE)
            t0 = time.perf_counter()  # the frame is taken: decide
            seen, tracked, understood, range_m, path_m, rule, contacts = _observe(
                policy, scene, cam, pipeline, image)
            eta, cmd, history = decide_frame(seen, tracked, cfg.policy, history, understood,
                                             range_m)
            result.decision_ms.append((time.perf_counter() - t0) * 1e3)
            t_wall = time.monotonic()
            _, engaging, sent = submit_frame(controller, mock, cmd, eta, session_over,
                                             range_m=range_m, path_m=path_m,
                                             confirmed=tracked is not None,
                                             contacts_m=contacts)
            result.decisions.append(FrameDecision(
                round(result.time_s, 2), round(heading, 2),
                None if eta is None else round(eta, 2), cmd.action, _round(range_m),
                _round(path_m), _round(seen), _round(tracked), rule))
            if controller.state.name == "active":
                if sent is not None and not engaging:  # the engaging frame waited: no latency
                    result.setpoint_ms.append((sent - t_wall) * 1e3)
            elif mock is not None:
                time.sleep(max(0.0, period_s - (time.monotonic() - t_wall)))
            advance()

    try:
        if mock is not None:
            mock.start()
        fly_alongside(controller, _guarded(camera, result), session_over=session_over)
    finally:
        if mock is not None:
            mock.stop()
    return result


def _observe(policy: str, scene: Scene, cam: Camera, pipeline, image: np.ndarray | None
             ) -> tuple[float | None, float | None, bool, float | None, float | None,
                        str | None, tuple[tuple[float, float], ...]]:
    """η and the tracked η (or None), whether the scene was understood, the range and
    path distance (:class:`~companion.control.supervisor.Decision`), the rule that read
    the frame's obstacle (``Obstacle.rule``; None without one) and the floor contacts with
    the floor taken to be covered behind them (``Estimate.footprint_ahead_right_m``), as
    the policy sees the frame (``image``: the rendered frame, for ``paper``, measured at
    the camera height the autopilot reports, as the service does). The oracle knows no
    range, and turns only for a rotated obstacle in view (not for the square one of
    ``--manhattan``); its true η is its own track, so it steers the same whether the policy
    steers by the track or not."""
    if policy == "paper":
        est = pipeline(image, camera_height_m=cam.height_m)
        return (est.eta_deg, est.eta_tracked_deg, est.scene_understood, est.range_m,
                est.path_m(pipeline.config.policy.path_half_width_m),
                est.obstacles[0].rule if est.obstacles else None,
                est.footprint_ahead_right_m(pipeline.config.policy.hidden_depth_m))
    if policy == "oracle":
        truth = scene_truth(scene, cam).obstacles[0]
        eta = truth.eta_deg if truth.corners_px and truth.non_manhattan else None
        return eta, eta, True, None, None, None, ()
    return None, None, True, None, None, None, ()


def _round(x: float | None) -> float | str | None:
    """A distance for the JSON: 2 decimals, None as is, inf as the string "inf"."""
    return None if x is None else ("inf" if math.isinf(x) else round(x, 2))


def _guarded(camera: Callable[[], None], result: RunResult) -> Callable[[], None]:
    def run() -> None:
        try:
            camera()
        except Exception as exc:  # recorded as the run's error, not a crash of the set
            result.outcome, result.detail = "error", f"{exc.__class__.__name__}: {exc}"
    return run


# --------------------------------------------------------------------------- many runs


def _one(job: tuple) -> tuple[Approach, RunResult]:
    """One run, with MAVSDK's own stderr lines silenced: under the renderer's load it warns
    of callbacks it had to drop, which the lock-step asks for again (see ``advance``);
    whatever goes wrong in a run is in its result's ``detail``."""
    import logging

    seed, run, policy, kw = job
    logging.getLogger("mavsdk").setLevel(logging.ERROR)
    kw = dict(kw)
    speed = kw.pop("speed_m_s", None)
    ap = draw_approach(seed, run, eye_level=kw.pop("eye_level", False),
                       manhattan=kw.pop("manhattan", False))
    if speed is not None:
        ap = replace(ap, speed_m_s=speed)
    from companion.control.offboard import AutopilotNotFound
    from sitl.autopilot import free_udp_port

    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 2)
        for attempt in range(3):
            port = None if kw.get("autopilot_url") else free_udp_port()
            try:
                return ap, fly_approach(ap, policy, port=port, **kw)
            except AutopilotNotFound:
                raise  # no autopilot at the URL: the whole set's one-line error
            except Exception as exc:
                if port is not None and "BIND_ERROR" in str(exc) and attempt < 2:
                    continue  # the other worker took the free port before MAVSDK bound it
                return ap, RunResult(run, "error", None, 0.0, 0, math.inf, 0.0, math.nan,
                                     detail=f"{exc.__class__.__name__}: {exc}")
        raise AssertionError("unreachable")
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def run_approaches(runs: int, seed: int, policy: str, *, workers: int = 2,
                   progress: Callable[[int, int, list[RunResult]], None] | None = None, **kw
                   ) -> list[tuple[Approach, RunResult]]:
    """Fly runs 0..``runs``-1 of the set ``seed``; ``workers`` processes side by side
    (one against an autopilot given by URL). ``kw`` go to :func:`fly_approach`."""
    jobs = [(seed, i, policy, kw) for i in range(runs)]
    out: list[tuple[Approach, RunResult]] = []
    if workers <= 1 or kw.get("autopilot_url"):
        for job in jobs:
            out.append(_one(job))
            if progress:
                progress(len(out), runs, [r for _, r in out])
    else:
        # One core each: BLAS or OpenCV threads of their own would only contend.
        for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(name, "1")
        with SPAWN.Pool(workers, initializer=cv2.setNumThreads, initargs=(1,)) as pool:
            for item in pool.imap_unordered(_one, jobs):
                out.append(item)
                if progress:
                    progress(len(out), runs, [r for _, r in out])
    return sorted(out, key=lambda item: item[0].run)


def _pct(values: Sequence[float], q: float) -> float | None:
    return round(float(np.percentile(values, q)), 2) if len(values) else None


def summarize(results: Sequence[tuple[Approach, RunResult]], policy: str, seed: int,
              renderer: str = "scene", eye_level: bool = False, manhattan: bool = False
              ) -> dict:
    """The figures of a set of runs (the ``--json`` document). ``turned_runs``: the runs
    whose heading left the course by more than :data:`TURNED_DEG` (with ``manhattan``,
    each a false alarm flown)."""
    rs = [r for _, r in results]
    n = len(rs)
    count = {k: sum(r.outcome == k for r in rs) for k in ("passed", "collision", "timeout",
                                                           "error")}
    decision = [v for r in rs for v in r.decision_ms]
    setpoint = [v for r in rs for v in r.setpoint_ms]
    passed_t = [r.time_s for r in rs if r.outcome == "passed"]
    per_run = []
    for ap, r in results:
        per_run.append({
            "run": r.run, "outcome": r.outcome, "hit": r.hit, "time_s": round(r.time_s, 2),
            "frames": r.frames, "min_clearance_m": round(r.min_clearance_m, 3),
            "max_turn_deg": round(r.max_turn_deg, 1), "altitude_m": round(r.altitude_m, 2),
            "top_above_camera_m": [round(v, 3) if math.isfinite(v) else None
                                   for v in r.top_above_camera_m],
            "obstacle_ahead_m": round(ap.obstacle_ahead_m, 2),
            "obstacle_off_line_m": round(ap.obstacle_off_line_m, 2),
            "obstacle_rel_yaw_deg": round(ap.obstacle_rel_yaw_deg, 1),
            "obstacle_above_m": round(ap.obstacle_above_m, 3),
            "speed_m_s": round(ap.speed_m_s, 2), "hfov_deg": round(ap.hfov_deg, 1),
            "detail": r.detail, "path": r.path, "decisions": r.decisions})
    return {
        "scenario": "approach", "policy": policy, "renderer": renderer, "seed": seed,
        "eye_level": eye_level, "manhattan": manhattan, "runs": n,
        "decision_fields": list(FrameDecision._fields),
        "passed": count["passed"], "collisions": count["collision"],
        "timeouts": count["timeout"], "errors": count["error"],
        "collision_free_rate": round((n - count["collision"] - count["error"]) / n, 4)
        if n else None,
        "pass_rate": round(count["passed"] / n, 4) if n else None,
        "turned_runs": sum(r.max_turn_deg > TURNED_DEG for r in rs),
        "time_to_pass_s": {"median": _pct(passed_t, 50), "p90": _pct(passed_t, 90)},
        "decision_latency_ms": {"median": _pct(decision, 50), "p99": _pct(decision, 99)},
        "frame_to_setpoint_ms": {"median": _pct(setpoint, 50), "p99": _pct(setpoint, 99)},
        "per_run": per_run,
    }


def format_report(summary: dict) -> list[str]:
    """The per-run table and the figures, for the terminal."""
    out = [f"{'run':>4} {'ahead':>6} {'off':>6} {'yaw':>6} {'speed':>6} {'fov':>5} "
           f"{'outcome':>10} {'time':>6} {'clear':>6} {'turn':>6}",
           f"{'':>4} {'m':>6} {'m':>6} {'deg':>6} {'m/s':>6} {'deg':>5} {'':>10} {'s':>6} "
           f"{'m':>6} {'deg':>6}"]
    for r in summary["per_run"]:
        what = r["outcome"] if r["hit"] is None else f"hit {r['hit'][:6]}"
        out.append(f"{r['run']:>4} {r['obstacle_ahead_m']:>6.2f} {r['obstacle_off_line_m']:>+6.2f}"
                   f" {r['obstacle_rel_yaw_deg']:>+6.1f} {r['speed_m_s']:>6.2f}"
                   f" {r['hfov_deg']:>5.0f} {what:>10} {r['time_s']:>6.1f}"
                   f" {r['min_clearance_m']:>6.2f} {r['max_turn_deg']:>6.1f}")
    s = summary
    n = s["runs"]
    drawn = "" if s.get("renderer", "scene") == "scene" else f", {s['renderer']} rooms"
    drawn += ", obstacle at eye level" if s.get("eye_level") else ""
    drawn += ", nothing to avoid (--manhattan)" if s.get("manhattan") else ""
    out.append(f"policy {s['policy']}{drawn}, {n} runs (seed {s['seed']}): passed {s['passed']}, "
               f"collisions {s['collisions']}, timeouts {s['timeouts']}, errors {s['errors']}; "
               f"collision-free {100 * s['collision_free_rate']:.1f} %, "
               f"passed {100 * s['pass_rate']:.1f} %")
    if s.get("manhattan"):
        out.append(f"turned for nothing: {s['turned_runs']} of {n} runs left the course by "
                   f"more than {TURNED_DEG:g}°")
    tp, dl, sp = s["time_to_pass_s"], s["decision_latency_ms"], s["frame_to_setpoint_ms"]
    if tp["median"] is not None:
        out.append(f"time to pass: median {tp['median']:.1f} s, p90 {tp['p90']:.1f} s")
    if dl["median"] is not None:
        out.append(f"decision latency per frame: median {dl['median']:.1f} ms, "
                   f"p99 {dl['p99']:.1f} ms")
    if sp["median"] is not None:
        out.append(f"frame → setpoint: median {sp['median']:.1f} ms, p99 {sp['p99']:.1f} ms")
    return out


_OUTCOME_BGR = {"passed": (60, 160, 40), "collision": (40, 40, 220), "timeout": (0, 150, 240),
                "error": (150, 60, 150)}


def write_trajectories(results: Sequence[tuple[Approach, RunResult]], path: str | Path,
                       columns: int = 10, panel_px: int = 170) -> None:
    """Top-down small multiples, one per run: room, obstacle (filled), furniture, the
    path flown coloured by outcome (green passed, red collision, orange timeout) and the
    pass line (dashed). The course points up in every panel."""
    rows = max(1, math.ceil(len(results) / columns))
    img = np.full((rows * panel_px + 30, min(columns, max(1, len(results))) * panel_px, 3),
                  255, np.uint8)
    for k, (ap, r) in enumerate(results):
        panel = np.full((panel_px, panel_px, 3), 255, np.uint8)  # so drawing is clipped to it
        u, v = ap.course_axes()
        start = np.array([ap.start_x_m, ap.start_y_m])
        span = ap.pass_distance_m() + 2.0
        scale = (panel_px - 20) / span

        def px(p, _u=u, _v=v, _s=scale, _st=start):
            d = np.asarray(p, float)[:2] - _st
            return (int(round(panel_px / 2 + _s * float(d @ _v))),
                    int(round(panel_px - 10 - _s * float(d @ _u))))

        cv2.rectangle(panel, (1, 1), (panel_px - 2, panel_px - 2), (200, 200, 200), 1)
        room = ap.room
        corners = [(room.x_min, room.y_min), (room.x_max, room.y_min),
                   (room.x_max, room.y_max), (room.x_min, room.y_max)]
        cv2.polylines(panel, [np.array([px(c) for c in corners], np.int32)], True,
                      (90, 90, 90), 1)
        for j, box in enumerate(ap.boxes):
            poly = np.array([px(c) for c in box.footprint()], np.int32)
            if j == 0:
                cv2.fillPoly(panel, [poly], (120, 120, 120))
            else:
                cv2.polylines(panel, [poly], True, (150, 150, 150), 1)
        a = start + ap.pass_distance_m() * u
        for t in np.arange(-3.0, 3.0, 0.5):
            cv2.line(panel, px(a + t * v), px(a + (t + 0.25) * v), (200, 140, 60), 1)
        colour = _OUTCOME_BGR.get(r.outcome, (0, 0, 0))
        if len(r.path) > 1:
            cv2.polylines(panel, [np.array([px(p) for p in r.path], np.int32)], False, colour,
                          2, cv2.LINE_AA)
        label = f"{r.run}: {r.outcome if r.hit is None else 'hit ' + r.hit}"
        cv2.putText(panel, label, (5, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1,
                    cv2.LINE_AA)
        top, left = 30 + (k // columns) * panel_px, (k % columns) * panel_px
        img[top:top + panel_px, left:left + panel_px] = panel
    cv2.putText(img, "top-down, course up: obstacle filled, furniture outlined, pass line "
                "dashed; green passed, red collision, orange timeout", (5, 20),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"cannot write {path}")


def simulate_approach(args, progress=None) -> int:
    """``companion sim --scenario approach``: fly, print the table and figures, write the
    JSON and the plot. 0 when every run ended (passed, collision or timeout), 1 on errors.
    ``progress(done, total, extra)`` is called as runs finish."""
    import json

    from companion.config import load_config

    if args.runs < 1:
        raise ValueError("--runs must be at least 1")
    if not 0.5 <= args.camera_hz <= 60.0:
        raise ValueError("--camera-hz must be between 0.5 and 60")
    if args.speed is not None and not 0.05 <= args.speed <= 5.0:
        raise ValueError("--speed must be between 0.05 and 5 m/s")
    if not -0.2 <= args.lens <= 0.1:
        raise ValueError("--lens must be between -0.2 and 0.1 (OpenCV's k1)")
    if args.renderer == "pathtraced":
        from sitl import pathtraced

        if args.lens:
            raise ValueError("--lens goes with --renderer scene: a path-traced run draws "
                             "its own lens")
        if not 1 <= args.spp <= 1024:
            raise ValueError("--spp must be between 1 and 1024")
        if not pathtraced.available():
            raise ValueError("--renderer pathtraced needs Mitsuba 3: "
                             "pip install 'companion[render]'")
    base = load_config(args.sim_config)
    started = time.perf_counter()

    def report(done: int, total: int, so_far: list[RunResult]) -> None:
        if progress is not None:
            hits = sum(r.outcome == "collision" for r in so_far)
            progress(done, total, f"runs, {hits} collisions")

    from companion.control.offboard import AutopilotNotFound

    try:
        results = run_approaches(
            args.runs, args.seed, args.policy, workers=max(1, args.workers), progress=report,
            autopilot_url=args.autopilot, camera_hz=args.camera_hz, width=args.width,
            height=args.height, base=base, focal_given=not args.no_focal,
            speed_m_s=args.speed, lens_k1=args.lens, renderer=args.renderer, spp=args.spp,
            eye_level=args.eye_level, manhattan=args.manhattan)
    except AutopilotNotFound as exc:
        raise ValueError(str(exc)) from None
    if progress is not None:
        progress(args.runs, args.runs, "")
    summary = summarize(results, args.policy, args.seed, args.renderer, args.eye_level,
                        args.manhattan)
    for line in format_report(summary):
        print(line)
    options = "" if args.speed is None else f" --speed {args.speed:g}"
    options += f" --lens {args.lens:g}" if args.lens else ""
    if args.renderer != "scene":
        options += f" --renderer {args.renderer} --spp {args.spp}"
    options += " --no-focal" if args.no_focal else ""
    options += " --eye-level" if args.eye_level else ""
    options += " --manhattan" if args.manhattan else ""
    if (args.width, args.height) != (CameraConfig.width, CameraConfig.height):
        options += f" --width {args.width} --height {args.height}"
    options += f" --camera-hz {args.camera_hz:g}" if args.camera_hz != CAMERA_HZ else ""
    options += f" --autopilot {args.autopilot}" if args.autopilot else ""
    print(closing_line(time.perf_counter() - started, "companion sim --scenario approach "
                       f"--runs {args.runs} --seed {args.seed} --policy {args.policy}{options}",
                       args.sim_config))
    for r in summary["per_run"]:
        if r["outcome"] == "error":
            print(f"run {r['run']}: error: {r['detail']}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(summary, f, indent=1)
    if args.plot:
        Path(args.plot).parent.mkdir(parents=True, exist_ok=True)
        write_trajectories(results, args.plot)
        print(f"plot: {args.plot}")
    return 1 if summary["errors"] else 0
