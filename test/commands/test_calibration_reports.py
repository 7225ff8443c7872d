"""The HTML reports of a normal run (the bundled calibration bag): numbers rounded to the digits
they support, tables rather than raw JSON, and no CHECK or warning where nothing is wrong."""
from __future__ import annotations

import html
import json
import re
from pathlib import Path

import pytest

from eye_in_hand.cli import main

ROOT = Path(__file__).resolve().parents[2]
BAG = ROOT / "bags" / "calibration"
TOPICS = ["/stereo/left/image_raw", "/stereo/right/image_raw"]
BOARD = "chessboard:9x6:0.025"

#: at most this many significant digits in any number of a report's text (a quaternion
#: component to 1e-6, a focal length to 0.001 px: 6 digits)
MAX_DIGITS = 6


def report_text(path: Path) -> str:
    """The visible text of a report: no style sheet, no embedded images, no tags."""
    page = path.read_text()
    page = re.sub(r"<style>.*?</style>", "", page, flags=re.S)
    page = re.sub(r"src='data:[^']*'", "", page)
    return html.unescape(re.sub(r"<[^>]+>", " ", page))


def long_numbers(text: str) -> list[str]:
    """Decimal numbers of more than :data:`MAX_DIGITS` significant digits."""
    out = []
    for number in re.findall(r"\d+\.\d+", text):
        digits = number.replace(".", "").lstrip("0")
        if len(digits) > MAX_DIGITS:
            out.append(number)
    return out


def test_long_numbers_finds_unrounded_floats() -> None:
    assert long_numbers("sigma 0.0577245114182452 mm") == ["0.0577245114182452"]
    assert long_numbers("fx 902.590, 0.000425 and q 0.711358, t 1700000021569766451") == []


@pytest.fixture(scope="module")
def reports(tmp_path_factory) -> dict[str, Path]:
    """A stereo and a hand-eye calibration of the bundled bag, as ``make demo`` makes them."""
    base = tmp_path_factory.mktemp("reports")
    assert main(["calibrate", "stereo", "--bag", str(BAG), "--left-topic", TOPICS[0],
                 "--right-topic", TOPICS[1], "--board", BOARD, "-o",
                 str(base / "calibration")]) == 0
    assert main(["calibrate", "handeye", "--bag", str(BAG), "--board", BOARD, "--calibration",
                 str(base / "calibration"), "--left-topic", TOPICS[0],
                 "--right-topic", TOPICS[1], "-o", str(base / "hand_eye")]) == 0
    return {"stereo": base / "calibration", "handeye": base / "hand_eye"}


@pytest.mark.parametrize("which", ["stereo", "handeye"])
def test_report_numbers_are_rounded_and_tabulated(reports, which: str) -> None:
    page = (reports[which] / "report.html").read_text()
    text = report_text(reports[which] / "report.html")
    assert not long_numbers(text), long_numbers(text)[:10]
    assert "<pre>" not in page and '"n_samples"' not in text   # no raw JSON block
    assert "<table>" in page


def test_handeye_report_of_a_normal_run_has_no_warning(reports, capsys) -> None:
    text = report_text(reports["handeye"] / "report.html")
    report = json.loads((reports["handeye"] / "report.json").read_text())
    assert report["warnings"] == [], report["warnings"]
    assert "CHECK" not in text and "warning" not in text.lower()
    # what the bag held is information, in the input table
    assert re.search(r"found\s+34 images, 15 still stops, 0 images with the robot moving", text)
    assert "Motion diagnostics" in text and "Against the ground truth" in text


def test_stereo_report_shows_values_to_the_digits_of_their_sigma(reports) -> None:
    text = report_text(reports["stereo"] / "report.html")
    m = re.search(r"\bfx\s+(\d+\.\d+)\s+(\d+\.\d+)", text)
    assert m, text[:2000]
    value, std = m.groups()
    assert len(std.replace(".", "").lstrip("0")) == 2                  # sigma: 2 digits
    assert len(value.split(".")[1]) == len(std.split(".")[1])          # value: as many decimals
    assert re.search(r"baseline \|T\| \[mm\]\s+60\.0\d+ ± 0\.\d+", text)
