"""The blur law of the centre sigma's shared terms, at blurs where wrong laws differ.

:mod:`eye_in_hand.core.detection` grows the shading term as ``1 + SHADE_BLUR_GAIN b^2`` and the
threshold-cut term as ``CUT_SIGMA_PX (1 + CUT_BLUR_GAIN b)``, with the blur
``b = sqrt(max(w^2 - BLUR_W0_PX^2, 0))`` from the measured edge width ``w``. At b = 0 and 1 px
``b`` and ``b^2`` agree; these tests hold the edge width at chosen values (the rest of the
detection unchanged, on one shaded blob) and check each term at intermediate blurs.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import eye_in_hand.core.detection as detection
from eye_in_hand.core.camera import CameraModel
from eye_in_hand.core.detection import (
    BLUR_W0_PX,
    CUT_BLUR_GAIN,
    CUT_SIGMA_PX,
    SHADE_BLUR_GAIN,
    ColorDetector,
    ColorRange,
    DetectorConfig,
    TargetSpec,
)
from eye_in_hand.sim.sphere import render_sphere

K = np.array([[900.0, 0.0, 320.0], [0.0, 900.0, 240.0], [0.0, 0.0, 1.0]])
CAM = CameraModel(K, np.zeros(5), 640, 480)


@pytest.fixture(scope="module")
def image() -> np.ndarray:
    """A red sphere lit from one side: brighter to the right and down (non-zero shading)."""
    rng = np.random.default_rng(4)
    img = np.full((480, 640, 3), (90, 110, 100), np.float64) + rng.normal(0, 1.0, (480, 640, 3))
    img = np.clip(img, 0, 255).astype(np.uint8)
    render_sphere(img, CAM, np.array([0.012, -0.008, 0.5]), 0.02, (30, 30, 210))
    red = img[..., 2] > 150
    ys, xs = np.mgrid[0:480, 0:640]
    gain = 0.75 + 0.25 * np.clip((xs - 300) / 80.0 + (ys - 200) / 160.0, 0.0, 1.0)
    out = img.astype(np.float64)
    out[red] *= gain[red][:, None]
    return np.clip(out, 0, 255).astype(np.uint8)


def _detect(image: np.ndarray, monkeypatch, b: float):
    """The detection with the edge width held at the width of a blur ``b``."""
    w = math.sqrt(BLUR_W0_PX ** 2 + b * b)
    monkeypatch.setattr(detection, "_edge_widths", lambda image, contours, *a: [w] * len(contours))
    det = ColorDetector(DetectorConfig(targets=(TargetSpec(
        "red", ColorRange((170, 120, 70), (10, 255, 255)), radius_m=0.02),)))
    d = det.detect(image, CAM)
    assert len(d) == 1
    return d[0]


@pytest.mark.parametrize("b", [0.3, 0.5, 0.7])
def test_shading_grows_with_b_squared_and_the_cut_with_b(image, monkeypatch, b) -> None:
    d0 = _detect(image, monkeypatch, 0.0)
    d = _detect(image, monkeypatch, b)
    assert d0.blur_px == 0.0 and d.blur_px == pytest.approx(b, rel=1e-12)
    s0 = float(np.hypot(*d0.shade_px))
    assert s0 > 1e-3, s0                                      # the blob is shaded
    np.testing.assert_allclose(d.shade_px, d0.shade_px * (1.0 + SHADE_BLUR_GAIN * b * b),
                               rtol=1e-12)
    assert d0.cut_sigma_px == pytest.approx(CUT_SIGMA_PX, rel=1e-12)
    assert d.cut_sigma_px == pytest.approx(CUT_SIGMA_PX * (1.0 + CUT_BLUR_GAIN * b), rel=1e-12)
    assert d.edge_sigma_px == d0.edge_sigma_px
    assert d.center_sigma_px == pytest.approx(
        math.hypot(d.edge_sigma_px, float(np.hypot(*d.shade_px)), d.cut_sigma_px), rel=1e-12)


def test_an_edge_narrower_than_the_unblurred_width_is_no_blur(image, monkeypatch) -> None:
    monkeypatch.setattr(detection, "_edge_widths",
                        lambda image, contours, *a: [0.5 * BLUR_W0_PX] * len(contours))
    det = ColorDetector(DetectorConfig(targets=(TargetSpec(
        "red", ColorRange((170, 120, 70), (10, 255, 255)), radius_m=0.02),)))
    d = det.detect(image, CAM)[0]
    assert d.blur_px == 0.0 and d.cut_sigma_px == pytest.approx(CUT_SIGMA_PX, rel=1e-12)
