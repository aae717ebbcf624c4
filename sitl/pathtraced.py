"""A second, independent renderer: rooms path-traced by Mitsuba 3 (evaluation only).

:mod:`sitl.scene` ray-casts flat-shaded boxes; the vision stages were developed on it. This
module draws the rooms a real camera meets, with an established physically based engine
(Mitsuba 3, ``scalar_rgb`` variant, unidirectional path tracing), so that a rule tuned to
one renderer's look shows up as a loss on the other:

- **Light.** Ceiling panels and a window are area lights: soft cast shadows (a box's shadow
  on the floor is a non-Manhattan edge at its foot) and interreflection (one bounce).
- **Materials.** Wood-plank, carpet or tiled floors, some of them glossy (reflections of the
  furniture and the lamps); painted, striped or patterned wallpaper; a baseboard; doors,
  windows and pictures; wood, paint and fabric furniture. Textures are drawn procedurally
  from the scene's random generator.
- **Furniture that is not a box**: a table on legs, a cabinet on a plinth with door seams
  and handles, a sofa with arms, back and cushions, and plain boxes. Several at once: a
  rotated obstacle ahead, sometimes a second rotated one, and Manhattan furniture.
- **Camera.** Fields of view of 50–110°, pitch and roll of a few degrees, radial lens
  distortion, motion blur from the vehicle's own yaw during the exposure, exposure error
  with clipped highlights, vignetting, shot and read noise.

Ground truth is exact and comes from the geometry, as in :mod:`sitl.scene`: each piece of
furniture's axes give its OVPs, M (eq. 9) and η, φ (eq. 10 with D = f, the pinhole focal
length before distortion); visibility and detectability are those of its bounding box
(:func:`sitl.scene.scene_truth`), and corner projections are moved by the same lens
distortion as the pixels. World frame as in :mod:`sitl.scene` (NED, floor ``z = 0``).

Mitsuba is an optional extra (``pip install 'companion[render]'``), never needed on the
drone. ``render`` takes about 1.3 s at 640×480 and 16 samples per pixel on one core.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from sitl.scene import (
    EAST,
    NORTH,
    SOUTH,
    WEST,
    Box,
    Camera,
    Room,
    Scene,
    SceneTruth,
    WallRect,
    at_eye_level,
    random_colour,
    random_decorations,
    scene_truth,
    yaw_axes,
)

__all__ = ["Furniture", "Look", "Room3D", "random_room", "random_look", "render", "truth",
           "available", "KINDS", "VERSION"]

VERSION = 2
"""bumped whenever a change alters the pictures: cached renders of another version are not reused"""
KINDS = ("box", "table", "cabinet", "sofa")
MAX_DEPTH = 3
"""path length: direct light and one bounce of interreflection (4 costs 40 % more)"""
UP = np.array([0.0, 0.0, -1.0])  # NED


def available() -> bool:
    """Whether Mitsuba 3 is installed (``companion[render]``)."""
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        return False
    return True


@dataclass(frozen=True)
class Furniture:
    """A piece of furniture standing on the floor. ``yaw_deg``: heading of its length axis;
    ``length`` × ``width`` × ``height`` metres: its bounding box; ``back`` of a sofa is on
    its −width side."""

    kind: str
    x: float
    y: float
    yaw_deg: float
    length: float
    width: float
    height: float
    colour: tuple[float, float, float]  # BGR 0..1
    material: str = "paint"  # paint | wood | fabric | gloss

    def bounding_box(self) -> Box:
        return Box(self.x, self.y, self.yaw_deg, self.length, self.width, self.height,
                   self.colour)

    def parts(self) -> list[tuple[tuple[float, float, float], tuple[float, float, float], float]]:
        """Cuboids in the furniture's own frame: (centre (along, across, up), half extents,
        shade factor). Shade < 1 darkens a part (seams, plinths, handles)."""
        L, W, H = self.length / 2, self.width / 2, self.height
        if self.kind == "table":
            t, leg, inset = 0.04, 0.025, 0.04
            out = [((0, 0, H - t / 2), (L, W, t / 2), 1.0)]
            for sx in (-1, 1):
                for sy in (-1, 1):
                    out.append(((sx * (L - inset - leg), sy * (W - inset - leg), (H - t) / 2),
                                (leg, leg, (H - t) / 2), 0.8))
            return out
        if self.kind == "cabinet":
            plinth, inset = 0.08, 0.05
            out = [((0, 0, plinth / 2), (L - inset, W - inset, plinth / 2), 0.35),
                   ((0, 0, plinth + (H - plinth) / 2), (L, W, (H - plinth) / 2), 1.0)]
            doors = 2 if self.length > 0.9 else 1
            for face in (-1, 1):  # seams and handles on both long faces
                for k in range(1, doors):
                    x = -L + 2 * L * k / doors
                    out.append(((x, face * (W + 0.002), plinth + (H - plinth) / 2),
                                (0.004, 0.003, (H - plinth) / 2 - 0.03), 0.3))
                for k in range(doors):
                    x = -L + 2 * L * (k + 0.5) / doors + 0.12 * (1 if k % 2 else -1)
                    out.append(((x, face * (W + 0.012), plinth + 0.6 * (H - plinth)),
                                (0.008, 0.012, 0.06), 0.4))
            return out
        if self.kind == "sofa":
            seat, arm_w, arm_h, back_d = 0.42, 0.15, min(0.62, H - 0.1), 0.2
            out = [((0, 0, seat / 2), (L, W, seat / 2), 0.9),
                   ((0, -W + back_d / 2, seat + (H - seat) / 2), (L, back_d / 2, (H - seat) / 2),
                    1.0)]
            for sx in (-1, 1):
                out.append(((sx * (L - arm_w / 2), back_d / 2, (seat + arm_h) / 2),
                            (arm_w / 2, W - back_d / 2, (arm_h - seat) / 2 + seat / 2), 1.0))
            inner = L - arm_w
            n = 3 if inner > 0.9 else 2
            cw = 2 * inner / n
            for k in range(n):
                cx = -inner + cw * (k + 0.5)
                out.append(((cx, back_d / 2 + 0.01, seat + 0.06),
                            (cw / 2 - 0.012, W - back_d / 2 - 0.03, 0.06), 1.05))
            return out
        return [((0, 0, H / 2), (L, W, H / 2), 1.0)]


@dataclass(frozen=True)
class Look:
    """Everything about the picture that is not geometry."""

    floor: str = "planks"  # planks | carpet | tiles
    floor_gloss: float = 0.0  # 0: matte; else the roughness (alpha) of a glossy coat
    wall: str = "paint"  # paint | stripes | pattern
    floor_colour: tuple[float, float, float] = (0.45, 0.55, 0.65)
    wall_colour: tuple[float, float, float] = (0.78, 0.8, 0.82)
    lamp_power: float = 6.0
    window_power: float = 0.0  # 0: no daylight window
    exposure_ev: float = 0.0  # exposure error, stops (+ over, − under)
    yaw_rate_deg_s: float = 0.0  # motion blur over the exposure
    exposure_ms: float = 10.0
    distortion_k1: float = 0.0  # radial, normalised by the focal length; > 0 barrel
    vignetting: float = 0.0  # fraction lost at the frame corner
    shot_noise: float = 1.0  # variance per grey level
    read_noise: float = 2.0  # grey levels
    spp: int = 16
    seed: int = 0  # textures, and the noise of a still
    frame: int = 0  # frame k of a video: its noise is drawn afresh, its textures stay

    @property
    def sampler_seed(self) -> int:
        """The path tracer's seed: the still's, moved on by the frame of a video."""
        return self.seed + self.frame


@dataclass(frozen=True)
class Room3D:
    """A path-traced scene: the room, its furniture and how it is pictured."""

    room: Room
    furniture: tuple[Furniture, ...]
    look: Look = field(default_factory=Look)

    def truth_scene(self) -> Scene:
        """The same geometry as :mod:`sitl.scene` sees it (bounding boxes), for the truth."""
        return Scene(room=self.room, boxes=tuple(f.bounding_box() for f in self.furniture),
                     seed=self.look.seed)


# --------------------------------------------------------------------------- textures


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], cells: tuple[int, int]
                  ) -> np.ndarray:
    """Smooth noise in about [−1, 1], ``cells`` random values stretched over ``shape``."""
    small = rng.normal(0.0, 1.0, cells).astype(np.float32)
    return np.clip(cv2.resize(small, shape[::-1], interpolation=cv2.INTER_CUBIC) / 2.0, -1, 1)


def _rgb(bgr: tuple[float, float, float]) -> np.ndarray:
    """BGR albedo (0..1, display) → linear RGB."""
    return np.array(bgr[::-1], dtype=np.float32) ** 2.2


def _wood(rng, colour, size=256, planks=1) -> np.ndarray:
    """Wood grain along u (texture x), ``planks`` boards across v with dark seams."""
    v = np.linspace(0.0, 1.0, size, endpoint=False, dtype=np.float32)
    warp = _smooth_noise(rng, (size, size), (6, 3)) * 0.04
    grain = np.sin(2 * np.pi * (v[:, None] * 40 * planks + warp * 30)) * 0.5 + 0.5
    fine = _smooth_noise(rng, (size, size), (64, 8)) * 0.06
    board = np.floor(v * planks).astype(int)
    shade = 0.85 + 0.3 * rng.random(planks)[board][:, None]
    img = _rgb(colour)[None, None] * (shade * (0.85 + 0.15 * grain + fine))[..., None]
    if planks > 1:
        seam = (v * planks) % 1.0 < 0.03
        img[seam] *= 0.35
        for b in range(planks):  # staggered end joints
            j = int(rng.random() * size)
            rows = board == b
            img[np.ix_(rows, [j, (j + 1) % size])] *= 0.35
    return np.clip(img, 0, 1)


def _carpet(rng, colour, size=256) -> np.ndarray:
    n = rng.normal(0.0, 0.06, (size, size)).astype(np.float32)
    blot = _smooth_noise(rng, (size, size), (8, 8)) * 0.08
    return np.clip(_rgb(colour)[None, None] * (1.0 + n + blot)[..., None], 0, 1)


def _tiles(rng, colour, size=256, n=2) -> np.ndarray:
    img = np.empty((size, size, 3), np.float32)
    step = size // n
    for i in range(n):
        for j in range(n):
            img[i * step:(i + 1) * step, j * step:(j + 1) * step] = (
                _rgb(colour) * (0.9 + 0.2 * rng.random()))
    grout = (np.arange(size) % step) < 3
    img[grout] *= 0.5
    img[:, grout] *= 0.5
    return img


def _wallpaper(rng, colour, kind, size=256) -> np.ndarray:
    base = _rgb(colour)
    u = np.arange(size)
    if kind == "stripes":
        period = int(rng.choice([16, 32, 64]))
        stripe = ((u // (period // 2)) % 2 == 0).astype(np.float32)
        f = 1.0 - 0.18 * stripe[None, :] * np.ones((size, 1), np.float32)
    else:  # dots on a diagonal grid: many short non-Manhattan gradients, as damask has
        yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
        p = 32.0
        d1 = np.hypot((xx % p) - p / 2, (yy % p) - p / 2)
        d2 = np.hypot(((xx + p / 2) % p) - p / 2, ((yy + p / 2) % p) - p / 2)
        f = 1.0 - 0.22 * ((np.minimum(d1, d2) < 5).astype(np.float32))
    return np.clip(base[None, None] * f[..., None], 0, 1)


# --------------------------------------------------------------------------- Mitsuba scene


def _mi():
    import mitsuba as mi

    if mi.variant() != "scalar_rgb":
        mi.set_variant("scalar_rgb")  # the LLVM variants abort on some machines
    return mi


_TO_MI = np.diag([1.0, -1.0, -1.0])  # NED → Mitsuba (x north, y west, z up): a rotation


def _transform(mi, columns: np.ndarray, origin: np.ndarray):
    """A Mitsuba transform whose local x, y, z map to the NED ``columns`` (3×3) at ``origin``."""
    m = np.eye(4)
    m[:3, :3] = _TO_MI @ columns
    m[:3, 3] = _TO_MI @ origin
    return mi.ScalarTransform4f(mi.ScalarMatrix4f(m.tolist()))


def _bsdf(mi, texture: np.ndarray | None = None, rgb=None, gloss: float = 0.0,
          uv_scale: tuple[float, float] = (1.0, 1.0)) -> dict:
    if texture is not None:
        refl = {"type": "bitmap", "bitmap": mi.Bitmap(np.ascontiguousarray(texture)),
                "filter_type": "bilinear", "wrap_mode": "repeat",
                "to_uv": mi.ScalarTransform4f().scale([uv_scale[0], uv_scale[1], 1.0])}
    else:
        refl = {"type": "rgb", "value": [float(c) for c in rgb]}
    if gloss > 0:
        inner = {"type": "roughplastic", "distribution": "ggx", "alpha": float(gloss),
                 "diffuse_reflectance": refl}
    else:
        inner = {"type": "diffuse", "reflectance": refl}
    return {"type": "twosided", "material": inner}


def _rect(mi, centre, u, v, hu, hv, bsdf) -> dict:
    """A rectangle: ``u``, ``v`` unit NED axes, half sizes; its normal is u × v."""
    n = np.cross(u, v)
    return {"type": "rectangle", "bsdf": bsdf,
            "to_world": _transform(mi, np.column_stack([u * hu, v * hv, n]), np.asarray(centre))}


def _lights(mi, panels: list[tuple], folder: str) -> dict:
    """Every light as one mesh, hence one emitter: ``panels`` are (centre, u, v, hu, hv,
    radiance RGB) rectangles, as :func:`_rect`, each emitting along u × v. The mesh is
    written to ``folder`` as PLY, which Mitsuba reads back as it reads any mesh.

    Mitsuba picks the emitter to sample by its index, and a scene's emitters come in a
    different order from one load to the next: with several, the same scene and seed
    rendered to different pictures (95 % of the pixels, by up to 100 grey levels), and a
    frozen split's figures changed with every fresh cache. Each panel's radiance is a texel
    of a one-row texture that its texture coordinates cover (Mitsuba samples a textured
    emitter through its texture, then maps the sample back onto the mesh).
    """
    k = len(panels)
    mesh = mi.Mesh("lights", 4 * k, 2 * k, has_vertex_texcoords=True)
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)
    vertices, uvs, faces = [], [], []
    for i, (centre, u, v, hu, hv, _) in enumerate(panels):
        for cu, cv in corners:  # counter-clockwise about u × v: the face normal
            vertices.append(_TO_MI @ (np.asarray(centre) + cu * hu * u + cv * hv * v))
            uvs.append([(i + (cu + 1) / 2) / k, (cv + 1) / 2])
        faces += [[4 * i, 4 * i + 1, 4 * i + 2], [4 * i, 4 * i + 2, 4 * i + 3]]
    params = mi.traverse(mesh)
    params["vertex_positions"] = np.ravel(vertices).astype(np.float32)
    params["vertex_texcoords"] = np.ravel(uvs).astype(np.float32)
    params["faces"] = np.ravel(faces).astype(np.uint32)
    params.update()
    path = os.path.join(folder, "lights.ply")
    mesh.write_ply(path)
    texels = np.array([[p[5] for p in panels]], dtype=np.float32)
    return {"type": "ply", "filename": path, "face_normals": True,
            "emitter": {"type": "area", "radiance": {
                "type": "bitmap", "bitmap": mi.Bitmap(texels), "filter_type": "nearest",
                "raw": True}},
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0] * 3}}}


def _cube(mi, centre, a: np.ndarray, b: np.ndarray, half, bsdf) -> dict:
    """A cuboid with half extents ``half`` along the unit NED axes ``a``, ``b`` and a × b."""
    axes = np.column_stack([a, b, np.cross(a, b)]) * np.asarray(half, dtype=float)[None, :]
    return {"type": "cube", "to_world": _transform(mi, axes, np.asarray(centre)), "bsdf": bsdf}


def _wall_frame(room: Room, wall: int):
    """(origin at the wall's west/south end on the floor, along axis, inward normal)."""
    ex, ey = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    if wall == NORTH:
        return np.array([room.x_max, room.y_min, 0.0]), ey, -ex
    if wall == SOUTH:
        return np.array([room.x_min, room.y_min, 0.0]), ey, ex
    if wall == EAST:
        return np.array([room.x_min, room.y_max, 0.0]), ex, -ey
    return np.array([room.x_min, room.y_min, 0.0]), ex, ey


def _scene_dict(mi, r3: Room3D, cam: Camera, folder: str) -> dict:
    room, look = r3.room, r3.look
    rng = np.random.default_rng(look.seed)
    cx, cy = (room.x_min + room.x_max) / 2, (room.y_min + room.y_max) / 2
    lx, ly, h = room.x_max - room.x_min, room.y_max - room.y_min, room.height
    ex, ey = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    d: dict = {"type": "scene", "integrator": {"type": "path", "max_depth": MAX_DEPTH}}

    # Camera: Mitsuba's local x is image left, y image up, z forward.
    rot = cam.rotation()  # rows: right, down, forward (NED)
    cols = np.column_stack([-rot[0], -rot[1], rot[2]])
    d["sensor"] = {
        "type": "perspective", "fov": cam.hfov_deg, "fov_axis": "x",
        "near_clip": 0.05, "far_clip": 100.0,
        "to_world": _transform(mi, cols, cam.position),
        "sampler": {"type": "independent", "sample_count": look.spp,
                    "seed": look.sampler_seed},
        "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                 "rfilter": {"type": "gaussian"}, "pixel_format": "rgb"},
    }

    # Floor and ceiling.
    if look.floor == "planks":
        tex, tile = _wood(rng, look.floor_colour, planks=4), 0.8
    elif look.floor == "carpet":
        tex, tile = _carpet(rng, look.floor_colour), 0.5
    else:
        tex, tile = _tiles(rng, look.floor_colour), float(2 * room.tile_m)
    d["floor"] = _rect(mi, [cx, cy, 0.0], ex, -ey, lx / 2, ly / 2,  # normal up (−z NED)
                       _bsdf(mi, tex, gloss=look.floor_gloss, uv_scale=(lx / tile, ly / tile)))
    d["ceiling"] = _rect(mi, [cx, cy, -h], ex, ey, lx / 2, ly / 2,
                         _bsdf(mi, rgb=_rgb((0.88, 0.88, 0.88))))
    # Walls, a baseboard, and what hangs on them.
    wall_tex = None if look.wall == "paint" else _wallpaper(rng, look.wall_colour, look.wall)
    for wall in (NORTH, SOUTH, EAST, WEST):
        o, along, inward = _wall_frame(room, wall)
        length = lx if wall in (EAST, WEST) else ly
        tint = 1.0 - 0.05 * (wall % 3)
        centre = o + along * length / 2 + UP * h / 2
        bsdf = (_bsdf(mi, wall_tex, uv_scale=(length / 0.6, h / 0.6)) if wall_tex is not None
                else _bsdf(mi, rgb=_rgb(look.wall_colour) * tint))
        # u × v must point inward: along × up or up × along.
        u, v = (along, UP) if np.dot(np.cross(along, UP), inward) > 0 else (UP, along)
        hu, hv = (length / 2, h / 2) if u is along else (h / 2, length / 2)
        d[f"wall{wall}"] = _rect(mi, centre, u, v, hu, hv, bsdf)
        d[f"base{wall}"] = _cube(mi, o + along * length / 2 + UP * 0.05 + inward * 0.008,
                                 along, inward, [length / 2, 0.008, 0.05],
                                 _bsdf(mi, rgb=_rgb((0.92, 0.92, 0.9))))
    for k, rect in enumerate(room.decorations):
        o, along, inward = _wall_frame(room, rect.wall)
        centre = (o + along * (rect.along + rect.width / 2) + UP * (rect.bottom + rect.top) / 2
                  + inward * 0.01)
        t = math.radians(rect.tilt_deg)
        a = math.cos(t) * along + math.sin(t) * UP
        b = -math.sin(t) * along + math.cos(t) * UP
        half = np.array([rect.width / 2, 0.01, (rect.top - rect.bottom) / 2])
        d[f"deco{k}"] = _cube(mi, centre, a, b, half[[0, 2, 1]],
                              _bsdf(mi, rgb=_rgb(rect.albedo) * 0.6))
        d[f"deco{k}i"] = _cube(mi, centre + inward * 0.004, a, b,
                               (half - np.array([rect.frame, -0.001, rect.frame]))[[0, 2, 1]],
                               _bsdf(mi, rgb=_rgb(rect.albedo)))

    # Lights: ceiling panels, and daylight through a window.
    nx, ny = (2, 1) if lx > ly else (1, 2)
    panels: list[tuple] = []
    for i in range(nx):
        for j in range(ny):
            px = room.x_min + lx * (i + 0.5) / nx
            py = room.y_min + ly * (j + 0.5) / ny
            panels.append(([px, py, -h + 0.01], ex, ey, 0.3, 0.3,  # ex × ey: faces down
                           [look.lamp_power] * 3))
    if look.window_power > 0:
        windows = [r for r in room.decorations if r.bottom > 0.5 and r.tilt_deg == 0]
        if windows:
            w = windows[0]
            o, along, inward = _wall_frame(room, w.wall)
            centre = (o + along * (w.along + w.width / 2) + UP * (w.bottom + w.top) / 2
                      + inward * 0.03)
            u, v = (along, UP) if np.dot(np.cross(along, UP), inward) > 0 else (UP, along)
            hu, hv = ((w.width / 2, (w.top - w.bottom) / 2) if u is along
                      else ((w.top - w.bottom) / 2, w.width / 2))
            panels.append((centre, u, v, hu, hv,
                           [look.window_power * c for c in (0.95, 1.0, 1.1)]))

    d["lights"] = _lights(mi, panels, folder)

    # Furniture.
    for k, f in enumerate(r3.furniture):
        a1, a2 = yaw_axes(f.yaw_deg)
        if f.material == "wood":
            tex = _wood(rng, f.colour)
        elif f.material == "fabric":
            tex = _carpet(rng, f.colour)
        else:
            tex = None
        for j, (c, half, shade) in enumerate(f.parts()):
            centre = np.array([f.x, f.y, 0.0]) + c[0] * a1 + c[1] * a2 + c[2] * UP
            if tex is not None and shade >= 0.99:
                bsdf = _bsdf(mi, tex * min(shade, 1.0))
            else:
                bsdf = _bsdf(mi, rgb=_rgb(f.colour) * shade,
                             gloss=0.15 if f.material == "gloss" else 0.0)
            d[f"f{k}p{j}"] = _cube(mi, centre, a1, a2, half, bsdf)
    if room.rug is not None:  # striped, as sitl.scene draws it: lines on the floor at its yaw
        rug = room.rug
        a1, a2 = yaw_axes(rug.yaw_deg)
        tex = _carpet(rng, rug.albedo)
        tex[:, tex.shape[1] // 2:] *= 0.45  # 0.7 of the albedo, as displayed
        d["rug"] = _rect(mi, [rug.x, rug.y, -0.004], a1, -a2, rug.length / 2, rug.width / 2,
                         _bsdf(mi, tex, uv_scale=(rug.length / (2 * rug.stripe_m), 1.0)))
    return d


# --------------------------------------------------------------------------- the camera


def _undistort_map(cam: Camera, k1: float) -> tuple[np.ndarray, np.ndarray]:
    """For every output (distorted) pixel, where to read the pinhole image."""
    f, (cx, cy) = cam.focal_px, cam.centre_px
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float32), np.arange(cam.height,
                                                                          dtype=np.float32))
    x, y = (u - cx) / f, (v - cy) / f
    s = 1.0 + k1 * (x * x + y * y)
    return (x * s * f + cx).astype(np.float32), (y * s * f + cy).astype(np.float32)


