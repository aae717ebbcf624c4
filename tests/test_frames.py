"""Per-frame results and their comparison between two runs (sitl.frames)."""

import json

import pytest

from sitl.evaluate import SceneResult
from sitl.frames import format_changes, frame_changes, frame_rows, read_frames, reading_of, view_of


def result(index, eta_est, eta_true=30.0, detectable=True, has_obstacle=True, mirrored=False,
           rule=None):
    return SceneResult(index=index, has_obstacle=has_obstacle, detectable=detectable,
                       eta_true_deg=eta_true if has_obstacle else None, eta_est_deg=eta_est,
                       corner_err_pct=None, latency_ms=3.0, mirrored=mirrored, kind="box",
                       rule=rule)


def rows(results, camera="640×480, 90°"):
    return frame_rows(results, "pathtraced", "dev", 11, camera)


def test_each_kind_of_change_is_found_and_nothing_else():
    old = rows([
        result(0, None),                      # gained
        result(1, 29.0),                      # lost
        result(2, None, has_obstacle=False, detectable=False),   # a new false alarm
        result(3, 12.0, has_obstacle=False, detectable=False),   # a false alarm gone
        result(4, 31.0),                      # error 1° → 6°: moved
        result(5, 31.0),                      # error 1° → 1.5°: within the tolerance
        result(6, None, detectable=False),    # not detectable: not scored, not a change
        result(7, 30.5, mirrored=True),       # unchanged
    ])
    new = rows([
        result(0, 30.2), result(1, None),
        result(2, -20.0, has_obstacle=False, detectable=False),
        result(3, None, has_obstacle=False, detectable=False),
        result(4, 36.0), result(5, 31.5), result(6, 10.0, detectable=False),
        result(7, 30.5, mirrored=True),
    ])
    changes, shared = frame_changes(old, new, eta_tol_deg=1.0)
    assert shared == 8
    assert [(c.index, c.what) for c in changes] == [
        (0, "gained"), (1, "lost"), (2, "false alarm"), (3, "false alarm gone"), (4, "eta")]
    moved = changes[-1]
    assert moved.old_err_deg == pytest.approx(1.0) and moved.new_err_deg == pytest.approx(6.0)


def test_frames_are_matched_by_camera_index_and_mirror_not_by_position():
    old = rows([result(0, 30.0), result(0, None, mirrored=True)])
    new = rows([result(0, None, mirrored=True), result(0, 30.0)])
    assert frame_changes(old, new) == ([], 2)
    other_camera = rows([result(0, None)], camera="320×240, 90°")
    changes, shared = frame_changes(old, other_camera)
    assert (changes, shared) == ([], 0)


def test_written_rows_read_back_and_format_one_line_per_change(tmp_path):
    path = tmp_path / "f.jsonl"
    old = rows([result(3, None), result(4, 30.0)])
    path.write_text("".join(json.dumps(r, ensure_ascii=False) + "\n" for r in old))
    back = read_frames(path)
    assert back == old
    changes, shared = frame_changes(back, rows([result(3, 31.0), result(4, 30.0)]))
    lines = format_changes(changes, shared)
    assert lines[0].startswith("2 frames in both runs; 1 changed")
    assert lines[1] == "640×480, 90°, pathtraced dev: 1 gained"
    assert lines[2].split()[:2] == ["3", "gained"]
    assert len(lines) == 3


def test_a_changed_frame_says_which_rule_read_it_in_each_run():
    old = rows([result(3, None), result(4, 30.0, rule="corner pair"),
                result(5, None, has_obstacle=False, detectable=False)])
    new = rows([result(3, 31.0, rule="hidden edge"), result(4, 36.0, rule="one face"),
                result(5, -8.0, has_obstacle=False, detectable=False, rule="single corner")])
    lines = format_changes(*frame_changes(old, new))
    by_frame = {line.split()[0]: line for line in lines[2:]}
    assert by_frame["3"].endswith("by — → hidden edge")
    assert by_frame["4"].endswith("by corner pair → one face")
    assert by_frame["5"].endswith("by — → single corner")
    # Rows written before rows had a rule read as they did.
    for row in old + new:
        del row["rule"]
    assert all(" by " not in line for line in format_changes(*frame_changes(old, new))[2:])


def test_a_line_that_is_not_a_frame_row_is_named(tmp_path):
    path = tmp_path / "f.jsonl"
    path.write_text(json.dumps(rows([result(0, None)])[0]) + "\n{\"figures\": 1}\n")
    with pytest.raises(ValueError, match=r"f\.jsonl:2: not a frame row"):
        read_frames(path)
    row = rows([result(0, None)])[0]
    del row["eta_est_deg"]  # the outcome it would compare is missing
    path.write_text(json.dumps(row) + "\n")
    with pytest.raises(ValueError, match=r"f\.jsonl:1: not a frame row"):
        read_frames(path)
    path.write_text("not json\n")
    with pytest.raises(ValueError, match=r"f\.jsonl:1: not JSON"):
        read_frames(path)


def test_the_diff_says_how_each_run_read_its_frames_and_keeps_views_apart(tmp_path):
    alone = rows([result(0, None), result(1, 30.0)])
    video = frame_rows([result(0, 30.4), result(1, 30.0)], "pathtraced", "dev", 11,
                       "640×480, 90°", reading="as a video")
    changes, shared = frame_changes(alone, video)
    assert shared == 2 and [c.what for c in changes] == ["gained"]
    first = format_changes(changes, shared, old_reading="each frame alone",
                           new_reading="as a video")[0]
    assert first.endswith("; old run: each frame alone; new run: as a video")
    # The same room seen from the height of the obstacle's top is another frame.
    higher = frame_rows([result(0, 30.4)], "pathtraced", "dev", 11, "640×480, 90°",
                        view="eye level")
    assert frame_changes(alone, higher) == ([], 0)
    # A file written before rows had a view or a reading: as drawn, each frame alone.
    for row in alone:
        del row["view"], row["reading"]
    path = tmp_path / "old.jsonl"
    path.write_text("".join(json.dumps(r, ensure_ascii=False) + "\n" for r in alone))
    back = read_frames(path)
    assert frame_changes(back, video)[1] == 2
    assert {r["reading"] for r in back} == {"each frame alone"}


def test_a_rows_view_and_reading_say_what_the_run_options_were():
    assert view_of() == "as drawn"
    assert view_of(eye_level=True, pitch_deg=10.0) == "eye level, pitched 10°"
    assert view_of(rug=True) == "a rug laid"
    assert reading_of() == "each frame alone"
    assert reading_of(as_video=True, focal_given=True) == "as a video, focal length given"
    assert reading_of(focal_given=True, lens_given=True) == (
        "each frame alone, focal length given, lens given")
