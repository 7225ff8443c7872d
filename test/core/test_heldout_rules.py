"""core: documented rules that held-out planted bugs showed no test pinned.

The TF time-jump boundary, the locator's shared threshold-cut term per image, a target's largest
error in mm, the edge width's cosine and the shading vector, the stereo pairing's skew figure,
the pose buffer's receive times, and the saddle corner refinement (no saddle, the largest move,
the corner sigma per axis against the scatter it predicts). See ``tools/mutation_heldout.py``.
"""
from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from eye_in_hand.core.calibration.board import BoardDetection
from eye_in_hand.core.calibration.detection import _refined, refine_saddle
from eye_in_hand.core.detection import SHADE_GAIN, center_sigma_parts, edge_width
from eye_in_hand.core.distances import target_stats
from eye_in_hand.core.locator import StereoLocator
from eye_in_hand.core.locator_params import LocatorConfig
from eye_in_hand.core.sync import ApproximateStereoSync, PoseBuffer
from eye_in_hand.core.tf import TfBuffer, TfPoseView
from eye_in_hand.core.transforms import from_rotvec
from eye_in_hand.errors import LocalizationError

S = 1_000_000_000


# -- tf: a time jump is *more* than jump_back_ns ------------------------------------------------

def test_a_transform_exactly_jump_back_older_does_not_clear() -> None:
    buf = TfBuffer(100)
    view = TfPoseView(buf, "base", "tool0", jump_back_ns=S)
    for k in range(5):
        buf.set_transform("base", "tool0", 10 * S + k * S // 2, np.eye(4))
    newest = 12 * S
    assert view.newest_ns == newest
    assert not view.check_jump(newest - S)
    assert view.resets["time_jump"] == 0
    assert view.check_jump(newest - S - 1)
    assert view.resets["time_jump"] == 1


# -- locator: the threshold cut of each image from its own detection -----------------------------

def test_pixel_covariance_takes_each_images_own_cut_and_edge_terms() -> None:
    cfg = SimpleNamespace(pixel_sigma=0.0)
    assert LocatorConfig.__dataclass_fields__["pixel_sigma"].default == 0.0
    dl = SimpleNamespace(edge_sigma_px=0.3, shade_px=np.array([0.05, -0.02]), cut_sigma_px=0.02)
    dr = SimpleNamespace(edge_sigma_px=0.2, shade_px=np.array([0.04, 0.01]), cut_sigma_px=0.07)
    sigma, cov = StereoLocator._pixel_cov(SimpleNamespace(config=cfg), dl, dr)
    assert sigma == 0.0 and cov is not None
    v = np.array([0.05, -0.02, 0.04, 0.01])
    want = np.diag([0.09, 0.09, 0.04, 0.04]) + np.outer(v, v)
    for axis in (0, 1):
        u = np.zeros(4)
        u[axis], u[2 + axis] = 0.02, 0.07
        want += np.outer(u, u)
    assert np.allclose(cov, want, rtol=1e-12, atol=0)


# -- distances: every error figure in mm --------------------------------------------------------

def test_target_largest_error_is_in_mm() -> None:
    track = np.array([[0.0, 0.0, 1.0], [0.0, 0.003, 1.0], [np.nan] * 3])
    truth = np.array([[0.0, 0.0, 1.001], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    (st,) = target_stats({"a": track}, {"a": truth})
    assert (st.located, st.truth_frames) == (2, 2)
    assert st.max_mm == pytest.approx(3.0)
    assert st.rms_mm == pytest.approx(np.sqrt((1.0 + 9.0) / 2))


# -- detection: edge width and shading ----------------------------------------------------------

def _disc(blur: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A large disc (edges at every angle to the sampling axes), blurred."""
    h = w = 240
    yy, xx = np.mgrid[0:h * 4, 0:w * 4]
    x, y = (xx + 0.5) / 4 - 0.5 - 119.3, (yy + 0.5) / 4 - 0.5 - 119.6
    img = np.where(x * x + y * y < 70.0 ** 2, 220.0, 30.0).reshape(h, 4, w, 4).mean((1, 3))
    img = cv2.GaussianBlur(img, (0, 0), blur).astype(np.uint8)
    mask = (img > 125).astype(np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    c = max(contours, key=len).reshape(-1, 2).astype(np.float64)
    return img, c, c.mean(axis=0)


def test_edge_width_corrects_the_sampling_axis_by_the_cosine() -> None:
    """An edge at angle ``a`` to the sampling axis reads ``s / cos a`` along it; times the
    cosine, the whole disc's contour reads what its points on the axes (cos 1) read, not the
    12 % more of the mean secant."""
    img, contour, centre = _disc(1.2)
    n = contour - centre
    on_axis = contour[np.abs(n).max(axis=1) / np.hypot(n[:, 0], n[:, 1]) > 0.995]
    assert len(on_axis) > 20
    assert edge_width(img, contour, centre) == pytest.approx(
        edge_width(img, on_axis, centre), rel=0.03)


def test_uniform_blob_has_no_shading_vector() -> None:
    """The shading vector is the grey-weighted minus the plain centroid, per axis: zero for a
    uniform blob, whatever its shape and place."""
    mask = np.zeros((80, 120), dtype=np.uint8)
    mask[10:30, 40:110] = 1
    grey = np.full(mask.shape, 150, dtype=np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    _, shade = center_sigma_parts(mask, grey, contours[0].reshape(-1, 2).astype(np.float64))
    assert np.allclose(shade, 0.0, atol=1e-12)
    grey = grey.astype(np.float64)
    grey[:, :] = np.arange(80)[:, None] + 100.0      # brighter downwards: y shift only
    _, shade = center_sigma_parts(mask, grey.astype(np.uint8),
                                  contours[0].reshape(-1, 2).astype(np.float64))
    ys = np.arange(10, 30)
    want = float((ys * (ys + 100.0)).sum() / (ys + 100.0).sum() - ys.mean())
    assert shade[0] == pytest.approx(0.0, abs=1e-12)
    assert shade[1] == pytest.approx(SHADE_GAIN * want, rel=1e-9)


# -- sync: the skew figure and the receive time of a re-sent pose --------------------------------

def test_max_abs_skew_counts_a_right_frame_before_its_left() -> None:
    sync: ApproximateStereoSync[int] = ApproximateStereoSync(5_000_000)
    pairs = sync.push_right(1_000_000_000, 0) + sync.push_left(1_003_000_000, 0)
    pairs += sync.push_right(2_000_000_000, 1) + sync.push_left(2_001_000_000, 1)
    pairs += sync.push_right(3_000_000_000, 2) + sync.push_left(3_000_000_000, 2)
    assert len(pairs) >= 2
    assert pairs[0].skew_ns == -3_000_000
    assert sync.stats.max_abs_skew_ns == 3_000_000


def test_a_pose_re_sent_at_its_stamp_takes_the_new_receive_time() -> None:
    buf = PoseBuffer(10)
    T = from_rotvec([0, 0, 0.1], [0.1, 0, 0])
    buf.add(5 * S, T, received_ns=5 * S)
    with pytest.raises(LocalizationError):
        buf.lookup(5 * S, 0, now_ns=20 * S, max_age_ns=S)
    buf.add(5 * S, T, received_ns=20 * S)
    assert np.allclose(buf.lookup(5 * S, 0, now_ns=20 * S, max_age_ns=S), T)


# -- calibration: the saddle refinement ----------------------------------------------------------

def _board(x0: float, y0: float, s: float, h: int = 160, w: int = 200) -> np.ndarray:
    yy, xx = np.mgrid[0:h * 4, 0:w * 4]
    x, y = (xx + 0.5) / 4 - 0.5, (yy + 0.5) / 4 - 0.5
    i, j = np.floor((x - x0) / s), np.floor((y - y0) / s)
    return np.where((i + j) % 2 == 0, 200.0, 50.0).reshape(h, 4, w, 4).mean(axis=(1, 3))


def test_saddle_sigma_per_axis_matches_the_corner_scatter() -> None:
    """Over 378 corners in six noisy renders the refined corners' RMS error per axis is the
    reported sigma (``sqrt(trace(cov) / 2)``) within 20 %."""
    rng = np.random.default_rng(1)
    errs, sig = [], []
    for k in range(6):
        x0, y0 = 20.3 + 0.37 * k, 15.7 + 0.21 * k
        img = cv2.GaussianBlur(_board(x0, y0, 14.0), (0, 0), 0.8)
        img = np.clip(img + rng.normal(scale=3.0, size=img.shape), 0, 255).astype(np.uint8)
        c = np.array([[x0 + 14 * a, y0 + 14 * b] for a in range(1, 10) for b in range(1, 8)])
        c = c[(c[:, 0] < 190) & (c[:, 1] < 150)]
        out, s = refine_saddle(img, c + rng.uniform(-0.4, 0.4, c.shape))
        errs.append(out - c)
        sig.append(s)
    e, s = np.concatenate(errs), np.concatenate(sig)
    assert np.all(np.isfinite(s))
    ratio = np.sqrt(np.mean(e ** 2)) / np.sqrt(np.mean(s ** 2))
    assert 0.8 < ratio < 1.2, ratio


def test_saddle_keeps_a_corner_without_a_saddle_or_moved_too_far() -> None:
    img = cv2.GaussianBlur(_board(20.3, 15.7, 14.0), (0, 0), 0.8).astype(np.uint8)
    blob = np.full((60, 60), 40, dtype=np.uint8)
    cv2.circle(blob, (30, 30), 6, 220, -1)
    blob = cv2.GaussianBlur(blob, (0, 0), 2.0)
    out, s = refine_saddle(blob, np.array([[31.0, 29.5]]))
    assert np.array_equal(out, [[31.0, 29.5]]) and np.isnan(s[0])
    start = np.array([[20.3 + 28 + 1.0, 15.7 + 28 - 0.2]])        # 1 px from the corner
    out, s = refine_saddle(img, start)
    assert np.linalg.norm(out[0] - [48.3, 43.7]) < 0.1 and np.isfinite(s[0])
    out, s = refine_saddle(img, start, max_shift=0.5)
    assert np.array_equal(out, start) and np.isnan(s[0])


def test_detection_sigma_is_the_median_of_the_corner_sigmas() -> None:
    rng = np.random.default_rng(4)
    board = _board(20.3, 15.7, 14.0)
    img = cv2.GaussianBlur(board, (0, 0), 0.8)
    img[:, 110:] = cv2.GaussianBlur(board, (0, 0), 3.0)[:, 110:]     # a skewed set of sigmas
    img = img + rng.normal(scale=2.0, size=img.shape)
    gray = np.clip(img, 0, 255).astype(np.uint8)
    c = np.array([[20.3 + 14 * a, 15.7 + 14 * b] for a in range(1, 10) for b in range(1, 8)])
    det = BoardDetection(True, c, np.zeros((len(c), 3)), np.arange(len(c)), (200, 160), "sb")
    out = _refined(det, gray, "saddle")
    s = out.meta["corner_sigma_px"]
    assert np.all(np.isfinite(s)) and abs(np.mean(s) - np.median(s)) > 0.05 * np.median(s)
    assert out.meta["sigma_px"] == pytest.approx(float(np.median(s)))


def test_subpixel_window_spacing_is_the_smaller_direction() -> None:
    """The classic detector's subpixel window stays inside one square: the corner spacing is
    the smaller of the two grid directions (a board foreshortened to 8 px rows, 20 px
    columns gives 8)."""
    from eye_in_hand.core.calibration.detection import _min_corner_spacing

    cols, rows = 5, 4
    grid = np.array([[30.0 + 20.0 * i, 40.0 + 8.0 * j] for j in range(rows) for i in range(cols)])
    assert _min_corner_spacing(grid, cols, rows) == pytest.approx(8.0)
    assert _min_corner_spacing(grid[:, ::-1].copy(), cols, rows) == pytest.approx(8.0)
