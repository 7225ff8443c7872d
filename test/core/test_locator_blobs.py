"""Blob sets (several blobs of one colour), their left/right association and stable ids.

Scenes are ray-cast with ``render_sphere`` into a small distorted 640x360 rig (f = 450 px,
B = 60 mm); the truth of every blob is known, so an id that changes hands is a test failure.
"""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.detection import DetectorConfig
from eye_in_hand.core.locator import StereoLocator
from eye_in_hand.core.locator_params import TARGET_PARAMETERS, locator_config_from_params
from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.sim.sphere import render_sphere

K = np.array([[450.0, 0.0, 320.0], [0.0, 452.0, 180.0], [0.0, 0.0, 1.0]])
RED, GREEN, BLUE = (30, 30, 200), (40, 200, 40), (200, 60, 30)
GREEN_P = {"targets.green.lower": [45, 120, 70], "targets.green.upper": [75, 255, 255]}
BLUE_P = {"targets.blue.lower": [100, 120, 70], "targets.blue.upper": [130, 255, 255]}


def make_rig() -> StereoRig:
    left = CameraModel(K, [-0.1, 0.03, 0.0005, -0.0003, 0.0], 640, 360)
    right = CameraModel(K + np.diag([1.5, 1.0, 0.0]), [-0.09, 0.02, 0.0, 0.0, 0.0], 640, 360)
    R = cv2.Rodrigues(np.array([0.004, -0.01, 0.002]))[0]
    return StereoRig(left, right, R, [-0.06, 0.0005, 0.0003]).rectified()


RIG = make_rig()


def render(spheres_left, spheres_right=None, seed=0):
    """Stereo pair of (centre in the left optical frame, radius, colour) spheres; a separate
    right list draws things only one camera sees (decoys)."""
    rng = np.random.default_rng(seed)
    out = []
    for cam, T, spheres in ((RIG.left, np.eye(4), spheres_left),
                            (RIG.right, RIG.right_T_left,
                             spheres_left if spheres_right is None else spheres_right)):
        img = np.clip(np.full((360, 640, 3), (90, 110, 100), float)
                      + rng.normal(0, 2, (360, 640, 3)), 0, 255).astype(np.uint8)
        for c, r, col in spheres:
            c_cam = T[:3, :3] @ np.asarray(c, float) + T[:3, 3]
            if cam.project(c_cam[None])[0, 0] > 0:   # (centre outside: not drawn)
                render_sphere(img, cam, c_cam, r, col)
        out.append(img)
    return out


def config(**extra):
    params = {"target_names": ["red"], "targets.red.radius_m": 0.012, "targets.red.count": 2}
    params.update(extra)
    return locator_config_from_params(params)


def right_twin(X, dv_px=0.0, scale=1.0):
    """A point seen in the right image on the rectified row of X (shifted dv_px) at 1.8 times
    X's disparity (about 50 px aside): a second red thing on X's epipolar line that only the
    right camera sees (the left one has it occluded)."""
    P1, P2 = RIG.P1, RIG.P2
    h = RIG.R1 @ X
    u, v = P1[0, 0] * h[0] / h[2] + P1[0, 2], P1[1, 1] * h[1] / h[2] + P1[1, 2]
    d = -P2[0, 3] / h[2]
    Z = h[2] * 1.05
    x_r = (u - 1.8 * d - P2[0, 2]) / P2[0, 0] * Z
    y_r = (v + dv_px - P2[1, 2]) / P2[1, 1] * Z
    # a point in the right rectified frame -> the left optical frame
    p_rect_r = np.array([x_r, y_r, Z])
    p_right = RIG.R2.T @ p_rect_r
    left_T_right = np.linalg.inv(RIG.right_T_left)
    return left_T_right[:3, :3] @ p_right + left_T_right[:3, 3]