def distort_points(cam: Camera, k1: float, pts: np.ndarray) -> np.ndarray:
    """Pinhole pixels (N×2) → where the distorted image shows them (inverse of the map)."""
    pts = np.atleast_2d(np.asarray(pts, dtype=float))
    if k1 == 0 or len(pts) == 0:
        return pts
    f, c = cam.focal_px, cam.centre_px
    xu = (pts - c) / f
    xd = xu.copy()
    for _ in range(20):  # xu = xd (1 + k1 |xd|²), solved by fixed point
        xd = xu / (1.0 + k1 * np.sum(xd * xd, axis=1, keepdims=True))
    return xd * f + c


def _yaw_blur(img: np.ndarray, cam: Camera, sweep_deg: float, taps: int = 7) -> np.ndarray:
    """Average of the image rotated about the world vertical over ``sweep_deg``: the blur of
    a pure yaw during the exposure (a homography per tap, exact for a rotation)."""
    if abs(sweep_deg) < 1e-3:
        return img
    f, (cx, cy) = cam.focal_px, cam.centre_px
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
    R = cam.rotation()
    out = np.zeros_like(img)
    for s in np.linspace(-sweep_deg / 2, sweep_deg / 2, taps):
        a = math.radians(s)
        Rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
        H = K @ R @ Rz @ R.T @ np.linalg.inv(K)
        out += cv2.warpPerspective(img, H, (cam.width, cam.height), flags=cv2.INTER_LINEAR,
                                   borderMode=cv2.BORDER_REFLECT)
    return out / taps


