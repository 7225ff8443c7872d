"""``eye-in-hand calibrate plan``: the next poses from a rendered stereo dataset; errors."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from eye_in_hand.cli import main
from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.handeye.synthetic import make_problem
from eye_in_hand.core.transforms import from_xyz_quat, invert
from eye_in_hand.io.datasets import write_dataset


def _load_renderer():
    """``calibrate handeye``'s test renderer (fast anti-aliased boards), not a copy of it."""
    import importlib.util

    path = Path(__file__).with_name("test_calibrate_handeye.py")
    spec = importlib.util.spec_from_file_location("_handeye_test_renderer", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module._render


_render = _load_renderer()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> tuple[Path, object]:
    cam = CameraModel(K=np.array([[560.0, 0, 320], [0, 560.0, 200], [0, 0, 1]]),
                      dist=np.array([-0.1, 0.05, 0, 0, 0]), width=640, height=400, name="left")
    P = make_problem(6, seed=5, stereo=True, noise_px=0.0, camera=cam)
    right = P.views[1]
    rig = StereoRig(left=cam, right=right.model, R=right.view_T_cam[:3, :3],
                    T=right.view_T_cam[:3, 3])
    images = [{v.name: _render(v.model, v.view_T_cam @ C) for v in P.views}
              for C in P.true_cam_T_board]
    root = tmp_path_factory.mktemp("plan_ds")
    write_dataset(root, setup="eye_in_hand", board="chessboard:9x6:0.025", images=images,
                  base_T_ee=list(P.true_base_T_ee), rig=rig)
    return root, P


def test_plan_prints_and_writes_the_next_poses(dataset, tmp_path: Path, capsys) -> None:
    root, P = dataset
    out = tmp_path / "plan.yaml"
    args = ["calibrate", "plan", str(root), "--count", "2", "--robot-sigma-mm", "0.1",
            "--candidates", "200", "-o", str(out)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "predicted 1-sigma now:" in printed
    assert "  1: xyz [" in printed and "  2: xyz [" in printed and "  3: xyz" not in printed
    doc = yaml.safe_load(out.read_text())
    assert doc["setup"] == "eye_in_hand" and doc["samples"] == 6
    assert doc["noise"]["robot_translation_m"] == pytest.approx(1e-4)
    sug = doc["suggestions"]
    assert len(sug) == 2
    assert sug[0]["std_mm"] < doc["std_mm"] and sug[1]["std_mm"] < sug[0]["std_mm"]
    for s in sug:
        B = from_xyz_quat(s["base_T_ee"]["xyz"], s["base_T_ee"]["quat_xyzw"])
        C = from_xyz_quat(s["cam_T_board"]["xyz"], s["cam_T_board"]["quat_xyzw"])
        # the board as the camera would see it at that flange pose (true X and board pose)
        C_true = invert(P.X) @ invert(B) @ P.Y
        assert np.linalg.norm(C[:3, 3] - C_true[:3, 3]) < 0.005
        assert f"{s['distance_m']:.3f} m" in printed
    # an existing file is refused without --overwrite, and left as it was
    before = out.read_text()
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists already" in err and "--overwrite" in err
    assert out.read_text() == before
    assert main([*args[:-2], "--seed", "1", "-o", str(out), "--overwrite"]) == 0
    assert yaml.safe_load(out.read_text())["suggestions"] != sug


@pytest.mark.parametrize("extra, message", [
    ([], "give exactly one input"),
    (["DATASET", "--count", "0"], "argument --count: must be an integer within [1, 20], got 0"),
    (["DATASET", "--max-tilt", "95"], "argument --max-tilt: must be within (0, 89.9] deg"),
    (["DATASET", "--robot-sigma-mm", "-1"], "argument --robot-sigma-mm: must be within [0, 100]"),
    (["DATASET", "--criterion", "volume"], "argument --criterion: invalid choice: 'volume'"),
    (["DATASET", "-o", "FOLDER"], "is a folder"),
])
def test_bad_options_are_refused_before_the_work(dataset, tmp_path: Path, capsys, extra,
                                                 message) -> None:
    root, _ = dataset
    argv = ["calibrate", "plan"] + [str(root) if a == "DATASET" else
                                    str(tmp_path) if a == "FOLDER" else a for a in extra]
    try:
        code = main(argv)
    except SystemExit as exc:          # refused by the parser: exit 2
        code = exc.code
    assert code == (2 if message.startswith("argument") else 1)
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err


def test_too_few_usable_samples(tmp_path: Path, capsys) -> None:
    cam = CameraModel(K=np.array([[560.0, 0, 320], [0, 560.0, 200], [0, 0, 1]]),
                      dist=np.zeros(5), width=640, height=400, name="left")
    P = make_problem(3, seed=2, noise_px=0.0, camera=cam)
    images = [{"image": _render(cam, C)} for C in P.true_cam_T_board]
    images[2] = {"image": np.full((400, 640), 110, np.uint8)}       # no board
    write_dataset(tmp_path / "ds", setup="eye_in_hand", board="chessboard:9x6:0.025",
                  images=images, base_T_ee=list(P.true_base_T_ee), camera=cam)
    assert main(["calibrate", "plan", str(tmp_path / "ds")]) == 1
    err = capsys.readouterr().err
    assert "only 2 usable samples" in err and "need at least 3" in err
