"""The usual board mistakes, found after the first few images (core.calibration.board_check)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from eye_in_hand.core.calibration import BoardSpec
from eye_in_hand.core.calibration.board_check import BoardCheck, aruco_dictionaries_in
from eye_in_hand.errors import CalibrationError


def _chessboard(cols: int = 9, rows: int = 6, px: int = 40) -> np.ndarray:
    """A flat image of a chessboard with ``cols`` x ``rows`` inner corners and a white margin."""
    img = np.full(((rows + 3) * px, (cols + 3) * px), 230, np.uint8)
    for i in range(cols + 1):
        for j in range(rows + 1):
            if (i + j) % 2 == 0:
                img[(j + 1) * px:(j + 2) * px, (i + 1) * px:(i + 2) * px] = 25
    return img


def _charuco(sx: int = 7, sy: int = 5, dictionary: str = "DICT_4X4_50") -> np.ndarray:
    board = cv2.aruco.CharucoBoard((sx, sy), 0.04, 0.03,
                                   cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco,
                                                                             dictionary)))
    return board.generateImage((sx * 60 + 80, sy * 60 + 80), marginSize=40)


def _feed(check: BoardCheck, image: np.ndarray, n: int, found: bool = False) -> None:
    for _ in range(n):
        check.add(image, found)


def test_squares_counted_instead_of_inner_corners():
    check = BoardCheck(BoardSpec.parse("chessboard:10x7:0.025"), "left images", after=3)
    _feed(check, _chessboard(), 2)             # not yet: the board may come later
    with pytest.raises(CalibrationError) as info:
        _feed(check, _chessboard(), 1)
    assert str(info.value) == (
        "no board chessboard:10x7:0.025 found in the first 3 left images; a 9x6 chessboard "
        "(inner corners) is found in 3 of them: squares counted instead of inner corners (a "
        "board of 10 x 7 squares has 9 x 6 inner corners). Pass --board chessboard:9x6:0.025")


def test_a_charuco_board_given_as_a_chessboard():
    image = _charuco()
    assert aruco_dictionaries_in(image) == ["DICT_4X4_50"]
    check = BoardCheck(BoardSpec.parse("chessboard:7x5:0.04"), after=2)
    with pytest.raises(CalibrationError) as info:
        _feed(check, image, 2)
    assert "a ChArUco board of 7x5 squares (DICT_4X4_50)" in str(info.value)
    assert "Pass --board charuco:7x5:0.04:0.03:DICT_4X4_50" in str(info.value)


@pytest.mark.parametrize("spec, fix", [
    ("charuco:7x5:0.04:0.03", "the markers are DICT_4X4_50, not DICT_5X5_100"),
    ("charuco:5x7:0.04:0.03:DICT_4X4_50", "squares x and y swapped"),
    ("charuco:6x4:0.04:0.03:DICT_4X4_50", "inner corners counted instead of squares"),
])
def test_charuco_mistakes(spec, fix):
    check = BoardCheck(BoardSpec.parse(spec), after=2)
    with pytest.raises(CalibrationError) as info:
        _feed(check, _charuco(), 2)
    assert fix in str(info.value)
    assert "charuco:7x5:0.04:0.03:DICT_4X4_50" in str(info.value)


def test_a_chessboard_given_as_charuco():
    check = BoardCheck(BoardSpec.parse("charuco:10x7:0.04:0.03"), after=2)
    with pytest.raises(CalibrationError) as info:
        _feed(check, _chessboard(), 2)
    assert "a chessboard, not a ChArUco board. Pass --board chessboard:9x6:0.04" in str(
        info.value)


def test_no_check_once_the_board_was_found_or_when_nothing_else_is_there():
    check = BoardCheck(BoardSpec.parse("chessboard:10x7:0.025"), after=2)
    check.add(_chessboard(), True)
    _feed(check, _chessboard(), 5)             # found once: the board is right
    blank = np.full((300, 400), 128, np.uint8)
    check = BoardCheck(BoardSpec.parse("chessboard:9x6:0.025"), after=2)
    _feed(check, blank, 5)                     # no board at all: nothing to suggest
    assert check.done
