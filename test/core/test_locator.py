"""Tests of eye_in_hand.core.locator: StereoLocator on ray-cast stereo pairs, parameters."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.locator import StereoLocator
from eye_in_hand.core.locator_params import (
    load_locator_config,
    load_parameter_file,
    locator_config_from_params,
)
from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.sim.sphere import render_sphere

K = np.array([[900.0, 0.0, 640.0], [0.0, 905.0, 360.0], [0.0, 0.0, 1.0]])
PARAM_FILE = Path(__file__).resolve().parents[2] / "config" / "detect_triangulate.yaml"
RED, GREEN = (30, 30, 200), (40, 200, 40)


def make_rig():
    left = CameraModel(K, [-0.3, 0.15, 0.001, -0.0005, -0.05], 1280, 720)
    right = CameraModel(K + np.diag([3.0, 2.0, 0.0]), [-0.28, 0.1, 0.0, 0.0, 0.0], 1280, 720)
    R = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]
    return StereoRig(left, right, R, [-0.06, 0.001, 0.0005])


RIG = make_rig().rectified()


def pair(spheres, seed=0):
    """spheres: list of (center_left (3,), radius, colour). Returns (left, right) images."""
    rng = np.random.default_rng(seed)
    imgs = []
    for cam, T in ((RIG.left, np.eye(4)), (RIG.right, RIG.right_T_left)):
        img = np.clip(np.full((720, 1280, 3), (90, 110, 100), float)
                      + rng.normal(0, 2, (720, 1280, 3)), 0, 255).astype(np.uint8)
        for c, r, col in spheres:
            render_sphere(img, cam, T[:3, :3] @ np.asarray(c) + T[:3, 3], r, col)
        imgs.append(img)
    return imgs


def with_method(method, **kw):
    return dataclasses.replace(load_locator_config(None), method=method, **kw)


@pytest.mark.parametrize("method", ["dlt", "disparity", "optimal"])
def test_locates_a_red_sphere_within_a_fraction_of_a_millimetre(method):
    loc = StereoLocator(make_rig(), with_method(method))  # rectified by the locator
    for i, X in enumerate([np.array([0.1, -0.05, 0.45]), np.array([-0.12, 0.08, 0.35])]):
        res = loc.locate(*pair([(X, 0.02, RED)], seed=i))
        assert res.rejected == {}
        t = res.first
        assert t is not None and t.name == "red" and t.method == method
        assert np.linalg.norm(t.point_m - X) < 3e-4, (t.point_m - X)
        assert t.residual_px < 0.2
        assert np.allclose(t.left_px, RIG.left.project(X[None])[0], atol=0.1)
        sig = np.sqrt(np.diag(t.covariance))
        assert 1e-5 < sig[2] < 5e-3 and sig[0] < sig[2]
        d = t.to_dict()
        assert list(d) == ["name", "id", "point_m", "covariance", "residual_px", "left_px",
                           "right_px"] and d["name"] == d["id"] == "red"
        assert np.array(d["covariance"]).shape == (3, 3)


def test_epipolar_association_skips_a_bigger_decoy():
    X = np.array([0.0, 0.02, 0.4])
    left, right = pair([(X, 0.02, RED)])
    cv2.circle(left, (300, 600), 60, RED, -1)   # only in the left image, and the largest blob
    res = StereoLocator(RIG, load_locator_config(None)).locate(left, right)
    assert np.linalg.norm(res.first.point_m - X) < 3e-4


def test_missing_targets_are_reported_not_guessed():
    loc = StereoLocator(RIG, load_locator_config(None))
    X = np.array([0.0, 0.0, 0.4])
    left, right = pair([(X, 0.02, RED)])
    empty = pair([])
    assert loc.locate(*empty).rejected == {"red": "not_detected"}
    res = loc.locate(left, empty[1])
    assert res.first is None and res.rejected == {"red": "not_detected_right"}
    # the same sphere 40 px lower in the right image is off the epipolar line
    shifted = np.roll(right, 40, axis=0)
    res = loc.locate(left, shifted)
    assert res.rejected == {"red": "epipolar"} and "epipolar" in res.messages["red"]


def test_two_targets_in_configured_order():
    params = {"target_names": ["green", "red"],
              "targets.green.lower": [45, 120, 70], "targets.green.upper": [75, 255, 255],
              "targets.green.radius_m": 0.015}
    loc = StereoLocator(RIG, locator_config_from_params(params))
    Xr, Xg = np.array([0.08, 0.0, 0.45]), np.array([-0.08, 0.03, 0.5])
    res = loc.locate(*pair([(Xr, 0.02, RED), (Xg, 0.015, GREEN)]))
    assert [t.name for t in res.targets] == ["green", "red"] and res.first.name == "green"
    assert np.linalg.norm(res.get("red").point_m - Xr) < 3e-4
    assert np.linalg.norm(res.get("green").point_m - Xg) < 3e-4


def test_parameter_file_defaults_and_overrides(tmp_path):
    assert load_locator_config(PARAM_FILE) == load_locator_config(None)
    f = tmp_path / "p.yaml"
    f.write_text("/**:\n  ros__parameters:\n    method: optimal\n    detector: {open_px: 0}\n"
                 "detect_triangulate:\n  ros__parameters:\n    method: disparity\n")
    flat = load_parameter_file(f)
    assert flat == {"method": "disparity", "detector.open_px": 0}
    cfg = load_locator_config(f)
    assert cfg.method == "disparity" and cfg.detector.open_px == 0


@pytest.mark.parametrize("params, match", [
    ({"method": "magic"}, "'method'"),
    ({"pixel_sigma": -1.0}, "'pixel_sigma'"),
    ({"detector.open_px": 2.5}, "'detector.open_px'"),
    ({"targets.red.lower": [181, 0, 0]}, "targets.red.lower"),
    ({"target_names": []}, "target_names"),
])
def test_bad_parameters_name_the_parameter(params, match):
    with pytest.raises(ConfigError, match=match):
        locator_config_from_params(params)


def test_bad_files_and_images(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_parameter_file(tmp_path / "none.yaml")
    (tmp_path / "other.yaml").write_text("other_node:\n  ros__parameters: {a: 1}\n")
    with pytest.raises(ConfigError, match="no parameters for node"):
        load_parameter_file(tmp_path / "other.yaml")
    loc = StereoLocator(RIG, load_locator_config(None))
    with pytest.raises(InputError, match="disagrees"):
        loc.locate(np.zeros((480, 640, 3), np.uint8), np.zeros((480, 640, 3), np.uint8))


def test_pixel_covariance_cut_and_shading_terms_are_common_to_both_images():
    """The shading and threshold-cut terms move both centres alike: they add to the variance of
    the pair's mean (the point's sideways position), not to that of the disparity (its depth)."""
    from eye_in_hand.core.detection import CUT_SIGMA_PX, Detection

    def det(edge: float, shade: tuple[float, float]) -> Detection:
        z = np.zeros(2)
        return Detection("t", z, z, z, 100.0, 1.0, (0, 0, 10, 10), edge_sigma_px=edge,
                         shade_px=np.array(shade), cut_sigma_px=CUT_SIGMA_PX)

    loc = StereoLocator(RIG, load_locator_config(None))
    _, S = loc._pixel_cov(det(0.02, (0.03, 0.0)), det(0.03, (0.03, 0.0)))
    assert CUT_SIGMA_PX > 0
    mean_x, mean_y = np.array([0.5, 0, 0.5, 0]), np.array([0, 0.5, 0, 0.5])
    disp_x, disp_y = np.array([1.0, 0, -1.0, 0]), np.array([0, 1.0, 0, -1.0])
    edge = (0.02 ** 2 + 0.03 ** 2)
    # the disparity sees the two edge terms only
    assert disp_x @ S @ disp_x == pytest.approx(edge)
    assert disp_y @ S @ disp_y == pytest.approx(edge)
    # the mean sees half the edge terms plus the whole cut (both axes) and shading (along x)
    assert mean_y @ S @ mean_y == pytest.approx(edge / 4 + CUT_SIGMA_PX ** 2)
    assert mean_x @ S @ mean_x == pytest.approx(edge / 4 + CUT_SIGMA_PX ** 2 + 0.03 ** 2)
    assert np.all(np.linalg.eigvalsh(S) > 0)


@pytest.mark.parametrize("method", ["dlt", "disparity"])
def test_a_sphere_too_close_to_refine_keeps_the_full_first_pass(method):
    """When the first pass puts a camera within the sphere's radius, the centres are not
    refined: the point and its covariance are those of a target without a radius, bit for bit
    (the first pass is computed without its covariance only when a refinement follows)."""
    X = np.array([0.03, -0.02, 0.4])
    left, right = pair([(X, 0.02, RED)])

    def located(radius):
        base = with_method(method, size_tol=0.0)
        spec = dataclasses.replace(base.detector.targets[0], radius_m=radius)
        cfg = dataclasses.replace(base, detector=dataclasses.replace(base.detector,
                                                                     targets=(spec,)))
        return StereoLocator(RIG, cfg).locate(left, right).first

    near, plain, refined = located(1.0), located(None), located(0.02)
    assert near.point_m.tobytes() == plain.point_m.tobytes()
    assert near.covariance.tobytes() == plain.covariance.tobytes()
    assert np.all(np.linalg.eigvalsh(near.covariance) > 0)
    assert np.isfinite(refined.covariance).all()
    assert refined.point_m.tobytes() != plain.point_m.tobytes()   # refinement did happen