def test_count_parameter_and_id_clash_are_checked():
    assert any(p.name == "count" for p in TARGET_PARAMETERS)
    cfg = config()
    assert cfg.detector.targets[0].count == 2 and cfg.stateful
    assert not locator_config_from_params({}).stateful
    with pytest.raises(ConfigError, match="targets.red.count"):
        config(**{"targets.red.count": -1})
    with pytest.raises(ConfigError, match="targets.red.count"):
        config(**{"targets.red.count": 1.5})
    spec = cfg.detector.targets[0]
    with pytest.raises(InputError, match="clash"):
        DetectorConfig(targets=(spec, dataclasses.replace(spec, name="red_1", count=1)))


def test_two_same_colour_blobs_crossing_rows_keep_their_ids():
    """A approaches and sinks, B recedes and rises: rows cross and the size order flips
    half-way, yet each id stays on its own sphere in every frame."""
    loc = StereoLocator(RIG, config())
    owner: dict[str, int] = {}
    located = 0
    for k, s in enumerate(np.linspace(0.0, 1.0, 13)):
        XA = np.array([-0.05, -0.04 + 0.08 * s, 0.52 - 0.12 * s])
        XB = np.array([0.03, 0.04 - 0.08 * s, 0.40 + 0.12 * s])
        res = loc.locate(*render([(XA, 0.012, RED), (XB, 0.012, RED)], seed=k))
        for t in res.targets:
            truth = min((0, 1), key=lambda w: np.linalg.norm(t.point_m - (XA, XB)[w]))
            assert np.linalg.norm(t.point_m - (XA, XB)[truth]) < 2e-3
            assert owner.setdefault(t.id, truth) == truth, f"frame {k}: {t.id} swapped"
            assert t.name == "red"
            located += 1
    assert sorted(owner) == ["red_0", "red_1"]
    assert located == 26    # unambiguous thanks to the depth/size gates: every frame, both


def test_crossing_without_the_size_gate_never_guesses():
    """Without the size check the swapped pairing of the crossing is plausible; the
    assignment still finds the only pairing with both blobs paired, and ids never swap."""
    loc = StereoLocator(RIG, config(size_tol=0.0))
    owner: dict[str, int] = {}
    for k, s in enumerate(np.linspace(0.0, 1.0, 9)):
        XA = np.array([-0.05, -0.04 + 0.08 * s, 0.52 - 0.12 * s])
        XB = np.array([0.03, 0.04 - 0.08 * s, 0.40 + 0.12 * s])
        res = loc.locate(*render([(XA, 0.012, RED), (XB, 0.012, RED)], seed=k))
        for t in res.targets:
            truth = min((0, 1), key=lambda w: np.linalg.norm(t.point_m - (XA, XB)[w]))
            assert np.linalg.norm(t.point_m - (XA, XB)[truth]) < 2e-3, f"frame {k}: guessed"
            assert owner.setdefault(t.id, truth) == truth
    assert len(owner) == 2


def test_a_partner_off_the_row_by_more_than_the_margin_is_not_taken():
    """Right image: a bigger red decoy on A's epipolar line, 2 px off A's row, plausible
    disparity. A first-come association (largest right blob first) takes the decoy."""
    X = np.array([0.01, 0.0, 0.45])
    decoy = right_twin(X, dv_px=2.0)
    left, right = render([(X, 0.012, RED)], [(X, 0.012, RED), (decoy, 0.0135, RED)])
    res = StereoLocator(RIG, config(**{"targets.red.count": 1})).locate(left, right)
    assert res.rejected == {} and res.ambiguous == {}
    assert np.linalg.norm(res.first.point_m - X) < 1e-3


@pytest.mark.parametrize("count", [1, 2, 0])
def test_a_blob_with_two_equally_good_partners_is_rejected_and_counted(count):
    X = np.array([0.01, 0.0, 0.45])
    decoy = right_twin(X, dv_px=0.0)
    left, right = render([(X, 0.012, RED)], [(X, 0.012, RED), (decoy, 0.0135, RED)])
    res = StereoLocator(RIG, config(**{"targets.red.count": count})).locate(left, right)
    assert res.targets == () and res.first is None
    assert res.rejected["red"] == "ambiguous" and res.ambiguous == {"red": 1}
    assert "equally well" in res.messages["red"]


