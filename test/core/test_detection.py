"""Tests of eye_in_hand.core.detection on ray-cast sphere images with known ground truth."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from eye_in_hand.core.camera import CameraModel
from eye_in_hand.core.detection import (
    ColorDetector,
    ColorRange,
    DetectorConfig,
    TargetSpec,
    angular_radius_from_minor_axis,
    bgr_to_hsi,
    sphere_center_direction,
    sphere_silhouette_center,
)
from eye_in_hand.errors import InputError
from eye_in_hand.sim.sphere import render_sphere

K = np.array([[900.0, 0.0, 640.0], [0.0, 905.0, 360.0], [0.0, 0.0, 1.0]])
RED = ColorRange((170, 120, 70), (10, 255, 255))
GREEN = ColorRange((45, 120, 70), (75, 255, 255))
BG = (90, 110, 100)


def background(seed=0, sigma=2.0):
    rng = np.random.default_rng(seed)
    img = np.full((720, 1280, 3), BG, np.float64) + rng.normal(0, sigma, (720, 1280, 3))
    return np.clip(img, 0, 255).astype(np.uint8)


def config(*targets, **kw):
    return DetectorConfig(targets=tuple(targets), **kw)


def test_color_range_validation_and_wrap():
    assert RED.wraps and not GREEN.wraps
    assert RED.contains((175, 200, 200)) and RED.contains((5, 200, 200))
    assert not RED.contains((90, 200, 200)) and not RED.contains((0, 50, 200))
    with pytest.raises(InputError, match=r"lower\[0\]"):
        ColorRange((180, 0, 0), (10, 255, 255))
    with pytest.raises(InputError, match=r"exceeds upper\[1\]"):
        ColorRange((0, 200, 0), (10, 100, 255))
    with pytest.raises(InputError, match="space"):
        ColorRange((0, 0, 0), (10, 255, 255), "xyz")


def test_wrapped_red_threshold_takes_both_ends_of_the_hue_circle():
    hsv = np.array([[[178, 200, 200], [2, 200, 200], [90, 200, 200], [5, 50, 200]]], np.uint8)
    assert RED.threshold(hsv).ravel().tolist() == [255, 255, 0, 0]


def test_hsi_conversion_of_primaries_and_grey():
    img = np.array([[[0, 0, 255], [0, 255, 0], [255, 0, 0], [128, 128, 128]]], np.uint8)
    hsi = bgr_to_hsi(img)
    assert hsi[0, :, 0].tolist()[:3] == [0, 60, 120]  # red 0, green 120, blue 240 degrees / 2
    assert hsi[0, :3, 1].tolist() == [255, 255, 255] and hsi[0, 3, 1] == 0
    assert hsi[0, :, 2].tolist() == [85, 85, 85, 128]


def test_sphere_center_formula_inverts_the_silhouette_centre():
    rng = np.random.default_rng(1)
    for _ in range(50):
        theta, alpha = rng.uniform(0, 0.7), rng.uniform(0.005, 0.15)
        phi = rng.uniform(0, 2 * np.pi)
        m = sphere_silhouette_center(theta, alpha)
        c = sphere_center_direction(m * np.array([np.cos(phi), np.sin(phi)]), alpha)
        assert np.allclose(c, math.tan(theta) * np.array([np.cos(phi), np.sin(phi)]), atol=1e-12)
    # the minor semi-axis formula agrees with the cone: b = sin(a) / sqrt(cos^2 t - sin^2 a)
    b = math.sin(0.1) / math.sqrt(math.cos(0.5) ** 2 - math.sin(0.1) ** 2)
    assert angular_radius_from_minor_axis(b, 0.5) == pytest.approx(0.1, abs=1e-12)


@pytest.mark.parametrize("dist", [[0, 0, 0, 0, 0], [-0.3, 0.15, 0.001, -0.0005, -0.05]])
def test_sphere_correction_recovers_the_projected_centre(dist):
    cam = CameraModel(K, dist, 1280, 720)
    det = ColorDetector(config(TargetSpec("red", RED, radius_m=0.02)))
    raw_err, corr_err = [], []
    for i, c in enumerate([(0.15, 0.1, 0.35), (0.1, -0.05, 0.3), (-0.25, 0.12, 0.4)]):
        img = background(i)
        render_sphere(img, cam, c, 0.02, (30, 30, 200))
        (d,) = det.detect(img, cam)
        truth = cam.project(np.array([c]))[0]
        raw_err.append(np.linalg.norm(d.centroid_px - truth))
        corr_err.append(np.linalg.norm(d.center_px - truth))
        assert np.allclose(cam.project(np.r_[d.center_norm, 1.0][None])[0], d.center_px)
        assert d.angular_radius == pytest.approx(math.asin(0.02 / np.linalg.norm(c)), rel=0.02)
        assert d.circularity > 0.85
        assert d.area_px == pytest.approx(d.bbox[2] * d.bbox[3] * math.pi / 4, rel=0.1)
    assert max(corr_err) < 0.1, corr_err
    if dist[0] == 0:  # without distortion the perspective offset is well over a pixel
        assert min(raw_err) > 0.8, raw_err


def test_no_target_and_gates_return_nothing():
    cam = CameraModel(K, [0] * 5, 1280, 720)
    det = ColorDetector(config(TargetSpec("red", RED, min_area_px=200, min_circularity=0.7)))
    img = background()
    assert det.detect(img, cam) == []
    cv2.rectangle(img, (100, 100), (400, 110), (30, 30, 200), -1)   # a thin bar: not circular
    cv2.circle(img, (700, 400), 5, (30, 30, 200), -1)               # too small
    cv2.circle(img, (1275, 300), 30, (30, 30, 200), -1)             # cut by the border
    assert det.detect(img, cam) == []
    cv2.circle(img, (600, 300), 20, (30, 30, 200), -1)
    (d,) = det.detect(img, cam)
    assert np.allclose(d.centroid_px, (600, 300), atol=0.05)


def test_multiple_targets_candidates_and_selection():
    cam = CameraModel(K, [0] * 5, 1280, 720)
    specs = (TargetSpec("red", RED), TargetSpec("green", GREEN, is_sphere=False))
    img = background()
    cv2.circle(img, (300, 300), 30, (30, 30, 200), -1)
    cv2.circle(img, (900, 500), 15, (30, 30, 200), -1)
    cv2.circle(img, (640, 200), 20, (40, 200, 40), -1)
    det = ColorDetector(config(*specs))
    found = det.detect(img, cam)
    assert [d.name for d in found] == ["red", "green"]
    assert np.allclose(found[0].centroid_px, (300, 300), atol=0.05)
    assert np.allclose(found[1].center_px, (640, 200), atol=0.05)  # flat target: no correction
    cands = det.candidates(img, cam)
    assert [len(cands["red"]), len(cands["green"])] == [2, 1]
    assert [round(c.centroid_px[0]) for c in cands["red"]] == [300, 900]  # largest first
    cv2.ellipse(img, (150, 600), (60, 25), 0, 0, 360, (30, 30, 200), -1)  # largest, elongated
    (big,) = ColorDetector(config(specs[0])).detect(img, cam)
    (round_,) = ColorDetector(config(specs[0], selection="circular")).detect(img, cam)
    assert np.allclose(big.centroid_px, (150, 600), atol=0.05)
    assert round_.circularity > big.circularity and round_.centroid_px[0] != 150
    nearest = ColorDetector(config(*specs, selection="nearest"))
    (red, _) = nearest.detect(img, cam, previous={"red": np.array([880.0, 490.0])})
    assert np.allclose(red.centroid_px, (900, 500), atol=0.05)


def test_full_resolution_path_matches_downscaled_path():
    img = background()
    cv2.circle(img, (333, 222), 25, (30, 30, 200), -1)
    a = ColorDetector(config(TargetSpec("red", RED), downscale=1)).detect(img)
    b = ColorDetector(config(TargetSpec("red", RED), downscale=4)).detect(img)
    assert np.allclose(a[0].centroid_px, b[0].centroid_px) and a[0].area_px == b[0].area_px
    assert np.all(np.isnan(a[0].center_norm))  # no camera model: no normalised coordinates


def test_bad_inputs_raise():
    det = ColorDetector(config(TargetSpec("red", RED)))
    cam = CameraModel(K, [0] * 5, 1280, 720)
    with pytest.raises(InputError, match="BGR uint8"):
        det.detect(np.zeros((720, 1280), np.uint8))
    with pytest.raises(InputError, match="disagrees"):
        det.detect(np.zeros((480, 640, 3), np.uint8), cam)
    with pytest.raises(InputError, match="unique"):
        config(TargetSpec("a", RED), TargetSpec("a", GREEN))
    with pytest.raises(InputError, match="selection"):
        config(TargetSpec("a", RED), selection="best")
    with pytest.raises(InputError, match="radius_m"):
        TargetSpec("a", RED, radius_m=-1.0)


def test_hsi_range_detects_the_same_sphere_as_hsv():
    cam = CameraModel(K, [0] * 5, 1280, 720)
    img = background(3)
    c = (0.05, 0.03, 0.4)
    render_sphere(img, cam, c, 0.02, (30, 30, 200))
    hsi = ColorRange((170, 100, 30), (10, 255, 255), "hsi")
    (a,) = ColorDetector(config(TargetSpec("red", hsi, radius_m=0.02))).detect(img, cam)
    (b,) = ColorDetector(config(TargetSpec("red", RED, radius_m=0.02))).detect(img, cam)
    # edge pixels (partly covered) fall either side of two different thresholds
    assert a.area_px == pytest.approx(b.area_px, rel=0.02)
    assert np.allclose(a.center_px, cam.project(np.array([c]))[0], atol=0.1)


def test_one_component_is_found_without_labelling_as_labelling_finds_it():
    """The fine pass labels a ROI's mask only when it holds several components: for one,
    ``_single_component`` gives the stats ``connectedComponentsWithStats`` gives (bounding
    box, pixel count) and the outer border ``cv2.findContours`` traces on the component's
    bounding box alone (the fine pass's contour: the same points in the same order), for
    several None, for none ``()``. Random blobs with holes, diagonal contacts (8-connected:
    one component), nested rings and image-edge contact."""
    from eye_in_hand.core.detection import _single_component

    rng = np.random.default_rng(3)
    seen = {"one": 0, "several": 0, "none": 0}
    for trial in range(400):
        h, w = rng.integers(8, 60, size=2)
        mask = np.zeros((h, w), np.uint8)
        for _ in range(int(rng.integers(0, 4))):
            c = (int(rng.integers(-5, w + 5)), int(rng.integers(-5, h + 5)))
            cv2.circle(mask, c, int(rng.integers(1, 15)), 255, -1)
            if rng.random() < 0.4:                       # a hole, maybe a blob inside it
                cv2.circle(mask, c, int(rng.integers(1, 6)), 0, -1)
                if rng.random() < 0.5:
                    cv2.circle(mask, c, 1, 255, -1)
        if trial % 7 == 0:                                # two squares touching at a corner
            mask[:] = 0
            mask[2:6, 2:6] = 255
            mask[6:9, 6:9] = 255
        n, _labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8,
                                                                ltype=cv2.CV_16U)
        got = _single_component(mask)
        if n == 1:
            assert got == ()
            seen["none"] += 1
        elif n == 2:
            assert got[:5] == tuple(int(v) for v in stats[1]), (trial, got, stats[1])
            x, y, w, h = got[:4]
            crop = cv2.threshold(mask[y:y + h, x:x + w], 0, 1, cv2.THRESH_BINARY)[1]
            alone, _ = cv2.findContours(crop, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            assert len(alone) == 1
            np.testing.assert_array_equal(got[5] - (x, y), alone[0])
            seen["one"] += 1
        else:
            assert got is None, (trial, n)
            seen["several"] += 1
    assert min(seen.values()) > 20, seen


def test_threshold_planes_is_threshold_pixel_for_pixel() -> None:
    """The coarse pass's plane-wise threshold gives inRange's masks: random uint8 images
    (hues above 179 too), random ranges (wrapping or not, bounds at 0, 179 and 255), several
    ranges on one shared ``ColorPlanes`` (its cached bounds are not modified by them nor by
    a caller writing into a mask it was given)."""
    from eye_in_hand.core.detection import ColorPlanes
    rng = np.random.default_rng(21)
    edges = [0, 1, 12, 80, 165, 178, 179]
    for _ in range(60):
        img = rng.integers(0, 256, (int(rng.integers(1, 40)), int(rng.integers(1, 40)), 3),
                           dtype=np.uint8)
        planes = ColorPlanes(img)
        ranges = []
        for _ in range(6):
            h0, h1 = (int(rng.choice(edges)) if rng.random() < 0.5 else int(rng.integers(0, 180))
                      for _ in range(2))
            sv = sorted(int(v) for v in rng.choice([0, 1, 25, 254, 255, 80, 200], 2)), \
                sorted(int(v) for v in rng.integers(0, 256, 2))
            ranges.append(ColorRange((h0, sv[0][0], sv[1][0]), (h1, sv[0][1], sv[1][1])))
        ranges.append(ColorRange((0, 0, 0), (179, 255, 255)))
        ranges.append(ColorRange((170, 0, 0), (10, 255, 255)))
        for r in ranges + ranges[::-1]:
            got = r.threshold_planes(planes)
            assert got.dtype == np.uint8 and got.shape == img.shape[:2]
            np.testing.assert_array_equal(got, r.threshold(img))
            got[:] = 7     # the caller's own array: the shared bounds stay as they were
