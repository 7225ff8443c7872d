"""The usual board mistakes, checked after the first few images instead of at the end.

A board spec that matches nothing in the images (squares counted instead of inner corners,
a ChArUco board given as a chessboard, the wrong ArUco dictionary, squares x/y swapped) made
every image "skipped" and failed after the whole input was read, with no hint.
:class:`BoardCheck` watches a detection loop: when none of the first :data:`CHECK_AFTER` images
holds the board, it looks for the usual alternatives in those images and, when one is found,
stops the run with the spec to pass.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any

import cv2
import numpy as np

from eye_in_hand.core.calibration.board import BoardSpec
from eye_in_hand.core.calibration.detection import detect_board
from eye_in_hand.errors import CalibrationError

__all__ = ["CHECK_AFTER", "BoardCheck", "board_alternatives", "aruco_dictionaries_in"]

#: Images without the board after which the usual mistakes are looked for.
CHECK_AFTER = 8
#: ArUco dictionaries looked for when a chessboard (or a ChArUco board) is never found.
ARUCO_DICTIONARIES = ("DICT_4X4_50", "DICT_5X5_100", "DICT_6X6_250", "DICT_7X7_1000",
                      "DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_36h11")
_MIN_MARKERS = 4


def aruco_dictionaries_in(image: np.ndarray) -> list[str]:
    """The ArUco dictionaries of which ``image`` shows at least a few markers."""
    gray: np.ndarray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if gray.dtype != np.uint8:
        # OpenCV's stubs refuse None for dst, which the function takes (a new array)
        gray = cv2.normalize(gray, None, 0, 255, cv2.NORM_MINMAX  # type: ignore[call-overload]
                             ).astype(np.uint8)
    out = []
    for name in ARUCO_DICTIONARIES:
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
        corners, ids, _ = cv2.aruco.ArucoDetector(dictionary).detectMarkers(gray)
        if ids is not None and len(ids) >= _MIN_MARKERS:
            out.append(name)
    return out


def _charuco(sx: int, sy: int, square: float, dictionary: str, legacy: bool = False
             ) -> BoardSpec:
    return BoardSpec("charuco", sx - 1, sy - 1, square, 0.75 * square, dictionary, legacy)


def board_alternatives(board: BoardSpec, dictionaries: list[str] | tuple[str, ...] = ()
                       ) -> list[tuple[BoardSpec, str]]:
    """The boards a user who gave ``board`` may have meant, each with what was wrong.

    Args:
        board: the board given.
        dictionaries: ArUco dictionaries seen in the images (for the ChArUco alternatives).
    """
    c, r, sq = board.cols, board.rows, board.square
    out: list[tuple[BoardSpec, str]] = []
    if board.kind == "chessboard":
        for name in dictionaries:   # first: a ChArUco board is a chessboard too
            for sx, sy in ((c, r), (c + 1, r + 1), (r, c), (r + 1, c + 1)):
                if min(sx, sy) >= 3:
                    out.append((_charuco(sx, sy, sq, name),
                                f"a ChArUco board ({name} markers), not a chessboard"))
        counted = "squares counted instead of inner corners (a board of {} x {} squares has " \
                  "{} x {} inner corners)"
        for cc, rr in ((c - 1, r - 1), (c - 1, r), (c, r - 1)):
            if min(cc, rr) >= 2:
                out.append((BoardSpec("chessboard", cc, rr, sq),
                            counted.format(c, r, c - 1, r - 1) if (cc, rr) == (c - 1, r - 1)
                            else "one side counted in squares instead of inner corners"))
    else:
        sx, sy = c + 1, r + 1
        if sx != sy:
            out.append((replace(board, cols=r, rows=c), "squares x and y swapped"))
        out.append((replace(board, cols=c + 1, rows=r + 1),
                    "inner corners counted instead of squares (a ChArUco board is given in "
                    "squares)"))
        out.append((replace(board, legacy=not board.legacy),
                    "the other ChArUco layout (legacy: OpenCV before 4.6)"))
        for name in dictionaries:
            if name != board.dictionary:
                out.append((replace(board, dictionary=name),
                            f"the markers are {name}, not {board.dictionary}"))
                if sx != sy:
                    out.append((replace(board, cols=r, rows=c, dictionary=name),
                                f"the markers are {name}, and squares x and y swapped"))
        out.append((BoardSpec("chessboard", c, r, sq),
                    "a chessboard, not a ChArUco board"))
    return out


def _board_text(board: BoardSpec) -> str:
    if board.kind == "chessboard":
        return f"a {board.cols}x{board.rows} chessboard (inner corners)"
    return f"a ChArUco board of {board.cols + 1}x{board.rows + 1} squares ({board.dictionary})"


def _spec_text(board: BoardSpec) -> str:
    text = str(board)
    if board.kind == "charuco":   # the marker side was not measured: say so
        text += "  (measure the marker side)"
    return text


class BoardCheck:
    """Watches a detection loop for a board that is in none of the first images.

    Call :meth:`add` with each image and whether the board was found in it, and
    :meth:`finish` after the last. Once the board was in none of the first ``after`` images
    (or of all of them, when there are fewer), the usual mistakes (:func:`board_alternatives`)
    are tried on them; when one is found the check raises, naming the fix. Once the board is
    found, or the alternatives were tried, it does nothing more (and keeps no images).

    Args:
        board: the board given.
        what: what the images are, for the message (``"left images"``).
        option: where the board was given (``"--board"``, ``"dataset.yaml board:"``).
        after: images without the board before the check.
    """

    def __init__(self, board: BoardSpec, what: str = "images", option: str = "--board",
                 after: int = CHECK_AFTER) -> None:
        self.board = board
        self.what = what
        self.option = option
        self.after = int(after)
        self._images: list[np.ndarray] = []
        self.done = self.after <= 0

    def add(self, image: np.ndarray | None, found: bool) -> None:
        """Count one image (None: unusable, not counted).

        Raises:
            CalibrationError: the board was in none of the first ``after`` images and an
                alternative is: the message names it and the spec to pass.
        """
        if self.done or image is None:
            return
        if found:
            self.done, self._images = True, []
            return
        self._images.append(image)
        if len(self._images) >= self.after:
            images, self._images, self.done = self._images, [], True
            self._check(images)

    def finish(self) -> None:
        """The end of the input: with fewer than ``after`` images, none with the board, check
        those (raises as :meth:`add`)."""
        if not self.done and self._images:
            images, self._images, self.done = self._images, [], True
            self._check(images)

    def _check(self, images: list[np.ndarray]) -> None:
        n = len(images)
        dictionaries: list[str] = []
        for image in images[:3]:
            dictionaries += [d for d in aruco_dictionaries_in(image) if d not in dictionaries]
        for alt, why in board_alternatives(self.board, dictionaries):
            hits = 0
            for i, image in enumerate(images):
                if _found(image, alt):
                    hits += 1
                elif hits == 0 and i >= 2:
                    break      # not in the first three either: the next alternative
            if hits >= min(2, n):
                raise CalibrationError(
                    f"no board {self.board} found in the first {n} {self.what}; "
                    f"{_board_text(alt)} is found in {hits} of them: {why}. Pass "
                    f"{self.option} {_spec_text(alt)}")


def _found(image: np.ndarray, board: BoardSpec) -> bool:
    kw: dict[str, Any] = ({"detector": "classic", "fast_check": True, "fallback": False}
                          if board.kind == "chessboard" else {})
    return detect_board(image, board, refine="none", **kw).found