def test_two_equally_good_assignments_are_rejected_unless_the_size_decides():
    """Two spheres on one row at one depth, 30 mm apart: both the true and the crossed pairing
    have positive disparities. Without the size check the two assignments are equally good
    (ambiguous, both rejected); with it the crossed pairing is implausible."""
    XA, XB = np.array([-0.015, 0.01, 0.45]), np.array([0.015, 0.01, 0.45])
    pair_ = render([(XA, 0.012, RED), (XB, 0.012, RED)])
    res = StereoLocator(RIG, config(size_tol=0.0)).locate(*pair_)
    assert res.targets == () and res.rejected["red"] == "ambiguous"
    assert res.ambiguous == {"red": 2}
    res = StereoLocator(RIG, config(size_tol=0.3)).locate(*pair_)
    assert res.rejected == {} and res.ambiguous == {}
    pts = sorted((t.point_m for t in res.targets), key=lambda p: p[0])
    assert np.linalg.norm(pts[0] - XA) < 1e-3 and np.linalg.norm(pts[1] - XB) < 1e-3


def test_a_blob_leaving_one_view_is_rejected_with_the_reason_and_the_other_keeps_its_id():
    loc = StereoLocator(RIG, config())
    XA = np.array([0.05, 0.03, 0.45])
    ids_a, ids_b = set(), set()
    # B moves left out of the right image (steps below tracking.gate_m) and back
    xs = [-0.20, -0.22, -0.24, -0.265, -0.29, -0.265, -0.24, -0.22]
    gone = 0
    for k, x in enumerate(xs):
        XB = np.array([x, -0.03, 0.45])
        res = loc.locate(*render([(XA, 0.012, RED), (XB, 0.012, RED)], seed=k))
        for t in res.targets:
            (ids_a if np.linalg.norm(t.point_m - XA) < 2e-3 else ids_b).add(t.id)
            if t.id in ids_b:
                assert np.linalg.norm(t.point_m - XB) < 2e-3
        u_right = RIG.right.project(
            (RIG.right_T_left[:3, :3] @ XB + RIG.right_T_left[:3, 3])[None])
        if u_right[0, 0] < -14:              # gone from the right image, still in the left
            gone += 1
            assert 0 < RIG.left.project(XB[None])[0, 0] < 640
            assert len(res.targets) == 1 and res.targets[0].id in ids_a
            missing = sorted(ids_b)
            assert [res.rejected[i] for i in missing] == ["not_detected_right"]
            assert res.rejected["red"] == "not_detected_right"
            assert "right" in res.messages[missing[0]]
        elif u_right[0, 0] > 14:             # wholly inside both images
            assert len(res.targets) == 2, res.rejected
    assert gone >= 1
    assert len(ids_a) == 1 and len(ids_b) == 1 and ids_a != ids_b   # B came back as itself


def test_ids_are_never_reused_and_retire_after_max_missed():
    loc = StereoLocator(RIG, config(**{"tracking.max_missed": 2}))
    XA, XB = np.array([-0.05, 0.0, 0.45]), np.array([0.05, 0.0, 0.45])
    res = loc.locate(*render([(XA, 0.012, RED), (XB, 0.012, RED)]))
    ids = {t.id: t.point_m for t in res.targets}
    b_id = min(ids, key=lambda i: np.linalg.norm(ids[i] - XB))
    a_id = ({"red_0", "red_1"} - {b_id}).pop()
    # B vanishes; a new red sphere appears far from where B was
    XC = np.array([0.0, 0.06, 0.5])
    for k in range(4):
        res = loc.locate(*render([(XA, 0.012, RED), (XC, 0.012, RED)], seed=k + 1))
        assert [t.id for t in res.targets] == [a_id, "red_2"]
        if k < 2:
            assert res.rejected == {b_id: "not_detected"}
        else:
            assert res.rejected == {}       # retired: no longer reported, and never reused
    loc.reset()
    res = loc.locate(*render([(XA, 0.012, RED)]))
    assert [t.id for t in res.targets] == ["red_0"]


