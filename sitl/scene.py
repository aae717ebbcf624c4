"""Synthetic indoor scenes with exact ground truth (simulation and tests only).

A Manhattan room (tiled floor, walls with doors, windows and pictures, a panelled
ceiling), box obstacles standing on the floor at any yaw, optional non-Manhattan clutter
that has no vertical edges (a rotated rug, tilted pictures), seen by a pinhole camera.
Pixels come from ray casting (2× supersampled), so depth and occlusion are exact and the
ground truth is computed from the same geometry that made the image.

World frame: NED, metres. x north, y east, z down; the floor is ``z = 0``, the ceiling
``z = −room.height``. The room's walls are aligned with x and y. Camera yaw is the
heading (clockwise from north, right positive), as PX4 reports it.

The truth for each box: its obstacle VPs (OVPs), M and η, φ by eq. 10 with D = the
focal length, its visible corner projections, and whether the method can detect it at
all (a vertical edge whose top and bottom corners are both visible with both of their
horizontal edges, and a yaw at least ``min_rel_yaw_deg`` off the room's axes).
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

__all__ = [
    "Camera",
    "Box",
    "WallRect",
    "Rug",
    "Room",
    "Scene",
    "ObstacleTruth",
    "SceneTruth",
    "render",
    "mirror",
    "orientations",
    "yaw_axes",
    "random_colour",
    "random_decorations",
    "random_scene",
    "rug_in_view",
    "striped_rug",
    "write_video",
    "yaw_sweep",
    "RENDERERS",
]

RENDERERS = ("scene", "pathtraced")
"""The renderers a scene can be drawn by: this module's, and :mod:`sitl.pathtraced`'s."""

# Surface ids: room surfaces 0..5, wall clutter none; box k face j: 100 + 10 k + j.
FLOOR, CEILING, NORTH, SOUTH, EAST, WEST = range(6)


@dataclass(frozen=True)
class Camera:
    """Pinhole camera. Angles in degrees, positions in metres (world NED)."""

    width: int = 640
    height: int = 480
    hfov_deg: float = 90.0
    x: float = 0.0
    y: float = 0.0
    height_m: float = 1.2  # above the floor
    yaw_deg: float = 0.0  # heading, right positive
    pitch_deg: float = 0.0  # nose up positive
    roll_deg: float = 0.0  # right side down positive

    @property
    def focal_px(self) -> float:
        return self.width / 2.0 / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def centre_px(self) -> np.ndarray:
        return np.array([(self.width - 1) / 2.0, (self.height - 1) / 2.0])

    @property
    def position(self) -> np.ndarray:
        return np.array([self.x, self.y, -self.height_m])

    def rotation(self) -> np.ndarray:
        """World → camera rotation; camera axes x right, y down, z forward."""
        yaw, pitch, roll = (math.radians(a) for a in (self.yaw_deg, self.pitch_deg, self.roll_deg))
        fwd = np.array(
            [math.cos(yaw) * math.cos(pitch), math.sin(yaw) * math.cos(pitch), -math.sin(pitch)]
        )
        right = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
        down = np.cross(fwd, right)
        right_r = math.cos(roll) * right + math.sin(roll) * down
        down_r = np.cross(fwd, right_r)
        return np.vstack([right_r, down_r, fwd])

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N×3) → pixels (N×2) and camera depth z (N,)."""
        pc = (np.atleast_2d(points) - self.position) @ self.rotation().T
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = self.focal_px * pc[:, :2] / z[:, None] + self.centre_px
        return uv, z

    def vp_of(self, direction: np.ndarray) -> np.ndarray:
        """Unit homogeneous pixel VP of a world direction (``K R d``)."""
        d = self.rotation() @ np.asarray(direction, dtype=float)
        f, c = self.focal_px, self.centre_px
        v = np.array([f * d[0] + c[0] * d[2], f * d[1] + c[1] * d[2], d[2]])
        v = v / np.linalg.norm(v)
        return v if v[2] >= 0 else -v


