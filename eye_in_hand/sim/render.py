"""Ray-cast rendering of the synthetic world through the distorted camera models, and its
per-frame ground truth.

Every pixel's ray is the exact inverse of the camera's distortion model: the ideal normalised
coordinates of all pixel centres are computed once per camera (OpenCV's iterative
undistortion, then Newton steps on our own evaluation of the distortion polynomial until the
re-projection round trip is below 1e-6 px) and cached. Rays are intersected exactly with the
spheres, the board rectangle and the table plane; the nearest hit is shaded (Lambert +
ambient). Pixels whose 3x3 neighbourhood sees more than one surface (object edges and
chessboard square edges) are re-rendered with a regular grid of ``supersample x supersample``
sub-pixel rays (their ideal coordinates interpolated bilinearly from the cached grid, error
< 1e-4 px), which anti-aliases edges at a fraction of the cost of supersampling the whole image.

Ground truth (:class:`FrameTruth`) is computed independently of the rendering: projections
with :meth:`CameraModel.project` (OpenCV), and the area centroid of each sphere's silhouette in
the distorted image from a dense polygon of the silhouette cone's boundary rays projected
through the distortion model (off axis the silhouette is an ellipse whose centroid is not the
projection of the centre; with distortion it is not even an ellipse).
"""
from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import cv2
import numpy as np

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.transforms import apply, compose, invert
from eye_in_hand.errors import InputError

__all__ = [
    "Scene",
    "Frame",
    "FrameTruth",
    "Renderer",
    "distort_normalized",
    "sphere_silhouette",
    "sphere_silhouette_centroid",
    "polygon_centroid",
    "board_in_view",
]

# Surface labels of the label image.
_BACKGROUND, _TABLE, _BOARD_WHITE, _BOARD_BLACK, _TARGET0 = 0, 1, 2, 3, 4
_BOARD_ALBEDO = (222.0, 18.0)  # white, black (grey levels)
_TEXTURE_SIZE_M = 3.0          # the table texture tile covers 3 m x 3 m
_TEXTURE_PX = 1024


@dataclass(frozen=True)
class FrameTruth:
    """Ground truth of one rendered frame (M targets, N board corners).

    Attributes:
        q: true joint vector, shape (n,).
        base_T_ee: (4, 4) true ``base_link`` -> ``tool0`` (the true arm at ``q``; the images
            come from it).
        base_T_cam: (4, 4) true ``base_link`` -> ``camera_left_optical_frame``.
        targets_base: target centres in ``base_link``, shape (M, 3).
        targets_cam: target centres in the left optical frame, shape (M, 3).
        targets_cam_right: target centres in the right optical frame, shape (M, 3).
        center_px_left, center_px_right: projections of the centres, shape (M, 2).
        silhouette_centroid_px_left, silhouette_centroid_px_right: area centroids of the
            silhouettes in the distorted images, shape (M, 2) (NaN if not in front).
        target_visible_left, target_visible_right: silhouette fully inside the image, (M,).
        board_corners_px_left, board_corners_px_right: projected inner corners, (N, 2).
        board_visible_left, board_visible_right: every corner inside the image by at least the
            largest projected square, and the board seen from its -z side
            (:func:`board_in_view`).
    """

    q: np.ndarray
    base_T_ee: np.ndarray
    base_T_cam: np.ndarray
    targets_base: np.ndarray
    targets_cam: np.ndarray
    targets_cam_right: np.ndarray
    center_px_left: np.ndarray
    center_px_right: np.ndarray
    silhouette_centroid_px_left: np.ndarray
    silhouette_centroid_px_right: np.ndarray
    target_visible_left: np.ndarray
    target_visible_right: np.ndarray
    board_corners_px_left: np.ndarray
    board_corners_px_right: np.ndarray
    board_visible_left: bool
    board_visible_right: bool
    base_T_ee_reported: np.ndarray | None = None


