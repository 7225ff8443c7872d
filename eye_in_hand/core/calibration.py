"""Calibration boards, board detection, and camera / stereo calibration (Zhang's method).

Board specification strings (:meth:`BoardSpec.parse`)::

    chessboard:COLSxROWS:SQUARE
        COLS x ROWS inner corners (the corners where four squares meet), SQUARE the side of one
        square in metres (or any length unit; results come out in the same unit).
        Example: ``chessboard:9x6:0.025`` (a 10 x 7 squares board, 25 mm squares).

    charuco:SQUARESXxSQUARESY:SQUARE:MARKER[:DICT][:legacy]
        A ChArUco board of SQUARESX x SQUARESY *squares* (so SQUARESX-1 x SQUARESY-1 inner
        corners), square side SQUARE and ArUco marker side MARKER (same unit, MARKER < SQUARE),
        markers from the OpenCV predefined dictionary DICT (default ``DICT_5X5_100``; the
        ``DICT_`` prefix is optional). ``legacy`` selects OpenCV's pre-4.6 layout for boards
        with an even number of rows. Example: ``charuco:7x5:0.04:0.03:DICT_4X4_50``.

Board frame: origin at the first inner corner (OpenCV's corner 0), x along the COLS direction,
y along the ROWS direction, z = x cross y (the board plane is z = 0). Inner corners are numbered
row by row, ``index = row * cols + col``, which is OpenCV's order for both board types (for
ChArUco it is also the corner id).

Detection (:func:`detect_board`) always returns a :class:`BoardDetection`; when no board is found
its ``found`` is False and ``reason`` says why, so callers can list skipped images.

Calibration: :func:`calibrate_camera` (``cv2.calibrateCameraExtended`` with per-view errors,
outlier flags and rejection, coverage, parameter standard deviations) and
:func:`calibrate_stereo` (each camera alone, then a joint bundle adjustment over both cameras'
intrinsics and distortion, the extrinsic and every board pose, then rectification and the
checks of :func:`stereo_quality`).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, Literal, Sequence

import numpy as np

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.errors import CalibrationError, InputError

__all__ = [
    "BoardSpec",
    "BoardDetection",
    "DETECTORS",
    "detect_board",
    "render_board",
    "CalibrationOptions",
    "ViewResult",
    "CameraCalibration",
    "StereoViewResult",
    "StereoQuality",
    "StereoCalibration",
    "STEREO_METHODS",
    "calibrate_camera",
    "calibrate_stereo",
    "stereo_quality",
    "outlier_threshold",
    "coverage",
]

#: Accepted values of the ``detector`` argument of :func:`detect_board`.
DETECTORS: tuple[str, ...] = ("auto", "classic", "sb")

_DEFAULT_CHARUCO_DICT = "DICT_5X5_100"
_BOARD_RE = re.compile(r"^\s*(\d+)\s*[xX]\s*(\d+)\s*$")


def _positive_float(text: str, what: str, spec: str) -> float:
    try:
        value = float(text)
    except ValueError as exc:
        raise InputError(f"board spec {spec!r}: {what} {text!r} is not a number") from exc
    if not np.isfinite(value) or value <= 0.0:
        raise InputError(f"board spec {spec!r}: {what} must be a positive number, got {text!r}")
    return value


@dataclass(frozen=True)
class BoardSpec:
    """A planar calibration board.

    Attributes:
        kind: ``"chessboard"`` or ``"charuco"``.
        cols: inner corners along the board's x axis (9 for a 9x6 chessboard).
        rows: inner corners along the board's y axis.
        square: side of one square, in the unit results are wanted in (metres by convention).
        marker: ChArUco marker side (same unit), 0.0 for a chessboard.
        dictionary: ChArUco ArUco dictionary name (``"DICT_5X5_100"``), empty for a chessboard.
        legacy: ChArUco pre-OpenCV-4.6 layout for boards with an even number of square rows.
    """

    kind: Literal["chessboard", "charuco"]
    cols: int
    rows: int
    square: float
    marker: float = 0.0
    dictionary: str = ""
    legacy: bool = False

    def __post_init__(self) -> None:
        if self.kind not in ("chessboard", "charuco"):
            raise InputError(f"board: unknown kind {self.kind!r} (use chessboard or charuco)")
        if int(self.cols) < 2 or int(self.rows) < 2:
            raise InputError(
                f"board: need at least 2x2 inner corners, got {self.cols}x{self.rows}")
        if not (np.isfinite(self.square) and self.square > 0.0):
            raise InputError(f"board: square must be positive, got {self.square}")
        if self.kind == "charuco":
            if not (np.isfinite(self.marker) and 0.0 < self.marker < self.square):
                raise InputError(
                    f"board: ChArUco marker side must be in (0, square={self.square}), "
                    f"got {self.marker}")
            import cv2

            if not hasattr(cv2.aruco, self.dictionary):
                raise InputError(f"board: unknown ArUco dictionary {self.dictionary!r}")

    # -- construction -----------------------------------------------------------------------
    @classmethod
    def parse(cls, spec: str) -> "BoardSpec":
        """Parse a board specification string (grammar in the module docstring).

        Args:
            spec: e.g. ``"chessboard:9x6:0.025"`` or ``"charuco:7x5:0.04:0.03:DICT_4X4_50"``.

        Returns:
            The board.

        Raises:
            InputError: the string does not follow the grammar (the message quotes it).
        """
        if not isinstance(spec, str):
            raise InputError(f"board spec must be a string, got {type(spec).__name__}")
        parts = [p.strip() for p in spec.strip().split(":")]
        kind = parts[0].lower()
        if kind == "chessboard":
            if len(parts) != 3:
                raise InputError(
                    f"board spec {spec!r}: expected chessboard:COLSxROWS:SQUARE, "
                    "e.g. chessboard:9x6:0.025")
            cols, rows = cls._parse_size(parts[1], spec, "inner corners")
            square = _positive_float(parts[2], "square size", spec)
            return cls("chessboard", cols, rows, square)
        if kind == "charuco":
            if len(parts) < 4 or len(parts) > 6:
                raise InputError(
                    f"board spec {spec!r}: expected charuco:SQUARESXxSQUARESY:SQUARE:MARKER"
                    "[:DICT][:legacy], e.g. charuco:7x5:0.04:0.03:DICT_5X5_100")
            sx, sy = cls._parse_size(parts[1], spec, "squares")
            if sx < 3 or sy < 3:
                raise InputError(f"board spec {spec!r}: a ChArUco board needs at least 3x3 squares")
            square = _positive_float(parts[2], "square size", spec)
            marker = _positive_float(parts[3], "marker size", spec)
            dictionary = _DEFAULT_CHARUCO_DICT
            legacy = False
            for extra in parts[4:]:
                if extra.lower() == "legacy":
                    legacy = True
                elif extra:
                    name = extra.upper()
                    dictionary = name if name.startswith("DICT_") else "DICT_" + name
                else:
                    raise InputError(f"board spec {spec!r}: empty field")
            try:
                return cls("charuco", sx - 1, sy - 1, square, marker, dictionary, legacy)
            except InputError as exc:
                raise InputError(f"board spec {spec!r}: {exc}") from exc
        raise InputError(
            f"board spec {spec!r}: unknown board type {parts[0]!r} "
            "(use chessboard:COLSxROWS:SQUARE or charuco:SXxSY:SQUARE:MARKER[:DICT])")

    @staticmethod
    def _parse_size(text: str, spec: str, what: str) -> tuple[int, int]:
        match = _BOARD_RE.match(text)
        if not match:
            raise InputError(f"board spec {spec!r}: {what} {text!r} is not of the form COLSxROWS")
        cols, rows = int(match.group(1)), int(match.group(2))
        if cols < 2 or rows < 2:
            raise InputError(f"board spec {spec!r}: need at least 2x2 {what}, got {text!r}")
        return cols, rows

    def __str__(self) -> str:
        if self.kind == "chessboard":
            return f"chessboard:{self.cols}x{self.rows}:{self.square:g}"
        text = (f"charuco:{self.cols + 1}x{self.rows + 1}:{self.square:g}:{self.marker:g}:"
                f"{self.dictionary}")
        return text + (":legacy" if self.legacy else "")

    # -- geometry -----------------------------------------------------------------------------
    @property
    def pattern_size(self) -> tuple[int, int]:
        """``(cols, rows)`` inner corners, as OpenCV's ``patternSize``."""
        return (int(self.cols), int(self.rows))

    @property
    def n_corners(self) -> int:
        """Number of inner corners."""
        return int(self.cols) * int(self.rows)

    def object_points(self) -> np.ndarray:
        """Inner corners in the board frame.

        Returns:
            array, shape (cols*rows, 3), float64: ``(col*square, row*square, 0)`` in OpenCV's
            order (row by row, ``index = row*cols + col``).
        """
        col, row = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        pts = np.zeros((self.n_corners, 3), dtype=np.float64)
        pts[:, 0] = col.ravel() * self.square
        pts[:, 1] = row.ravel() * self.square
        return pts

    def charuco_board(self):
        """The OpenCV ``cv2.aruco.CharucoBoard`` of a ChArUco spec.

        Raises:
            InputError: the board is a chessboard.
        """
        if self.kind != "charuco":
            raise InputError(f"board {self}: not a ChArUco board")
        import cv2

        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        board = cv2.aruco.CharucoBoard((self.cols + 1, self.rows + 1), float(self.square),
                                       float(self.marker), dictionary)
        board.setLegacyPattern(bool(self.legacy))
        return board