def develop(linear_rgb: np.ndarray, cam: Camera, look: Look) -> np.ndarray:
    """What the camera makes of the scene's radiance: yaw blur, lens distortion,
    vignetting, auto-exposure with an error of ``exposure_ev`` stops, clipped highlights,
    sRGB, shot and read noise, 8 bits. Returns H×W×3 uint8 BGR."""
    rng = np.random.default_rng([look.seed, 7, look.frame] if look.frame else [look.seed, 7])
    img = np.nan_to_num(linear_rgb.astype(np.float32), nan=0.0, posinf=0.0)
    # The path tracer's own grain, smoothed as a camera's noise reduction would; edges stay.
    scale = max(float(np.percentile(img, 99)), 1e-6)
    img = cv2.bilateralFilter(img / scale, 5, 0.08, 1.5) * scale
    img = _yaw_blur(img, cam, look.yaw_rate_deg_s * look.exposure_ms / 1000.0)
    if look.distortion_k1:
        mx, my = _undistort_map(cam, look.distortion_k1)
        img = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    if look.vignetting:
        cx, cy = cam.centre_px
        yy, xx = np.mgrid[0:cam.height, 0:cam.width].astype(np.float32)
        r2 = ((xx - cx) ** 2 + (yy - cy) ** 2) / (cx * cx + cy * cy)
        img *= (1.0 - look.vignetting * r2)[..., None]
    lum = img @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    gain = 0.18 / max(float(np.median(lum)), 1e-6) * 2.0 ** look.exposure_ev
    img = np.clip(img * gain, 0.0, 1.0)
    img = np.where(img <= 0.0031308, 12.92 * img, 1.055 * np.power(img, 1 / 2.4) - 0.055) * 255.0
    sigma = np.sqrt(look.shot_noise * img + look.read_noise ** 2)
    img = img + rng.normal(0.0, 1.0, img.shape).astype(np.float32) * sigma
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)[..., ::-1].copy()


