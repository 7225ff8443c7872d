"""Consistency of the camera-frame point covariance (``target/point_cov``) against the simulator.

Run:  .venv/bin/python benchmarks/bench_point_cov.py [--views N] [--test-views N]

With the true stereo rig (``World.default().rig.rectified()``, no calibration error) and
``config/eye_in_hand.yaml``, on two orbits rendered like the benchmarks' (1280x720, sensor noise
1 grey level, supersample 3):

* the benchmark orbit: the localization bag of ``bench_localization.py --consistency-only``
  (trajectory seed 22, 90 views at 30 Hz, the same render seeds; ideal arm);
* the ``test/sim/test_nees.py`` orbit (trajectory seed 4, sampled at 3 Hz, 25 views).

Per orbit it prints

* the centre error of each image against the true projected sphere centre, per image axis:
  its mean over the orbit (systematic), its spread (random) and the part common to the left and
  right images (``E[e_left e_right]``) that the model's edge and shading terms leave out;
* the camera-frame point's NEES (3 dof, consistent: [1.5, 6]) and 95 % coverage, and the same
  split into the two directions across the line of sight (lateral, 2 dof) and along it (depth,
  1 dof), with the errors and the reported sigmas in mm;

once with the per-detection covariance as the locator reports it, once without its blur terms
(``SHADE_BLUR_GAIN = CUT_BLUR_GAIN = 0``: the shading and threshold-cut terms as measured
without blur, the model before the detection's blur estimate) and once with its threshold-cut
term set to zero (``CUT_SIGMA_PX = 0``, the model before that term), for comparison.

``--blur SIGMA`` renders the two orbits with a Gaussian blur (the bags are rendered without);
the detector's blur estimate (``Detection.blur_px``, from the edge width) is printed with the
centre errors.

Then the threshold cut alone (``--cut-views``, 0 = skip): the test_nees orbit in flat light
(ambient 1: no shading), each image rendered with its exact anti-aliased coverage map; the
binary blob's centroid against the coverage-weighted centroid (the cut's error; its part common
to the two images ``E[e_l e_r]`` is what ``CUT_SIGMA_PX`` covers), and the coverage centroid
against the true silhouette centroid (the reference's own error).
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

import eye_in_hand.core.detection as detection
from eye_in_hand.core.locator import StereoLocator
from eye_in_hand.core.locator_params import load_locator_config
from eye_in_hand.sim import World
from eye_in_hand.sim.output import _IMAGE_CLOCK_OFFSET_NS, _interp_q, joint_samples
from eye_in_hand.sim.robot_error import RobotErrorSpec
from eye_in_hand.sim.scenarios import localization_trajectory

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "config" / "eye_in_hand.yaml"
CHI2_95 = {1: 3.8415, 2: 5.9915, 3: 7.8147}


def benchmark_orbit(world: World, views: int) -> list[tuple[np.ndarray, int]]:
    """(q, render seed) of the bench_localization consistency bag's images (write_bag's)."""
    seed = 22
    stamps_l, qs, _ = joint_samples(world, "localization", frames=views, seed=seed)
    stamps = np.array(stamps_l, dtype=np.int64)
    t, out = int(stamps[0]) + _IMAGE_CLOCK_OFFSET_NS, []
    while t <= stamps[-1] and len(out) < views:
        out.append((_interp_q(stamps, qs, t)[0], seed * 1_000_003 + len(out)))
        t += int(round(1e9 / 30.0))
    return out


def test_orbit(world: World, views: int) -> list[tuple[np.ndarray, int]]:
    """(q, render seed) of test/sim/test_nees.py's orbit, continued to ``views`` views."""
    traj = localization_trajectory(world, views / 3.0, 3.0, seed=4)
    return [(q, k) for k, (_, q) in enumerate(traj)][:views]


def render(world: World, jobs: list[tuple[np.ndarray, int]], blur: float = 0.0) -> list:
    return [world.render(q, seed=s, noise_sigma=1.0, supersample=3, blur_sigma=blur)
            for q, s in jobs]