@dataclass(frozen=True)
class BoardDetection:
    """The result of looking for a board in one image.

    Attributes:
        found: True when a usable board was detected.
        corners: array, shape (N, 2), float64: corner pixels (x right, y down), in the order of
            ``object_points``; shape (0, 2) when not found.
        object_points: array, shape (N, 3), float64: the same corners in the board frame.
        ids: array, shape (N,), int: corner indices into :meth:`BoardSpec.object_points`
            (all of them, 0..N-1, for a chessboard; the visible subset for ChArUco).
        image_size: ``(width, height)`` of the image in pixels.
        detector: the detector that produced the corners (``classic``, ``sb``, ``charuco``) or
            the last one tried when not found.
        reason: why nothing was found (empty when found).
        meta: detector details (``tried``: detectors run; ``orientation_from_colour``: the
            corner order was fixed by the squares' colours).
    """

    found: bool
    corners: np.ndarray
    object_points: np.ndarray
    ids: np.ndarray
    image_size: tuple[int, int]
    detector: str
    reason: str = ""
    meta: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def missing(cls, image_size: tuple[int, int], detector: str, reason: str) -> "BoardDetection":
        """A not-found result carrying ``reason``."""
        return cls(False, np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64),
                   image_size, detector, reason)

    @property
    def n_corners(self) -> int:
        """Number of detected corners."""
        return int(self.corners.shape[0])

    def reversed(self) -> "BoardDetection":
        """The same chessboard detection with the corner order rotated by 180 degrees.

        Used to make left/right orderings agree when the detector returned a symmetric board
        flipped in one image. Only valid for full chessboard detections.
        """
        return BoardDetection(self.found, self.corners[::-1].copy(), self.object_points,
                              self.ids, self.image_size, self.detector, self.reason, self.meta)


def _to_gray(image: np.ndarray) -> np.ndarray:
    import cv2

    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if arr.ndim == 3 and arr.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if arr.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        arr = cv2.cvtColor(arr, code)
    elif arr.ndim != 2:
        raise InputError(f"image: expected shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), "
                         f"got {arr.shape}")
    if arr.dtype == np.uint16:
        arr = (arr >> 8).astype(np.uint8)
    elif arr.dtype != np.uint8:
        if not np.issubdtype(arr.dtype, np.floating):
            raise InputError(f"image: unsupported dtype {arr.dtype}")
        arr = np.clip(arr * (255.0 if float(np.nanmax(arr)) <= 1.0 else 1.0), 0, 255)
        arr = arr.astype(np.uint8)
    return np.ascontiguousarray(arr)


def _min_corner_spacing(corners: np.ndarray, cols: int, rows: int) -> float:
    grid = corners.reshape(rows, cols, 2)
    dx = np.linalg.norm(np.diff(grid, axis=1), axis=2)
    dy = np.linalg.norm(np.diff(grid, axis=0), axis=2)
    return float(min(dx.min(), dy.min()))


def _detect_classic(gray: np.ndarray, board: BoardSpec, subpix_window: int,
                    fast_check: bool) -> np.ndarray | None:
    import cv2

    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    if fast_check:
        flags |= cv2.CALIB_CB_FAST_CHECK
    ok, corners = cv2.findChessboardCorners(gray, board.pattern_size, flags=flags)
    if not ok or corners is None:
        return None
    corners = corners.reshape(-1, 2).astype(np.float32)
    # keep the refinement window inside one square so it never reaches a neighbouring corner
    spacing = _min_corner_spacing(corners.astype(np.float64), board.cols, board.rows)
    half = int(max(1, min(subpix_window, np.floor(spacing / 2.0 - 1.0))))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.1)
    refined = cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2), (half, half), (-1, -1), criteria)
    return refined.reshape(-1, 2).astype(np.float64)


def _detect_sb(gray: np.ndarray, board: BoardSpec) -> np.ndarray | None:
    import cv2

    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE
    ok, corners = cv2.findChessboardCornersSB(gray, board.pattern_size, flags=flags)
    if not ok or corners is None:
        return None
    return corners.reshape(-1, 2).astype(np.float64)


def _detect_charuco(gray: np.ndarray, board: BoardSpec, min_corners: int) -> tuple[
        np.ndarray | None, np.ndarray | None, str]:
    import cv2

    detector = cv2.aruco.CharucoDetector(board.charuco_board())
    corners, ids, marker_corners, _ = detector.detectBoard(gray)
    n_markers = 0 if marker_corners is None else len(marker_corners)
    if corners is None or ids is None or len(ids) == 0:
        return None, None, f"no ChArUco corners found ({n_markers} markers seen)"
    if len(ids) < min_corners:
        return None, None, (f"only {len(ids)} ChArUco corners found ({n_markers} markers seen), "
                            f"need {min_corners}")
    return corners.reshape(-1, 2).astype(np.float64), ids.reshape(-1).astype(np.int64), ""


def _canonical_order(gray: np.ndarray, corners: np.ndarray,
                     board: BoardSpec) -> tuple[np.ndarray, bool]:
    """Put chessboard corners in the board's canonical order.

    The classic and SB detectors can return the same board in opposite (180 degree rotated)
    orders. When ``cols + rows`` is odd the two orders are told apart by colour: the canonical
    order has the square between corners 0, 1, cols and cols+1 (and every square of the same
    parity) dark. Boards with ``cols + rows`` even look the same after a half turn; their order
    is left as the detector gave it.

    Returns:
        ``(corners, decided)``: corners, shape (N, 2), possibly reversed; ``decided`` is True
        when the orientation was fixed by colour.
    """
    if (board.cols + board.rows) % 2 == 0:
        return corners, False
    grid = corners.reshape(board.rows, board.cols, 2)
    centres = 0.25 * (grid[:-1, :-1] + grid[:-1, 1:] + grid[1:, :-1] + grid[1:, 1:])
    jj, ii = np.meshgrid(np.arange(board.rows - 1), np.arange(board.cols - 1), indexing="ij")
    parity = ((ii + jj) % 2 == 0).ravel()
    xy = np.round(centres.reshape(-1, 2)).astype(np.int64)
    h, w = gray.shape
    xy[:, 0] = np.clip(xy[:, 0], 1, w - 2)
    xy[:, 1] = np.clip(xy[:, 1], 1, h - 2)
    # 3x3 mean around each square centre
    vals = np.zeros(xy.shape[0])
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            vals += gray[xy[:, 1] + dy, xy[:, 0] + dx]
    even, odd = vals[parity].mean(), vals[~parity].mean()
    if even > odd:
        return corners[::-1].copy(), True
    return corners, True


