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
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from eye_in_hand.errors import InputError

__all__ = [
    "BoardSpec",
    "BoardDetection",
    "DETECTORS",
    "detect_board",
    "render_board",
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
