"""The YUD metric on constructed cases, and a small real check on three train images."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from sitl.yud import (
    VARIANTS,
    YudReport,
    _Yud,
    angular_errors_deg,
    area_under_curve,
    evaluate_yud,
    evaluate_yud_variants,
    format_yud,
    zoom_roll,
)

YUD = Path(__file__).resolve().parents[2] / "shared" / "data" / "yud"


def test_perfect_vps_give_aa_100():
    errors = angular_errors_deg(np.eye(3), np.eye(3))
    assert np.allclose(errors, 0.0)
    assert area_under_curve(errors, 3.0) == pytest.approx(100.0)


def test_a_2_degree_error_gives_the_known_aa():
    tilt = np.radians(2.0)
    est = np.array([[np.cos(tilt), np.sin(tilt), 0.0], [0, 1.0, 0], [0, 0, 1.0]])
    errors = angular_errors_deg(np.eye(3)[:1], est)
    assert errors[0] == pytest.approx(2.0, abs=1e-9)
    # CDF is 0 below 2° and 1 from 2°: AA@θ = (θ - 2) / θ.
    assert area_under_curve(errors, 3.0) == pytest.approx(100 / 3)
    assert area_under_curve(errors, 5.0) == pytest.approx(60.0)
    assert area_under_curve(errors, 10.0) == pytest.approx(80.0)
    assert area_under_curve(np.array([4.0]), 3.0) == 0.0


def test_sign_free_and_nothing_estimated():
    assert angular_errors_deg(np.eye(3)[:1], -np.eye(3)[:1])[0] == pytest.approx(0.0)
    assert list(angular_errors_deg(np.eye(3), [])) == [90.0, 90.0, 90.0]


def test_the_table_rounds_each_figure_once():
    # One error of 0.496638°: AA@3° = 83.4454, which rounded to two places first would
    # print as 83.5.
    errors = np.array([3.0 * (1 - 0.834454)])
    report = YudReport(split="train", images=1, focal_given=True, errors_deg=errors,
                       ms_per_image=1.0, focal_estimates_px=np.empty(0), true_focal_px=674.9,
                       assign_precision=None, assign_recall=None)
    row = format_yud([report])[1].split()
    assert row[3:6] == ["83.4", "90.1", "95.0"]
    assert row[6] == "0.50°"


@pytest.mark.parametrize(("zoom", "roll_deg"), [(1.0, 0.0), (1.5, 10.0), (2.0, -15.0)])
def test_a_zoomed_and_rolled_view_images_each_direction_where_its_truth_says(zoom, roll_deg):
    # A bright dot where direction d images in the original camera must land, after the
    # warp, at K' R d: the image and the rotated ground truth describe the same camera.
    f, pp = 500.0, np.array([300.0, 250.0])
    image = np.zeros((480, 640), np.uint8)
    d = np.array([0.08, -0.05, 1.0])
    dot = f * d[:2] / d[2] + pp
    x, y = np.round(dot).astype(int)
    image[y - 2:y + 3, x - 2:x + 3] = 255
    dot = np.array([x, y], float)  # the dot's true centre, on the pixel grid
    d = np.array([(dot[0] - pp[0]) / f, (dot[1] - pp[1]) / f, 1.0])
    view, focal, r = zoom_roll(image, f, pp, zoom, roll_deg)
    assert focal == pytest.approx(zoom * f)
    ys, xs = np.nonzero(view > 0)
    weights = view[ys, xs].astype(float)
    found = np.array([xs @ weights, ys @ weights]) / weights.sum()
    rd = r @ d
    expected = focal * rd[:2] / rd[2] + np.array([(640 - 1) / 2.0, (480 - 1) / 2.0])
    assert found == pytest.approx(expected, abs=0.3)


@pytest.mark.skipif(not (YUD / "yud.json").is_file(),
                    reason="the York Urban DB lives outside the repository (../shared/data)")
def test_views_of_three_train_images_keep_their_manhattan_frame():
    errors = evaluate_yud_variants(YUD, "train", limit=3)
    assert list(errors) == ["as is", *VARIANTS]
    for name, e in errors.items():
        assert len(e) == 9, name
        assert np.median(e) < 3.0, name


def test_a_mirrored_photograph_keeps_its_truth_in_place(tmp_path):
    # A VP of the truth, projected through the mirrored intrinsics, lands where the
    # mirrored image shows it: at x → W − 1 − x, y unchanged; so do the labelled segments.
    w, h, f, pp = 64, 48, 50.0, np.array([30.0, 20.0])
    image = np.random.default_rng(0).integers(0, 255, (h, w, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "a.png"), image)
    k = np.array([[f, 0, pp[0]], [0, f, pp[1]], [0, 0, 1.0]])
    dirs = np.array([[0.6, 0.1, 0.79], [-0.3, 0.05, 0.95], [0.02, 1.0, 0.03]])
    im = {"file": "a.png", "vps_dir": dirs.tolist(), "segments": [[1, 2, 40, 9]]}
    yud = _Yud(tmp_path, f, np.linalg.inv(k), [im])
    plain, truth, segs, k_inv = yud.view(im, False)
    flipped, truth_m, segs_m, k_inv_m = yud.view(im, True)
    assert np.array_equal(flipped, plain[:, ::-1])
    for d, d_m in zip(truth, truth_m, strict=True):
        p, p_m = k @ d, np.linalg.inv(k_inv_m) @ d_m
        assert p_m[0] / p_m[2] == pytest.approx(w - 1 - p[0] / p[2])
        assert p_m[1] / p_m[2] == pytest.approx(p[1] / p[2])
    assert segs_m.tolist() == [[w - 1 - 1, 2, w - 1 - 40, 9]]
    assert np.array_equal(k_inv, yud.k_inv) and np.array_equal(segs, [[1, 2, 40, 9]])


@pytest.mark.skipif(not (YUD / "yud.json").is_file(),
                    reason="the York Urban DB lives outside the repository (../shared/data)")
def test_three_train_images_and_their_mirror_images_find_their_manhattan_frame():
    report = evaluate_yud(YUD, "train", focal_given=True, limit=3, mirrored=True)
    assert report.images == 6 and len(report.errors_deg) == 18
    assert np.median(report.errors_deg[9:]) < 2.0  # the mirrored photographs'


@pytest.mark.skipif(not (YUD / "yud.json").is_file(),
                    reason="the York Urban DB lives outside the repository (../shared/data)")
def test_three_train_images_find_their_manhattan_frame():
    report = evaluate_yud(YUD, "train", focal_given=True, limit=3)
    figures = report.figures()
    assert figures["images"] == 3
    assert figures["median_err_deg"] < 2.0
    assert figures["assign_precision"] > 0.9


@pytest.mark.skipif(not (YUD / "yud.json").is_file(),
                    reason="the York Urban DB lives outside the repository (../shared/data)")
def test_speed_side_by_side_times_both_methods_on_the_same_images():
    pytest.importorskip("lu_vp_detect", reason="optional peer")
    from sitl.yud import speed_side_by_side

    mine, theirs = speed_side_by_side(YUD, "train", limit=2)
    assert 0 < mine < 1000 and 0 < theirs < 10000