@dataclass(frozen=True)
class Frame:
    """A rendered stereo pair and its ground truth.

    Attributes:
        left, right: (H, W, 3) uint8 BGR images.
        truth: :class:`FrameTruth`.
        coverage_left, coverage_right: per-target anti-aliased coverage, (M, H, W) float32 in
            [0, 1], only when ``render(..., with_coverage=True)``; else None.
    """

    left: np.ndarray
    right: np.ndarray
    truth: FrameTruth
    coverage_left: np.ndarray | None = None
    coverage_right: np.ndarray | None = None


def distort_normalized(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply the plumb_bob / rational_polynomial distortion to ideal normalised coordinates.

    Args:
        xy: shape (N, 2) ideal normalised coordinates (x/z, y/z).
        dist: 5 (k1 k2 p1 p2 k3) or 8 (+ k4 k5 k6) coefficients.

    Returns:
        Distorted normalised coordinates, shape (N, 2) (multiply by K for pixels).
    """
    d = np.zeros(8)
    d[:len(dist)] = dist
    k1, k2, p1, p2, k3, k4, k5, k6 = d
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def _pixels_from_normalized(cam: CameraModel, xy: np.ndarray) -> np.ndarray:
    xyd = distort_normalized(xy, cam.dist)
    K = cam.K
    return np.stack([K[0, 0] * xyd[:, 0] + K[0, 1] * xyd[:, 1] + K[0, 2],
                     K[1, 1] * xyd[:, 1] + K[1, 2]], axis=1)


def _undistort_exact(cam: CameraModel, px: np.ndarray, iterations: int = 4) -> np.ndarray:
    """Ideal normalised coordinates of distorted pixels ``px`` (N, 2), refined by Newton steps
    on :func:`distort_normalized` (finite-difference Jacobian) after OpenCV's estimate."""
    xy = cam.undistort_points(px)
    h = 1e-7
    for _ in range(iterations):
        f0 = _pixels_from_normalized(cam, xy) - px
        if np.max(np.abs(f0)) < 1e-9:
            break
        fx = (_pixels_from_normalized(cam, xy + (h, 0.0)) - px - f0) / h
        fy = (_pixels_from_normalized(cam, xy + (0.0, h)) - px - f0) / h
        a, c = fx[:, 0], fx[:, 1]
        b, d = fy[:, 0], fy[:, 1]
        det = a * d - b * c
        det = np.where(np.abs(det) < 1e-18, 1e-18, det)
        dx = (d * f0[:, 0] - b * f0[:, 1]) / det
        dy = (-c * f0[:, 0] + a * f0[:, 1]) / det
        xy = xy - np.stack([dx, dy], axis=1)
    return xy


def polygon_centroid(poly: np.ndarray) -> tuple[float, np.ndarray]:
    """Signed area and area centroid of a closed polygon given by its vertices (N, 2)."""
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * float(np.sum(cross))
    cx = float(np.sum((x + xn) * cross)) / (6.0 * area)
    cy = float(np.sum((y + yn) * cross)) / (6.0 * area)
    return area, np.array([cx, cy])


def sphere_silhouette(cam: CameraModel, center_cam: np.ndarray, radius: float,
                      n: int = 2048) -> np.ndarray | None:
    """The outline of a sphere's image in the distorted image, as a polygon (n, 2) pixels.

    The outline is the image of the silhouette cone's boundary: rays from the optical centre
    tangent to the sphere. Returns None if part of the cone is not in front of the camera.
    """
    c = np.asarray(center_cam, dtype=np.float64).reshape(3)
    dist = float(np.linalg.norm(c))
    if dist <= radius:
        return None
    u = c / dist
    beta = math.asin(radius / dist)
    helper = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    phi = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    rays = (math.cos(beta) * u[None, :]
            + math.sin(beta) * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))
    if np.min(rays[:, 2]) <= 1e-6:
        return None
    return _pixels_from_normalized(cam, rays[:, :2] / rays[:, 2:3])


def sphere_silhouette_centroid(cam: CameraModel, center_cam: np.ndarray, radius: float,
                               n: int = 2048) -> np.ndarray:
    """Area centroid (2,) of a sphere's silhouette in the distorted image (NaN if not in
    front of the camera). The polygon of ``n`` outline points has a centroid error of
    order (perimeter / n)^2 / radius, far below 1e-4 px for the defaults."""
    poly = sphere_silhouette(cam, center_cam, radius, n)
    if poly is None:
        return np.full(2, np.nan)
    return polygon_centroid(poly)[1]