def opencv_distortion(cam: Camera, k1: float) -> tuple[float, float, float, float, float]:
    """This renderer's lens (``xu = xd (1 + k1 |xd|²)``, normalised by the focal length)
    as OpenCV's coefficients ``(k1, k2, p1, p2, k3)``, which map the other way
    (``xd = xu (1 + k1 r² + k2 r⁴ + k3 r⁶)``): least squares over the radii the frame
    shows, within 0.1 px at 640×480 for a 110° lens and k1 = 0.04."""
    rd = np.linspace(0.0, 1.02 * float(np.hypot(*cam.centre_px)) / cam.focal_px, 200)[1:]
    ru = rd * (1.0 + k1 * rd * rd)
    a = np.stack([ru ** 2, ru ** 4, ru ** 6], axis=1)
    (c1, c2, c3), *_ = np.linalg.lstsq(a, rd / ru - 1.0, rcond=None)
    return float(c1), float(c2), 0.0, 0.0, float(c3)


def truth(r3: Room3D, cam: Camera) -> SceneTruth:
    """The exact truth of ``r3`` seen by ``cam``: that of its bounding boxes
    (:func:`sitl.scene.scene_truth`) with each one's furniture kind, image points moved by
    the lens distortion, and the lens (:func:`opencv_distortion`)."""
    t = scene_truth(r3.truth_scene(), cam)
    t = replace(t, obstacles=[replace(o, kind=r3.furniture[o.box].kind) for o in t.obstacles])
    k1 = r3.look.distortion_k1
    if not k1:
        return t
    moved = []
    for o in t.obstacles:
        c = distort_points(cam, k1, np.array(o.corners_px).reshape(-1, 2))
        fc = np.array(o.floor_corners).reshape(-1, 3)
        fc[:, :2] = distort_points(cam, k1, fc[:, :2])
        moved.append(replace(o, corners_px=c.tolist(), floor_corners=fc.tolist()))
    return replace(t, obstacles=moved, distortion=opencv_distortion(cam, k1))


