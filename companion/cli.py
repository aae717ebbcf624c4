"""``companion``: the command line.

- ``companion --video FILE --dry-run [--log PATH] [--annotate OUT.mp4]``: the pipeline
  and the turn policy on every frame of a recording, no autopilot.
- ``companion run [--config PATH] [--source SRC]``: the service on the vehicle
  (see :mod:`companion.service`).
- ``companion eval``: accuracy on seeded synthetic scenes (see :mod:`sitl.evaluate`).

A user mistake (bad file, bad config) prints one line ``companion: error: …`` and exits
2; Ctrl-C stops cleanly, keeping the log and annotated video written so far (exit 130).
"""

from __future__ import annotations

import argparse
import json
import os
import select
import sys
import time
from dataclasses import replace
from pathlib import Path

from companion.capture import CaptureError, ImageFolder, is_camera, open_recording
from companion.config import CameraConfig, Config, ConfigError, load_config

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141  # as a shell reports a process ended by SIGPIPE


class UserError(Exception):
    """Something the user can fix; printed as one line."""


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("companion")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed)"


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="companion",
        description="Monocular non-Manhattan obstacle avoidance (Wang & Wei 2020).",
    )
    ap.add_argument("--video", metavar="FILE", help="video file, or folder of images, to process")
    ap.add_argument("--dry-run", action="store_true", help="no autopilot: decide, do not fly")
    ap.add_argument("--config", metavar="PATH",
                    help="YAML config (default: built-in defaults); before a command, that "
                         "command's --config")
    ap.add_argument("--log", metavar="PATH", help="write one JSON line per frame")
    ap.add_argument("--annotate", metavar="OUT.mp4", help="write an annotated video")
    ap.add_argument("--focal-px", type=float, metavar="F", help="known focal length in pixels")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--version", action="version", version=f"companion {_version()}")
    sub = ap.add_subparsers(dest="command", metavar="{run,eval,sim,bench}")
    rn = sub.add_parser("run", help="the service: camera → pipeline → PX4 offboard")
    rn.add_argument("--config", metavar="PATH", dest="run_config",
                    help="YAML config (default: built-in defaults, offboard disabled)")
    rn.add_argument("--source", metavar="SRC",
                    help="camera index or /dev path, video file or image folder "
                         "(default: camera.device from the config)")
    sm = sub.add_parser("sim", help="the closed loop in simulation (renderer, MAVSDK, mock PX4)")
    from sitl.closed_loop import add_arguments as add_sim_arguments

    add_sim_arguments(sm)
    bn = sub.add_parser("bench", help="time every stage; frame-to-setpoint latency in SITL")
    from sitl.bench import add_arguments as add_bench_arguments

    add_bench_arguments(bn)
    ev = sub.add_parser("eval", help="accuracy on seeded synthetic scenes")
    ev.add_argument("--scenes", type=int, default=200, help="number of scenes (default 200)")
    ev.add_argument("--seed", type=int, default=0, help="seed of the scene set (default 0)")
    ev.add_argument("--config", metavar="PATH", dest="eval_config", help="YAML config")
    ev.add_argument("--width", type=int, default=CameraConfig.width)
    ev.add_argument("--height", type=int, default=CameraConfig.height)
    ev.add_argument(
        "--no-focal",
        action="store_true",
        help="do not give the pipeline the rendered focal length (it estimates it)",
    )
    ev.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    ev.add_argument("--json", metavar="PATH", help="also write the figures as JSON")
    ev.add_argument("--frames", metavar="PATH",
                    help="with --scenes or --renderer (not --clips): also write one JSON line "
                         "per frame, to compare two runs with --diff")
    ev.add_argument("--diff", nargs=2, metavar=("OLD", "NEW"),
                    help="instead: the frames whose outcome differs between two --frames "
                         "files (detections gained and lost, false alarms, η errors moved)")
    ev.add_argument("--yud", metavar="DIR",
                    help="instead: layout-VP accuracy on the York Urban Database in DIR")
    ev.add_argument("--renderer", choices=("scene", "pathtraced", "all"),
                    help="instead: the frozen dev and test splits of this renderer (pathtraced "
                         "needs companion[render]), focal length not given, at 640×480 90°, "
                         "640×480 60° and 320×240 90°")
    ev.add_argument("--lens-given", action="store_true",
                    help="with --renderer: give the pipeline the rendered focal length and "
                         "lens distortion, a calibrated camera (a diagnosis)")
    ev.add_argument("--focal-given", action="store_true",
                    help="with --renderer: give the pipeline the rendered focal length (a "
                         "diagnosis; the targets are without it)")
    ev.add_argument("--mirrored", action="store_true",
                    help="with --renderer (and --clips) or --yud: also run each frame, clip or "
                         "photograph mirrored left to right and pool the two, twice the "
                         "sample, to tell a rule change on dev or train from chance")
    ev.add_argument("--eye-level", action="store_true",
                    help="with --renderer: each split room seen from the height of its "
                         "rotated obstacle's top, as a vehicle flying at the furniture's "
                         "height sees it (the top edge-on, along the horizon)")
    ev.add_argument("--pitch", type=float, default=0.0, metavar="DEG",
                    help="with --renderer: each split room seen by the camera pitched DEG "
                         "further nose down (-30 to 30), as a multicopter's fixed camera "
                         "sees it while it accelerates forward")
    ev.add_argument("--rug", action="store_true",
                    help="with --renderer: each split room with a striped rug turned 10–80° "
                         "off the room's axes on the floor in front of the camera (the "
                         "path-traced split rooms have none of their own)")
    ev.add_argument("--as-video", action="store_true",
                    help="with --renderer: each camera's frames of the split run in order "
                         "through one pipeline, as companion --video runs a recording, so "
                         "the focal length and the lens are learnt across them (not with "
                         "--lens-given or --clips)")
    ev.add_argument("--clips", action="store_true",
                    help="with --renderer: per-frame and tracked η on yawing clips")
    ev.add_argument("--long", action="store_true",
                    help="with --clips: 24-frame clips, long enough to learn the lens, also "
                         "scored from frame 12 on")
    ev.add_argument("--split", choices=("dev", "train", "test", "all"), default=None,
                    help="with --renderer: dev, test or all (default all); with --yud: train "
                         "(= dev), test (default) or all. Tune on dev/train only")
    ev.add_argument("--no-peer", action="store_true",
                    help="with --yud: do not run the peer lu-vp-detect even if installed")
    ev.add_argument("--variants", action="store_true",
                    help="with --yud: also zoomed and rolled views of the photographs "
                         "(focal length given), to develop on the train split")
    return ap


