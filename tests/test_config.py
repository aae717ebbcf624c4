"""Config: defaults, the shipped file, and one clear error per bad key."""

from pathlib import Path

import pytest

from companion.config import Config, ConfigError, from_mapping, load_config

ROOT = Path(__file__).resolve().parents[1]


def test_shipped_config_equals_defaults():
    assert load_config(ROOT / "config" / "companion.yaml") == Config()


def test_no_file_means_defaults():
    assert load_config(None) == Config()


def test_partial_file_overrides_only_its_keys(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("policy:\n  max_turn_deg: 15\nvision:\n  corners:\n    top_k: 50\n")
    cfg = load_config(p)
    assert cfg.policy.max_turn_deg == 15.0
    assert cfg.vision.corners.top_k == 50
    assert cfg.policy.deadband_deg == Config().policy.deadband_deg


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        ({"polcy": {}}, "unknown key 'polcy'"),
        ({"vision": {"corners": {"topk": 5}}}, "unknown key 'vision.corners.topk'"),
        ({"vision": {"max_segments": "many"}}, "vision.max_segments must be an integer"),
        ({"vision": {"max_segments": 2.5}}, "vision.max_segments must be an integer"),
        ({"policy": {"max_turn_deg": True}}, "policy.max_turn_deg must be a number"),
        ({"policy": {"max_turn_deg": -5}}, "policy.max_turn_deg must be between"),
        ({"vision": {"detector": "hough"}}, "vision.detector must be one of edlines, lsd"),
        ({"policy": 3}, "policy must be a mapping"),
        # Values the vision stages cannot run with (a zero-width histogram bin, no V3
        # hypothesis to complete) are refused here, not met as a crash mid-flight.
        ({"vision": {"vanishing": {"histogram_bin_deg": 0}}},
         "vision.vanishing.histogram_bin_deg must be between 0.05 and 10"),
        ({"vision": {"vanishing": {"histogram_sigma_deg": 0}}},
         "vision.vanishing.histogram_sigma_deg must be between"),
        ({"vision": {"vanishing": {"vertical_alternatives": 0}}},
         "vision.vanishing.vertical_alternatives must be between 1 and 16"),
        ({"vision": {"obstacles": {"orthogonal_tol_deg": 0}}},
         "vision.obstacles.orthogonal_tol_deg must be between"),
        ([1, 2], "top level must be a mapping"),
        ({"camera": {"focal_px": 300, "distortion": -0.1}},
         "camera.distortion must be a list of 1 to 5 numbers"),
        ({"camera": {"focal_px": 300, "distortion": [0.1] * 6}},
         "camera.distortion must be a list of 1 to 5 numbers"),
        ({"camera": {"focal_px": 300, "distortion": [-0.1, "x"]}},
         "camera.distortion[1] must be a number"),
        # The coefficients are relative to the focal length: without it they mean nothing.
        ({"camera": {"distortion": [-0.1]}}, "camera.distortion needs camera.focal_px"),
    ],
)
def test_bad_values_name_the_key(data, needle):
    with pytest.raises(ConfigError) as e:
        from_mapping(data, source="x.yaml")
    msg = str(e.value)
    assert msg.startswith("x.yaml: ")
    assert needle in msg
    assert "\n" not in msg


def test_lens_distortion_is_a_list_of_opencv_coefficients():
    cam = from_mapping({"camera": {"focal_px": 300, "distortion": [-0.25, 0.07]}}).camera
    assert cam.distortion == (-0.25, 0.07)
    assert Config().camera.distortion is None


def test_null_allowed_only_where_optional():
    assert from_mapping({"camera": {"focal_px": None}}).camera.focal_px is None
    with pytest.raises(ConfigError, match="policy.deadband_deg must not be empty"):
        from_mapping({"policy": {"deadband_deg": None}})


def test_unreadable_and_invalid_files(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="is a directory"):
        load_config(tmp_path)
    bad = tmp_path / "bad.yaml"
    bad.write_text("policy: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)