def render(r3: Room3D, cam: Camera) -> tuple[np.ndarray, SceneTruth]:
    """Path-trace ``r3`` as ``cam`` sees it: (H×W×3 uint8 BGR, :class:`SceneTruth`)."""
    mi = _mi()
    with tempfile.TemporaryDirectory(prefix="companion-") as folder:
        scene = mi.load_dict(_scene_dict(mi, r3, cam, folder))
    linear = np.array(mi.render(scene, spp=r3.look.spp, seed=r3.look.sampler_seed))
    return develop(linear[..., :3], cam, r3.look), truth(r3, cam)


# --------------------------------------------------------------------------- random rooms


def _furniture(rng, kind: str, x: float, y: float, yaw: float) -> Furniture:
    if kind == "table":
        size = (rng.uniform(0.9, 1.8), rng.uniform(0.6, 1.0), rng.uniform(0.7, 0.78))
        material = "wood"
    elif kind == "cabinet":
        size = (rng.uniform(0.6, 1.6), rng.uniform(0.4, 0.6), rng.uniform(0.8, 1.9))
        material = str(rng.choice(["wood", "paint", "gloss"]))
    elif kind == "sofa":
        size = (rng.uniform(1.5, 2.2), rng.uniform(0.8, 0.95), rng.uniform(0.75, 0.95))
        material = "fabric"
    else:
        size = (rng.uniform(0.6, 1.6), rng.uniform(0.4, 1.0), rng.uniform(0.5, 1.6))
        material = str(rng.choice(["paint", "wood", "gloss"]))
    return Furniture(kind, float(x), float(y), float(yaw), *(float(s) for s in size),
                     random_colour(rng, 0.15, 0.65), material)