def board_in_view(cam: CameraModel, cam_T_board: np.ndarray, corners_px: np.ndarray,
                  cols: int, rows: int, margin_px: float = 0.0) -> bool:
    """Whether a board is fully visible: seen from its -z side, every inner corner in front of
    the camera and inside the image by at least one projected square (so that the outer
    squares are in view too) or ``margin_px``, whichever is larger.

    Args:
        cam: the camera; cam_T_board: (4, 4); corners_px: (cols * rows, 2) projections.
    """
    if invert(cam_T_board)[2, 3] >= 0 or not np.all(np.isfinite(corners_px)):
        return False
    grid = corners_px.reshape(rows, cols, 2)
    spacing = max(float(np.max(np.linalg.norm(np.diff(grid, axis=1), axis=2))),
                  float(np.max(np.linalg.norm(np.diff(grid, axis=0), axis=2))))
    m = max(spacing, margin_px)
    return bool(np.all(corners_px[:, 0] >= m) and np.all(corners_px[:, 1] >= m)
                and np.all(corners_px[:, 0] <= cam.width - 1 - m)
                and np.all(corners_px[:, 1] <= cam.height - 1 - m))


class _RayCache:
    """Ideal normalised coordinates of every pixel centre of one camera (H, W, 2) float64."""

    def __init__(self, cam: CameraModel) -> None:
        self.cam = cam
        W, H = cam.width, cam.height
        v, u = np.mgrid[0:H, 0:W].astype(np.float64)
        px = np.stack([u.ravel(), v.ravel()], axis=1)
        xy = _undistort_exact(cam, px)
        self.xy = xy.reshape(H, W, 2)
        dirs = np.empty((H * W, 3), dtype=np.float32)
        dirs[:, :2] = xy
        dirs[:, 2] = 1.0
        self.dirs = dirs

    def round_trip_error(self) -> float:
        """Largest |project(ray(pixel)) - pixel| over the grid, pixels."""
        H, W = self.xy.shape[:2]
        v, u = np.mgrid[0:H, 0:W].astype(np.float64)
        px = _pixels_from_normalized(self.cam, self.xy.reshape(-1, 2))
        return float(np.max(np.abs(px - np.stack([u.ravel(), v.ravel()], axis=1))))

    def interpolate(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Bilinear interpolation of the grid at sub-pixel positions (K,), returns (K, 2)."""
        H, W = self.xy.shape[:2]
        x0 = np.clip(np.floor(u).astype(np.int64), 0, W - 2)
        y0 = np.clip(np.floor(v).astype(np.int64), 0, H - 2)
        fx = (u - x0)[:, None]
        fy = (v - y0)[:, None]
        g = self.xy
        top = g[y0, x0] * (1 - fx) + g[y0, x0 + 1] * fx
        bot = g[y0 + 1, x0] * (1 - fx) + g[y0 + 1, x0 + 1] * fx
        return top * (1 - fy) + bot * fy


def _make_texture(seed: int, color_bgr: tuple[int, int, int]) -> np.ndarray:
    """The procedural table texture, (_TEXTURE_PX, _TEXTURE_PX, 3) float32 albedo.

    Wooden planks of slightly different flat colours with dark joints, a few darker stains
    and a faint low-frequency mottling. Mostly piecewise constant, so that rendered images
    stay structured (edges, texture) and still compress well in bags.
    """
    rng = np.random.default_rng(seed)
    n = _TEXTURE_PX
    base = np.asarray(color_bgr, np.float32)
    gain = np.ones((n, n), np.float32)
    plank_px = max(8, n // 28)                      # ~11 cm planks on the 3 m tile
    edges = np.arange(0, n + plank_px, plank_px)
    for k in range(len(edges) - 1):
        lo, hi = edges[k], min(edges[k + 1], n)
        gain[:, lo:hi] = 1.0 + rng.uniform(-0.12, 0.12)
        # plank butt joints at random positions along the plank
        for y in rng.integers(0, n, size=2):
            gain[y:y + 2, lo:hi] = 0.55
        gain[:, lo:lo + 2] = 0.5                      # joint between planks
    yy, xx = np.mgrid[0:n, 0:n]
    for _ in range(14):                              # stains
        cx, cy = rng.uniform(0, n, size=2)
        ax, ay = rng.uniform(6, 40, size=2)
        inside = ((xx - cx) / ax) ** 2 + ((yy - cy) / ay) ** 2 <= 1.0
        gain[inside] *= rng.uniform(0.7, 0.9)
    mottle = cv2.GaussianBlur(rng.standard_normal((n // 16, n // 16)).astype(np.float32),
                              (0, 0), 1.5)
    scaled: np.ndarray = mottle / max(float(mottle.std()), 1e-6)
    mottle = cv2.resize(scaled, (n, n),
                        interpolation=cv2.INTER_NEAREST)
    gain *= 1.0 + 0.04 * np.round(mottle * 2) / 2   # a few flat levels
    return np.clip(gain[:, :, None] * base[None, None, :], 0, 255).astype(np.float32)


def _bilinear_wrap(tex: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookup (K, C) of a (N, N, C) texture at texel coordinates x, y (K,), wrapping
    (``cv2.remap``, 1/32-texel interpolation steps: ample for a texture)."""
    n = tex.shape[0]
    k = x.size
    cols = 1024
    rows = max(1, -(-k // cols))
    pad = rows * cols - k
    mx = np.pad(np.mod(x, n).astype(np.float32), (0, pad)).reshape(rows, cols)
    my = np.pad(np.mod(y, n).astype(np.float32), (0, pad)).reshape(rows, cols)
    out = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    return out.reshape(rows * cols, -1)[:k]


class Scene(Protocol):
    """What the renderer reads of a scene (read-only); :class:`eye_in_hand.sim.world.World` is
    one. Defined here so that the world depends on the renderer and not the other way round.

    ``arm`` and ``true_arm`` have ``fk(q) -> base_T_ee`` (4, 4); each of ``targets`` has
    ``name``, ``center_base`` (3,), ``radius_m`` and ``color_bgr``; ``board`` is a
    :class:`~eye_in_hand.core.calibration.BoardSpec`.
    """

    @property
    def rig(self) -> StereoRig: ...
    @property
    def ee_T_cam(self) -> np.ndarray: ...
    @property
    def arm(self) -> Any: ...
    @property
    def true_arm(self) -> Any: ...
    @property
    def targets(self) -> Sequence[Any]: ...
    @property
    def board(self) -> Any: ...
    @property
    def base_T_board(self) -> np.ndarray: ...
    @property
    def board_margin(self) -> float: ...
    @property
    def table_height(self) -> float: ...
    @property
    def table_color_bgr(self) -> tuple[int, int, int]: ...
    @property
    def texture_seed(self) -> int: ...
    @property
    def light_dir_base(self) -> np.ndarray: ...
    @property
    def ambient(self) -> float: ...

    def board_points(self) -> np.ndarray: ...

    def target_centers_base(self) -> np.ndarray: ...


class Renderer:
    """Renders a :class:`Scene` (a :class:`~eye_in_hand.sim.world.World`); caches rays per
    camera (thread-safe)."""

    def __init__(self, world: Scene) -> None:
        self.world = world
        self._lock = threading.Lock()
        self._rays: dict[str, _RayCache] = {}
        self._texture: np.ndarray | None = None

    # -- caches ---------------------------------------------------------------------------
    def rays(self, side: str) -> _RayCache:
        """The ray grid of the ``"left"`` or ``"right"`` camera (built on first use)."""
        with self._lock:
            if side not in self._rays:
                cam = self.world.rig.left if side == "left" else self.world.rig.right
                self._rays[side] = _RayCache(cam)
            return self._rays[side]

    def texture(self) -> np.ndarray:
        with self._lock:
            if self._texture is None:
                self._texture = _make_texture(self.world.texture_seed,
                                              self.world.table_color_bgr)
            return self._texture

    # -- ground truth ---------------------------------------------------------------------
    def truth(self, q) -> FrameTruth:
        """Ground truth at joint vector ``q`` (see :class:`FrameTruth`)."""
        w = self.world
        qv = np.asarray(q, dtype=np.float64).reshape(-1)
        base_T_ee = w.true_arm.fk(qv)
        base_T_cam = compose(base_T_ee, w.ee_T_cam)
        cam_T_base = invert(base_T_cam)
        right_T_base = compose(w.rig.right_T_left, cam_T_base)
        centers = w.target_centers_base()
        t_left = apply(cam_T_base, centers) if len(centers) else np.zeros((0, 3))
        t_right = apply(right_T_base, centers) if len(centers) else np.zeros((0, 3))
        out: dict[str, np.ndarray | bool] = {}
        for side, cam, pts, T in (("left", w.rig.left, t_left, cam_T_base),
                                  ("right", w.rig.right, t_right, right_T_base)):
            out[f"center_px_{side}"] = (cam.project(pts) if len(pts) else np.zeros((0, 2)))
            cents, vis = [], []
            for tgt, c in zip(w.targets, pts, strict=True):
                poly = sphere_silhouette(cam, c, tgt.radius_m)
                if poly is None:
                    cents.append(np.full(2, np.nan))
                    vis.append(False)
                    continue
                cents.append(polygon_centroid(poly)[1])
                vis.append(bool(np.all(poly >= -0.5) and np.all(poly[:, 0] <= cam.width - 0.5)
                                and np.all(poly[:, 1] <= cam.height - 0.5)))
            out[f"silhouette_centroid_px_{side}"] = np.array(cents).reshape(-1, 2)
            out[f"target_visible_{side}"] = np.array(vis, dtype=bool)
            cam_T_board = compose(T, w.base_T_board)
            px = cam.project(apply(cam_T_board, w.board_points()))
            out[f"board_corners_px_{side}"] = px
            visible = board_in_view(cam, cam_T_board, px, w.board.cols, w.board.rows)
            out[f"board_visible_{side}"] = visible
        return FrameTruth(q=qv, base_T_ee=base_T_ee, base_T_cam=base_T_cam,
                          targets_base=centers, targets_cam=t_left, targets_cam_right=t_right,
                          base_T_ee_reported=w.arm.fk(qv), **out)  # type: ignore[arg-type]

    # -- rendering ------------------------------------------------------------------------
    def render(self, q, *, seed: int = 0, noise_sigma: float = 2.0, supersample: int = 3,
               blur_sigma: float = 0.0, exposure: float = 1.0,
               with_coverage: bool = False) -> Frame:
        """Render the stereo pair at joint vector ``q``.

        Args:
            q: joint vector (n,), radians.
            seed: seed of the sensor noise (same seed and inputs give identical images).
            noise_sigma: standard deviation of additive Gaussian noise, grey levels (0: none).
            supersample: sub-pixel rays per axis on edge pixels (1: no anti-aliasing).
            blur_sigma: Gaussian blur applied before the noise, pixels (0: none).
            exposure: gain on the rendered radiance before clipping to 0-255.
            with_coverage: also return per-target coverage maps.

        Returns:
            :class:`Frame` with the two uint8 BGR images and the ground truth.

        Raises:
            InputError: a parameter out of range.
        """
        if supersample < 1 or supersample > 8:
            raise InputError(f"supersample must be in 1..8, got {supersample}")
        if noise_sigma < 0 or blur_sigma < 0 or not exposure > 0:
            raise InputError("noise_sigma and blur_sigma must be >= 0 and exposure > 0")
        truth = self.truth(q)
        rng = np.random.default_rng(seed)
        cam_T_base = invert(truth.base_T_cam)
        images, coverages = [], []
        for side, T in (("left", cam_T_base),
                        ("right", compose(self.world.rig.right_T_left, cam_T_base))):
            img, cov = self._render_camera(self.rays(side), T, supersample, with_coverage)
            if blur_sigma > 0:
                img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
            if exposure != 1.0:
                img = img * np.float32(exposure)
            if noise_sigma > 0:
                img = img + rng.standard_normal(img.shape, dtype=np.float32) * np.float32(
                    noise_sigma)
            images.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
            coverages.append(cov)
        return Frame(left=images[0], right=images[1], truth=truth,
                     coverage_left=coverages[0], coverage_right=coverages[1])

    def _scene_in_camera(self, cam_T_base: np.ndarray) -> dict[str, np.ndarray | float]:
        w = self.world
        R, t = cam_T_base[:3, :3], cam_T_base[:3, 3]
        cam_T_board = compose(cam_T_base, w.base_T_board)
        s: dict[str, Any] = {}
        # table plane z_base = h: normal n (cam), offset: n . X = n . p0
        n_tab = R[:, 2]
        p_tab = R @ np.array([0.0, 0.0, w.table_height]) + t
        s["n_tab"], s["k_tab"] = n_tab, float(n_tab @ p_tab)
        s["x_tab"], s["y_tab"], s["o_tab"] = R[:, 0], R[:, 1], t
        s["n_board"] = cam_T_board[:3, 2]
        s["o_board"] = cam_T_board[:3, 3]
        s["k_board"] = float(s["n_board"] @ s["o_board"])
        s["x_board"], s["y_board"] = cam_T_board[:3, 0], cam_T_board[:3, 1]
        s["light"] = R @ w.light_dir_base
        s["centers"] = (apply(cam_T_base, w.target_centers_base()) if w.targets
                        else np.zeros((0, 3)))
        return s

    def _shade(self, dirs: np.ndarray, s: dict) -> tuple[np.ndarray, np.ndarray]:
        """Colour (K, 3) float32 and label (K,) int16 of rays ``dirs`` (K, 3), camera frame."""
        w = self.world
        cols = np.stack([s["n_tab"], s["n_board"], s["x_board"], s["y_board"], s["x_tab"],
                         s["y_tab"], s["light"], *s["centers"]], axis=1).astype(np.float32)
        D = dirs @ cols  # (K, 7 + M)
        K = dirs.shape[0]
        inf = np.float32(np.inf)
        t_best = np.full(K, inf, np.float32)
        label = np.zeros(K, np.int16)
        # table
        dn = D[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t_tab = np.float32(s["k_tab"]) / dn
        ok = (t_tab > 0) & np.isfinite(t_tab)
        t_best = np.where(ok, t_tab, t_best)
        label[ok] = _TABLE
        # board rectangle
        with np.errstate(divide="ignore", invalid="ignore"):
            t_b = np.float32(s["k_board"]) / D[:, 1]
        ob = s["o_board"]
        bu = t_b * D[:, 2] - np.float32(ob @ s["x_board"])
        bv = t_b * D[:, 3] - np.float32(ob @ s["y_board"])
        sq = w.board.square
        m = w.board_margin
        u0, u1 = -sq - m, w.board.cols * sq + m
        v0, v1 = -sq - m, w.board.rows * sq + m
        ok_b = (t_b > 0) & (t_b < t_best) & (bu >= u0) & (bu <= u1) & (bv >= v0) & (bv <= v1)
        t_best = np.where(ok_b, t_b, t_best)
        in_sq = (bu >= -sq) & (bu < w.board.cols * sq) & (bv >= -sq) & (bv < w.board.rows * sq)
        parity = (np.floor(bu / sq).astype(np.int32) + np.floor(bv / sq).astype(np.int32)) & 1
        black = in_sq & (parity == 0)
        label[ok_b] = np.where(black[ok_b], _BOARD_BLACK, _BOARD_WHITE)
        # spheres
        dd = np.einsum("ij,ij->i", dirs, dirs)
        normal_light = np.zeros(K, np.float32)
        for k, tgt in enumerate(w.targets):
            c = s["centers"][k]
            b = D[:, 7 + k]
            cc = np.float32(c @ c - tgt.radius_m ** 2)
            disc = b * b - dd * cc
            hit = disc > 0
            if not np.any(hit):
                continue
            t_s = np.where(hit, (b - np.sqrt(np.maximum(disc, 0))) / dd, inf)
            ok_s = hit & (t_s > 0) & (t_s < t_best)
            t_best = np.where(ok_s, t_s, t_best)
            label[ok_s] = _TARGET0 + k
            # n . L = (t d.L - c.L) / r, on the rays that hit (t_s is inf elsewhere)
            nl = (np.where(ok_s, t_s, np.float32(0.0)) * D[:, 6]
                  - np.float32(c @ s["light"])) / np.float32(tgt.radius_m)
            normal_light = np.where(ok_s, nl, normal_light)
        # colours
        amb = np.float32(w.ambient)
        color = np.empty((K, 3), np.float32)
        bg = np.float32(60.0) + np.float32(40.0) * np.clip(-dirs[:, 1] / np.sqrt(dd), -1, 1)
        color[:] = bg[:, None]
        # Lambert on the planes is view independent: table normal +z_base, board face -z_board
        L = w.light_dir_base
        plane_light = amb + (1 - amb) * max(0.0, float(L[2]))
        sel = label == _TABLE
        if np.any(sel):
            X = t_best[sel, None] * dirs[sel]
            tu = X @ s["x_tab"].astype(np.float32) - np.float32(s["o_tab"] @ s["x_tab"])
            tv = X @ s["y_tab"].astype(np.float32) - np.float32(s["o_tab"] @ s["y_tab"])
            scale = np.float32(_TEXTURE_PX / _TEXTURE_SIZE_M)
            tex = _bilinear_wrap(self.texture(), tu * scale, tv * scale)
            color[sel] = tex * np.float32(plane_light)
        board_light = amb + (1 - amb) * max(0.0, float(-L @ w.base_T_board[:3, 2]))
        for lab, alb in ((_BOARD_WHITE, _BOARD_ALBEDO[0]), (_BOARD_BLACK, _BOARD_ALBEDO[1])):
            color[label == lab] = np.float32(alb * board_light)
        for k, tgt in enumerate(w.targets):
            sel = label == _TARGET0 + k
            if np.any(sel):
                shade = amb + (1 - amb) * np.clip(normal_light[sel], 0, 1)
                color[sel] = shade[:, None] * np.asarray(tgt.color_bgr, np.float32)[None, :]
        return color, label

    def _render_camera(self, rays: _RayCache, cam_T_base: np.ndarray, ss: int,
                       with_coverage: bool) -> tuple[np.ndarray, np.ndarray | None]:
        H, W = rays.xy.shape[:2]
        s = self._scene_in_camera(cam_T_base)
        color, label = self._shade(rays.dirs, s)
        img = color.reshape(H, W, 3)
        lab = label.reshape(H, W)
        M = len(self.world.targets)
        cov = None
        if with_coverage:
            cov = np.stack([(lab == _TARGET0 + k).astype(np.float32) for k in range(M)]) \
                if M else np.zeros((0, H, W), np.float32)
        if ss <= 1:
            return img, cov
        # edge pixels: any 8-neighbour with another label
        pad = np.pad(lab, 1, mode="edge")
        edge = np.zeros((H, W), bool)
        for dy in (0, 1, 2):
            for dx in (0, 1, 2):
                if dy == 1 and dx == 1:
                    continue
                edge |= pad[dy:dy + H, dx:dx + W] != lab
        ys, xs = np.nonzero(edge)
        if ys.size == 0:
            return img, cov
        offs = (np.arange(ss) + 0.5) / ss - 0.5
        ou: np.ndarray
        ov: np.ndarray
        ou, ov = np.meshgrid(offs, offs)
        ou, ov = ou.ravel(), ov.ravel()
        S = ou.size
        u = (xs[:, None] + ou[None, :]).ravel()
        v = (ys[:, None] + ov[None, :]).ravel()
        xy = rays.interpolate(u, v)
        dirs = np.empty((xy.shape[0], 3), np.float32)
        dirs[:, :2] = xy
        dirs[:, 2] = 1.0
        sub_color, sub_label = self._shade(dirs, s)
        img[ys, xs] = sub_color.reshape(-1, S, 3).mean(axis=1)
        if cov is not None:
            sl = sub_label.reshape(-1, S)
            for k in range(M):
                cov[k, ys, xs] = (sl == _TARGET0 + k).mean(axis=1)
        return img, cov