def measure(loc: StereoLocator, frames: list) -> dict[str, np.ndarray]:
    """Per view: pixel errors (4,), pixel covariance (4, 4), point error (3,), covariance,
    truth."""
    e_px, corr, S, e, P, truth, blur, shade = [], [], [], [], [], [], [], []
    for f in frames:
        t = loc.locate(f.left, f.right).first
        if t is None:
            continue
        e_px.append(np.concatenate([t.left_px - f.truth.center_px_left[0],
                                    t.right_px - f.truth.center_px_right[0]]))
        # the sphere-centre correction's own error: the centre's error minus the centroid's
        corr.append(e_px[-1] - np.concatenate([
            t.left.centroid_px - f.truth.silhouette_centroid_px_left[0],
            t.right.centroid_px - f.truth.silhouette_centroid_px_right[0]]))
        S.append(loc._pixel_cov(t.left, t.right)[1])
        e.append(t.point_m - f.truth.targets_cam[0])
        P.append(t.covariance)
        truth.append(f.truth.targets_cam[0])
        blur.append([t.left.blur_px, t.right.blur_px])
        shade.append(np.concatenate([t.left.shade_px, t.right.shade_px]))
    return {k: np.array(v) for k, v in
            (("e_px", e_px), ("corr", corr), ("S", S), ("e", e), ("P", P), ("truth", truth),
             ("blur", blur), ("shade", shade))}


