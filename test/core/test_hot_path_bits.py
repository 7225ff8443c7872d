"""The per-blob and per-target hot paths give the bits of their plain NumPy spelling.

Detection and triangulation spell a few NumPy calls out for speed (issue 24): ``np.mean`` as
the sum over the count, ``np.linspace`` as ``arange`` times the step, ``np.linalg.norm`` as the
root of the summed squares, one ``cv2.projectPoints`` for one direction. Every output bag must
stay the same byte for byte, so each is checked here against the plain spelling it replaced,
to the last bit, on many inputs.
"""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from eye_in_hand.core import detection, triangulation
from eye_in_hand.core.camera import CameraModel

K = np.array([[900.0, 0.0, 640.0], [0.0, 905.0, 360.0], [0.0, 0.0, 1.0]])
DIST = {"plumb_bob": [-0.3, 0.15, 0.001, -0.0005, -0.05],
        "rational_polynomial": [-0.3, 0.15, 0.001, -0.0005, -0.05, 0.01, 0.0, 0.002]}


def _bits(*values) -> list[bytes]:
    return [np.asarray(v, dtype=np.float64).tobytes() for v in values]


@pytest.mark.parametrize("model", sorted(DIST))
def test_project_direction_is_project_of_the_direction(model: str) -> None:
    cam = CameraModel(K, DIST[model], 1280, 720, distortion_model=model)
    rng = np.random.default_rng(3)
    for x, y in rng.uniform(-0.8, 0.8, (300, 2)):
        got = cam.project_direction(x, y)
        assert got.shape == (2,)
        assert _bits(got) == _bits(cam.project(np.array([[x, y, 1.0]]))[0])
    # several directions in one call (the detector's spheres of one image): each one's bits
    for n in (1, 2, 7):
        xy = rng.uniform(-0.8, 0.8, (n, 2))
        many = cam.project_directions(xy)
        assert many.shape == (n, 2)
        assert _bits(many) == _bits(np.array([cam.project_direction(x, y) for x, y in xy]))