def yaw_axes(yaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """The horizontal unit axes (world NED) of a thing on the floor at ``yaw_deg``: along
    its length, and across it to the right."""
    a = math.radians(yaw_deg)
    return np.array([math.cos(a), math.sin(a), 0.0]), np.array([-math.sin(a), math.cos(a), 0.0])


@dataclass(frozen=True)
class Box:
    """A box standing on the floor. ``yaw_deg`` is its length axis's heading."""

    x: float
    y: float
    yaw_deg: float
    length: float
    width: float
    height: float
    albedo: tuple[float, float, float] = (0.55, 0.45, 0.35)  # BGR, 0..1

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        return yaw_axes(self.yaw_deg)

    def footprint(self) -> np.ndarray:
        """Four floor corners (4×3), counter-clockwise seen from above."""
        a1, a2 = self.axes()
        c = np.array([self.x, self.y, 0.0])
        hl, hw = self.length / 2, self.width / 2
        return np.array(
            [
                c + hl * a1 + hw * a2,
                c - hl * a1 + hw * a2,
                c - hl * a1 - hw * a2,
                c + hl * a1 - hw * a2,
            ]
        )

    def radius(self) -> float:
        return math.hypot(self.length, self.width) / 2


@dataclass(frozen=True)
class WallRect:
    """A rectangle on a wall: door, window or picture. ``along`` metres from the wall's
    west/south end, ``bottom``/``top`` metres above the floor; ``tilt_deg`` ≠ 0 makes it
    non-Manhattan clutter."""

    wall: int
    along: float
    width: float
    bottom: float
    top: float
    albedo: tuple[float, float, float]
    frame: float = 0.04
    tilt_deg: float = 0.0


@dataclass(frozen=True)
class Rug:
    """A striped rectangle on the floor at any yaw: non-Manhattan lines, no verticals."""

    x: float
    y: float
    yaw_deg: float
    length: float
    width: float
    albedo: tuple[float, float, float] = (0.3, 0.25, 0.5)
    stripe_m: float = 0.25


@dataclass(frozen=True)
class Room:
    x_min: float = -2.0
    x_max: float = 8.0
    y_min: float = -4.0
    y_max: float = 4.0
    height: float = 2.8
    tile_m: float = 0.6
    decorations: tuple[WallRect, ...] = ()
    rug: Rug | None = None
    floor_albedo: tuple[float, float, float] = (0.62, 0.62, 0.6)
    wall_albedo: tuple[float, float, float] = (0.78, 0.8, 0.82)


@dataclass(frozen=True)
class Scene:
    room: Room = field(default_factory=Room)
    boxes: tuple[Box, ...] = ()
    noise_sigma: float = 3.0  # grey levels
    blur_sigma: float = 0.6  # pixels
    min_rel_yaw_deg: float = 8.0  # a box this far off the room's axes is non-Manhattan
    seed: int = 0


@dataclass(frozen=True)
class ObstacleTruth:
    """Ground truth for one box. VPs are unit homogeneous pixel 3-vectors."""

    box: int
    rel_yaw_deg: float  # box yaw relative to the room, folded into (−45°, 45°]
    non_manhattan: bool
    ovps: list[list[float]]  # O1, O2
    m_px: list[float] | None  # eq. 9, centred, y up
    eta_deg: float  # eq. 10 with D = focal
    phi_deg: float
    corners_px: list[list[float]]  # visible corner projections
    detectable: bool
    floor_corners: list[list[float]] = field(default_factory=list)
    """visible bottom corners: [x, y, range_m], range the horizontal distance from the
    camera, metres (the truth of :mod:`companion.vision.ranging`)"""
    kind: str = "box"  # what the box bounds: box, table, cabinet or sofa (sitl.pathtraced)
    eye_level: bool = False
    """not ``detectable`` only because the top is seen edge-on, at the camera's height:
    a vertical edge passes every test of ``detectable`` but that its top corner's two
    horizontal edges are apart, which they cannot be when both lie along the horizon. Its
    bottom corner and the vertical edge still fix the obstacle's OVPs (the horizon stands
    in for the top edges)"""


@dataclass(frozen=True)
class SceneTruth:
    focal_px: float
    width: int
    height: int
    layout_vps: list[list[float]]  # room north, east, down axes
    obstacles: list[ObstacleTruth]
    camera_height_m: float = 0.0
    distortion: tuple[float, ...] = ()  # the lens as OpenCV's (k1, k2, p1, p2, k3); () pinhole

    def to_json(self) -> dict:
        return asdict(self)


# --------------------------------------------------------------------------- ray casting


def _cast(scene: Scene, origin: np.ndarray, dirs: np.ndarray):
    """First hit of rays ``origin + t·dirs`` (dirs N×3): t (N,), surface id (N,), normal."""
    room = scene.room
    n = len(dirs)
    lo = np.array([room.x_min, room.y_min, -room.height])
    hi = np.array([room.x_max, room.y_max, 0.0])
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = np.where(dirs > 0, hi, lo)
        t_axes = (bound - origin) / dirs
    t_axes = np.where(np.abs(dirs) > 1e-12, t_axes, np.inf)
    axis = np.argmin(t_axes, axis=1)
    t = t_axes[np.arange(n), axis]
    positive = dirs[np.arange(n), axis] > 0
    # axis 0: x (north/south walls), 1: y (east/west), 2: z (floor/ceiling).
    ids = np.select(
        [(axis == 2) & positive, axis == 2, (axis == 0) & positive, axis == 0, positive],
        [FLOOR, CEILING, NORTH, SOUTH, EAST],
        WEST,
    )
    normal = np.zeros((n, 3))
    normal[np.arange(n), axis] = np.where(positive, -1.0, 1.0)

    for k, box in enumerate(scene.boxes):
        # Cheap cone test first: only rays toward the box's bounding sphere go on.
        centre = np.array([box.x, box.y, -box.height / 2])
        to_c = centre - origin
        dist_c = float(np.linalg.norm(to_c))
        r_bound = math.sqrt(box.length**2 + box.width**2 + box.height**2) / 2
        if dist_c > r_bound:
            cos_lim = math.sqrt(1.0 - (r_bound / dist_c) ** 2)
            cand = np.flatnonzero(dirs @ (to_c / dist_c) >= cos_lim - 1e-9)
        else:
            cand = np.arange(n)
        if len(cand) == 0:
            continue
        a1, a2 = box.axes()
        rot = np.vstack([a1, a2, [0.0, 0.0, 1.0]])
        o = rot @ (origin - np.array([box.x, box.y, 0.0]))
        d = dirs[cand] @ rot.T
        m = len(cand)
        blo = np.array([-box.length / 2, -box.width / 2, -box.height])
        bhi = np.array([box.length / 2, box.width / 2, 0.0])
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (blo - o) / d
            t2 = (bhi - o) / d
        tmin = np.minimum(t1, t2)
        tmax = np.maximum(t1, t2)
        par = np.abs(d) < 1e-12
        inside = (o >= blo) & (o <= bhi)
        tmin = np.where(par, np.where(inside, -np.inf, np.inf), tmin)
        tmax = np.where(par, np.where(inside, np.inf, -np.inf), tmax)
        enter_axis = np.argmax(tmin, axis=1)
        t_enter = tmin[np.arange(m), enter_axis]
        t_exit = tmax.min(axis=1)
        hit = (t_enter <= t_exit) & (t_enter > 1e-6) & (t_enter < t[cand])
        if not hit.any():
            continue
        rows = cand[hit]
        axis_h = enter_axis[hit]
        face_sign = d[hit, axis_h] > 0  # entering through the low face
        t[rows] = t_enter[hit]
        ids[rows] = 100 + 10 * k + 2 * axis_h + face_sign
        local_n = np.zeros((len(rows), 3))
        local_n[np.arange(len(rows)), axis_h] = np.where(face_sign, -1.0, 1.0)
        normal[rows] = local_n @ rot
    return t, ids, normal


def _hash01(i: np.ndarray, j: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic pseudo-random value in [0, 1) per integer cell (i, j)."""
    h = (i.astype(np.int64) * 73856093) ^ (j.astype(np.int64) * 19349663) ^ (seed * 83492791)
    h = (h ^ (h >> 13)) * 1274126177
    return ((h ^ (h >> 16)) & 0xFFFF) / 65536.0


def _wall_coords(ids: np.ndarray, pts: np.ndarray, room: Room) -> tuple[np.ndarray, np.ndarray]:
    """Position along the wall (from its west/south end) and height above the floor."""
    along = np.where(np.isin(ids, (NORTH, SOUTH)), pts[:, 1] - room.y_min, pts[:, 0] - room.x_min)
    return along, -pts[:, 2]


def _albedo(scene: Scene, ids: np.ndarray, pts: np.ndarray) -> np.ndarray:
    room = scene.room
    n = len(ids)
    alb = np.zeros((n, 3))
    # Floor: tiles with grout and per-tile variation.
    fl = ids == FLOOR
    if fl.any():
        u = pts[fl, 0] / room.tile_m
        v = pts[fl, 1] / room.tile_m
        iu, iv = np.floor(u), np.floor(v)
        var = 0.88 + 0.2 * _hash01(iu, iv, scene.seed)
        grout = ((u - iu) < 0.03) | ((v - iv) < 0.03)
        base = np.array(room.floor_albedo)[None] * var[:, None]
        a = np.where(grout[:, None], base * 0.55, base)
        if room.rug is not None:
            r = room.rug
            ca, sa = math.cos(math.radians(r.yaw_deg)), math.sin(math.radians(r.yaw_deg))
            dx, dy = pts[fl, 0] - r.x, pts[fl, 1] - r.y
            lu, lv = ca * dx + sa * dy, -sa * dx + ca * dy
            on = (np.abs(lu) <= r.length / 2) & (np.abs(lv) <= r.width / 2)
            stripe = (np.floor((lu + r.length / 2) / r.stripe_m) % 2) == 0
            rug = np.array(r.albedo)[None] * np.where(stripe, 1.0, 0.7)[:, None]
            a = np.where(on[:, None], rug, a)
        alb[fl] = a
    # Ceiling: light panels.
    ce = ids == CEILING
    if ce.any():
        u, v = pts[ce, 0] / 1.2, pts[ce, 1] / 1.2
        seam = ((u - np.floor(u)) < 0.015) | ((v - np.floor(v)) < 0.015)
        alb[ce] = np.where(seam[:, None], 0.6, 0.9)
    # Walls: paint, baseboard, decorations.
    wl = np.isin(ids, (NORTH, SOUTH, EAST, WEST))
    if wl.any():
        w_ids = ids[wl]
        along, up = _wall_coords(w_ids, pts[wl], room)
        tint = 1.0 - 0.06 * (w_ids % 3)
        a = np.array(room.wall_albedo)[None] * tint[:, None]
        a = np.where((up < 0.1)[:, None], np.array([0.35, 0.33, 0.3]), a)
        by_wall = {w: np.flatnonzero(w_ids == w) for w in (NORTH, SOUTH, EAST, WEST)}
        for rect in room.decorations:
            sel = by_wall[rect.wall]
            cx, cy = rect.along + rect.width / 2, (rect.bottom + rect.top) / 2
            tilt = math.radians(rect.tilt_deg)
            du, dv = along[sel] - cx, up[sel] - cy
            lu = math.cos(tilt) * du + math.sin(tilt) * dv
            lv = -math.sin(tilt) * du + math.cos(tilt) * dv
            hw, hh = rect.width / 2, (rect.top - rect.bottom) / 2
            inside = (np.abs(lu) <= hw) & (np.abs(lv) <= hh)
            inner = inside & (np.abs(lu) <= hw - rect.frame) & (np.abs(lv) <= hh - rect.frame)
            a[sel[inside]] = np.array(rect.albedo) * 0.6
            a[sel[inner]] = np.array(rect.albedo)
        alb[wl] = a
    # Boxes: albedo per box, faint wood grain along the length axis.
    bx = ids >= 100
    if bx.any():
        k = (ids[bx] - 100) // 10
        for kk in np.unique(k):
            sel = np.flatnonzero(bx)[k == kk]
            alb[sel] = np.array(scene.boxes[kk].albedo)
    return alb


def _shade(scene: Scene, pts: np.ndarray, normal: np.ndarray, alb: np.ndarray) -> np.ndarray:
    room = scene.room
    light = np.array(
        [(room.x_min + room.x_max) / 2, (room.y_min + room.y_max) / 2, -room.height + 0.3]
    )
    to_l = light - pts
    dist = np.linalg.norm(to_l, axis=1)
    lam = np.clip(np.sum(normal * to_l, axis=1) / np.maximum(dist, 1e-9), 0.0, 1.0)
    fall = 1.0 / (1.0 + (dist / 5.0) ** 2)
    # A low key light from one side so that the faces of a box differ in brightness.
    key = np.array([0.55, -0.75, 0.35]) / np.linalg.norm([0.55, -0.75, 0.35])
    fill = 0.35 * np.clip(-(normal @ key), 0.0, 1.0)
    return alb * (0.22 + 0.85 * lam * fall + fill)[:, None]


def _rays(cam: Camera, scale: int) -> np.ndarray:
    w, h = cam.width * scale, cam.height * scale
    f = cam.focal_px * scale
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    d_cam = np.stack([(u - cx) / f, (v - cy) / f, np.ones_like(u)], axis=-1).reshape(-1, 3)
    d = d_cam @ cam.rotation()  # camera → world (R is orthonormal)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def render_image(scene: Scene, cam: Camera, supersample: int = 2,
                 frame: int | None = None) -> np.ndarray:
    """The scene as the camera sees it: H×W×3 uint8 BGR, with blur and sensor noise.

    ``frame``: the sensor noise of that frame of a video, drawn anew each frame as a
    camera's is (from ``scene.seed`` and ``frame``); None: the scene's one still picture.
    """
    dirs = _rays(cam, supersample)
    t, ids, normal = _cast(scene, cam.position, dirs)
    pts = cam.position + t[:, None] * dirs
    color = _shade(scene, pts, normal, _albedo(scene, ids, pts))
    img = color.reshape(cam.height * supersample, cam.width * supersample, 3)
    img = cv2.resize(img.astype(np.float32), (cam.width, cam.height), interpolation=cv2.INTER_AREA)
    img *= 255.0
    if scene.blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), scene.blur_sigma)
    if scene.noise_sigma > 0:
        rng = np.random.default_rng(scene.seed if frame is None else [scene.seed, frame])
        img += rng.normal(0.0, scene.noise_sigma, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


def visible(scene: Scene, cam: Camera, points: np.ndarray, margin_px: float = 2.0) -> np.ndarray:
    """Whether each world point is in the frame (with a margin) and not occluded."""
    pts = np.atleast_2d(points)
    uv, z = cam.project(pts)
    in_frame = (
        (z > 1e-6)
        & (uv[:, 0] >= margin_px)
        & (uv[:, 0] <= cam.width - 1 - margin_px)
        & (uv[:, 1] >= margin_px)
        & (uv[:, 1] <= cam.height - 1 - margin_px)
    )
    delta = pts - cam.position
    dist = np.linalg.norm(delta, axis=1)
    t, _, _ = _cast(scene, cam.position, delta / dist[:, None])
    return in_frame & (t >= dist * (1 - 1e-4) - 1e-4)


# --------------------------------------------------------------------------- truth


def _fold45(angle_deg: float) -> float:
    a = (angle_deg + 45.0) % 90.0 - 45.0
    return 45.0 if a == -45.0 else a


def _visible_run_px(scene, cam, start, end, samples=48) -> float:
    """Pixel length of the visible part of edge start→end that begins at ``start``."""
    s = np.linspace(0.0, 1.0, samples)[1:]
    pts = start + s[:, None] * (end - start)
    vis = visible(scene, cam, pts)
    run = int(np.argmin(vis)) if not vis.all() else len(vis)
    if run == 0:
        return 0.0
    uv, _ = cam.project(np.vstack([start, pts[run - 1]]))
    return float(np.linalg.norm(uv[1] - uv[0]))


def _box_truth(scene: Scene, cam: Camera, k: int, min_edge_px: float) -> ObstacleTruth:
    box = scene.boxes[k]
    f, c = cam.focal_px, cam.centre_px
    a1, a2 = box.axes()
    ovps = [cam.vp_of(a1), cam.vp_of(a2)]
    # eq. 9: M is the OVP closest to the centre; eq. 10 with D = f.
    dist = [np.linalg.norm(v[:2] - v[2] * c) / max(abs(v[2]), 1e-300) for v in ovps]
    m = ovps[int(np.argmin(dist))]
    mx, my = m[0] - m[2] * c[0], -(m[1] - m[2] * c[1])
    eta = math.degrees(math.atan2(mx, m[2] * f))
    phi = math.degrees(math.atan2(my, math.hypot(m[2] * f, mx)))
    m_px = [mx / m[2], my / m[2]] if abs(m[2]) > 1e-12 else None

    bottom = box.footprint()
    top = bottom + np.array([0.0, 0.0, -box.height])
    corners = np.vstack([bottom, top])
    vis = visible(scene, cam, corners)
    uv, _ = cam.project(corners)
    rel = _fold45(box.yaw_deg)
    non_manhattan = abs(rel) >= scene.min_rel_yaw_deg

    # A vertical edge whose two ends are corners with both horizontal edges in view, each
    # pair apart in the image: detectable. Apart everywhere but at the top: eye level.
    detectable = eye_level = False
    if non_manhattan:
        for i in range(4):
            b, t = i, i + 4
            if not (vis[b] and vis[t]) or np.linalg.norm(uv[b] - uv[t]) < min_edge_px:
                continue
            seen, apart = [], []
            for ring in (bottom, top):
                runs, dirs = [], []
                for nb in ((i + 1) % 4, (i + 3) % 4):
                    runs.append(_visible_run_px(scene, cam, ring[i], ring[nb]))
                    pu, _ = cam.project(
                        np.vstack([ring[i], ring[i] + 0.05 * (ring[nb] - ring[i])])
                    )
                    dirs.append((pu[1] - pu[0]) / max(np.linalg.norm(pu[1] - pu[0]), 1e-9))
                seen.append(min(runs) >= min_edge_px)
                apart.append(abs(dirs[0][0] * dirs[1][1] - dirs[0][1] * dirs[1][0])
                             >= math.sin(math.radians(10)))
            if all(seen) and all(apart):
                detectable = True
                break
            eye_level = eye_level or (all(seen) and apart[0])
        eye_level = eye_level and not detectable
    return ObstacleTruth(
        box=k,
        rel_yaw_deg=rel,
        non_manhattan=non_manhattan,
        ovps=[v.tolist() for v in ovps],
        m_px=m_px,
        eta_deg=eta,
        phi_deg=phi,
        corners_px=uv[vis].tolist(),
        detectable=detectable,
        eye_level=eye_level,
        floor_corners=[[float(uv[i][0]), float(uv[i][1]),
                        float(math.hypot(*(bottom[i][:2] - cam.position[:2])))]
                       for i in range(4) if vis[i]],
    )


def scene_truth(scene: Scene, cam: Camera, min_edge_px: float = 15.0) -> SceneTruth:
    """Ground truth of ``scene`` seen by ``cam`` (see the module docstring)."""
    axes = (np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]))
    return SceneTruth(
        focal_px=cam.focal_px,
        width=cam.width,
        height=cam.height,
        layout_vps=[cam.vp_of(a).tolist() for a in axes],
        obstacles=[_box_truth(scene, cam, k, min_edge_px) for k in range(len(scene.boxes))],
        camera_height_m=cam.height_m,
    )


def render(scene: Scene, cam: Camera, supersample: int = 2,
           frame: int | None = None) -> tuple[np.ndarray, SceneTruth]:
    """Image (H×W×3 uint8 BGR) and :class:`SceneTruth` of ``scene`` seen by ``cam``
    (``frame``: see :func:`render_image`)."""
    return render_image(scene, cam, supersample, frame), scene_truth(scene, cam)


def _mirror_vp(vp: list[float], width: int) -> list[float]:
    """A homogeneous pixel VP (unit 3-vector) of the frame mirrored left to right."""
    x, y, w = vp
    v = np.array([(width - 1) * w - x, y, w])
    return (v / np.linalg.norm(v)).tolist()


def orientations(mirrored: bool) -> tuple[bool, ...]:
    """The views of a frame an evaluation runs, each ``True`` when mirrored left to right
    (:func:`mirror`): as taken, and mirrored as well when ``mirrored`` is asked for."""
    return (False, True) if mirrored else (False,)


def mirror(image: np.ndarray, truth: SceneTruth) -> tuple[np.ndarray, SceneTruth]:
    """``image`` mirrored left to right (pixel x → W − 1 − x, about the principal point
    ((W − 1) / 2)) and the truth of the room it then shows: the same room seen in a
    mirror, so each obstacle's η, yaw and M_x change sign while φ and ranges stay.

    A second, independent view of every frame at no rendering cost: the stages' rules
    are not symmetric in their search order, and a change worth a few points on a split
    of a few dozen obstacles is told from chance better on twice the frames.
    The lens's tangential term p2 changes sign; the radial terms stay.
    """
    w = truth.width

    def xs(points):
        return [[w - 1 - p[0], *p[1:]] for p in points]

    obstacles = [replace(o, rel_yaw_deg=_fold45(-o.rel_yaw_deg),
                         ovps=[_mirror_vp(v, w) for v in o.ovps],
                         m_px=None if o.m_px is None else [-o.m_px[0], o.m_px[1]],
                         eta_deg=-o.eta_deg, corners_px=xs(o.corners_px),
                         floor_corners=xs(o.floor_corners))
                 for o in truth.obstacles]
    lens = list(truth.distortion)
    if len(lens) >= 4:
        lens[3] = -lens[3]
    return np.ascontiguousarray(image[:, ::-1]), replace(
        truth, layout_vps=[_mirror_vp(v, w) for v in truth.layout_vps], obstacles=obstacles,
        distortion=tuple(lens))


# --------------------------------------------------------------------------- generators


def random_colour(rng: np.random.Generator, lo: float, hi: float) -> tuple[float, float, float]:
    """A BGR albedo (0..1) near a grey level drawn from ``lo``..``hi``."""
    base = rng.uniform(lo, hi)
    return tuple(float(np.clip(base + rng.uniform(-0.12, 0.12), 0.05, 0.95)) for _ in range(3))


def random_decorations(rng: np.random.Generator, room: Room, clutter: bool
                       ) -> tuple[WallRect, ...]:
    """Doors, windows and pictures on every wall; with ``clutter``, tilted pictures too."""
    out = []
    lengths = {
        NORTH: room.y_max - room.y_min,
        SOUTH: room.y_max - room.y_min,
        EAST: room.x_max - room.x_min,
        WEST: room.x_max - room.x_min,
    }
    for wall, length in lengths.items():
        for _ in range(int(rng.integers(1, 4))):
            kind = rng.choice(["door", "window", "picture"])
            if kind == "door":
                w, b, t = rng.uniform(0.8, 1.0), 0.0, rng.uniform(1.95, 2.1)
            elif kind == "window":
                w, b = rng.uniform(0.8, 1.6), rng.uniform(0.8, 1.0)
                t = b + rng.uniform(0.8, 1.2)
            else:
                w, b = rng.uniform(0.4, 1.0), rng.uniform(1.2, 1.5)
                t = b + rng.uniform(0.3, 0.7)
            along = rng.uniform(0.2, max(0.3, length - w - 0.2))
            out.append(
                WallRect(wall, along, w, b, min(t, room.height - 0.1), random_colour(rng, 0.2, 0.7))
            )
        if clutter and rng.random() < 0.5:
            w = rng.uniform(0.3, 0.6)
            out.append(
                WallRect(
                    wall,
                    rng.uniform(0.2, max(0.3, length - w - 0.2)),
                    w,
                    1.3,
                    1.3 + rng.uniform(0.3, 0.5),
                    random_colour(rng, 0.2, 0.6),
                    tilt_deg=float(rng.uniform(10, 35) * rng.choice([-1, 1])),
                )
            )
    return tuple(out)


def random_scene(
    rng: np.random.Generator,
    width: int = 640,
    height: int = 480,
    obstacle: bool = True,
    aligned_boxes: int | None = None,
    clutter: bool = True,
    hfov_deg: float | None = None,
    eye_level: bool = False,
) -> tuple[Scene, Camera]:
    """A random room, camera and boxes (all randomness from ``rng``).

    The field of view is ``hfov_deg``, else drawn from 60–90° (drawn either way, so
    that the rest of the scene does not depend on it).

    With ``obstacle`` one box is rotated 12°–45° off the room's axes and placed 2.2–5 m
    ahead inside the field of view; ``aligned_boxes`` (random 0–2 by default, 1–3 without
    an obstacle) are Manhattan boxes anywhere in the room. With ``eye_level`` the camera
    is then moved to the height of the rotated box's top (:func:`at_eye_level`): the
    same room, seen by a vehicle flying at the furniture's height.
    """
    length, wid = rng.uniform(7.0, 12.0), rng.uniform(5.0, 9.0)
    room_h = rng.uniform(2.5, 3.2)
    room0 = Room(
        x_min=0.0,
        x_max=length,
        y_min=-wid / 2,
        y_max=wid / 2,
        height=room_h,
        tile_m=float(rng.choice([0.3, 0.4, 0.5, 0.6])),
        floor_albedo=random_colour(rng, 0.4, 0.75),
        wall_albedo=random_colour(rng, 0.6, 0.85),
    )
    drawn_fov = float(rng.uniform(60.0, 90.0))
    cam = Camera(
        width=width,
        height=height,
        hfov_deg=hfov_deg or drawn_fov,
        x=float(rng.uniform(0.8, 2.0)),
        y=float(rng.uniform(-wid / 4, wid / 4)),
        height_m=float(rng.uniform(0.8, 1.8)),
        yaw_deg=float(rng.uniform(-35.0, 35.0)),
        pitch_deg=float(rng.uniform(-6.0, 6.0)),
        roll_deg=float(rng.uniform(-3.0, 3.0)),
    )
    boxes: list[Box] = []

    def free(x: float, y: float, r: float) -> bool:
        if not (room0.x_min + r + 0.1 < x < room0.x_max - r - 0.1):
            return False
        if not (room0.y_min + r + 0.1 < y < room0.y_max - r - 0.1):
            return False
        if math.hypot(x - cam.x, y - cam.y) < r + 1.2:
            return False
        return all(math.hypot(x - b.x, y - b.y) > r + b.radius() + 0.2 for b in boxes)

    if obstacle:
        for _ in range(200):
            dist = rng.uniform(2.2, 5.0)
            bearing = cam.yaw_deg + rng.uniform(-0.3, 0.3) * cam.hfov_deg
            x = cam.x + dist * math.cos(math.radians(bearing))
            y = cam.y + dist * math.sin(math.radians(bearing))
            rel = rng.uniform(12.0, 45.0) * rng.choice([-1, 1])
            yaw = float(rel + 90.0 * rng.integers(0, 4))
            # Both side faces must show: the line of sight 15°–75° off the box's axes.
            if not 15.0 <= (yaw - bearing) % 90.0 <= 75.0:
                continue
            b = Box(
                x,
                y,
                yaw,
                float(rng.uniform(0.6, 1.6)),
                float(rng.uniform(0.4, 1.0)),
                float(rng.uniform(0.5, 1.6)),
                random_colour(rng, 0.15, 0.6),
            )
            if free(x, y, b.radius()):
                boxes.append(b)
                break
    rotated = boxes[0] if boxes else None
    n_aligned = (
        aligned_boxes
        if aligned_boxes is not None
        else int(rng.integers(0 if obstacle else 1, 3 if obstacle else 4))
    )
    for _ in range(n_aligned):
        for _ in range(50):
            b = Box(
                float(rng.uniform(room0.x_min, room0.x_max)),
                float(rng.uniform(room0.y_min, room0.y_max)),
                float(90.0 * rng.integers(0, 4)),
                float(rng.uniform(0.5, 1.5)),
                float(rng.uniform(0.4, 1.0)),
                float(rng.uniform(0.4, 1.8)),
                random_colour(rng, 0.15, 0.6),
            )
            if free(b.x, b.y, b.radius()):
                boxes.append(b)
                break
    rug = None
    if clutter and rng.random() < 0.5:
        rug = striped_rug(rng, float(rng.uniform(room0.x_min + 2, room0.x_max - 1)),
                          float(rng.uniform(room0.y_min + 1, room0.y_max - 1)))
    room = replace(room0, decorations=random_decorations(rng, room0, clutter), rug=rug)
    scene = Scene(
        room=room,
        boxes=tuple(boxes),
        noise_sigma=float(rng.uniform(1.5, 5.0)),
        blur_sigma=float(rng.uniform(0.4, 1.0)),
        seed=int(rng.integers(0, 2**31 - 1)),
    )
    if eye_level and rotated is not None:
        cam = at_eye_level(rng, cam, rotated.height)
    return scene, cam


def rug_in_view(rng: np.random.Generator, room: Room, cam: Camera) -> Rug:
    """A striped rug turned 10°–80° off the room's axes on the floor in front of ``cam``
    (all randomness from ``rng``): its centre 1.5–4.5 m ahead, within the middle 60 % of
    the field of view, inside the room. Furniture may stand on it, as on a real rug.

    A rug is the clutter that fools the fewer-corner rules (stripes meeting an aligned
    box's edge read as a rotated face); ``companion eval --rug`` lays one in every split
    room, the path-traced splits having none of their own."""
    dist = rng.uniform(1.5, 4.5)
    bearing = math.radians(cam.yaw_deg + rng.uniform(-0.3, 0.3) * cam.hfov_deg)
    margin = 0.6
    x = float(np.clip(cam.x + dist * math.cos(bearing), room.x_min + margin, room.x_max - margin))
    y = float(np.clip(cam.y + dist * math.sin(bearing), room.y_min + margin, room.y_max - margin))
    return striped_rug(rng, x, y)


def striped_rug(rng: np.random.Generator, x: float, y: float) -> Rug:
    """A striped rug centred at ``x``, ``y`` (metres): turned 10°–80° off the room's axes,
    1.2–2.5 m × 0.8–1.6 m, its colour drawn (all randomness from ``rng``)."""
    return Rug(x, y, float(rng.uniform(10.0, 80.0)), float(rng.uniform(1.2, 2.5)),
               float(rng.uniform(0.8, 1.6)), random_colour(rng, 0.2, 0.6))


EYE_LEVEL_M = 0.15
"""an eye-level camera is within this of the obstacle's top (2–4° at 2.2–5 m)"""


def at_eye_level(rng: np.random.Generator, cam: Camera, top_m: float) -> Camera:
    """``cam`` moved up or down to within :data:`EYE_LEVEL_M` of ``top_m`` (metres above
    the floor), as a vehicle flying at a piece of furniture's height sees it: the top is
    seen edge-on, along the horizon, where every horizontal direction looks alike."""
    return replace(cam, height_m=float(top_m + rng.uniform(-EYE_LEVEL_M, EYE_LEVEL_M)))


# --------------------------------------------------------------------------- video


def yaw_sweep(
    cam: Camera, start_deg: float, end_deg: float, frames: int, advance_m: float = 0.0
) -> Iterator[Camera]:
    """Cameras yawing from ``start_deg`` to ``end_deg`` (and moving ``advance_m`` forward)."""
    for i in range(frames):
        s = i / max(frames - 1, 1)
        yaw = start_deg + s * (end_deg - start_deg)
        x = cam.x + s * advance_m * math.cos(math.radians(cam.yaw_deg))
        y = cam.y + s * advance_m * math.sin(math.radians(cam.yaw_deg))
        yield replace(cam, yaw_deg=yaw, x=x, y=y)


def write_video(
    scene: Scene,
    cameras: Iterable[Camera],
    path: str | Path,
    fps: float = 10.0,
    truth_path: str | Path | None = None,
) -> int:
    """Render ``cameras`` into an MP4 (OpenCV, mp4v) and per-frame truth as JSON lines.

    Returns the number of frames written.
    """
    path = Path(path)
    writer = None
    count = 0
    with contextlib.ExitStack() as stack:
        truth_file = (
            stack.enter_context(open(truth_path, "w", encoding="utf-8")) if truth_path else None
        )
        stack.callback(lambda: writer is not None and writer.release())
        for i, cam in enumerate(cameras):
            img, truth = render(scene, cam, frame=i + 1)
            if writer is None:
                writer = cv2.VideoWriter(
                    str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (cam.width, cam.height)
                )
                if not writer.isOpened():
                    raise OSError(f"cannot write video {path}")
            writer.write(img)
            if truth_file:
                rec = {"frame": i, "t": i / fps, "camera": asdict(cam), **truth.to_json()}
                truth_file.write(json.dumps(rec) + "\n")
            count += 1
    return count
