"""Calibration boards: the board specification string, detections, and an exact renderer."""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, Literal

import cv2
import numpy as np

from eye_in_hand.errors import InputError

_DEFAULT_CHARUCO_DICT = "DICT_5X5_100"
_BOARD_RE = re.compile(r"^\s*(\d+)\s*[xX]\s*(\d+)\s*$")


#: Largest plausible square (or marker) side in a board spec string, metres. A printed board's
#: squares are millimetres to centimetres; 25 means 25 mm given in the wrong unit. (Unit
#: squares, 1.0, remain: a board whose results are wanted in squares.)
MAX_SQUARE_M = 1.0


def _in_metres(spec: str, parts: list[str], fields: tuple[int, ...]) -> None:
    """Refuse a square side above :data:`MAX_SQUARE_M`, naming the spec in metres."""
    square = float(parts[fields[0]])
    if square <= MAX_SQUARE_M:
        return
    fixed = list(parts)
    for i in fields:
        if float(parts[i]) > MAX_SQUARE_M:
            fixed[i] = f"{float(parts[i]) / 1000:g}"
    raise InputError(
        f"board spec {spec!r}: square size {square:g} would be {square:g} m: squares are in "
        f"metres; for {square:g} mm pass {':'.join(fixed)!r}")


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
            if not hasattr(cv2.aruco, self.dictionary):
                raise InputError(f"board: unknown ArUco dictionary {self.dictionary!r}")

    # -- construction -----------------------------------------------------------------------
    @classmethod
    def parse(cls, spec: str) -> BoardSpec:
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
            _in_metres(spec, parts, (2,))
            return cls("chessboard", cols, rows, square)
        if kind == "charuco":
            if len(parts) < 4 or len(parts) > 6:
                raise InputError(
                    f"board spec {spec!r}: expected charuco:SQUARESXxSQUARESY:SQUARE:MARKER"
                    "[:DICT][:legacy], e.g. charuco:7x5:0.04:0.03:DICT_5X5_100")
            sx, sy = cls._parse_size(parts[1], spec, "squares")
            if sx < 3 or sy < 3:
                raise InputError(f"board spec {spec!r}: a ChArUco board needs at least 3x3 "
                                 "squares")
            square = _positive_float(parts[2], "square size", spec)
            marker = _positive_float(parts[3], "marker size", spec)
            _in_metres(spec, parts, (2, 3))
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

    def charuco_board(self) -> Any:
        """The OpenCV ``cv2.aruco.CharucoBoard`` of a ChArUco spec.

        Raises:
            InputError: the board is a chessboard.
        """
        if self.kind != "charuco":
            raise InputError(f"board {self}: not a ChArUco board")
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
    meta: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def missing(cls, image_size: tuple[int, int], detector: str, reason: str) -> BoardDetection:
        """A not-found result carrying ``reason``."""
        return cls(False, np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64),
                   image_size, detector, reason)

    @property
    def n_corners(self) -> int:
        """Number of detected corners."""
        return int(self.corners.shape[0])

    def reversed(self) -> BoardDetection:
        """The same chessboard detection with the corner order rotated by 180 degrees.

        Used to make left/right orderings agree when the detector returned a symmetric board
        flipped in one image. Only valid for full chessboard detections.
        """
        return BoardDetection(self.found, self.corners[::-1].copy(), self.object_points,
                              self.ids, self.image_size, self.detector, self.reason, self.meta)


def render_board(board: BoardSpec, K: np.ndarray, dist: np.ndarray, cam_T_board: np.ndarray,
                 image_size: tuple[int, int], *, supersample: int = 3, margin_squares: float = 1.0,
                 black: int = 25, white: int = 230, background: int = 110,
                 return_corners: bool = False) -> Any:
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
                               criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20,
                                         1e-9))
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

def _pair_points(ld: BoardDetection, rd: BoardDetection
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Corners seen in both images: (ids, object (N,3), left (N,2), right (N,2))."""
    common, li, ri = np.intersect1d(ld.ids, rd.ids, return_indices=True)
    return common, ld.object_points[li], ld.corners[li], rd.corners[ri]