def test_colours_and_blob_sets_in_one_frame():
    params = {"target_names": ["green", "red", "blue"], **GREEN_P, **BLUE_P,
              "targets.green.radius_m": 0.012, "targets.red.radius_m": 0.012,
              "targets.blue.radius_m": 0.012, "targets.red.count": 2, "targets.blue.count": 0}
    loc = StereoLocator(RIG, locator_config_from_params(params))
    truth = {"green": np.array([0.0, -0.05, 0.4]),
             "red": [np.array([-0.08, 0.0, 0.45]), np.array([0.07, 0.01, 0.5])],
             "blue": [np.array([-0.05, 0.06, 0.42]), np.array([0.02, 0.05, 0.48]),
                      np.array([0.09, 0.07, 0.44])]}
    spheres = [(truth["green"], 0.012, GREEN)] + [(X, 0.012, RED) for X in truth["red"]] + \
        [(X, 0.012, BLUE) for X in truth["blue"]]
    res = loc.locate(*render(spheres))
    assert res.rejected == {} and res.ambiguous == {}
    assert [t.id for t in res.targets] == ["green", "red_0", "red_1", "blue_0", "blue_1",
                                           "blue_2"]
    assert res.first.id == "green"
    for t in res.targets:
        cands = truth[t.name] if t.name != "green" else [truth["green"]]
        assert min(np.linalg.norm(t.point_m - X) for X in cands) < 1e-3
    assert res.get("red_1") is res.targets[2]
    # count: 2 keeps the two best (largest) of three red blobs
    three = [(np.array([-0.08, 0.0, 0.45]), 0.012, RED), (np.array([0.07, 0.01, 0.5]), 0.010,
                                                          RED),
             (np.array([0.0, 0.06, 0.45]), 0.015, RED)]
    res = StereoLocator(RIG, config()).locate(*render(three))
    assert len(res.targets) == 2 and res.rejected == {}
    assert sorted(round(float(t.point_m[0]), 2) for t in res.targets) == [-0.08, 0.0]


def test_first_of_a_blob_set_is_its_lowest_id():
    loc = StereoLocator(RIG, config())
    res = loc.locate(*render([(np.array([-0.05, 0.0, 0.45]), 0.012, RED),
                              (np.array([0.05, 0.0, 0.45]), 0.012, RED)]))
    assert res.first is res.targets[0] and res.first.id == "red_0"
    assert res.first_name == "red" and res.get("red") is res.first


def test_a_small_blob_next_to_a_big_one_of_the_same_colour_is_still_its_own_detection():
    """The full-resolution window of the small disc (margin 16 px) reaches 9 px into the big
    one, a larger component than the disc itself: the detection must be the component that
    covers the small disc's coarse blob, not the bigger neighbour (which drops the disc)."""
    from eye_in_hand.core.detection import ColorDetector

    img = np.full((360, 640, 3), (90, 110, 100), np.uint8)
    cv2.circle(img, (200, 180), 100, RED, -1)
    cv2.circle(img, (300 + 8 + 5, 180), 5, RED, -1)
    det = ColorDetector(dataclasses.replace(config().detector, roi_margin_px=16))
    found = det.candidates(img)["red"]
    assert len(found) == 2
    centres = sorted(float(d.centroid_px[0]) for d in found)
    assert abs(centres[0] - 200) < 0.5 and abs(centres[1] - 313) < 0.5


