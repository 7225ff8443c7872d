"""Tests of `eye-in-hand tune-color` and of core.detection.range_from_samples."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from eye_in_hand.cli import main
from eye_in_hand.core.detection import (
    ColorDetector,
    DetectorConfig,
    TargetSpec,
    convert_color,
    range_from_samples,
)
from eye_in_hand.errors import InputError


def test_space_choices_are_the_detectors_colour_spaces():
    from eye_in_hand.cli import build_parser
    from eye_in_hand.core.detection import COLOR_SPACES

    tune = build_parser(["tune-color"])._subparsers._group_actions[0].choices["tune-color"]
    space = next(a for a in tune._actions if a.dest == "space")
    assert tuple(space.choices) == (*COLOR_SPACES, "both")


def test_range_from_samples_wraps_for_red_and_not_for_green():
    rng = np.random.default_rng(5)
    n = 2000
    red = np.c_[(rng.normal(0, 3, n) % 180).astype(np.uint8),
                rng.integers(150, 230, n), rng.integers(100, 200, n)].astype(np.uint8)
    r = range_from_samples(red, percentile=2, margin=(2, 10, 10))
    assert r.wraps and 170 <= r.lower[0] <= 177 and 3 <= r.upper[0] <= 10
    assert 130 <= r.lower[1] <= 155 and 225 <= r.upper[1] <= 240
    assert np.mean(r.threshold(red[None]) > 0) > 0.95
    green = red.copy()
    green[:, 0] = (rng.normal(60, 3, n)).astype(np.uint8)
    g = range_from_samples(green, percentile=2, margin=(2, 10, 10))
    assert not g.wraps and 48 <= g.lower[0] <= 56 and 64 <= g.upper[0] <= 72
    with pytest.raises(InputError, match="percentile"):
        range_from_samples(red, percentile=60)
    with pytest.raises(InputError, match="samples"):
        range_from_samples(np.zeros((0, 3), np.uint8))


@pytest.mark.parametrize("color", [(30, 30, 200), (40, 190, 60)])
def test_printed_block_pastes_into_the_parameter_file_and_detects(tmp_path, capsys, color):
    rng = np.random.default_rng(6)
    img = np.clip(np.full((300, 400, 3), (90, 110, 100), float) + rng.normal(0, 3, (300, 400, 3)),
                  0, 255).astype(np.uint8)
    noisy = np.clip(np.array(color, float) + rng.normal(0, 6, (70, 70, 3)), 0, 255)
    disc = np.zeros((300, 400), np.uint8)
    cv2.circle(disc, (200, 150), 35, 1, -1)
    img[disc > 0] = noisy.reshape(-1, 3)[: int(disc.sum())].astype(np.uint8)
    path = tmp_path / "img.png"
    cv2.imwrite(str(path), img)
    assert main(["tune-color", str(path), "--roi", "185,135,30,30", "--name", "ball"]) == 0
    out = capsys.readouterr().out
    block = yaml.safe_load(out)["ball"]
    assert block["color_space"] == "hsv" and "hsi" in out
    from eye_in_hand.core.detection import ColorRange
    cr = ColorRange(tuple(block["lower"]), tuple(block["upper"]), block["color_space"])
    mask = cr.threshold(convert_color(img, "hsv")) > 0
    assert mask[disc > 0].mean() > 0.9 and mask[disc == 0].mean() < 0.01
    (det,) = ColorDetector(DetectorConfig(targets=(TargetSpec("ball", cr),))).detect(img)
    assert np.allclose(det.centroid_px, (200, 150), atol=0.3)


def test_bad_arguments(tmp_path, capsys):
    path = tmp_path / "img.png"
    cv2.imwrite(str(path), np.zeros((50, 50, 3), np.uint8))
    assert main(["tune-color", str(path), "--roi", "40,40,20,20"]) == 1
    assert "beyond" in capsys.readouterr().err
    assert main(["tune-color", str(tmp_path / "x.png"), "--roi", "0,0,2,2"]) == 1
    with pytest.raises(SystemExit):
        main(["tune-color", str(path), "--roi", "1,2,3"])