def _blob_contours(n_blobs: int, seed: int):
    """Outer contours (int32 (K, 1, 2)) of noisy, slightly elliptic discs of 5-60 px radius."""
    rng = np.random.default_rng(seed)
    for _ in range(n_blobs):
        r = rng.uniform(5, 60)
        size = int(2 * r + 40)
        img = np.zeros((size, size), np.uint8)
        cv2.ellipse(img, (size // 2, size // 2), (int(r), int(r * rng.uniform(0.8, 1.0))),
                    rng.uniform(0, 180), 0, 360, 255, -1)
        img[rng.random(img.shape) < 0.02] ^= 255
        contours, _ = cv2.findContours(img, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        yield img, max(contours, key=cv2.contourArea)


def _tau_plain(res: np.ndarray, var: float) -> float:
    """``_correlation_time`` as the FFT loop alone."""
    n = len(res)
    tau = 1.0
    if var > 0:
        spec = np.fft.rfft(res)
        ac = np.fft.irfft(spec * np.conj(spec), n) / (n * var)
        for k in range(1, n // 4):
            if ac[k] < 0.05:
                break
            tau += 2.0 * float(ac[k])
    return tau


def _edge_sigma_plain(contour: np.ndarray) -> float:
    """``center_sigma_parts``' edge term with ``np.mean``."""
    n = len(contour)
    (cx, cy), (d1, d2), ang = cv2.fitEllipse(contour.astype(np.float32))
    a, b = 0.5 * d1, 0.5 * d2
    c, s_ = math.cos(math.radians(ang)), math.sin(math.radians(ang))
    d = contour - (cx, cy)
    u, v = d[:, 0] * c + d[:, 1] * s_, -d[:, 0] * s_ + d[:, 1] * c
    rho = np.sqrt((u / a) ** 2 + (v / b) ** 2)
    res = (rho - 1.0) * np.hypot(u, v) / np.maximum(rho, 1e-12)
    res = res - res.mean()
    var = float(np.mean(res * res))
    return math.sqrt(var * 2.0 * _tau_plain(res, var) / n)


def _edge_width_plain(image: np.ndarray, contour: np.ndarray, center: np.ndarray) -> float:
    """``edge_width`` with ``np.linspace``."""
    n = len(contour)
    band = detection._EDGE_BAND_PX
    pts = contour[np.linspace(0, n, min(n, detection._EDGE_PROFILES),
                              endpoint=False).astype(int)]
    nrm = pts - center
    anrm = np.abs(nrm)
    horiz = anrm[:, 0] >= anrm[:, 1]
    cos = np.maximum(anrm[:, 0], anrm[:, 1]) / np.maximum(np.hypot(nrm[:, 0], nrm[:, 1]), 1e-9)
    sign = np.sign(np.where(horiz, nrm[:, 0], nrm[:, 1]))
    step = (sign[:, None] * np.arange(-band, band + 2)[None, :]).astype(np.intp)
    along = np.where(horiz[:, None], step, 0)
    h, w = image.shape[:2]
    ipts = pts.astype(int)
    xs = np.clip(ipts[:, :1] + along, 0, w - 1)
    ys = np.clip(ipts[:, 1:] + (step - along), 0, h - 1)
    prof = image[ys, xs].astype(np.float32)
    d = np.sqrt((np.diff(prof, axis=1) ** 2).sum(axis=2))
    s1, s2 = d.sum(axis=1), (d * d).sum(axis=1)
    ok = s2 > 0
    return float(np.mean(s1[ok] ** 2 / s2[ok] * cos[ok])) / (2.0 * math.sqrt(math.pi))


def test_blob_measurements_are_those_of_the_plain_spelling() -> None:
    rng = np.random.default_rng(5)
    checked = 0
    for mask, c in _blob_contours(40, 1):
        local = c.reshape(-1, 2).astype(np.float64)
        if len(local) < 12:
            continue
        checked += 1
        edge, _ = detection.center_sigma_parts(mask // 255, mask, local)
        assert _bits(edge) == _bits(_edge_sigma_plain(local))
        # edge_width: the profiles at the contour points np.linspace gives
        image = rng.integers(0, 256, mask.shape + (3,), dtype=np.uint8)
        image[mask > 0] //= 4
        centre = local.mean(axis=0)
        width = detection.edge_width(image, c.reshape(-1, 2), centre)
        assert math.isfinite(width)
        assert _bits(width) == _bits(_edge_width_plain(image, c.reshape(-1, 2), centre))
    assert checked >= 30


def _polygon_plain(contour_norm: np.ndarray, scale: float) -> tuple[np.ndarray | None, float]:
    """``_polygon_center_and_minor_axis`` as one polygon's plain NumPy."""
    c0 = contour_norm.mean(axis=0)
    p = (contour_norm - c0) * scale
    x, y = p[:, 0], p[:, 1]
    nxt = np.roll(p, -1, axis=0)
    xn, yn = nxt[:, 0], nxt[:, 1]
    cross = x * yn - xn * y
    a = np.sum(cross) / 2.0
    if abs(a) < 1e-9:
        return None, float("nan")
    cx = np.sum((x + xn) * cross) / (6.0 * a)
    cy = np.sum((y + yn) * cross) / (6.0 * a)
    sxx = np.sum((x * x + x * xn + xn * xn) * cross) / (12.0 * a) - cx * cx
    syy = np.sum((y * y + y * yn + yn * yn) * cross) / (12.0 * a) - cy * cy
    sxy = np.sum((x * yn + 2 * x * y + 2 * xn * yn + xn * y) * cross) / (24.0 * a) - cx * cy
    lam_min = 0.5 * (sxx + syy) - math.sqrt(max(0.0, 0.25 * (sxx - syy) ** 2 + sxy * sxy))
    return c0 + np.array([cx, cy]) / scale, (2.0 * math.sqrt(max(lam_min, 0.0)) + 0.5) / scale


def test_blobs_measured_together_have_the_bits_of_each_alone(monkeypatch) -> None:
    """The detector measures all of an image's blobs in one pass of NumPy calls
    (``_edge_sigmas``, ``_edge_widths``, ``_polygon_centers_and_minor_axes``): each blob's
    numbers are those of its plain one-blob spelling, to the last bit. Groups of 1-6 blobs of
    5-60 px radius (smooth contours whose residuals take the FFT among them), contours too
    short to measure, and each blob in a region just around it, so that its profiles are
    clamped to its own region, not to the image."""
    rng = np.random.default_rng(9)
    blobs = [c.reshape(-1, 2) for _, c in _blob_contours(60, 4)]
    blobs += [np.array([[0, 0], [1, 0], [2, 1], [1, 2], [0, 1]], np.int32)]   # too short
    image = rng.integers(0, 256, (300, 400, 3), dtype=np.uint8)
    taus: list[float] = []
    tau = detection._correlation_time
    monkeypatch.setattr(detection, "_correlation_time",
                        lambda res, var: taus.append(tau(res, var)) or taus[-1])
    short = 0
    for _ in range(40):
        pick = [blobs[i] for i in rng.choice(len(blobs), int(rng.integers(1, 7)), replace=False)]
        local = [c.astype(np.float64) for c in pick]
        together = detection._edge_sigmas(local)
        for c, got in zip(local, together, strict=True):
            if len(c) < 12:
                assert got is None
                short += 1
                continue
            assert _bits(got) == _bits(_edge_sigma_plain(c))
        # each blob in a region 2 px around its bounding box, somewhere in the image
        origins, sizes, regional, centers = [], [], [], []
        for c in pick:
            x, y, w, h = cv2.boundingRect(c.reshape(-1, 1, 2))
            w, h = w + 4, h + 4
            ox, oy = int(rng.integers(0, 400 - w)), int(rng.integers(0, 300 - h))
            origins.append((ox, oy))
            sizes.append((w, h))
            regional.append(c - (x - 2, y - 2))
            centers.append(regional[-1].mean(axis=0) + rng.normal(0, 0.3, 2))
        widths = detection._edge_widths(image, regional, centers, origins, sizes)
        for c, centre, (ox, oy), (w, h), got in zip(regional, centers, origins, sizes, widths,
                                                     strict=True):
            if len(c) < 12:
                assert math.isnan(got)
                continue
            want = _edge_width_plain(image[oy:oy + h, ox:ox + w], c, centre)
            assert _bits(got) == _bits(want)
        norm = [(c + rng.normal(0, 0.2, c.shape)) / 900.0 for c in pick if len(c) >= 5]
        if norm:
            polys = detection._polygon_centers_and_minor_axes(np.concatenate(norm),
                                                              [len(c) for c in norm], 900.0)
            for c, (centre, minor) in zip(norm, polys, strict=True):
                want_c, want_minor = _polygon_plain(c, 900.0)
                assert want_c is not None and centre is not None
                assert _bits(centre, minor) == _bits(want_c, want_minor)
    # contours too short, and residuals correlated enough for the FFT (tau above 1)
    assert short > 0 and sum(t > 1.0 for t in taus) >= 10, taus


def _lag1(res: np.ndarray) -> float:
    n = len(res)
    spec = np.fft.rfft(res)
    return float(np.fft.irfft(spec * np.conj(spec), n)[1] / (n * np.mean(res * res)))


def _residuals(x: np.ndarray) -> tuple[np.ndarray, float]:
    r = x - x.mean()
    return r, float(np.mean(r * r))


def test_correlation_time_is_the_ffts_whatever_the_lag_one_correlation() -> None:
    """The lag-1 shortcut gives the FFT loop's tau to the bit: residuals whose lag-1
    correlation spans the 0.05 cut (AR(1) series), and series tuned to within 1e-13 of it on
    either side (where only the FFT can decide)."""
    rng = np.random.default_rng(11)
    below = above = near = 0
    for _ in range(600):
        n = int(rng.integers(12, 500))
        phi = rng.uniform(-0.1, 0.3)
        e = rng.normal(0.0, rng.uniform(0.05, 2.0), n)
        x = np.empty(n)
        x[0] = e[0]
        for i in range(1, n):
            x[i] = phi * x[i - 1] + e[i]
        res, var = _residuals(x)
        got = detection._correlation_time(res, var)
        assert _bits(got) == _bits(_tau_plain(res, var))
        below += _lag1(res) < 0.05
        above += _lag1(res) >= 0.05
    for seed in range(40):
        r2 = np.random.default_rng(100 + seed)
        x = r2.normal(0.0, 1.0, int(r2.integers(40, 400)))
        lo, hi = -0.5, 0.5     # x + t roll(x): the lag-1 correlation rises with t
        for _ in range(200):
            t = 0.5 * (lo + hi)
            if _lag1(_residuals(x + t * np.roll(x, -1))[0]) < 0.05:
                lo = t
            else:
                hi = t
        for t in (lo, hi):
            res, var = _residuals(x + t * np.roll(x, -1))
            assert abs(_lag1(res) - 0.05) < 1e-13
            near += 1
            assert _bits(detection._correlation_time(res, var)) == _bits(_tau_plain(res, var))
    assert below > 100 and above > 100 and near == 80
    # no spread at all, and NaN: tau 1 as before
    assert detection._correlation_time(np.zeros(20), 0.0) == 1.0
    assert detection._correlation_time(np.full(20, np.nan), float("nan")) == 1.0


@pytest.mark.parametrize("shape, axis", [((7,), None), ((300,), None), ((12, 2), 0),
                                         ((451, 2), 0), ((5, 3), None)])
def test_mean_is_numpys_mean(shape: tuple[int, ...], axis: int | None) -> None:
    rng = np.random.default_rng(len(shape) * 1000 + shape[0])
    for _ in range(50):
        x = rng.normal(0.0, 10.0, shape) ** 3
        assert _bits(detection._mean(x, axis=axis)) == _bits(np.mean(x, axis=axis))


def test_dlt_rows_and_residual_are_those_of_the_plain_spelling() -> None:
    rng = np.random.default_rng(7)
    P1 = np.array([[900.0, 0, 640, 0], [0, 900, 360, 0], [0, 0, 1, 0]])
    for _ in range(300):
        P2 = P1.copy()
        P2[0, 3] = -900 * rng.uniform(0.03, 0.2)
        P2[:2, 2] += rng.normal(0, 2, 2)
        xl = rng.uniform([0, 0], [1280, 720])
        xr = xl - [rng.uniform(5, 300), rng.normal(0, 0.5)]
        X, J = triangulation._dlt_rect(P1, P2, xl, xr, with_jacobian=True)
        A = np.stack([xl[0] * P1[2] - P1[0], xl[1] * P1[2] - P1[1],
                      xr[0] * P2[2] - P2[0], xr[1] * P2[2] - P2[1]])
        scale = 1.0 / np.linalg.norm(A, axis=1)
        A *= scale[:, None]
        vt = np.linalg.svd(A)[2]
        want = vt[-1][:3] / vt[-1][3]
        h = np.append(want, 1.0)
        w = np.array([P1[2] @ h, P1[2] @ h, P2[2] @ h, P2[2] @ h]) * scale
        M = A[:, :3]
        want_J = -np.linalg.solve(M.T @ M, M.T * w[None, :])
        assert _bits(X, J) == _bits(want, want_J)
        a, b = P1 @ h, P2 @ h
        e = np.concatenate([a[:2] / a[2] - xl, b[:2] / b[2] - xr])
        assert _bits(triangulation._reproj_rms(P1, P2, X, xl, xr)) == \
            _bits(math.sqrt(np.mean(e * e)))