def _clock(seconds: float) -> str:
    """``m:ss``, or ``h:mm:ss`` from an hour on."""
    m, sec = divmod(int(round(seconds)), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


def progress_line(done: int, total: int, elapsed_s: float, extra: str = "") -> str:
    """One progress line: a bar of ``done`` of ``total`` (a count alone when the total is
    unknown), what is being done (``extra``), the time taken so far and, once a second has
    passed and something is done, the time left at the rate so far."""
    if total > 0:
        filled = int(30 * min(done / total, 1.0))
        line = f"[{'#' * filled}{'.' * (30 - filled)}] {done}/{total}"
    else:
        line = f"{done}"
    if extra:
        line += f" {extra}"
    if elapsed_s >= 1.0:
        line += f"  {_clock(elapsed_s)}"
        if total > 0 and 0 < done < total:
            line += f", ~{_clock(elapsed_s * (total - done) / done)} left"
    return line


class _Progress:
    """A one-line progress bar on stderr, only when stderr is a terminal."""

    def __init__(self, enabled: bool):
        self.enabled = enabled and sys.stderr.isatty()
        self._start = time.monotonic()
        self._last = 0.0

    def update(self, done: int, total: int, extra: str = "") -> None:
        now = time.monotonic()
        if not self.enabled or (now - self._last < 0.1 and done != total):
            return
        self._last = now
        sys.stderr.write(f"\r{progress_line(done, total, now - self._start, extra)}\033[K")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\r\033[K")
            sys.stderr.flush()


def _config(path: str | None, focal_px: float | None) -> Config:
    cfg = load_config(path)
    if focal_px is not None:
        if not focal_px > 0:
            raise UserError(f"--focal-px must be positive, got {focal_px:g}")
        cfg = replace(cfg, camera=replace(cfg.camera, focal_px=focal_px))
    return cfg


def _open_output(path: str, what: str):
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        return open(path, "w", encoding="utf-8")
    except OSError as e:
        raise UserError(f"cannot write {what} {path}: {e.strerror or e}") from None


def dry_run(args) -> int:
    """Pipeline + policy on every frame of ``args.video``; prints a summary."""
    import cv2

    from companion.control.policy import TurnHistory, decide_frame
    from companion.report import DecisionLog, Summary, annotate, log_record
    from companion.vision.pipeline import Pipeline

    if is_camera(args.video):
        raise UserError(f"{args.video} is a camera, not a recording: `companion run --source "
                        f"{args.video}` runs on it (with offboard.enabled false, the default, "
                        "it decides and commands nothing)")
    cfg = _config(args.config, args.focal_px)
    pipeline = Pipeline(cfg)
    video = open_recording(args.video)
    folder = isinstance(video, ImageFolder)
    log_file = _open_output(args.log, "log") if args.log else None
    log = DecisionLog(log_file) if log_file else None
    writer = None
    if args.annotate:
        Path(args.annotate).parent.mkdir(parents=True, exist_ok=True)
        writer = cv2.VideoWriter(
            args.annotate, cv2.VideoWriter_fourcc(*"mp4v"), video.fps, (video.width, video.height)
        )  # images of another size than the first are resized to it
        if not writer.isOpened():
            video.close()
            raise UserError(f"cannot write annotated video {args.annotate}")
    if cfg.camera.focal_px:
        focal = f"focal {cfg.camera.focal_px:g} px (given)"
        if cfg.camera.distortion is not None:
            # [0] declares a pinhole: nothing is undone, and the lens is not estimated.
            focal += (", lens distortion undone" if any(cfg.camera.distortion)
                      else ", a pinhole lens (nothing undone)")
    else:
        focal = ("focal length estimated from the layout VPs, carried from frame to frame "
                 "(half the width until a frame gives it); D of eq. 10 = that focal length")
    if folder:
        print(f"{video.path}: {len(video)} images; {focal}")
    else:
        print(
            f"{video.path}: {video.width}×{video.height}, {len(video) or 'unknown'} frames at "
            f"{video.fps:.1f} fps; {focal}"
        )
    summary = Summary()
    progress = _Progress(not args.no_progress)
    interrupted = False
    start = time.perf_counter()
    history = TurnHistory()
    try:
        for frame in video:
            # The picture this frame's estimate is made in (lens undone, once it is known),
            # taken before the frame is processed: processing it may settle the lens.
            picture = pipeline.pinhole(frame.image) if writer is not None else None
            learning_lens = pipeline.learning_lens
            t0 = time.perf_counter()
            est = pipeline(frame.image)
            _, cmd, history = decide_frame(est.eta_deg, est.eta_tracked_deg, cfg.policy,
                                           history, est.scene_understood, est.range_m)
            latency_ms = (time.perf_counter() - t0) * 1e3
            summary.add(est, latency_ms, learning_lens)
            if log:
                log.write(log_record(frame.index, frame.t_s, est, cmd, latency_ms, frame.source))
            if writer is not None:
                out = annotate(picture, est, cmd)
                if out.shape[:2] != (video.height, video.width):
                    out = cv2.resize(out, (video.width, video.height))
                writer.write(out)
            eta = "η —" if est.eta_deg is None else f"η {est.eta_deg:+.1f}°"
            progress.update(frame.index + 1, len(video), f"{eta} {cmd.action}")
    except KeyboardInterrupt:
        interrupted = True
    finally:
        progress.close()
        video.close()
        if writer is not None:
            writer.release()
        if log_file:
            log_file.close()
    wall = time.perf_counter() - start
    for line in summary.lines(wall):
        print(line)
    if not pipeline.config.camera.focal_px and summary.frames:  # it was to be estimated
        print(pipeline.describe_focal())
    if pipeline.config.camera.distortion is None:  # the lens was to be learnt
        print(pipeline.running_lens.describe())
    if args.log:
        print(f"log: {args.log}")
    if args.annotate:
        print(f"annotated video: {args.annotate}")
    if interrupted:
        print("interrupted: outputs hold every frame processed so far", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


def run_eval(args) -> int:
    """``companion eval``: render seeded scenes, print the accuracy figures."""
    from sitl.evaluate import View, format_report
    from sitl.evaluate import run_eval as evaluate

    if args.mirrored and (args.variants or not (args.renderer or args.yud)):
        raise UserError("--mirrored goes with --renderer NAME or --yud DIR (not --variants)")
    if args.eye_level and (args.clips or not args.renderer):
        raise UserError("--eye-level goes with --renderer NAME (not --clips)")
    if args.pitch and (args.clips or not args.renderer):
        raise UserError("--pitch goes with --renderer NAME (not --clips)")
    if args.rug and (args.clips or not args.renderer):
        raise UserError("--rug goes with --renderer NAME (not --clips)")
    if not -30.0 <= args.pitch <= 30.0:
        raise UserError(f"--pitch {args.pitch:g}: give -30 to 30 degrees")
    if args.as_video and (args.clips or args.lens_given or not args.renderer):
        raise UserError("--as-video goes with --renderer NAME (not --clips, which are videos "
                        "already, nor --lens-given: the split's rooms each have their own lens)")
    if args.diff:
        return run_eval_diff(args)
    if args.frames and (args.yud or args.clips):
        raise UserError("--frames goes with --scenes or --renderer NAME (not --clips, --yud)")
    if args.yud:
        args.split = {"dev": "train", None: "test"}.get(args.split, args.split)
        return run_eval_yud(args)
    if args.renderer:
        return run_eval_splits(args)
    if args.split:
        raise UserError("--split needs --renderer NAME or --yud DIR")
    if args.long:
        raise UserError("--long goes with --renderer NAME --clips")
    if args.focal_given or args.lens_given:
        raise UserError("--focal-given and --lens-given go with --renderer NAME (without "
                        "it, the focal length is given unless --no-focal)")
    if args.variants:
        raise UserError("--variants needs --yud DIR (views of the York Urban DB photographs)")
    if args.scenes < 1:
        raise UserError("--scenes must be at least 1")
    cfg = _config(args.eval_config, None)
    progress = _Progress(True)
    start = time.perf_counter()
    try:
        report = evaluate(
            scenes=args.scenes,
            seed=args.seed,
            config=cfg,
            view=View(args.width, args.height),
            assume_focal=not args.no_focal,
            workers=args.workers,
            progress=lambda d, n: progress.update(d, n, "scenes"),
        )
    finally:
        progress.close()
    for line in format_report(report):
        print(line)
    _rerun_line(start, f"companion eval --scenes {args.scenes} --seed {args.seed}"
                + (f" --width {args.width} --height {args.height}"
                   if (args.width, args.height) != (CameraConfig.width, CameraConfig.height)
                   else "")
                + (" --no-focal" if args.no_focal else ""), args)
    if args.json:
        with _open_output(args.json, "figures") as f:
            json.dump(report.figures(), f, indent=2)
    if args.frames:
        from sitl.frames import frame_rows, reading_of

        _write_frames(args.frames, frame_rows(
            report.results, "scene", None, args.seed, f"{args.width}×{args.height}",
            reading=reading_of(focal_given=not args.no_focal)))
    return 0


def _rerun_line(start: float, command: str, args) -> None:
    """An eval's closing line: the seconds since ``start`` (``time.perf_counter``) and the
    command that measures the same again, with the config it ran on, so that figures
    copied from it carry their command whole."""
    from companion.report import closing_line

    print(closing_line(time.perf_counter() - start, command, args.eval_config))


def _write_frames(path: str, rows: list[dict]) -> None:
    with _open_output(path, "frames") as f:
        for row in rows:
            f.write(json.dumps(row, ensure_ascii=False) + "\n")
    print(f"{len(rows)} frames written to {path}")


def run_eval_diff(args) -> int:
    """``companion eval --diff OLD NEW``: the frames whose outcome changed."""
    from sitl.frames import format_changes, frame_changes, read_frames

    if args.renderer or args.yud or args.frames:
        raise UserError("--diff compares two --frames files; it runs nothing itself")
    runs = []
    for path in args.diff:
        try:
            runs.append(read_frames(path))
        except FileNotFoundError:
            raise UserError(f"frames file not found: {path}") from None
        except (OSError, UnicodeDecodeError, ValueError) as e:
            raise UserError(f"cannot read frames file {path}: {e}") from None
    changes, shared = frame_changes(*runs)
    if not shared:
        raise UserError(f"{args.diff[0]} and {args.diff[1]} share no frame (another split, "
                        "seed or camera?)")
    old, new = (" / ".join(sorted({r["reading"] for r in rows})) for rows in runs)
    for line in format_changes(changes, shared, old_reading=old, new_reading=new):
        print(line)
    return 0


def run_eval_splits(args) -> int:
    """``companion eval --renderer R [--split S]``: the frozen splits, one table per renderer."""
    from sitl.evaluate import SPLITS, format_splits, run_split

    renderers = ("scene", "pathtraced") if args.renderer == "all" else (args.renderer,)
    if "pathtraced" in renderers:
        from sitl.pathtraced import available

        if not available():
            raise UserError("the pathtraced renderer needs Mitsuba 3: "
                            "pip install 'companion[render]'")
    split = {"train": "dev", None: "all"}.get(args.split, args.split)
    splits = ("dev", "test") if split == "all" else (split,)
    cfg = _config(args.eval_config, None)
    start = time.perf_counter()
    if args.long and not args.clips:
        raise UserError("--long goes with --clips")
    if args.clips:
        if args.focal_given or args.lens_given:
            raise UserError("--clips estimates the focal length as a video does; "
                            "--focal-given and --lens-given are for the splits")
        return _eval_clips(args, renderers, splits, cfg, start)
    figures = {}
    by_renderer = {}
    for renderer in renderers:
        reports = {}
        for s in splits:
            seed, n = SPLITS[(renderer, s)]
            progress = _Progress(True)
            try:
                reports[s] = run_split(renderer, s, cfg, args.workers,
                                       lambda d, t, p=progress, r=renderer, s=s: p.update(
                                           d, t, f"{r} {s}"), focal_given=args.focal_given,
                                       lens_given=args.lens_given, mirrored=args.mirrored,
                                       eye_level=args.eye_level, pitch_deg=args.pitch,
                                       as_video=args.as_video, rug=args.rug)
            finally:
                progress.close()
        for line in format_splits(renderer, reports, args.focal_given, args.lens_given,
                                  args.mirrored, args.eye_level, args.pitch, args.as_video,
                                  args.rug):
            print(line)
        figures[renderer] = {s: {cam: rep.figures() for cam, rep in by_cam.items()}
                             for s, by_cam in reports.items()}
        by_renderer[renderer] = reports
    _rerun_line(start, f"companion eval --renderer {args.renderer}"
                + (f" --split {split}" if split != "all" else "")
                + (" --focal-given" if args.focal_given else "")
                + (" --lens-given" if args.lens_given else "")
                + (" --mirrored" if args.mirrored else "")
                + (" --eye-level" if args.eye_level else "")
                + (f" --pitch {args.pitch:g}" if args.pitch else "")
                + (" --rug" if args.rug else "")
                + (" --as-video" if args.as_video else ""), args)
    if args.json:
        with _open_output(args.json, "figures") as f:
            json.dump(figures, f, indent=2)
    if args.frames:
        from sitl.frames import frame_rows, reading_of, view_of

        view = view_of(args.eye_level, args.pitch, args.rug)
        reading = reading_of(args.as_video, args.focal_given, args.lens_given)
        _write_frames(args.frames, [
            row for renderer, reports in by_renderer.items() for s, by_cam in reports.items()
            for cam, rep in by_cam.items()
            for row in frame_rows(rep.results, renderer, s, SPLITS[(renderer, s)][0], cam,
                                  view, reading)])
    return 0


def _eval_clips(args, renderers, splits, cfg: Config, start: float) -> int:
    from sitl.evaluate import clip_figures, format_clips, late_frames, run_clips

    figures = {}
    for renderer in renderers:
        by_split = {}
        for s in splits:
            progress = _Progress(True)
            try:
                by_split[s] = run_clips(s, cfg, args.workers,
                                        lambda d, t, p=progress, r=renderer, s=s: p.update(
                                            d, t, f"{r} clips {s}"), renderer=renderer,
                                        long=args.long, mirrored=args.mirrored)
            finally:
                progress.close()
        for line in format_clips(by_split, renderer, args.long, args.mirrored):
            print(line)
        figures[renderer] = {s: {"per_frame": clip_figures(fr, False),
                                 "tracked": clip_figures(fr, True)}
                             for s, fr in by_split.items()}
        if args.long:
            for s, fr in by_split.items():
                late = late_frames(fr)
                figures[renderer][s].update(late_per_frame=clip_figures(late, False),
                                            late_tracked=clip_figures(late, True))
    _rerun_line(start, f"companion eval --renderer {args.renderer} --clips"
                + (" --long" if args.long else "") + (" --mirrored" if args.mirrored else "")
                + (f" --split {splits[0]}" if len(splits) == 1 else ""), args)
    if args.json:
        with _open_output(args.json, "figures") as f:
            json.dump(figures, f, indent=2)
    return 0


def _eval_yud_variants(args, cfg: Config, start: float) -> int:
    from sitl.yud import THRESHOLDS_DEG, area_under_curve, evaluate_yud_variants, format_variants

    errors = evaluate_yud_variants(args.yud, args.split, cfg)
    print(f"York Urban DB, {args.split} split, focal length given: layout VPs on the "
          "photographs and on zoomed and rolled views of them")
    for line in format_variants(errors):
        print(line)
    _rerun_line(start, f"companion eval --yud {args.yud} --split {args.split} --variants",
                args)
    if args.json:
        with _open_output(args.json, "figures") as f:
            json.dump({name: [round(area_under_curve(e, th), 2) for th in THRESHOLDS_DEG]
                       for name, e in errors.items()}, f, indent=2)
    return 0


def run_eval_yud(args) -> int:
    """``companion eval --yud DIR``: layout VPs on real photographs, focal given and not,
    beside the peer lu-vp-detect when it is installed."""
    from sitl.peers import PeerUnavailable
    from sitl.yud import evaluate_yud, evaluate_yud_lu, format_yud, speed_side_by_side

    folder = Path(args.yud)
    if not (folder / "yud.json").is_file():
        raise UserError(f"{folder}: no yud.json here (expected the converted York Urban DB)")
    cfg = _config(args.eval_config, None)
    start = time.perf_counter()
    if args.variants:
        return _eval_yud_variants(args, cfg, start)
    reports, peer_missing = [], None
    if args.mirrored:
        peer_missing = "--mirrored is for companion's own decisions"
    for given in (True, False):
        reports.append(evaluate_yud(folder, args.split, given, cfg, mirrored=args.mirrored))
        if args.no_peer or peer_missing:
            continue
        try:
            reports.append(evaluate_yud_lu(folder, args.split, given))
        except PeerUnavailable as exc:
            peer_missing = str(exc)
    print(f"York Urban DB, {args.split} split: layout VPs (V1, V2, V3) against the "
          "hand-labelled Manhattan VPs"
          + ("; each photograph also mirrored left to right, the two pooled" if args.mirrored
             else ""))
    for line in format_yud(reports):
        print(line)
    ours = next(r for r in reports if r.focal_given and r.method == "companion")
    if not (args.no_peer or peer_missing):
        mine, theirs = speed_side_by_side(folder, args.split, cfg)
        print(f"speed, focal given, timed in turns on each image: companion {mine:.1f} ms, "
              f"lu-vp-detect {theirs:.1f} ms per image (median): {theirs / mine:.1f}× faster "
              "(image → layout VPs)")
    if ours.pipeline_ms_per_image is not None:
        print(f"the whole companion pipeline (VPs, corners, obstacles, η): "
              f"{ours.pipeline_ms_per_image:.1f} ms per image, focal given")
    if peer_missing:
        print(f"peer not run: {peer_missing}")
    _rerun_line(start, f"companion eval --yud {args.yud} --split {args.split}"
                + (" --mirrored" if args.mirrored else ""), args)
    if args.json:
        with _open_output(args.json, "figures") as f:
            json.dump([r.figures() for r in reports], f, indent=2)
    return 0


def run_live(args) -> int:
    """``companion run``: logs to stdout, one line per state change plus health lines."""
    import logging

    from companion.service import run_service

    config = load_config(args.run_config)
    logging.basicConfig(level=logging.INFO, stream=sys.stdout,
                        format="%(asctime)s %(name)s: %(message)s")
    logging.getLogger("mavsdk").setLevel(logging.WARNING)
    return run_service(config, args.source)


_OWN_CONFIG = {"run": "run_config", "eval": "eval_config", "sim": "sim_config",
               "bench": "bench_config"}
"""each command's own ``--config`` (its ``dest``)"""


def _apply_global_options(args) -> None:
    """``companion --config X eval`` means ``companion eval --config X``: a command takes
    the global ``--config`` when it has none of its own, rather than running silently on
    the defaults. The dry run's other options mean nothing to a command, and are an
    error rather than ignored."""
    own = _OWN_CONFIG[args.command]
    if args.config:
        if getattr(args, own) and getattr(args, own) != args.config:
            raise UserError(f"two configs given: --config {args.config} before "
                            f"`{args.command}` and --config {getattr(args, own)} after it")
        setattr(args, own, args.config)
    stray = [flag for flag, given in (("--video", args.video), ("--dry-run", args.dry_run),
                                      ("--log", args.log), ("--annotate", args.annotate),
                                      ("--focal-px", args.focal_px is not None)) if given]
    if stray:
        hint = " (a recording for the service: `companion run --source FILE`)" if (
            args.command == "run" and args.video) else ""
        verb = "goes" if len(stray) == 1 else "go"
        raise UserError(f"{', '.join(stray)} {verb} with `companion --video FILE --dry-run`, "
                        f"not with `companion {args.command}`{hint}")


def _main(argv: list[str] | None) -> int:
    ap = _parser()
    args = ap.parse_args(argv)
    try:
        if args.command is not None:
            _apply_global_options(args)
        if args.command == "eval":
            return run_eval(args)
        if args.command == "run":
            return run_live(args)
        if args.command == "sim":
            from sitl.closed_loop import simulate

            try:
                if args.scenario == "approach":
                    from sitl.approach import simulate_approach

                    progress = _Progress(True)
                    try:
                        return simulate_approach(args, progress.update)
                    finally:
                        progress.close()
                return simulate(args)
            except ValueError as exc:
                raise UserError(str(exc)) from None
        if args.command == "bench":
            from sitl.bench import bench

            try:
                return bench(args, _config(args.bench_config, None))
            except ValueError as exc:
                raise UserError(str(exc)) from None
        if args.video is None:
            ap.print_usage(sys.stderr)
            raise UserError("nothing to do: give --video FILE --dry-run, or a command (eval)")
        if not args.dry_run:
            raise UserError(
                "--video needs --dry-run: a recording cannot fly the vehicle "
                "(live control is `companion run`)"
            )
        return dry_run(args)
    except (UserError, ConfigError, CaptureError) as e:
        print(f"companion: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def main(argv: list[str] | None = None) -> int:
    """The ``companion`` command; returns its exit code."""
    try:
        code = _main(argv)
        sys.stdout.flush()  # here, where a closed pipe is caught, not at exit
        return code
    except BrokenPipeError:
        if not _stdout_reader_gone():
            raise  # another pipe broke: a fault to see, not a reader that left
        # The reader went away (`companion eval … | head`): nothing more to print, and
        # Python's own flush at exit must not fail on the closed pipe either.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE


def _stdout_reader_gone() -> bool:
    """Whether stdout is a pipe whose reading end was closed (poll reports an error on it)."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):  # no poll here, or no real stdout
        return False


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