def test_the_multi_target_world_and_its_parameter_file_work_together():
    """config/world_multi.yaml (four spheres, two the same red) on its localization orbit,
    located with config/detect_triangulate_multi.yaml: every sphere, red ids on one sphere each.
    Rendered at 640x360 (intrinsics scaled) to stay fast."""
    from pathlib import Path

    from eye_in_hand.core.locator_params import load_locator_config
    from eye_in_hand.sim import World
    from eye_in_hand.sim.scenarios import localization_trajectory

    config_dir = Path(__file__).resolve().parents[2] / "config"
    world = World.from_yaml(config_dir / "world_multi.yaml").with_image_size(640, 360)
    colours = [t.color_bgr for t in world.targets]
    assert len(world.targets) >= 4 and any(colours.count(c) == 2 for c in colours)
    cfg = load_locator_config(config_dir / "detect_triangulate_multi.yaml")
    assert [t.count for t in cfg.detector.targets] == [2, 1, 1]
    loc = StereoLocator(world.rig.rectified(), cfg)
    owner: dict[str, int] = {}
    for k, (_, q) in enumerate(localization_trajectory(world, 0.2, 10.0, seed=0)):
        fr = world.render(q, seed=k, noise_sigma=1.0, supersample=2)
        assert all(0.25 < np.linalg.norm(X) < 0.65 for X in fr.truth.targets_cam)
        res = loc.locate(fr.left, fr.right)
        assert res.rejected == {} and [t.id for t in res.targets] == [
            "red_0", "red_1", "green", "blue"]
        for t in res.targets:
            d = np.linalg.norm(fr.truth.targets_cam - t.point_m, axis=1)
            assert d.min() < 1.5e-3
            assert owner.setdefault(t.id, int(np.argmin(d))) == int(np.argmin(d))
    assert sorted(owner.values()) == [0, 1, 2, 3]


def test_a_blob_missed_in_separate_single_frames_keeps_its_id():
    """``tracking.max_missed`` counts consecutive misses: a blob seen again starts from 0, so
    three single-frame misses separated by frames where it is seen (more misses in total than
    max_missed = 2) never retire its id."""
    loc = StereoLocator(RIG, config(**{"tracking.max_missed": 2}))
    XA, XB = np.array([-0.05, 0.0, 0.45]), np.array([0.05, 0.0, 0.45])
    res = loc.locate(*render([(XA, 0.012, RED), (XB, 0.012, RED)]))
    ids = {t.id: t.point_m for t in res.targets}
    b_id = min(ids, key=lambda i: np.linalg.norm(ids[i] - XB))
    for k in range(3):
        res = loc.locate(*render([(XA, 0.012, RED)], seed=2 * k + 1))        # B missed once
        assert res.rejected == {b_id: "not_detected"}
        assert res.messages[b_id].endswith("missed 1)"), res.messages[b_id]
        res = loc.locate(*render([(XA, 0.012, RED), (XB, 0.012, RED)], seed=2 * k + 2))
        got = {t.id: t.point_m for t in res.targets}
        assert set(got) == set(ids), got                                     # B as itself
        assert np.linalg.norm(got[b_id] - XB) < 2e-3 and res.rejected == {}


def test_a_blob_that_jumps_beyond_the_gate_gets_a_new_id():
    """tracking.gate_m (0.03 m) is the largest step a blob keeps its id over: a blob 5 cm from
    its last position is a new blob (its old id is reported missing), one 2 cm away is not."""
    loc = StereoLocator(RIG, config())
    XA, XB = np.array([-0.08, 0.0, 0.45]), np.array([0.05, 0.0, 0.45])
    res = loc.locate(*render([(XA, 0.012, RED), (XB, 0.012, RED)]))
    ids = {t.id: t.point_m for t in res.targets}
    b_id = min(ids, key=lambda i: np.linalg.norm(ids[i] - XB))
    XB2 = XB + [0.02, 0.0, 0.0]
    res = loc.locate(*render([(XA, 0.012, RED), (XB2, 0.012, RED)], seed=1))
    assert {t.id for t in res.targets} == set(ids) and res.rejected == {}
    XB3 = XB2 + [0.05, 0.0, 0.0]
    res = loc.locate(*render([(XA, 0.012, RED), (XB3, 0.012, RED)], seed=2))
    got = {t.id: t.point_m for t in res.targets}
    assert b_id not in got and "red_2" in got, got
    assert np.linalg.norm(got["red_2"] - XB3) < 2e-3
    assert res.rejected == {b_id: "not_detected"}