def detect_board(image: np.ndarray, board: BoardSpec, detector: str = "auto", *,
                 subpix_window: int = 5, fallback: bool = True, fast_check: bool = False,
                 min_charuco_corners: int = 6) -> BoardDetection:
    """Find a calibration board in an image.

    Chessboards: ``classic`` is ``cv2.findChessboardCorners`` (adaptive threshold, normalised
    image) refined with ``cv2.cornerSubPix`` over a ``(2*subpix_window+1)``-pixel window (shrunk
    when squares are small so the window stays within one square), the recipe of OpenCV's own
    calibration test; ``sb`` is ``cv2.findChessboardCornersSB`` (exhaustive, accuracy mode).
    ``auto`` runs ``classic`` and, when it finds nothing and ``fallback`` is set, ``sb``
    (see the calibration README section for the measurements behind this default).
    Chessboard corners are returned in a canonical order whichever detector found them (see
    :func:`_canonical_order`: for boards with ``cols + rows`` odd, e.g. 9x6, the square between
    corners 0, 1, cols, cols+1 is a dark square), so detections from different detectors and
    from the two cameras of a rig agree.
    ChArUco boards always use ``cv2.aruco.CharucoDetector``; ``detector`` is ignored for them.

    Args:
        image: array, shape (H, W), (H, W, 1), (H, W, 3) BGR or (H, W, 4) BGRA; uint8, uint16
            or float in [0, 1].
        board: the board to look for.
        detector: ``"auto"``, ``"classic"`` or ``"sb"``.
        subpix_window: half size of the cornerSubPix window (classic detector).
        fallback: with ``classic`` or ``sb``, also try the other detector when the first finds
            nothing (``auto`` always falls back unless this is False).
        fast_check: pass ``CALIB_CB_FAST_CHECK`` to the classic detector (quick rejection of
            images without a board; may miss blurred boards).
        min_charuco_corners: fewest ChArUco corners accepted as a detection.

    Returns:
        A :class:`BoardDetection`; ``found`` is False with a ``reason`` when no board was found.

    Raises:
        InputError: bad image shape or dtype, unknown detector name.
    """
    if detector not in DETECTORS:
        raise InputError(f"detector: expected one of {', '.join(DETECTORS)}, got {detector!r}")
    if not isinstance(board, BoardSpec):
        raise InputError(f"board: expected a BoardSpec, got {type(board).__name__}")
    gray = _to_gray(image)
    size = (int(gray.shape[1]), int(gray.shape[0]))
    if board.kind == "charuco":
        corners, ids, reason = _detect_charuco(gray, board, max(4, int(min_charuco_corners)))
        if corners is None or ids is None:
            return BoardDetection.missing(size, "charuco", reason)
        obj = board.object_points()[ids]
        return BoardDetection(True, corners, obj, ids, size, "charuco")

    order = {"auto": ["classic", "sb"], "classic": ["classic", "sb"], "sb": ["sb", "classic"]}
    tried = order[detector] if fallback else order[detector][:1]
    for name in tried:
        if name == "classic":
            corners = _detect_classic(gray, board, int(subpix_window), fast_check)
        else:
            corners = _detect_sb(gray, board)
        if corners is not None:
            corners, canonical = _canonical_order(gray, corners, board)
            ids = np.arange(board.n_corners, dtype=np.int64)
            return BoardDetection(True, corners, board.object_points(), ids, size, name,
                                  meta={"tried": tried[:tried.index(name) + 1],
                                        "orientation_from_colour": canonical})
    names = " and ".join(f"findChessboardCorners{'SB' if n == 'sb' else ''}" for n in tried)
    return BoardDetection.missing(
        size, tried[-1], f"no {board.cols}x{board.rows} chessboard found ({names})")


def render_board(board: BoardSpec, K: np.ndarray, dist: np.ndarray, cam_T_board: np.ndarray,
                 image_size: tuple[int, int], *, supersample: int = 3, margin_squares: float = 1.0,
                 black: int = 25, white: int = 230, background: int = 110,
                 return_corners: bool = False):
    """Render a chessboard seen by a distorted pinhole camera (exact, per-pixel ray casting).

    Every (sub-)pixel is undistorted (``cv2.undistortPoints``), its ray intersected with the
    board plane and coloured by the square it hits, then the supersamples are averaged. Meant
    for tests and benchmarks that need board images with known corner positions.

    Args:
        board: a chessboard spec (ChArUco is not rendered).
        K: array, shape (3, 3): camera matrix.
        dist: array, shape (n,): OpenCV distortion coefficients.
        cam_T_board: array, shape (4, 4): board pose in the camera frame.
        image_size: ``(width, height)``.
        supersample: sub-pixels per pixel along each axis.
        margin_squares: white border around the squares, in squares.
        black: grey level of black squares.
        white: grey level of white squares and the border.
        background: grey level outside the board.
        return_corners: also return the projected inner corners.

    Returns:
        image, array, shape (H, W), uint8; with ``return_corners`` also the inner corners'
        pixel positions, array, shape (cols*rows, 2), float64 (OpenCV order).

    Raises:
        InputError: ChArUco board, bad shapes.
    """
    import cv2

    if board.kind != "chessboard":
        raise InputError("render_board: only chessboards can be rendered")
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    dist = np.asarray(dist, dtype=np.float64).ravel()
    T = np.asarray(cam_T_board, dtype=np.float64).reshape(4, 4)
    width, height = int(image_size[0]), int(image_size[1])
    s = max(1, int(supersample))
    offs = (np.arange(s) + 0.5) / s - 0.5
    u = (np.arange(width)[:, None] + offs[None, :]).ravel()
    v = (np.arange(height)[:, None] + offs[None, :]).ravel()
    uu, vv = np.meshgrid(u, v)
    px = np.stack([uu.ravel(), vv.ravel()], axis=1)
    norm = cv2.undistortPoints(px.reshape(-1, 1, 2), K, dist,
                               criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-9))
    rays = np.concatenate([norm.reshape(-1, 2), np.ones((px.shape[0], 1))], axis=1)
    # plane z=0 in the board frame: n . (X - t) = 0 in camera coordinates
    R, t = T[:3, :3], T[:3, 3]
    n = R[:, 2]
    denom = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (n @ t) / denom
    hit = np.isfinite(lam) & (lam > 0)
    X = rays * lam[:, None]
    local = (X - t) @ R  # board coordinates
    sq = board.square
    i = np.floor(local[:, 0] / sq)
    j = np.floor(local[:, 1] / sq)
    inside_sq = (i >= -1) & (i <= board.cols - 1) & (j >= -1) & (j <= board.rows - 1)
    m = margin_squares * sq
    inside_board = ((local[:, 0] >= -sq - m) & (local[:, 0] <= board.cols * sq + m)
                    & (local[:, 1] >= -sq - m) & (local[:, 1] <= board.rows * sq + m))
    val = np.full(px.shape[0], float(background))
    val[hit & inside_board] = white
    dark = hit & inside_sq & (((i + j).astype(np.int64) % 2) == 0)
    val[dark] = black
    img = val.reshape(height, s, width, s).mean(axis=(1, 3))
    img = np.clip(np.round(img), 0, 255).astype(np.uint8)
    if not return_corners:
        return img
    rvec, _ = cv2.Rodrigues(R)
    corners, _ = cv2.projectPoints(board.object_points(), rvec, t, K, dist)
    return img, corners.reshape(-1, 2)


# ================================================================================================
# Camera and stereo calibration
# ================================================================================================

#: Default floor of the outlier threshold, as a multiple of the median per-view RMS.
OUTLIER_MEDIAN_FACTOR = 2.0
#: Robust spread term of the outlier threshold: median + this many scaled MADs.
OUTLIER_MAD_FACTOR = 4.0
#: Fewest corners a view needs to take part in a calibration.
MIN_POINTS_PER_VIEW = 6

_INTRINSIC_NAMES = ("fx", "fy", "cx", "cy")
_DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


@dataclass(frozen=True)
class CalibrationOptions:
    """Which camera parameters are estimated.

    Attributes:
        rational: use the 8-coefficient ``rational_polynomial`` model (k1..k6, p1, p2) instead
            of ``plumb_bob`` (k1, k2, p1, p2, k3).
        fix_k3: keep k3 at 0.
        zero_tangent: keep p1 = p2 = 0.
        fix_aspect: keep fx / fy at its initial value (1 for a fresh calibration).
        fix_principal_point: keep cx, cy at the image centre.
    """

    rational: bool = False
    fix_k3: bool = False
    zero_tangent: bool = False
    fix_aspect: bool = False
    fix_principal_point: bool = False

    @property
    def distortion_model(self) -> str:
        """ROS name of the distortion model."""
        return "rational_polynomial" if self.rational else "plumb_bob"

    @property
    def n_dist(self) -> int:
        """Number of distortion coefficients."""
        return 8 if self.rational else 5

    def cv_flags(self) -> int:
        """The matching ``cv2.CALIB_*`` flags."""
        import cv2

        flags = 0
        if self.rational:
            flags |= cv2.CALIB_RATIONAL_MODEL
        if self.fix_k3:
            flags |= cv2.CALIB_FIX_K3
        if self.zero_tangent:
            flags |= cv2.CALIB_ZERO_TANGENT_DIST
        if self.fix_aspect:
            flags |= cv2.CALIB_FIX_ASPECT_RATIO
        if self.fix_principal_point:
            flags |= cv2.CALIB_FIX_PRINCIPAL_POINT
        return flags

    def free_intrinsics(self) -> np.ndarray:
        """Mask over ``fx, fy, cx, cy, dist...``: True where the parameter is estimated.

        With ``fix_aspect`` fy is marked fixed; it follows fx at the initial ratio.
        """
        free = np.ones(4 + self.n_dist, dtype=bool)
        if self.fix_aspect:
            free[1] = False
        if self.fix_principal_point:
            free[2:4] = False
        if self.zero_tangent:
            free[4 + 2:4 + 4] = False
        if self.fix_k3:
            free[4 + 4] = False
        return free

    def to_dict(self) -> dict:
        """The options as a JSON-able dict."""
        return {"distortion_model": self.distortion_model, "fix_k3": self.fix_k3,
                "zero_tangent": self.zero_tangent, "fix_aspect": self.fix_aspect,
                "fix_principal_point": self.fix_principal_point}