def random_room(rng: np.random.Generator, width: int = 640, height: int = 480,
                obstacle: bool = True, hfov_deg: float | None = None,
                spp: int = 16, eye_level: bool = False) -> tuple[Room3D, Camera]:
    """A random furnished room and camera (all randomness from ``rng``).

    With ``obstacle`` one piece of furniture (box, table, cabinet or sofa) is rotated
    12°–45° off the room's axes, 2.2–5 m ahead within the field of view, and a second
    rotated one stands elsewhere in a third of the rooms; 0–2 further pieces (1–3 without
    an obstacle) are aligned with the room. The field of view is ``hfov_deg``, else drawn
    from 50–110°. With ``eye_level`` the camera is then moved to the height of the
    rotated piece's top (:func:`sitl.scene.at_eye_level`): the same room, seen from the
    furniture's height.
    """
    length, wid = rng.uniform(7.0, 12.0), rng.uniform(5.0, 9.0)
    room_h = rng.uniform(2.5, 3.2)
    room0 = Room(x_min=0.0, x_max=length, y_min=-wid / 2, y_max=wid / 2, height=room_h,
                 tile_m=float(rng.choice([0.3, 0.4, 0.5, 0.6])))
    fov = float(rng.uniform(50.0, 110.0))
    cam = Camera(
        width=width, height=height, hfov_deg=hfov_deg or fov,
        x=float(rng.uniform(0.8, 2.0)), y=float(rng.uniform(-wid / 4, wid / 4)),
        height_m=float(rng.uniform(0.8, 1.8)), yaw_deg=float(rng.uniform(-35.0, 35.0)),
        pitch_deg=float(rng.uniform(-5.0, 5.0)), roll_deg=float(rng.uniform(-4.0, 4.0)),
    )
    pieces: list[Furniture] = []

    def free(x: float, y: float, r: float) -> bool:
        if not (room0.x_min + r + 0.1 < x < room0.x_max - r - 0.1):
            return False
        if not (room0.y_min + r + 0.1 < y < room0.y_max - r - 0.1):
            return False
        if math.hypot(x - cam.x, y - cam.y) < r + 1.2:
            return False
        return all(math.hypot(x - p.x, y - p.y) > r + p.bounding_box().radius() + 0.2
                   for p in pieces)

    def rotated(near: bool) -> None:
        for _ in range(200):
            kind = str(rng.choice(KINDS))
            if near:
                dist = rng.uniform(2.2, 5.0)
                bearing = cam.yaw_deg + rng.uniform(-0.3, 0.3) * cam.hfov_deg
                x = cam.x + dist * math.cos(math.radians(bearing))
                y = cam.y + dist * math.sin(math.radians(bearing))
            else:
                x, y = rng.uniform(room0.x_min, room0.x_max), rng.uniform(room0.y_min, room0.y_max)
                bearing = math.degrees(math.atan2(y - cam.y, x - cam.x))
            yaw = float(rng.uniform(12.0, 45.0) * rng.choice([-1, 1]) + 90.0 * rng.integers(0, 4))
            if near and not 15.0 <= (yaw - bearing) % 90.0 <= 75.0:
                continue  # both side faces show
            p = _furniture(rng, kind, x, y, yaw)
            if free(x, y, p.bounding_box().radius()):
                pieces.append(p)
                return

    if obstacle:
        rotated(near=True)
        ahead = pieces[0] if pieces else None
        if rng.random() < 1 / 3:
            rotated(near=False)
    for _ in range(int(rng.integers(0 if obstacle else 1, 3 if obstacle else 4))):
        for _ in range(50):
            p = _furniture(rng, str(rng.choice(KINDS)), rng.uniform(room0.x_min, room0.x_max),
                           rng.uniform(room0.y_min, room0.y_max), 90.0 * rng.integers(0, 4))
            if free(p.x, p.y, p.bounding_box().radius()):
                pieces.append(p)
                break
    decorations = tuple(r for r in random_decorations(rng, room0, clutter=True)
                        if isinstance(r, WallRect))
    room = replace(room0, decorations=decorations)
    look = random_look(rng, spp)
    if eye_level and obstacle and ahead is not None:
        cam = at_eye_level(rng, cam, ahead.bounding_box().height)
    return Room3D(room, tuple(pieces), look), cam