def lateral_basis(p: np.ndarray) -> np.ndarray:
    """(3, 3): two unit vectors across the line of sight to ``p``, then the line of sight."""
    z = p / np.linalg.norm(p)
    a = np.cross(z, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    return np.stack([a, np.cross(z, a), z])


def print_pixels(m: dict[str, np.ndarray]) -> None:
    e, S = m["e_px"], m["S"]
    mean, std = e.mean(axis=0), e.std(axis=0)
    sig = np.sqrt(np.mean([np.diag(s) for s in S], axis=0))
    print("  centre error vs the true sphere centre (px; x, y per image): "
          f"left mean {mean[0]:+.3f} {mean[1]:+.3f}, spread {std[0]:.3f} {std[1]:.3f}; "
          f"right mean {mean[2]:+.3f} {mean[3]:+.3f}, spread {std[2]:.3f} {std[3]:.3f}; "
          f"model sigma (RMS) left {sig[0]:.3f} {sig[1]:.3f}, right {sig[2]:.3f} {sig[3]:.3f}")
    b = m["blur"]
    print(f"  the detector's blur estimate (Detection.blur_px): mean {b.mean():.3f} px, "
          f"{b.min():.3f}-{b.max():.3f} px")
    # the shading gain this orbit shows: least squares of the left/right-mean error on the
    # left/right-mean brightness asymmetry g (shade_px = SHADE_GAIN (1 + SHADE_BLUR_GAIN b^2) g)
    grow = 1.0 + detection.SHADE_BLUR_GAIN * b ** 2
    g = m["shade"] / (detection.SHADE_GAIN * np.repeat(grow, 2, axis=1))
    c, gc = (e[:, :2] + e[:, 2:]) / 2, (g[:, :2] + g[:, 2:]) / 2
    gain = float(gc.ravel() @ c.ravel()) / float(gc.ravel() @ gc.ravel())
    b2 = float(np.mean(b ** 2))
    implied = (gain / detection.SHADE_GAIN - 1.0) / b2 if b2 > 0.01 else float("nan")
    res = c - detection.SHADE_GAIN * grow.mean(axis=1)[:, None] * gc
    print(f"  shading: least-squares gain of the left/right-mean error on g {gain:.4f} "
          f"({gain / detection.SHADE_GAIN:.2f} x SHADE_GAIN; with mean b^2 {b2:.3f}: "
          f"SHADE_BLUR_GAIN {implied:.2f}, the model's {detection.SHADE_BLUR_GAIN:g}); the "
          f"left/right-mean error after the model's shading term {np.sqrt(np.mean(res ** 2)):.4f}"
          f" px RMS over the axes")
    cross = np.mean(e[:, :2] * e[:, 2:], axis=0)             # E[e_l e_r], per axis
    cross_model = np.mean(S[:, [0, 1], [2, 3]], axis=0)
    corr = [np.corrcoef(e[:, k], e[:, 2 + k])[0, 1] for k in (0, 1)]
    cut2 = np.mean((1.0 + detection.CUT_BLUR_GAIN * b[:, 0]) *
                   (1.0 + detection.CUT_BLUR_GAIN * b[:, 1]))
    beyond = cross - (cross_model - cut2 * detection.CUT_SIGMA_PX ** 2)
    print(f"  common to left and right: E[e_l e_r] x {cross[0]:+.5f} y {cross[1]:+.5f} px^2 "
          f"(correlation {corr[0]:+.2f} {corr[1]:+.2f}); model {cross_model[0]:.5f} "
          f"{cross_model[1]:.5f} px^2; beyond the shading term: x {beyond[0]:+.5f} y "
          f"{beyond[1]:+.5f} px^2, {np.sqrt(max(beyond.mean(), 0.0)):.3f} px RMS over the axes "
          f"(CUT_SIGMA_PX {detection.CUT_SIGMA_PX:g}, times 1 + CUT_BLUR_GAIN b)")
    zd = [np.array([(u @ x) / np.sqrt(u @ s_ @ u) for x, s_ in zip(e, S, strict=False)])
          for u in (np.array([1.0, 0, -1.0, 0]), np.array([0, 1.0, 0, -1.0]))]
    c = m["corr"]
    print(f"  left - right (what the depth sees) over the model's sigma: RMS x "
          f"{np.sqrt(np.mean(zd[0] ** 2)):.2f} y {np.sqrt(np.mean(zd[1] ** 2)):.2f} "
          "(1 when right);"
          f" the sphere-centre correction's own error: mean {np.abs(c.mean(axis=0)).max():.4f} px"
          f" at most, spread {c.std(axis=0).max():.4f} px at most")


def print_point(m: dict[str, np.ndarray], label: str) -> None:
    m2, lat, dep, el, sl, ed, sd = [], [], [], [], [], [], []
    for e, P, p in zip(m["e"], m["P"], m["truth"], strict=False):
        m2.append(float(e @ np.linalg.solve(P, e)))
        B = lateral_basis(p)
        x, C = B @ e, B @ P @ B.T
        lat.append(float(x[:2] @ np.linalg.solve(C[:2, :2], x[:2])))
        dep.append(float(x[2] ** 2 / C[2, 2]))
        el.append(x[:2])
        sl.append(np.sqrt(np.diag(C)[:2]))
        ed.append(x[2])
        sd.append(np.sqrt(C[2, 2]))
    m2, lat, dep = np.array(m2), np.array(lat), np.array(dep)
    el, sl = np.array(el) * 1e3, np.array(sl) * 1e3
    ed, sd = np.array(ed) * 1e3, np.array(sd) * 1e3
    print(f"  {label}: NEES {m2.mean():.2f} (3 dof, consistent 1.5-6), 95 % coverage "
          f"{100 * np.mean(m2 <= CHI2_95[3]):.1f} %; lateral NEES {lat.mean():.2f} (2 dof), "
          f"coverage {100 * np.mean(lat <= CHI2_95[2]):.1f} %; depth NEES {dep.mean():.2f} "
          f"(1 dof), coverage {100 * np.mean(dep <= CHI2_95[1]):.1f} %")
    print(f"      lateral error RMS {np.sqrt(np.mean(el ** 2)):.4f} mm (mean "
          f"{el[:, 0].mean():+.4f}, {el[:, 1].mean():+.4f} mm), sigma {sl.min():.4f}-"
          f"{sl.max():.4f} mm (RMS {np.sqrt(np.mean(sl ** 2)):.4f}); depth error RMS "
          f"{np.sqrt(np.mean(ed ** 2)):.4f} mm (mean {ed.mean():+.4f}), sigma RMS "
          f"{np.sqrt(np.mean(sd ** 2)):.4f} mm")


def print_cut(loc: StereoLocator, world: World, views: int) -> None:
    """The threshold cut's error in flat light against the exact coverage centroid."""
    flat = dataclasses.replace(world, ambient=1.0)
    cut, ref = [], []
    for q, s in test_orbit(flat, views):
        f = flat.render(q, seed=s, noise_sigma=1.0, supersample=3, with_coverage=True)
        t = loc.locate(f.left, f.right).first
        if t is None:
            continue
        row_c, row_r = [], []
        for det, cov, sil in ((t.left, f.coverage_left, f.truth.silhouette_centroid_px_left),
                              (t.right, f.coverage_right, f.truth.silhouette_centroid_px_right)):
            c = cov[0]
            ys, xs = np.nonzero(c > 0)
            w = c[ys, xs]
            cc = np.array([w @ xs, w @ ys]) / w.sum()
            row_c.append(det.centroid_px - cc)
            row_r.append(cc - sil[0])
        cut.append(np.concatenate(row_c))
        ref.append(np.concatenate(row_r))
    e, r = np.array(cut), np.array(ref)
    common = np.mean(e[:, :2] * e[:, 2:], axis=0)
    rms = float(np.sqrt(max(common.mean(), 0.0)))
    print(f"threshold cut, test_nees orbit in flat light ({len(e)} views): binary centroid - "
          f"coverage centroid RMS left {np.sqrt(np.mean(e[:, 0] ** 2)):.3f} "
          f"{np.sqrt(np.mean(e[:, 1] ** 2)):.3f} px, right {np.sqrt(np.mean(e[:, 2] ** 2)):.3f} "
          f"{np.sqrt(np.mean(e[:, 3] ** 2)):.3f} px (mean {e.mean(axis=0).round(3)}); common to "
          f"left and right E[e_l e_r] x {common[0]:+.5f} y {common[1]:+.5f} px^2: "
          f"{np.sqrt(max(common[0], 0.0)):.3f}, {np.sqrt(max(common[1], 0.0)):.3f} px, "
          f"{rms:.3f} px RMS over the axes (CUT_SIGMA_PX {detection.CUT_SIGMA_PX:g}); "
          f"coverage centroid - true silhouette centroid RMS {np.sqrt(np.mean(r ** 2)):.4f} px")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--views", type=int, default=90, help="benchmark-orbit views (90)")
    parser.add_argument("--test-views", type=int, default=25,
                        help="test_nees-orbit views (25)")
    parser.add_argument("--blur", type=float, default=0.0,
                        help="Gaussian blur of the orbits' renders (px, 1 sigma; default 0, "
                             "as the benchmarks' bags): where the model's terms were not "
                             "measured")
    parser.add_argument("--cut-views", type=int, default=25,
                        help="flat-light views of the threshold-cut part (25; 0 = skip)")
    args = parser.parse_args()
    world = World.default().with_robot_error(RobotErrorSpec.none())
    loc = StereoLocator(world.rig.rectified(), load_locator_config(CONFIG))
    cut = detection.CUT_SIGMA_PX
    gains = detection.SHADE_BLUR_GAIN, detection.CUT_BLUR_GAIN
    for name, jobs in ((f"benchmark orbit (seed 22, {args.views} views at 30 Hz)",
                        benchmark_orbit(world, args.views) if args.views > 0 else []),
                       (f"test_nees orbit (seed 4, {args.test_views} views at 3 Hz)",
                        test_orbit(world, args.test_views) if args.test_views > 0 else [])):
        if not jobs:
            continue
        t0 = time.perf_counter()
        frames = render(world, jobs, args.blur)
        blur = f" blurred {args.blur:g} px" if args.blur > 0 else ""
        print(f"{name}: rendered {len(frames)} pairs{blur} in "
              f"{time.perf_counter() - t0:.0f} s, "
              f"true rig, {CONFIG.name}", flush=True)
        for c, g, label in (
                (cut, gains, f"as reported (threshold-cut term {cut:g} px, blur terms)"),
                (cut, (0.0, 0.0), "without the blur terms (the unblurred model)"),
                (0.0, (0.0, 0.0), "without the blur terms and the threshold-cut term")):
            detection.CUT_SIGMA_PX = c
            detection.SHADE_BLUR_GAIN, detection.CUT_BLUR_GAIN = g
            try:
                m = measure(loc, frames)
            finally:
                detection.CUT_SIGMA_PX = cut
                detection.SHADE_BLUR_GAIN, detection.CUT_BLUR_GAIN = gains
            if g == gains:
                print_pixels(m)
            print_point(m, label)
    if args.cut_views > 0:
        print_cut(loc, world, args.cut_views)
    return 0


if __name__ == "__main__":
    sys.exit(main())