@dataclass(frozen=True)
class ViewResult:
    """One board view in a calibration.

    Attributes:
        name: the image (file name, or ``topic@stamp`` for bag frames).
        n_points: corners observed.
        rms_px: RMS reprojection error of this view, pixels (NaN when not used).
        used: the view took part in the final solution.
        outlier: the view's RMS is above the outlier threshold.
        cam_T_board: array, shape (4, 4): board pose in the camera frame (None when not used).
        corners: array, shape (N, 2): observed corners, pixels.
        residuals: array, shape (N, 2): observed minus reprojected corners, pixels.
        index: position of the view in the detections given to the calibration.
    """

    name: str
    n_points: int
    rms_px: float
    used: bool
    outlier: bool
    cam_T_board: np.ndarray | None
    corners: np.ndarray
    residuals: np.ndarray
    index: int = -1

    def to_dict(self) -> dict:
        """JSON-able summary (without the arrays)."""
        return {"file": self.name, "rms_px": _f(self.rms_px), "used": self.used,
                "outlier": self.outlier, "n_points": self.n_points}


def _f(value: float) -> float | None:
    value = float(value)
    return value if np.isfinite(value) else None


def _as_pose(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    import cv2

    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))[0]
    T[:3, 3] = np.asarray(tvec, dtype=np.float64).reshape(3)
    return T


def _rvec(R: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].reshape(3)


def outlier_threshold(view_rms: np.ndarray, absolute_px: float | None = None) -> float:
    """The per-view RMS above which a view is flagged as an outlier.

    ``max(2 * median, median + 4 * 1.4826 * MAD)`` of the per-view RMS values, or
    ``absolute_px`` when given.

    Args:
        view_rms: array, shape (V,): per-view RMS, pixels.
        absolute_px: fixed threshold in pixels, overriding the robust rule.

    Returns:
        The threshold in pixels (inf when there are fewer than 3 views).
    """
    if absolute_px is not None:
        return float(absolute_px)
    vals = np.asarray(view_rms, dtype=np.float64)
    vals = vals[np.isfinite(vals)]
    if vals.size < 3:
        return float("inf")
    med = float(np.median(vals))
    mad = 1.4826 * float(np.median(np.abs(vals - med)))
    return max(OUTLIER_MEDIAN_FACTOR * med, med + OUTLIER_MAD_FACTOR * mad)


def coverage(corner_sets: Sequence[np.ndarray], image_size: tuple[int, int],
             scale: float = 0.25) -> tuple[float, np.ndarray]:
    """Fraction of the image area covered by at least one board (convex hull of its corners).

    Args:
        corner_sets: per view, array, shape (N, 2) of corner pixels.
        image_size: ``(width, height)``.
        scale: resolution of the coverage map relative to the image.

    Returns:
        ``(fraction, counts)``: fraction in [0, 1]; counts, array, shape
        (round(H*scale), round(W*scale)), int32: how many boards cover each cell.
    """
    import cv2

    w = max(1, int(round(image_size[0] * scale)))
    h = max(1, int(round(image_size[1] * scale)))
    counts = np.zeros((h, w), dtype=np.int32)
    for corners in corner_sets:
        pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
        if pts.shape[0] < 3:
            continue
        hull = cv2.convexHull(np.round(pts * scale).astype(np.int32))
        mask = np.zeros((h, w), dtype=np.uint8)
        cv2.fillConvexPoly(mask, hull, 1)
        counts += mask
    return float(np.count_nonzero(counts)) / float(h * w), counts


@dataclass(frozen=True)
class CameraCalibration:
    """Result of :func:`calibrate_camera`.

    Attributes:
        camera: the calibrated camera (R identity, P = [K | 0]).
        rms_px: overall RMS reprojection error over all corners of the used views, pixels.
        views: one entry per view given (used or rejected).
        std: standard deviations of the estimated parameters (``fx``, ``fy``, ``cx``, ``cy``,
            ``k1``...), from the Jacobian at the solution (``cv2.calibrateCameraExtended``);
            0 for fixed parameters.
        coverage: fraction of the image covered by the used boards.
        coverage_map: array, shape (h, w): boards per cell (see :func:`coverage`).
        outlier_threshold_px: the per-view RMS threshold used to flag outliers.
        rejected: names of views dropped by ``reject_outliers``.
        options: the options used.
    """

    camera: CameraModel
    rms_px: float
    views: tuple[ViewResult, ...]
    std: dict
    coverage: float
    coverage_map: np.ndarray
    outlier_threshold_px: float
    rejected: tuple[str, ...]
    options: CalibrationOptions

    @property
    def used_views(self) -> list[ViewResult]:
        """The views in the final solution."""
        return [v for v in self.views if v.used]

    def to_dict(self) -> dict:
        """JSON-able report content (``camera`` block + ``views`` list)."""
        cam = self.camera
        return {
            "camera": {
                "name": cam.name,
                "image_size": [cam.width, cam.height],
                "rms_px": _f(self.rms_px),
                "K": cam.K.tolist(),
                "dist": cam.dist.tolist(),
                "distortion_model": cam.distortion_model,
                "std": {k: _f(v) for k, v in self.std.items()},
                "coverage": _f(self.coverage),
                "n_views_used": len(self.used_views),
                "outlier_threshold_px": _f(self.outlier_threshold_px),
                "outliers": [v.name for v in self.views if v.outlier],
                "rejected": list(self.rejected),
                "options": self.options.to_dict(),
            },
            "views": [v.to_dict() for v in self.views],
        }


def _usable(det: BoardDetection) -> bool:
    return bool(det.found) and det.n_corners >= MIN_POINTS_PER_VIEW


def _check_sizes(dets: Sequence[BoardDetection], names: Sequence[str], what: str
                 ) -> tuple[int, int]:
    sizes = {tuple(d.image_size) for d in dets}
    if len(sizes) > 1:
        first = tuple(dets[0].image_size)
        bad = next(i for i, d in enumerate(dets) if tuple(d.image_size) != first)
        raise CalibrationError(
            f"{what}: images differ in size: {names[0]} is {first[0]}x{first[1]}, "
            f"{names[bad]} is {dets[bad].image_size[0]}x{dets[bad].image_size[1]}")
    return tuple(dets[0].image_size)  # type: ignore[return-value]


def _names(dets: Sequence[BoardDetection], names: Sequence[str] | None, what: str) -> list[str]:
    if names is None:
        return [f"{what}[{i}]" for i in range(len(dets))]
    if len(names) != len(dets):
        raise InputError(f"{what}: {len(names)} names for {len(dets)} detections")
    return [str(n) for n in names]


def _std_dict(std_intr: np.ndarray, options: CalibrationOptions) -> dict:
    std = np.asarray(std_intr, dtype=np.float64).ravel()
    out = {n: float(std[i]) for i, n in enumerate(_INTRINSIC_NAMES)}
    for i, n in enumerate(_DIST_NAMES[:options.n_dist]):
        out[n] = float(std[4 + i]) if 4 + i < std.size else 0.0
    return out


def _mono_once(obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int],
               options: CalibrationOptions):
    import cv2

    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    try:
        rms, K, dist, rvecs, tvecs, std_intr, _std_extr, per_view = cv2.calibrateCameraExtended(
            [o.astype(np.float32) for o in obj],
            [p.astype(np.float32).reshape(-1, 1, 2) for p in img],
            size, None, None, flags=options.cv_flags(), criteria=criteria)
    except cv2.error as exc:
        raise CalibrationError(f"cv2.calibrateCamera failed: {str(exc).strip()}") from exc
    dist = np.asarray(dist, dtype=np.float64).ravel()[:options.n_dist]
    if dist.size < options.n_dist:
        dist = np.concatenate([dist, np.zeros(options.n_dist - dist.size)])
    return float(rms), K, dist, rvecs, tvecs, std_intr, per_view


