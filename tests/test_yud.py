"""The YUD metric on constructed cases, and a small real check on three train images."""

from pathlib import Path

import numpy as np
import pytest

from sitl.yud import angular_errors_deg, area_under_curve, evaluate_yud

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