def test_a_blob_after_a_retired_id_gets_a_fresh_id():
    """Ids count up over the whole run: a new blob after an id retired gets the next id, not
    the retired one's number nor one counted from the blobs now known."""
    loc = StereoLocator(RIG, config(**{"tracking.max_missed": 1, "targets.red.count": 0}))
    XA, XB = np.array([-0.05, 0.0, 0.45]), np.array([0.05, 0.0, 0.45])
    XC, XD = np.array([0.0, 0.06, 0.5]), np.array([0.02, -0.06, 0.5])
    res = loc.locate(*render([(XA, 0.012, RED), (XB, 0.012, RED)]))
    assert sorted(t.id for t in res.targets) == ["red_0", "red_1"]
    a_id = min(res.targets, key=lambda t: np.linalg.norm(t.point_m - XA)).id
    for k in range(2):                                   # B missed twice: retired
        res = loc.locate(*render([(XA, 0.012, RED)], seed=k + 1))
    assert [t.id for t in res.targets] == [a_id] and res.rejected == {}
    res = loc.locate(*render([(XA, 0.012, RED), (XC, 0.012, RED)], seed=5))
    assert [t.id for t in res.targets] == [a_id, "red_2"]
    res = loc.locate(*render([(XA, 0.012, RED), (XC, 0.012, RED), (XD, 0.012, RED)], seed=6))
    assert [t.id for t in res.targets] == [a_id, "red_2", "red_3"]


def test_the_size_gate_refuses_a_sphere_too_small_for_its_disparity():
    """The size check is two-sided: a sphere half the configured radius looks twice as far
    as its disparity says (factor 2 > 1 + size_tol = 1.5), and is refused like one twice as
    big."""
    X = np.array([0.0, 0.0, 0.45])
    for r in (0.006, 0.024):
        loc = StereoLocator(RIG, config(size_tol=0.5, **{"targets.red.count": 1}))
        res = loc.locate(*render([(X, r, RED)]))
        assert res.targets == () and set(res.rejected.values()) == {"size"}, (r, res.rejected)
    res = StereoLocator(RIG, config(size_tol=0.5, **{"targets.red.count": 1})).locate(
        *render([(X, 0.012, RED)]))
    assert len(res.targets) == 1


def test_ids_follow_the_nearest_known_blob_when_both_are_within_the_gate():
    """With a wide gate (10 cm) both known blobs are candidates for both new ones: each id
    goes to the blob nearest its last position (smallest summed distance), as A and B pass
    each other left to right 6 cm apart in height."""
    loc = StereoLocator(RIG, config(**{"tracking.gate_m": 0.1}))
    owner: dict[str, int] = {}
    for k, x in enumerate(np.linspace(-0.04, 0.04, 5)):
        XA, XB = np.array([x, -0.03, 0.45]), np.array([-x, 0.03, 0.45])
        res = loc.locate(*render([(XA, 0.012, RED), (XB, 0.012, RED)], seed=k))
        assert len(res.targets) == 2
        for t in res.targets:
            truth = min((0, 1), key=lambda w: np.linalg.norm(t.point_m - (XA, XB)[w]))
            assert owner.setdefault(t.id, truth) == truth, f"frame {k}: {t.id} swapped"
    assert sorted(owner) == ["red_0", "red_1"]