def calibrate_camera(detections: Sequence[BoardDetection], names: Sequence[str] | None = None, *,
                     options: CalibrationOptions = CalibrationOptions(),
                     reject_outliers: bool = False, outlier_threshold_px: float | None = None,
                     min_views: int = 3, camera_name: str = "camera",
                     max_rejection_rounds: int = 3) -> CameraCalibration:
    """Calibrate one camera from board detections (Zhang's method, ``cv2.calibrateCamera``).

    Views without a board (``found`` False) or with fewer than ``MIN_POINTS_PER_VIEW`` corners
    are ignored (callers list them with their reason). Views whose RMS is above the outlier
    threshold (:func:`outlier_threshold`) are flagged; with ``reject_outliers`` they are dropped
    and the calibration recomputed (up to ``max_rejection_rounds`` times, never going below
    ``min_views``).

    Args:
        detections: one per image, all of the same image size.
        names: the images' names for the report (default ``camera[i]``).
        options: which parameters to estimate.
        reject_outliers: drop flagged views and recompute.
        outlier_threshold_px: fixed per-view RMS threshold instead of the robust rule.
        min_views: fewest usable views accepted.
        camera_name: name written into the camera model.
        max_rejection_rounds: rejection rounds at most.

    Returns:
        The :class:`CameraCalibration`.

    Raises:
        CalibrationError: fewer than ``min_views`` usable views, image sizes differ, or OpenCV
            fails.
    """
    names = _names(detections, names, camera_name)
    usable = [i for i, d in enumerate(detections) if _usable(d)]
    if len(usable) < max(1, int(min_views)):
        raise CalibrationError(
            f"{camera_name}: only {len(usable)} usable board view(s) of {len(detections)} "
            f"image(s), need at least {min_views}")
    size = _check_sizes([detections[i] for i in usable], [names[i] for i in usable], camera_name)
    active = list(usable)
    rejected: list[int] = []
    for _round in range(max(0, int(max_rejection_rounds)) + 1):
        obj = [detections[i].object_points for i in active]
        img = [detections[i].corners for i in active]
        rms, K, dist, rvecs, tvecs, std_intr, per_view = _mono_once(obj, img, size, options)
        per_view = np.asarray(per_view, dtype=np.float64).ravel()
        thr = outlier_threshold(per_view, outlier_threshold_px)
        flagged = [active[k] for k in range(len(active)) if per_view[k] > thr]
        if not (reject_outliers and flagged) or _round == max_rejection_rounds:
            break
        if len(active) - len(flagged) < min_views:
            break
        rejected.extend(flagged)
        active = [i for i in active if i not in flagged]

    camera = CameraModel(K=K, dist=dist, width=size[0], height=size[1],
                         distortion_model=options.distortion_model, name=camera_name)
    pose_of = {i: _as_pose(rvecs[k], tvecs[k]) for k, i in enumerate(active)}
    views = []
    for i, det in enumerate(detections):
        if not det.found:
            continue
        if i in pose_of:
            T = pose_of[i]
            proj = _project(det.object_points, T, K, dist)
            res = det.corners - proj
            view_rms = float(np.sqrt(np.mean(np.sum(res ** 2, axis=1))))
            views.append(ViewResult(names[i], det.n_corners, view_rms, True, view_rms > thr, T,
                                    det.corners, res, i))
        else:
            # rejected (or too few corners): report its error under the final intrinsics
            res, view_rms, T = _residuals_free_pose(det, K, dist)
            views.append(ViewResult(names[i], det.n_corners, view_rms, False,
                                    i in rejected or view_rms > thr, T, det.corners, res, i))
    frac, cmap = coverage([detections[i].corners for i in active], size)
    return CameraCalibration(camera=camera, rms_px=rms, views=tuple(views),
                             std=_std_dict(std_intr, options), coverage=frac, coverage_map=cmap,
                             outlier_threshold_px=thr,
                             rejected=tuple(names[i] for i in rejected), options=options)


def _project(obj: np.ndarray, cam_T_board: np.ndarray, K: np.ndarray, dist: np.ndarray
             ) -> np.ndarray:
    import cv2

    proj, _ = cv2.projectPoints(obj.reshape(-1, 1, 3), _rvec(cam_T_board[:3, :3]),
                                cam_T_board[:3, 3].copy(), K, dist)
    return proj.reshape(-1, 2)