def random_look(rng: np.random.Generator, spp: int = 16) -> Look:
    """A random :class:`Look` (all randomness from ``rng``): floor, walls, light, exposure,
    yaw blur, lens, vignetting and noise. :func:`random_room` draws each room's look here;
    ``sitl.approach`` draws the look of a flown room here too."""
    return Look(
        floor=str(rng.choice(["planks", "carpet", "tiles"])),
        floor_gloss=float(rng.choice([0.0, 0.0, rng.uniform(0.05, 0.25)])),
        wall=str(rng.choice(["paint", "paint", "stripes", "pattern"])),
        floor_colour=random_colour(rng, 0.3, 0.7),
        wall_colour=random_colour(rng, 0.55, 0.88),
        lamp_power=float(rng.uniform(4.0, 12.0)),
        window_power=float(rng.choice([0.0, rng.uniform(8.0, 30.0)])),
        exposure_ev=float(rng.normal(0.0, 0.5)),
        yaw_rate_deg_s=float(rng.choice([0.0, rng.uniform(-45.0, 45.0)])),
        exposure_ms=float(rng.uniform(5.0, 20.0)),
        distortion_k1=float(rng.uniform(0.0, 0.04)),
        vignetting=float(rng.uniform(0.0, 0.35)),
        shot_noise=float(rng.uniform(0.05, 0.3)),
        read_noise=float(rng.uniform(1.0, 4.0)),
        spp=spp,
        seed=int(rng.integers(0, 2**31 - 1)),
    )
