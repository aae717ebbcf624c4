"""Render the sample recording shipped in ``samples/``: ``python -m sitl.sample``.

A room with a box rotated 30° off the walls, 3.2 m ahead; the camera yaws from 35° left
of the box's face to 5° right of it, so η sweeps through the values a turn would see.
Writes the MP4 and a per-frame truth file (JSON lines).
"""

from __future__ import annotations

import argparse

from sitl.scene import EAST, NORTH, WEST, Box, Camera, Room, Scene, WallRect, write_video, yaw_sweep


def sample_scene() -> tuple[Scene, Camera]:
    room = Room(
        x_min=0.0,
        x_max=9.0,
        y_min=-3.5,
        y_max=3.5,
        height=2.8,
        tile_m=0.5,
        decorations=(
            WallRect(NORTH, 1.0, 0.9, 0.0, 2.05, (0.35, 0.45, 0.6)),
            WallRect(NORTH, 4.2, 1.4, 0.9, 2.0, (0.75, 0.65, 0.5)),
            WallRect(EAST, 5.0, 0.9, 0.0, 2.05, (0.3, 0.35, 0.45)),
            WallRect(WEST, 3.0, 0.8, 1.3, 1.8, (0.3, 0.5, 0.35)),
        ),
    )
    box = Box(
        x=4.4, y=0.3, yaw_deg=30.0, length=1.2, width=0.7, height=1.0, albedo=(0.3, 0.35, 0.55)
    )
    scene = Scene(room=room, boxes=(box,), noise_sigma=2.0, blur_sigma=0.6, seed=7)
    cam = Camera(width=640, height=480, hfov_deg=80.0, x=1.2, y=0.0, height_m=1.3, yaw_deg=-5.0)
    return scene, cam


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="samples/room_turn.mp4")
    ap.add_argument("--truth", default="samples/room_turn.truth.jsonl")
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--fps", type=float, default=10.0)
    args = ap.parse_args(argv)
    scene, cam = sample_scene()
    n = write_video(scene, yaw_sweep(cam, -5.0, 35.0, args.frames), args.out, args.fps, args.truth)
    print(f"wrote {n} frames to {args.out} and truth to {args.truth}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
