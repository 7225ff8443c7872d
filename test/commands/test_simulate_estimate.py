"""``simulate`` says what it will write before it starts (pairs, time, disk), and a small
calibration bag (few stops, still images only) is quick to make and still calibrates."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from eye_in_hand.cli import main
from eye_in_hand.sim.output import recording_counts

#: docs/simulator.md: the disk estimate of a run is within this factor of what it writes
FACTOR = 1.5


def _estimate(err: str) -> tuple[int, float]:
    m = re.search(r"simulate: (\d+) stereo pairs at \d+x\d+: about [\d.,]+ (?:s|min|h) and "
                  r"([\d.,]+) MB on disk", err)
    assert m, err
    return int(m.group(1)), float(m.group(2).replace(",", "")) * 1e6


def _written(out: str) -> tuple[int, float, Path]:
    m = re.search(r"wrote bag (\S+) \(mcap, [\d.]+ MB\): (\d+) stereo pairs", out)
    assert m, out
    path = Path(m.group(1))
    return int(m.group(2)), sum(p.stat().st_size for p in path.rglob("*") if p.is_file()), path


def test_recording_counts_of_the_calibration_time_line() -> None:
    # the bundled calibration bag: 15 stops, 2 settled images each (+1 at some stops)
    assert recording_counts("calibration", 15, hold_frames=2, still_images_only=True) == (34,
                                                                                            3181)
    moving, robot = recording_counts("calibration", 16)
    still, robot_still = recording_counts("calibration", 16, still_images_only=True)
    assert robot == robot_still and moving > 10 * still
    assert recording_counts("localization", 90) == (90, 376)


@pytest.mark.parametrize("noise", ["1", "0"])
def test_estimate_is_close_to_what_is_written(tmp_path: Path, capsys, noise: str) -> None:
    out = tmp_path / "loc"
    assert main(["simulate", "--scenario", "localization", "--frames", "4", "--size", "320x180",
                 "--supersample", "1", "--noise", noise, "-o", str(out)]) == 0
    captured = capsys.readouterr()
    pairs, disk = _estimate(captured.err)
    written, size, _ = _written(captured.out)
    assert pairs == written
    assert 1 / FACTOR <= disk / size <= FACTOR, (disk, size)


def test_small_still_only_calibration_bag_states_its_cost_and_calibrates(tmp_path: Path,
                                                                         capsys) -> None:
    bag = tmp_path / "calib"
    assert main(["simulate", "--scenario", "calibration", "--frames", "6", "--still-images-only",
                 "--hold-frames", "1", "--size", "640x360", "--noise", "0", "-o",
                 str(bag)]) == 0
    captured = capsys.readouterr()
    pairs, disk = _estimate(captured.err)
    written, size, _ = _written(captured.out)
    assert pairs == written == 8       # one settled image per stop, two at some
    assert 1 / FACTOR <= disk / size <= FACTOR, (disk, size)
    assert main(["calibrate", "handeye", "--bag", str(bag), "--board", "chessboard:9x6:0.025",
                 "--no-html", "-o", str(tmp_path / "hand_eye")]) == 0
    assert (tmp_path / "hand_eye" / "hand_eye.yaml").is_file()


def test_calibration_estimate_names_the_smaller_still_only_bag(tmp_path: Path, capsys) -> None:
    """A calibration bag films the moves between its stops: the estimate says so and what
    ``--still-images-only`` would cost instead (refused here for want of disk, so that
    nothing is rendered)."""
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    real = shutil.disk_usage
    try:
        shutil.disk_usage = lambda _p: usage(1 << 30, 1 << 30, 1000)   # type: ignore[assignment]
        assert main(["simulate", "--scenario", "calibration", "-o",
                     str(tmp_path / "c")]) == 1
    finally:
        shutil.disk_usage = real    # type: ignore[assignment]
    err = capsys.readouterr().err
    m = re.search(r"simulate: (\d+) stereo pairs at 1280x720: about (\d+) min and ([\d,]+) MB "
                  r"on disk.*; with --still-images-only: (\d+) pairs, about (\d+) min and "
                  r"(\d+) MB", err)
    assert m, err
    assert int(m.group(1)) > 10 * int(m.group(4))
    assert float(m.group(3).replace(",", "")) > 10 * float(m.group(6))