def _residuals_free_pose(det: BoardDetection, K: np.ndarray, dist: np.ndarray
                         ) -> tuple[np.ndarray, float, np.ndarray | None]:
    import cv2

    if det.n_corners < 4:
        return np.full((det.n_corners, 2), np.nan), float("nan"), None
    ok, rvec, tvec = cv2.solvePnP(det.object_points, det.corners.reshape(-1, 1, 2), K, dist,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return np.full((det.n_corners, 2), np.nan), float("nan"), None
    T = _as_pose(rvec, tvec)
    res = det.corners - _project(det.object_points, T, K, dist)
    return res, float(np.sqrt(np.mean(np.sum(res ** 2, axis=1)))), T


# -- stereo -------------------------------------------------------------------------------------

#: Accepted values of the ``method`` argument of :func:`calibrate_stereo`.
STEREO_METHODS: tuple[str, ...] = ("bundle", "opencv")


@dataclass(frozen=True)
class StereoViewResult:
    """One stereo pair in a stereo calibration.

    Attributes:
        name: the left image's name.
        right_name: the right image's name.
        left_found, right_found: the board was found in that image.
        n_points: corners used in the joint fit (left + right).
        rms_px: RMS reprojection error of this pair in the joint fit (NaN when not used).
        used: the pair took part in the final joint solution (both or one side).
        paired: the board was seen in both images (the pair counts for the extrinsic).
        outlier: the RMS is above the outlier threshold.
        left_residuals, right_residuals: arrays, shape (N, 2), observed minus reprojected
            (None when that side was not used).
    """

    name: str
    right_name: str
    left_found: bool
    right_found: bool
    n_points: int
    rms_px: float
    used: bool
    paired: bool
    outlier: bool
    left_residuals: np.ndarray | None = None
    right_residuals: np.ndarray | None = None

    def to_dict(self) -> dict:
        """JSON-able summary (without the arrays)."""
        return {"file": self.name, "right_file": self.right_name, "rms_px": _f(self.rms_px),
                "used": self.used, "paired": self.paired, "outlier": self.outlier,
                "left_found": self.left_found, "right_found": self.right_found,
                "n_points": self.n_points}


@dataclass(frozen=True)
class StereoQuality:
    """Geometric checks of a stereo calibration on the paired views.

    Attributes:
        epipolar_error_px: mean symmetric distance of a corner to the epipolar line of its
            partner, in undistorted pixels.
        epipolar_error_max_px: its maximum.
        rectified_dy_mean_px: mean |y_left - y_right| of corners after rectification.
        rectified_dy_max_px: its maximum.
        square_measured_mean: mean distance between adjacent corners triangulated in 3-D, in
            board units (should equal the board's square).
        square_measured_std: standard deviation of those distances.
        n_points: corners compared.
    """

    epipolar_error_px: float
    epipolar_error_max_px: float
    rectified_dy_mean_px: float
    rectified_dy_max_px: float
    square_measured_mean: float
    square_measured_std: float
    n_points: int


@dataclass(frozen=True)
class StereoCalibration:
    """Result of :func:`calibrate_stereo`.

    Attributes:
        rig: the calibrated, rectified rig (``X_right = R X_left + T``, board units).
        left, right: the per-camera (mono) calibrations the joint fit started from.
        rms_px: RMS reprojection error of the joint fit over all corners of both cameras.
        views: one entry per image pair.
        std: standard deviations from the joint fit's Jacobian: ``left.fx`` ...,
            ``right.k1`` ..., ``T.x``, ``T.y``, ``T.z``, ``baseline``, ``R.rx/ry/rz`` (rad).
        quality: the geometric checks.
        method: ``bundle`` or ``opencv``.
        alpha: the rectification's free-scaling parameter.
        outlier_threshold_px: the per-pair RMS threshold used to flag outliers.
        rejected: names of pairs dropped by ``reject_outliers``.
        options: the options used.
        fix_intrinsics: the intrinsics were kept at the mono results.
    """

    rig: StereoRig
    left: CameraCalibration
    right: CameraCalibration
    rms_px: float
    views: tuple[StereoViewResult, ...]
    std: dict
    quality: StereoQuality
    method: str
    alpha: float
    outlier_threshold_px: float
    rejected: tuple[str, ...]
    options: CalibrationOptions
    fix_intrinsics: bool

    def to_dict(self) -> dict:
        """JSON-able report content (``left``, ``right``, ``stereo`` blocks + ``views``)."""
        rig = self.rig

        def cam_block(cam: CameraModel, mono: CameraCalibration, side: str) -> dict:
            return {
                "name": cam.name,
                "image_size": [cam.width, cam.height],
                "rms_px": _f(self.side_rms(side)),
                "mono_rms_px": _f(mono.rms_px),
                "K": cam.K.tolist(),
                "dist": cam.dist.tolist(),
                "distortion_model": cam.distortion_model,
                "R_rect": cam.R.tolist(),
                "P_rect": cam.P.tolist(),
                "std": {k.split(".", 1)[1]: _f(v) for k, v in self.std.items()
                        if k.startswith(side + ".")},
                "coverage": _f(mono.coverage),
                "n_views": len(mono.used_views),
            }

        q = self.quality
        return {
            "left": cam_block(rig.left, self.left, "left"),
            "right": cam_block(rig.right, self.right, "right"),
            "stereo": {
                "rms_px": _f(self.rms_px),
                "R": rig.R.tolist(),
                "T": rig.T.tolist(),
                "baseline": _f(rig.baseline),
                "rotation_deg": _f(np.degrees(np.linalg.norm(_rvec(rig.R)))),
                "std": {k: _f(v) for k, v in self.std.items()
                        if not k.startswith(("left.", "right."))},
                "epipolar_error_px": _f(q.epipolar_error_px),
                "epipolar_error_max_px": _f(q.epipolar_error_max_px),
                "rectified_dy_mean_px": _f(q.rectified_dy_mean_px),
                "rectified_dy_max_px": _f(q.rectified_dy_max_px),
                "square_measured": {"mean": _f(q.square_measured_mean),
                                    "std": _f(q.square_measured_std), "n": q.n_points},
                "Q": None if rig.Q is None else rig.Q.tolist(),
                "alpha": self.alpha,
                "method": self.method,
                "fix_intrinsics": self.fix_intrinsics,
                "n_pairs_used": sum(1 for v in self.views if v.used and v.paired),
                "outlier_threshold_px": _f(self.outlier_threshold_px),
                "outliers": [v.name for v in self.views if v.outlier],
                "rejected": list(self.rejected),
                "options": self.options.to_dict(),
            },
            "views": [v.to_dict() for v in self.views],
        }

    def side_rms(self, side: str) -> float:
        """RMS of one camera's residuals in the joint fit, pixels."""
        key = "left_residuals" if side == "left" else "right_residuals"
        res = [getattr(v, key) for v in self.views if v.used and getattr(v, key) is not None]
        if not res:
            return float("nan")
        allres = np.concatenate(res)
        return float(np.sqrt(np.mean(np.sum(allres ** 2, axis=1))))


class _Bundle:
    """Joint least squares over both cameras' intrinsics, distortion, the extrinsic and the
    per-view board poses (in the left camera frame), with analytic Jacobians from
    ``cv2.projectPoints`` and ``cv2.composeRT``."""

    def __init__(self, K: list[np.ndarray], dist: list[np.ndarray], ext_rvec: np.ndarray,
                 ext_tvec: np.ndarray, poses: list[tuple[np.ndarray, np.ndarray]],
                 obs: list[list[tuple[np.ndarray, np.ndarray] | None]],
                 options: CalibrationOptions, fix_intrinsics: bool) -> None:
        self.nd = options.n_dist
        self.nc = 4 + self.nd
        self.nv = len(poses)
        self.obs = obs  # obs[v][c] = (object (N,3), image (N,2)) or None
        self.aspect = [float(k[0, 0] / k[1, 1]) for k in K]
        self.fix_aspect = options.fix_aspect
        x = []
        for c in range(2):
            x.extend([K[c][0, 0], K[c][1, 1], K[c][0, 2], K[c][1, 2]])
            x.extend(np.asarray(dist[c], dtype=np.float64).ravel()[:self.nd])
        x.extend(ext_rvec)
        x.extend(ext_tvec)
        for r, t in poses:
            x.extend(r)
            x.extend(t)
        self.x0 = np.asarray(x, dtype=np.float64)
        free = np.ones(self.x0.size, dtype=bool)
        cam_free = (np.zeros(self.nc, dtype=bool) if fix_intrinsics
                    else options.free_intrinsics())
        free[:self.nc] = cam_free
        free[self.nc:2 * self.nc] = cam_free
        self.free = free
        self.ext0 = 2 * self.nc
        self.pose0 = self.ext0 + 6
        self.m = 2 * sum(o[0].shape[0] for view in obs for o in view if o is not None)

    def camera(self, x: np.ndarray, c: int) -> tuple[np.ndarray, np.ndarray]:
        p = x[c * self.nc:(c + 1) * self.nc]
        fy = p[0] / self.aspect[c] if self.fix_aspect else p[1]
        K = np.array([[p[0], 0.0, p[2]], [0.0, fy, p[3]], [0.0, 0.0, 1.0]])
        return K, p[4:].copy()

    def evaluate(self, x: np.ndarray, jac: bool = True
                 ) -> tuple[np.ndarray, Any, list[list[np.ndarray | None]]]:
        """Residuals (projected - observed), the sparse Jacobian (CSR, all parameters) and the
        per-view residuals (observed - projected) of each camera."""
        import cv2
        from scipy.sparse import csr_matrix

        r = np.empty(self.m)
        rows_l: list[np.ndarray] = []
        cols_l: list[np.ndarray] = []
        vals_l: list[np.ndarray] = []

        def put(row0: int, block: np.ndarray, cols: np.ndarray) -> None:
            nr = block.shape[0]
            rows_l.append(np.repeat(np.arange(row0, row0 + nr), cols.size))
            cols_l.append(np.tile(cols, nr))
            vals_l.append(block.ravel())

        per_view: list[list[np.ndarray | None]] = []
        row = 0
        er, et = x[self.ext0:self.ext0 + 3], x[self.ext0 + 3:self.ext0 + 6]
        ext_cols = np.arange(self.ext0, self.ext0 + 6)
        cams = [self.camera(x, 0), self.camera(x, 1)]
        for v in range(self.nv):
            pv = self.pose0 + 6 * v
            vr, vt = x[pv:pv + 3], x[pv + 3:pv + 6]
            pose_cols = np.arange(pv, pv + 6)
            out: list[np.ndarray | None] = [None, None]
            for c in range(2):
                o = self.obs[v][c]
                if o is None:
                    continue
                obj, img = o
                n = obj.shape[0]
                if c == 0:
                    rr, tt = vr, vt
                else:
                    comp = cv2.composeRT(vr, vt, er, et)
                    rr, tt = comp[0].ravel(), comp[1].ravel()
                K, d = cams[c]
                proj, jp = cv2.projectPoints(obj.reshape(-1, 1, 3), rr, tt, K, d)
                res = proj.reshape(-1, 2) - img
                out[c] = -res
                r[row:row + 2 * n] = res.ravel()
                if jac:
                    Jrt = jp[:, 0:6]
                    Jf, Jc, Jd = jp[:, 6:8], jp[:, 8:10], jp[:, 10:10 + self.nd]
                    base = c * self.nc
                    if self.fix_aspect:
                        Jf = np.column_stack([Jf[:, 0] + Jf[:, 1] / self.aspect[c],
                                              np.zeros(Jf.shape[0])])
                    put(row, np.hstack([Jf, Jc, Jd]), np.arange(base, base + self.nc))
                    if c == 0:
                        put(row, Jrt, pose_cols)
                    else:
                        _, _, dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2 = comp
                        Jr, Jt = Jrt[:, :3], Jrt[:, 3:]
                        put(row, np.hstack([Jr @ dr3dr1 + Jt @ dt3dr1, Jr @ dr3dt1 + Jt @ dt3dt1]),
                            pose_cols)
                        put(row, np.hstack([Jr @ dr3dr2 + Jt @ dt3dr2, Jr @ dr3dt2 + Jt @ dt3dt2]),
                            ext_cols)
                row += 2 * n
            per_view.append(out)
        J = None
        if jac:
            J = csr_matrix((np.concatenate(vals_l), (np.concatenate(rows_l),
                                                     np.concatenate(cols_l))),
                           shape=(self.m, x.size))
        return r, J, per_view

    def _normal(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r, J, _ = self.evaluate(x, jac=True)
        Jf = J[:, self.free]
        return r, np.asarray((Jf.T @ Jf).todense()), np.asarray(Jf.T @ r).ravel()

    def solve(self, max_iterations: int = 100) -> tuple[np.ndarray, np.ndarray]:
        """Levenberg-Marquardt (Marquardt's diagonal scaling) on the normal equations.

        The Jacobian is sparse (each board pose touches only its own rows); the normal matrix
        has the size of the parameter vector, so hundreds of views stay cheap.

        Returns:
            ``(x, covariance)``: all parameters, and the covariance over all parameters (zero
            rows/columns for fixed ones).
        """
        import scipy.linalg

        x = self.x0.copy()
        free = self.free
        r, A, g = self._normal(x)
        cost = float(r @ r)
        lam = 1e-3
        for _ in range(max_iterations):
            diag = np.diag(A).copy()
            diag[diag <= 0] = 1.0
            step = None
            while lam < 1e16:
                try:
                    M = A + lam * np.diag(diag)
                    step = -scipy.linalg.cho_solve(scipy.linalg.cho_factor(M), g)
                except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
                    lam *= 10.0
                    continue
                x_try = x.copy()
                x_try[free] += step
                r_try = self.evaluate(x_try, jac=False)[0]
                cost_try = float(r_try @ r_try)
                if np.isfinite(cost_try) and cost_try < cost:
                    break
                lam *= 10.0
                step = None
            if step is None:
                break
            improvement = (cost - cost_try) / max(cost, 1e-300)
            x, cost = x_try, cost_try
            lam = max(lam / 10.0, 1e-12)
            r, A, g = self._normal(x)
            if improvement < 1e-12 or np.linalg.norm(step) < 1e-12 * (1 + np.linalg.norm(x[free])):
                break
        return x, self._covariance(r, A)

    def _covariance(self, r: np.ndarray, A: np.ndarray) -> np.ndarray:
        n_free = int(self.free.sum())
        dof = max(1, r.size - n_free)
        sigma2 = float(r @ r) / dof
        try:
            cov = np.linalg.inv(A) * sigma2
        except np.linalg.LinAlgError:
            cov = np.linalg.pinv(A) * sigma2
        full = np.zeros((self.x0.size, self.x0.size))
        idx = np.flatnonzero(self.free)
        full[np.ix_(idx, idx)] = cov
        return full

    def covariance(self, x: np.ndarray) -> np.ndarray:
        """Covariance of all parameters at ``x`` (sigma^2 (J^T J)^-1 over the free ones)."""
        r, A, _ = self._normal(x)
        return self._covariance(r, A)


def _pair_points(ld: BoardDetection, rd: BoardDetection
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Corners seen in both images: (ids, object (N,3), left (N,2), right (N,2))."""
    common, li, ri = np.intersect1d(ld.ids, rd.ids, return_indices=True)
    return common, ld.object_points[li], ld.corners[li], rd.corners[ri]


def _align_symmetric(board: BoardSpec | None, ld: BoardDetection, rd: BoardDetection
                     ) -> BoardDetection:
    """Flip the right detection of a symmetric chessboard when its order opposes the left's."""
    if board is None or board.kind != "chessboard" or (board.cols + board.rows) % 2 == 1:
        return rd
    if ld.n_corners != rd.n_corners or ld.n_corners < 2:
        return rd
    dl = ld.corners[-1] - ld.corners[0]
    dr = rd.corners[-1] - rd.corners[0]
    return rd.reversed() if float(dl @ dr) < 0 else rd


def stereo_quality(rig: StereoRig, pairs: Sequence[tuple[BoardDetection, BoardDetection]],
                   board: BoardSpec | None = None) -> StereoQuality:
    """Epipolar error, rectified row difference and triangulated square length.

    Args:
        rig: a rectified rig (:meth:`StereoRig.rectified`).
        pairs: ``(left, right)`` detections of the same board.
        board: the board (its ``cols`` give the corner grid for the square-length check;
            default: taken as the detections' grid, adjacent ids along rows).

    Returns:
        The :class:`StereoQuality`.

    Raises:
        CalibrationError: no pair has common corners, or the rig is not rectified.
    """
    import cv2

    if not rig.is_rectified:
        raise CalibrationError("stereo_quality: the rig must be rectified")
    K1, K2 = rig.left.K, rig.right.K
    Tx = np.array([[0, -rig.T[2], rig.T[1]], [rig.T[2], 0, -rig.T[0]], [-rig.T[1], rig.T[0], 0]])
    F = np.linalg.inv(K2).T @ Tx @ rig.R @ np.linalg.inv(K1)
    epi, dy, lengths = [], [], []
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
    for ld, rd in pairs:
        ids, _obj, pl, pr = _pair_points(ld, rd)
        if ids.size == 0:
            continue
        ul = cv2.undistortPoints(pl.reshape(-1, 1, 2), K1, rig.left.dist, None, None, K1,
                                 crit).reshape(-1, 2)
        ur = cv2.undistortPoints(pr.reshape(-1, 1, 2), K2, rig.right.dist, None, None, K2,
                                 crit).reshape(-1, 2)
        hl = np.hstack([ul, np.ones((ul.shape[0], 1))])
        hr = np.hstack([ur, np.ones((ur.shape[0], 1))])
        lr = hl @ F.T  # epipolar lines in the right image
        ll = hr @ F    # epipolar lines in the left image
        d_r = np.abs(np.sum(lr * hr, axis=1)) / np.hypot(lr[:, 0], lr[:, 1])
        d_l = np.abs(np.sum(ll * hl, axis=1)) / np.hypot(ll[:, 0], ll[:, 1])
        epi.append(0.5 * (d_r + d_l))
        rl = rig.left.rectify_points(pl)
        rr = rig.right.rectify_points(pr)
        dy.append(np.abs(rl[:, 1] - rr[:, 1]))
        X = cv2.triangulatePoints(rig.P1, rig.P2, rl.T, rr.T)
        X = (X[:3] / X[3]).T
        cols = board.cols if board is not None else None
        if cols is None:
            continue
        pos = {int(i): k for k, i in enumerate(ids)}
        for i, k in pos.items():
            if (i % cols) < cols - 1 and (i + 1) in pos:
                lengths.append(np.linalg.norm(X[pos[i + 1]] - X[k]))
            if (i + cols) in pos:
                lengths.append(np.linalg.norm(X[pos[i + cols]] - X[k]))
    if not epi:
        raise CalibrationError("stereo_quality: no stereo pair with common board corners")
    e = np.concatenate(epi)
    d = np.concatenate(dy)
    sq = np.asarray(lengths, dtype=np.float64)
    return StereoQuality(
        epipolar_error_px=float(e.mean()), epipolar_error_max_px=float(e.max()),
        rectified_dy_mean_px=float(d.mean()), rectified_dy_max_px=float(d.max()),
        square_measured_mean=float(sq.mean()) if sq.size else float("nan"),
        square_measured_std=float(sq.std(ddof=1)) if sq.size > 1 else float("nan"),
        n_points=int(e.size))


def calibrate_stereo(left: Sequence[BoardDetection], right: Sequence[BoardDetection],
                     left_names: Sequence[str] | None = None,
                     right_names: Sequence[str] | None = None, *,
                     board: BoardSpec | None = None,
                     options: CalibrationOptions = CalibrationOptions(),
                     method: str = "bundle", fix_intrinsics: bool = False, alpha: float = 0.0,
                     reject_outliers: bool = False, outlier_threshold_px: float | None = None,
                     min_views: int = 3, max_rejection_rounds: int = 3) -> StereoCalibration:
    """Calibrate a stereo rig: each camera alone, then everything jointly, then rectify.

    1. Each camera is calibrated alone (:func:`calibrate_camera`) on every image where it saw
       the board.
    2. The extrinsic is initialised as the average of the per-pair ``right_T_left``.
    3. Joint refinement. ``method="bundle"`` (default): Levenberg-Marquardt over both cameras'
       intrinsics and distortion, the extrinsic and every board pose, using all views (pairs
       where only one camera saw the board still constrain that camera), analytic Jacobians.
       ``method="opencv"``: ``cv2.stereoCalibrate`` with ``CALIB_USE_INTRINSIC_GUESS`` on the
       paired views only. Intrinsics are free unless ``fix_intrinsics``.
    4. Rectification (``cv2.stereoRectify`` with ``alpha``), then the quality checks
       (:func:`stereo_quality`) and per-pair errors; pairs above the outlier threshold are
       flagged and, with ``reject_outliers``, dropped and everything recomputed.

    Args:
        left: detections in the left images.
        right: detections in the right images, pair i being ``(left[i], right[i])``.
        left_names, right_names: image names for the report.
        board: the board (used for the square-length check and symmetric-board ordering).
        options: which intrinsic parameters to estimate.
        method: ``"bundle"`` or ``"opencv"``.
        fix_intrinsics: keep the mono intrinsics and distortion in the joint step.
        alpha: rectification free scaling in [0, 1] (0: only valid pixels, 1: all pixels).
        reject_outliers: drop flagged pairs and recompute.
        outlier_threshold_px: fixed per-pair RMS threshold instead of the robust rule.
        min_views: fewest usable pairs (board in both images) accepted.
        max_rejection_rounds: rejection rounds at most.

    Returns:
        The :class:`StereoCalibration`.

    Raises:
        CalibrationError: different numbers of left and right images, image sizes that differ,
            fewer than ``min_views`` usable pairs, or a solver failure.
        InputError: unknown method, alpha out of range.
    """
    if method not in STEREO_METHODS:
        raise InputError(f"method: expected one of {', '.join(STEREO_METHODS)}, got {method!r}")
    if not (0.0 <= float(alpha) <= 1.0):
        raise InputError(f"alpha: expected a value in [0, 1], got {alpha}")
    if len(left) != len(right):
        raise CalibrationError(f"stereo: {len(left)} left image(s) but {len(right)} right "
                               "image(s); they must pair up one to one")
    lnames = _names(left, left_names, "left")
    rnames = _names(right, right_names, "right")
    right = [_align_symmetric(board, ld, rd) if ld.found and rd.found else rd
             for ld, rd in zip(left, right)]
    found_l = [d for d in left if d.found]
    found_r = [d for d in right if d.found]
    if found_l and found_r and tuple(found_l[0].image_size) != tuple(found_r[0].image_size):
        raise CalibrationError(
            f"stereo: left images are {found_l[0].image_size[0]}x{found_l[0].image_size[1]} but "
            f"right images are {found_r[0].image_size[0]}x{found_r[0].image_size[1]}")
    active = [i for i in range(len(left)) if _usable(left[i]) or _usable(right[i])]
    rejected: list[int] = []
    for _round in range(max(0, int(max_rejection_rounds)) + 1):
        result = _stereo_once(left, right, lnames, rnames, active, board, options, method,
                              fix_intrinsics, float(alpha), outlier_threshold_px, min_views,
                              rejected)
        flagged = [i for i, v in zip(range(len(left)), result.views) if v.used and v.outlier]
        paired_left = sum(1 for i, v in enumerate(result.views)
                          if v.used and v.paired and i not in flagged)
        if not (reject_outliers and flagged) or _round == max_rejection_rounds \
                or paired_left < min_views:
            return result
        rejected.extend(flagged)
        active = [i for i in active if i not in flagged]
    return result  # pragma: no cover - the loop always returns


def _stereo_once(left: Sequence[BoardDetection], right: Sequence[BoardDetection],
                 lnames: list[str], rnames: list[str], active: list[int],
                 board: BoardSpec | None, options: CalibrationOptions, method: str,
                 fix_intrinsics: bool, alpha: float, thr_abs: float | None, min_views: int,
                 rejected: list[int]) -> StereoCalibration:
    import cv2

    from eye_in_hand.core.transforms import average_transforms

    n = len(left)
    missing = BoardDetection.missing((0, 0), "", "not used")
    ldets = [left[i] if i in active else missing for i in range(n)]
    rdets = [right[i] if i in active else missing for i in range(n)]
    paired = [i for i in active if _usable(left[i]) and _usable(right[i])
              and _pair_points(left[i], right[i])[0].size >= MIN_POINTS_PER_VIEW]
    if len(paired) < max(1, int(min_views)):
        raise CalibrationError(
            f"stereo: only {len(paired)} pair(s) with the board in both images of {n}, "
            f"need at least {min_views}")
    mono_l = calibrate_camera(ldets, lnames, options=options, min_views=min_views,
                              camera_name="left", max_rejection_rounds=0)
    mono_r = calibrate_camera(rdets, rnames, options=options, min_views=min_views,
                              camera_name="right", max_rejection_rounds=0)
    pose_l = {v.index: v.cam_T_board for v in mono_l.views if v.used}
    pose_r = {v.index: v.cam_T_board for v in mono_r.views if v.used}
    rels = [pose_r[i] @ np.linalg.inv(pose_l[i]) for i in paired if i in pose_l and i in pose_r]
    if not rels:
        raise CalibrationError("stereo: no pair has a board pose in both cameras")
    r_T_l = average_transforms(rels)
    size = mono_l.camera.size
    K = [np.array(mono_l.camera.K), np.array(mono_r.camera.K)]
    dist = [np.array(mono_l.camera.dist), np.array(mono_r.camera.dist)]
    ext_r, ext_t = _rvec(r_T_l[:3, :3]), r_T_l[:3, 3].copy()

    if method == "opencv":
        obj, pl, pr = [], [], []
        for i in paired:
            _, o, a, b = _pair_points(left[i], right[i])
            obj.append(o.astype(np.float32))
            pl.append(a.astype(np.float32).reshape(-1, 1, 2))
            pr.append(b.astype(np.float32).reshape(-1, 1, 2))
        flags = options.cv_flags() | (cv2.CALIB_FIX_INTRINSIC if fix_intrinsics
                                      else cv2.CALIB_USE_INTRINSIC_GUESS)
        criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
        try:
            out = cv2.stereoCalibrateExtended(
                obj, pl, pr, K[0], dist[0], K[1], dist[1], size, _as_pose(ext_r, ext_t)[:3, :3],
                ext_t.reshape(3, 1), flags=flags | cv2.CALIB_USE_EXTRINSIC_GUESS,
                criteria=criteria)
        except cv2.error as exc:
            raise CalibrationError(f"cv2.stereoCalibrate failed: {str(exc).strip()}") from exc
        _, K0, d0, K1, d1, Rx, Tx = out[:7]
        rvecs, tvecs = out[9], out[10]
        K = [np.asarray(K0), np.asarray(K1)]
        dist = [np.asarray(d0).ravel()[:options.n_dist], np.asarray(d1).ravel()[:options.n_dist]]
        ext_r, ext_t = _rvec(Rx), np.asarray(Tx, dtype=np.float64).ravel()
        views_in = list(paired)
        poses = [(np.asarray(rvecs[k]).ravel(), np.asarray(tvecs[k]).ravel())
                 for k in range(len(paired))]
        obs = [[(o, a), (o, b)] for o, a, b in
               ((_pair_points(left[i], right[i])[1], _pair_points(left[i], right[i])[2],
                 _pair_points(left[i], right[i])[3]) for i in paired)]
    else:
        views_in, poses, obs = [], [], []
        r_T_l_now = _as_pose(ext_r, ext_t)
        for i in active:
            has_l, has_r = i in pose_l, i in pose_r
            if not (has_l or has_r):
                continue
            T = pose_l[i] if has_l else np.linalg.inv(r_T_l_now) @ pose_r[i]
            views_in.append(i)
            poses.append((_rvec(T[:3, :3]), T[:3, 3].copy()))
            obs.append([(left[i].object_points, left[i].corners) if has_l else None,
                        (right[i].object_points, right[i].corners) if has_r else None])
    bundle = _Bundle(K, dist, ext_r, ext_t, poses, obs, options, fix_intrinsics)
    if method == "bundle":
        x, cov = bundle.solve()
    else:
        x = bundle.x0
        cov = bundle.covariance(x)
    res_all, _, per_view = bundle.evaluate(x, jac=False)
    rms = float(np.sqrt(np.sum(res_all ** 2) / (res_all.size / 2)))
    cams = []
    for c, mono in enumerate((mono_l, mono_r)):
        Kc, dc = bundle.camera(x, c)
        cams.append(CameraModel(K=Kc, dist=dc, width=size[0], height=size[1],
                                distortion_model=options.distortion_model, name=mono.camera.name))
    Rx = _as_pose(x[bundle.ext0:bundle.ext0 + 3], np.zeros(3))[:3, :3]
    Tx = x[bundle.ext0 + 3:bundle.ext0 + 6].copy()
    rig = StereoRig(left=cams[0], right=cams[1], R=Rx, T=Tx).rectified(alpha)

    # per-view results and outliers
    view_rms = {}
    res_of: dict[int, list[np.ndarray | None]] = {}
    for k, i in enumerate(views_in):
        parts = [p for p in per_view[k] if p is not None]
        allres = np.concatenate(parts)
        view_rms[i] = float(np.sqrt(np.mean(np.sum(allres ** 2, axis=1))))
        res_of[i] = per_view[k]
    thr = outlier_threshold(np.array(list(view_rms.values())), thr_abs)
    views = []
    for i in range(n):
        used = i in view_rms
        vr = view_rms.get(i, float("nan"))
        lr, rr = res_of.get(i, [None, None])
        npts = sum(p.shape[0] for p in (lr, rr) if p is not None)
        views.append(StereoViewResult(
            name=lnames[i], right_name=rnames[i], left_found=bool(left[i].found),
            right_found=bool(right[i].found), n_points=npts, rms_px=vr, used=used,
            paired=i in paired, outlier=(used and vr > thr) or i in rejected,
            left_residuals=lr, right_residuals=rr))

    # standard deviations
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    names_c = list(_INTRINSIC_NAMES) + list(_DIST_NAMES[:options.n_dist])
    std: dict[str, float] = {}
    for c, side in enumerate(("left", "right")):
        for k, nm in enumerate(names_c):
            std[f"{side}.{nm}"] = float(sd[c * bundle.nc + k])
        if options.fix_aspect and not fix_intrinsics:
            std[f"{side}.fy"] = std[f"{side}.fx"] / bundle.aspect[c]
    e0 = bundle.ext0
    for k, nm in enumerate(("R.rx", "R.ry", "R.rz", "T.x", "T.y", "T.z")):
        std[nm] = float(sd[e0 + k])
    covT = cov[e0 + 3:e0 + 6, e0 + 3:e0 + 6]
    g = Tx / np.linalg.norm(Tx)
    std["baseline"] = float(np.sqrt(max(0.0, g @ covT @ g)))

    quality = stereo_quality(rig, [(left[i], right[i]) for i in paired], board)
    return StereoCalibration(rig=rig, left=mono_l, right=mono_r, rms_px=rms, views=tuple(views),
                             std=std, quality=quality, method=method, alpha=alpha,
                             outlier_threshold_px=thr,
                             rejected=tuple(lnames[i] for i in rejected), options=options,
                             fix_intrinsics=fix_intrinsics)
