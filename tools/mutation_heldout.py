"""Held-out planted bugs: batches of realistic one-line bugs that are *not* in
:data:`mutation.MUTANTS`, to measure how far the suite stands for bugs nobody wrote a test for.

``tools/mutation.py``'s table is what ``make mutation`` insists on: every bug in it was planted
once and a test was written where none caught it, so its score is 100 % by construction. These
batches are the honest figure: each was written without looking at which tests exist for the
bug (batch 2 after batch 1's survivors had got tests) and is run against a *broad* selection of
tests per module (:func:`broad_tests`): the module's own tests (``mutation.TESTS``) plus every
test file that imports the module, leaving out the slow whole-system tests
(:data:`SLOW`) unless the module is a node. Batch 1's survivors got tests and joined
``mutation.MUTANTS``; batch 2 is the measurement of the 95 % target (docs/development.md).

Usage::

    .venv/bin/python tools/mutation_heldout.py --batch 2          # run batch 2, 2 workers
    .venv/bin/python tools/mutation_heldout.py --batch 1 -k select
    .venv/bin/python tools/mutation_heldout.py --batch 2 --list   # mutants and their tests
    .venv/bin/python tools/mutation_heldout.py --batch 3 --list   # the third batch (a record)

Options other than ``--batch`` are those of ``tools/mutation.py`` (``-k``, ``-j``, ``-v``,
``--list``, ``--baseline``, ``--timeout``); it runs with the same machinery (private copies of
the tree, ``pytest -x`` per mutant). Mutants that became stale (the code moved on) are reported
as such and are not re-anchored: a batch is a record of one measurement.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mutation  # noqa: E402
from mutation import Mutant as M  # noqa: E402

ROOT = mutation.ROOT

#: Whole-system tests left out of the broad selection unless the mutated module is a node
#: (minutes each: the demo, the README tour, the docs' runnable examples, the live cell).
SLOW = ("test/test_demo.py", "test/test_readme_tour.py", "test/test_docs_examples.py",
        "test/nodes/test_live_cell_calibration.py")


#: Modules whose users reach them through another module (a re-export, a mixin): the
#: modules whose importers count as theirs too.
REACHED_THROUGH = {"io/bag_samples.py": ("io/datasets.py",),
                   "nodes/hand_eye_targets.py": ("nodes/hand_eye.py",),
                   "nodes/hand_eye_tf.py": ("nodes/hand_eye.py",)}


def _importers(module: str) -> list[str]:
    dotted = "eye_in_hand." + module[:-3].replace("/", ".")
    parent, name = dotted.rsplit(".", 1)
    pat = re.compile(re.escape(dotted) + r"(?![\w])|from\s+" + re.escape(parent)
                     + r"\s+import\s+\(?[\w\s,]*?\b" + re.escape(name) + r"\b")
    return [f.relative_to(ROOT).as_posix() for f in sorted((ROOT / "test").rglob("test_*.py"))
            if pat.search(f.read_text(encoding="utf-8"))]


def broad_tests(module: str) -> tuple[str, ...]:
    """The module's own tests, then every test file that imports it (by its dotted name, or
    ``from <package> import ... <name>``; with :data:`REACHED_THROUGH`, those of the modules it
    is reached through), sorted; :data:`SLOW` left out unless ``module`` is a node."""
    own = list(mutation.TESTS.get(module, ()))
    users = set(_importers(module))
    for other in REACHED_THROUGH.get(module, ()):
        users |= set(_importers(other))
    found = sorted(rel for rel in users
                   if rel not in own and (rel not in SLOW or module.startswith("nodes/")))
    return tuple(own + found)


_local = threading.local()


def _run_tests(tree: Path, tests: tuple[str, ...], timeout_s: float) -> tuple[bool, float]:
    """:func:`mutation._run_tests`, keeping the first failing test's id (printed with the
    mutant's line) so that a catch can be checked against the unmutated tree."""
    t0 = time.monotonic()
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1",
           "PYTHONPATH": os.pathsep.join([str(tree)] + ([os.environ["PYTHONPATH"]]
                                                       if os.environ.get("PYTHONPATH")
                                                       else []))}
    _local.failure = ""
    try:
        proc = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p",
                               "no:cacheprovider", "-rfE", *tests], cwd=tree,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              timeout=timeout_s, env=env)
        passed = proc.returncode == 0
        if not passed:
            lines = [ln for ln in proc.stdout.splitlines() if ln.startswith(("FAILED", "ERROR"))]
            _local.failure = lines[0] if lines else proc.stdout.strip().splitlines()[-1:][0] \
                if proc.stdout.strip() else f"exit status {proc.returncode}"
    except subprocess.TimeoutExpired:
        passed = False
        _local.failure = "time-out"
    return passed, time.monotonic() - t0


def _print(*args: object, **kwargs: object) -> None:
    text = " ".join(str(a) for a in args)
    failure = getattr(_local, "failure", "")
    if failure and text.startswith("caught"):
        text += f"\n             by {failure[:160]}"
    print(text, **kwargs)  # type: ignore[call-overload]


B1: tuple[M, ...] = (
    # -- core/handeye/average.py
    M("avg-parallel-counted-twice", "core/handeye/average.py",
      "    parallel = ~small & (sep < min_axis_angle_deg)\n",
      "    parallel = (sep < min_axis_angle_deg)\n",
      "a pair with a small rotation is counted under parallel axes too (counted twice)"),
    M("avg-geodesic-step-side", "core/handeye/average.py",
      "            M = M @ Rotation.from_rotvec(step).as_matrix()\n",
      "            M = Rotation.from_rotvec(step).as_matrix() @ M\n",
      "the Karcher mean's step applied on the wrong side"),
    M("avg-rot-dev-transpose", "core/handeye/average.py",
      '        Rotation.from_matrix(np.einsum("ji,kjl->kil", R, Xs[:, :3, :3])).as_rotvec(), '
      'axis=1))\n',
      '        Rotation.from_matrix(np.einsum("ij,kjl->kil", R, Xs[:, :3, :3])).as_rotvec(), '
      'axis=1))\n',
      "the per-pair rotation spread measured against R, not R^T (transpose missing)"),
    M("avg-kron-eigvec-index", "core/handeye/average.py",
      "    v = vecs[:, :, 0]                                  # smallest eigenvalue\n",
      "    v = vecs[:, 0, :]                                  # smallest eigenvalue\n",
      "the Kronecker per-pair solution takes a row, not the smallest eigenvector"),
    M("avg-kron-scale-sign", "core/handeye/average.py",
      "    scale = np.sign(safe) / np.cbrt(np.abs(safe))\n",
      "    scale = 1.0 / np.cbrt(np.abs(safe))\n",
      "the Kronecker per-pair scale ignores the sign of det (translation sign flipped)"),
    # -- core/handeye/budget.py
    M("budget-dof-correction", "core/handeye/budget.py",
      "    r2 = float(np.mean(np.square(board_dev_mm))) * n / max(n - 2, 1)\n",
      "    r2 = float(np.mean(np.square(board_dev_mm))) * n / max(n - 1, 1)\n",
      "the in-sample scatter corrected by n/(n-1), not n/(n-2)"),
    M("budget-estimate-minus-camera", "core/handeye/budget.py",
      '             "estimate_mm": float(np.sqrt(max(0.0, h2 - r2)))}\n',
      '             "estimate_mm": float(np.sqrt(max(0.0, h2 - c2)))}\n',
      "the estimate's part subtracts the camera's part, not the in-sample scatter"),
    M("budget-systematic-rotation-sign", "core/handeye/budget.py",
      "        moved = d[:, :3] + np.cross(d[:, 3:], np.asarray(lev))\n",
      "        moved = d[:, :3] - np.cross(d[:, 3:], np.asarray(lev))\n",
      "the systematic correction's rotation moves the board origin the wrong way"),
    M("budget-largest-min", "core/handeye/budget.py",
      '    out["largest"] = max(finite, key=lambda k: finite[k])\n',
      '    out["largest"] = min(finite, key=lambda k: finite[k])\n',
      "the budget names the smallest part as the largest"),
    # -- core/handeye/select.py
    M("select-corner-rms-per-coordinate", "core/handeye/select.py",
      "            px[i] = float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))\n",
      "            px[i] = float(np.sqrt(np.mean(e ** 2)))\n",
      "the held-out corner RMS per coordinate, not per corner (sqrt 2 low)"),
    M("select-ref-mean", "core/handeye/select.py",
      "    ref_mm = max(float(np.median([np.sqrt(np.mean(h.mm ** 2)) for h in"
      " held_out.values()])),\n",
      "    ref_mm = max(float(np.mean([np.sqrt(np.mean(h.mm ** 2)) for h in"
      " held_out.values()])),\n",
      "the mm scale is the mean over the methods, not the median"),
    M("select-paired-unsquared", "core/handeye/select.py",
      "    d = per[best] ** 2 - per[reference] ** 2\n",
      "    d = per[best] - per[reference]\n",
      "the paired test on differences of errors, not of squared errors"),
    M("select-se-ddof", "core/handeye/select.py",
      '    se = float(np.std(d, ddof=1) / np.sqrt(d.size)) if d.size > 1 else float("inf")\n',
      '    se = float(np.std(d) / np.sqrt(d.size)) if d.size > 1 else float("inf")\n',
      "the standard error from the population standard deviation (ddof 0)"),
    M("select-centre-origin", "core/handeye/select.py",
      "        c = (np.mean(s.observations[0].object_points, axis=0) if s.observations\n",
      "        c = (np.zeros(3) if s.observations\n",
      "the held-out position measured at the board origin, not the corners' centre"),
    M("select-deg-transpose", "core/handeye/select.py",
      "            Rotation.from_matrix(Y[:3, :3].T @ Yi[:3, :3]).as_rotvec())))\n",
      "            Rotation.from_matrix(Y[:3, :3] @ Yi[:3, :3]).as_rotvec())))\n",
      "the held-out rotation error without the transpose"),
    # -- core/handeye/eiv.py
    M("eiv-loo-coupling", "core/handeye/eiv.py",
      "            _, xg = _schur_solve(S - nm.A_k[i] + BDB[i], rhs + nm.gg_k[i] - BDg[i])\n",
      "            _, xg = _schur_solve(S - nm.A_k[i], rhs + nm.gg_k[i] - BDg[i])\n",
      "leave-one-out keeps the left-out sample's correction coupling in the Schur complement"),
    M("eiv-prior-linearised", "core/handeye/eiv.py",
      "        r_lin[m:] += step[12:]\n", "        pass\n",
      "the prior residuals not updated by the step in the variance-component estimate"),
    M("eiv-pose-translation-level", "core/handeye/eiv.py",
      '            t = (C[:, :3, 3] - self.C[:, :3, 3]) / sig["robot_t"]\n',
      '            t = (C[:, :3, 3] - self.C[:, :3, 3]) / sig["cam_r"]\n',
      "pose pairs: the translation residual whitened by the rotation level"),
    M("eiv-prior-hat", "core/handeye/eiv.py",
      '    h_prior = np.einsum("kii->ki", Cuu).ravel()\n',
      "    h_prior = np.zeros(Cuu.shape[0] * 6)\n",
      "the prior rows' hat-matrix diagonal left out of the robot groups' redundancy"),
    # -- core/handeye/systematic.py
    M("systematic-features-transpose", "core/handeye/systematic.py",
      '    return Rotation.from_matrix(np.einsum("ji,njk->nik", R_ref, base_T_ee[:, :3, :3]))'
      '.as_rotvec()\n',
      '    return Rotation.from_matrix(np.einsum("ij,njk->nik", R_ref, base_T_ee[:, :3, :3]))'
      '.as_rotvec()\n',
      "the orientation feature log(R_ref R_i), not log(R_ref^T R_i)"),
    M("systematic-correction-transpose", "core/handeye/systematic.py",
      "    return np.concatenate([r @ A_t.T, r @ A_r.T], axis=1)\n",
      "    return np.concatenate([r @ A_t, r @ A_r], axis=1)\n",
      "correction() applies A^T r instead of the fitted A r"),
    M("systematic-residual-variance", "core/handeye/systematic.py",
      "    s2 = float(2.0 * res.cost / dof)\n", "    s2 = float(res.cost / dof)\n",
      "the residual variance from the cost without its factor 2"),
    M("systematic-nees-model-term", "core/handeye/systematic.py",
      "            S = s2 * (np.eye(6) + Jn @ Ainv @ Jn.T)\n",
      "            S = s2 * np.eye(6)\n",
      "held-out NEES ignores the uncertainty of X, Y and the model"),
    M("systematic-loo-gradient-sign", "core/handeye/systematic.py",
      "            dp = np.linalg.solve(A - Ji.T @ Ji, Ji.T @ ri)\n",
      "            dp = np.linalg.solve(A - Ji.T @ Ji, -Ji.T @ ri)\n",
      "the leave-one-out step goes the wrong way"),
    M("systematic-prior-scale", "core/handeye/systematic.py",
      "            out.append(p[12:] / level)\n", "            out.append(p[12:] * level)\n",
      "the prior residual multiplies by the level instead of dividing"),
    M("systematic-min-samples", "core/handeye/systematic.py",
      "    if n < _MIN_SAMPLES_SYSTEMATIC:\n", "    if n <= _MIN_SAMPLES_SYSTEMATIC:\n",
      "six samples treated as too few for the systematic term"),
    # -- core/handeye/plan.py
    M("plan-score-deg-target", "core/handeye/plan.py",
      "    return (mm / cfg.target_mm) ** 2 + (deg / cfg.target_deg) ** 2\n",
      "    return (mm / cfg.target_mm) ** 2 + (deg / cfg.target_mm) ** 2\n",
      "the rotation part of the trace score divided by the mm target"),
    M("plan-greedy-no-accumulate", "core/handeye/plan.py",
      "        S = S + info[k]\n", "        S = S\n",
      "the greedy pick forgets the earlier suggestions' information"),
    M("plan-margin-height", "core/handeye/plan.py",
      "            & np.all((px[..., 0] >= m) & (px[..., 0] <= v.model.width - 1 - m)\n",
      "            & np.all((px[..., 0] >= m) & (px[..., 0] <= v.model.height - 1 - m)\n",
      "the image margin on x checked against the height"),
    M("plan-distance-margin-high", "core/handeye/plan.py",
      "    d_range = (dist.min() * (1.0 - cfg.distance_margin), dist.max() * (1.0 +"
      " cfg.distance_margin))\n",
      "    d_range = (dist.min() * (1.0 - cfg.distance_margin), dist.max())\n",
      "the distance range not widened above the farthest reached distance"),
    M("plan-suggest-twice", "core/handeye/plan.py",
      "        free[k] = False\n", "        pass\n",
      "the same candidate can be suggested twice"),
    # -- core/tf.py
    M("tf-compose-order", "core/tf.py",
      "            T = self._edges[child].at(stamp_ns, max_gap_ns) @ T\n",
      "            T = T @ self._edges[child].at(stamp_ns, max_gap_ns)\n",
      "a chain's transforms composed in the wrong order"),
    M("tf-newest-max", "core/tf.py",
      "            newest = min(newest, n)\n", "            newest = max(newest, n)\n",
      "newest_ns of a chain is its newest edge's, not the earliest newest"),
    M("tf-reparent-count", "core/tf.py",
      "            if edge is not None and not same_parent:\n",
      "            if edge is not None:\n",
      "every update of a known edge counted as a reparenting"),
    M("tf-jump-boundary", "core/tf.py",
      "        if (newest is not None and newest - int(stamp_ns) > self._jump_back) or (\n",
      "        if (newest is not None and newest - int(stamp_ns) >= self._jump_back) or (\n",
      "a transform exactly jump_back_ns older clears the buffer"),
    M("tf-leading-slash", "core/tf.py",
      '    name = frame_id.lstrip("/")\n', "    name = frame_id\n",
      "a leading slash in a frame id makes another frame"),
    # -- core/locator.py
    M("locator-count-off-by-one", "core/locator.py",
      "        keep = accepted if spec.count == 0 else accepted[:spec.count]\n",
      "        keep = accepted if spec.count == 0 else accepted[:spec.count - 1]\n",
      "a blob set keeps one blob fewer than count"),
    M("locator-assign-cost-axis", "core/locator.py",
      "                    cost[i, j] = abs(xl[i][self._row] - xr[j][self._row])\n",
      "                    cost[i, j] = abs(xl[i][1 - self._row] - xr[j][1 - self._row])\n",
      "the assignment cost on the disparity axis, not the row difference"),
    M("locator-size-one-sided", "core/locator.py",
      "                factor = max(rng / rng_size, rng_size / rng)\n",
      "                factor = rng / rng_size\n",
      "the size gate rejects only a pair that is too far, not too near"),
    M("locator-why-missing-gate", "core/locator.py",
      "        gate_px = max(10.0, self._f * self.config.track_gate_m / z) * max(1, tr.missed)\n",
      "        gate_px = max(10.0, self._f * self.config.track_gate_m / z)\n",
      "the reason search gate does not grow with the misses"),
    M("locator-cut-right", "core/locator.py",
      "            u[axis], u[2 + axis] = dl.cut_sigma_px, dr.cut_sigma_px\n",
      "            u[axis], u[2 + axis] = dl.cut_sigma_px, dl.cut_sigma_px\n",
      "the right image's threshold-cut term taken from the left detection"),
    M("locator-id-reuse", "core/locator.py",
      "                tr = _Track(state.next_k)\n", "                tr = _Track(len(tracks))\n",
      "a new blob's id from the number of known blobs (a retired id reused)"),
    # -- core/distances.py
    M("distances-abs-error", "core/distances.py",
      "                                   error_mm=1000.0 * float(np.mean(d[both] - dt[both])),\n",
      "                                   error_mm=1000.0 * float(np.mean(np.abs(d[both] -"
      " dt[both]))),\n",
      "the error against the truth as a mean absolute, not the signed mean"),
    M("distances-max-units", "core/distances.py",
      "                               1000.0 * float(e.max()) if e.size else math.nan))\n",
      "                               float(e.max()) if e.size else math.nan))\n",
      "a target's largest error in metres, reported as mm"),
    M("distances-self-pairs", "core/distances.py",
      "        for j in range(i + 1, len(ids)):\n", "        for j in range(i, len(ids)):\n",
      "each target paired with itself"),
    M("distances-known-order", "core/distances.py",
      "    return (a, b) if a <= b else (b, a)\n", "    return (a, b)\n",
      "a known distance given as (b, a) not matched to the pair (a, b)"),
    M("distances-match-gate", "core/distances.py",
      "            if cost[r, c] <= max_distance_m}\n", "            }\n",
      "truth matched beyond max_distance_m"),
    # -- core/eye_to_hand.py
    M("eye-to-hand-result-pose", "core/eye_to_hand.py",
      "                            base_T_ee=_IDENTITY.copy())\n",
      "                            base_T_ee=self.base_T_cam.copy())\n",
      "the result's base_T_ee is the camera mount, not the identity"),
    M("eye-to-hand-validate-early", "core/eye_to_hand.py",
      "        target_in_base(_IDENTITY, self.base_T_cam, np.zeros(3),"
      " cov_hand_eye=self.cov_hand_eye)\n",
      "        pass\n",
      "a malformed covariance accepted by the constructor (fails at the first target)"),
    # -- core/detection.py
    M("detection-edge-width-constant", "core/detection.py",
      "    return float(np.mean(s1[ok] ** 2 / s2[ok] * cos[ok])) / (2.0 * math.sqrt(math.pi))\n",
      "    return float(np.mean(s1[ok] ** 2 / s2[ok] * cos[ok])) / (2.0 * math.pi)\n",
      "the edge width divided by 2 pi, not 2 sqrt(pi)"),
    M("detection-edge-width-cosine", "core/detection.py",
      "    return float(np.mean(s1[ok] ** 2 / s2[ok] * cos[ok])) / (2.0 * math.sqrt(math.pi))\n",
      "    return float(np.mean(s1[ok] ** 2 / s2[ok])) / (2.0 * math.sqrt(math.pi))\n",
      "the edge width without the normal's cosine to the sampling axis"),
    M("detection-shade-y-mean", "core/detection.py",
      "                          float((wgt * ys).sum()) / total - float(ys.mean())])\n",
      "                          float((wgt * ys).sum()) / total - float(xs.mean())])\n",
      "the shading shift's y part relative to the x mean"),
    M("detection-sigma-drops-shade", "core/detection.py",
      "math.hypot(edge, float(np.hypot(*shade)), cut)", "math.hypot(edge, cut)",
      "the centre sigma leaves out the shading term"),
    # -- core/sync.py
    M("sync-slop-inclusive", "core/sync.py",
      "            if gap > self._slop:\n", "            if gap >= self._slop:\n",
      "a pair exactly slop apart is not paired"),
    M("sync-skew-abs", "core/sync.py",
      "        self.stats.max_abs_skew_ns = max(self.stats.max_abs_skew_ns, abs(rs - ls))\n",
      "        self.stats.max_abs_skew_ns = max(self.stats.max_abs_skew_ns, rs - ls)\n",
      "max_abs_skew_ns ignores pairs whose right frame is earlier"),
    M("sync-evict-old", "core/sync.py",
      "                return jumped  # older than everything in a full buffer: evicted at once\n",
      "                pass\n",
      "a pose older than everything in a full buffer is inserted (and a newer one evicted)"),
    M("waits-cap", "core/sync.py",
      "        return waited_s > limit and (self._over[kind] or waited_s > 2.0 * limit + 0.5)\n",
      "        return waited_s > limit and (self._over[kind] or waited_s > 2.0 * limit)\n",
      "the wait cap without its 0.5 s"),
    M("pose-receive-refresh", "core/sync.py",
      "            self._received[i] = recv\n", "            pass\n",
      "a pose re-sent at the same stamp keeps the old receive time"),
    # -- core/calibration/detection.py
    M("saddle-accepts-extremum", "core/calibration/detection.py",
      "        ok = active & (det < 0)\n", "        ok = active & (det != 0)\n",
      "a window without a saddle (a blob) moves the corner to its extremum"),
    M("saddle-gradient-block", "core/calibration/detection.py",
      "        cg = v[:, None, None] * AtA_inv[3:5, 3:5][None]\n",
      "        cg = v[:, None, None] * AtA_inv[:2, :2][None]\n",
      "the corner covariance from the quadratic terms' block, not the gradient's"),
    M("saddle-sigma-per-axis", "core/calibration/detection.py",
      "    sigma[good] = np.sqrt(np.maximum(np.trace(cov[good], axis1=1, axis2=2), 0.0) / 2.0)\n",
      "    sigma[good] = np.sqrt(np.maximum(np.trace(cov[good], axis1=1, axis2=2), 0.0))\n",
      "the corner sigma as a 2-D norm, not per axis"),
    M("saddle-max-shift", "core/calibration/detection.py",
      "    good = np.isfinite(cov[:, 0, 0]) & (moved <= max_shift)\n",
      "    good = np.isfinite(cov[:, 0, 0])\n",
      "a corner moved beyond max_shift is kept"),
    M("saddle-residual-dof", "core/calibration/detection.py",
      "        v = np.sum(res * res, axis=1) / max(A.shape[0] - 6, 1)\n",
      "        v = np.sum(res * res, axis=1) / A.shape[0]\n",
      "the fit's residual variance without the 6 fitted parameters"),
    M("calib-sigma-median", "core/calibration/detection.py",
      "                sigma_px=float(np.median(finite)) if finite.size else float(\"nan\"))\n",
      "                sigma_px=float(np.mean(finite)) if finite.size else float(\"nan\"))\n",
      "the detection's sigma_px as the mean, not the median, of its corners'"),
    # -- io/
    M("bag-samples-window", "io/bag_samples.py",
      "    half = int(round(still_window_s * 0.5e9))\n",
      "    half = int(round(still_window_s * 1e9))\n",
      "the stillness window twice still_window_s"),
    M("bag-samples-middle", "io/bag_samples.py",
      '    chosen = {g[len(g) // 2][0]: (f"stop{k:03d}", g[len(g) // 2][1])\n',
      '    chosen = {g[0][0]: (f"stop{k:03d}", g[0][1])\n',
      "a stop's first image chosen, not its middle one"),
    M("bag-samples-still-or", "io/bag_samples.py",
      "        return dt <= still_translation_m and float(np.arccos(c)) <= rot_tol\n",
      "        return dt <= still_translation_m or float(np.arccos(c)) <= rot_tol\n",
      "a pose that only rotates counted as still"),
    M("config-asymmetric-covariance", "io/config.py",
      "        if np.max(np.abs(cov - cov.T)) > 1e-9 * max(1.0, float(np.max(np.abs(cov)))):\n",
      "        if False:\n",
      "an asymmetric covariance accepted in hand_eye.yaml"),
    M("config-noise-zero", "io/config.py",
      "                    or v < 0:\n", "                    or v <= 0:\n",
      "a robot_pose_noise of 0 refused (documented >= 0)"),
    # -- nodes/
    M("hand-eye-tf-right-extrinsic", "nodes/hand_eye_tf.py",
      "                                                       np.linalg.inv(rig.right_T_left))\n",
      "                                                       rig.right_T_left)\n",
      "camera_frame -> right_camera_frame published as right_T_left, not its inverse"),
    M("hand-eye-targets-cov-block", "nodes/hand_eye_targets.py",
      "            cov = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6)[:3,"
      " :3]\n",
      "            cov = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6)[3:,"
      " 3:]\n",
      "a target point's covariance read from the rotation block"),
    M("hand-eye-gap-units", "nodes/hand_eye.py",
      "            max_gap_ns=int(cfg.max_pose_gap_s * 1e9), buffer_size=cfg.pose_buffer_size,\n",
      "            max_gap_ns=int(cfg.max_pose_gap_s * 1e6), buffer_size=cfg.pose_buffer_size,\n",
      "max_pose_gap_s converted with 1e6 (a thousandth of the gap)"),
    M("detect-slop-units", "nodes/detect_triangulate.py",
      '        slop_ns = int(round(node_values["sync.slop_s"] * 1e9))\n',
      '        slop_ns = int(round(node_values["sync.slop_s"] * 1e6))\n',
      "sync.slop_s converted with 1e6"),
    M("detect-max-targets", "nodes/detect_triangulate.py",
      "            if len(self._pub_targets) >= self._max_targets:\n",
      "            if len(self._pub_targets) > self._max_targets:\n",
      "one id more than max_targets gets publishers"),
)


B2: tuple[M, ...] = (
    # -- core/handeye/average.py
    M("avg2-tsai-half-angle", "core/handeye/average.py",
      "    Px = 2.0 * Pp / np.sqrt(1.0 + np.einsum(\"ki,ki->k\", Pp, Pp))[:, None]\n",
      "    Px = Pp / np.sqrt(1.0 + np.einsum(\"ki,ki->k\", Pp, Pp))[:, None]\n",
      "the per-pair Tsai rotation without the factor 2 of the modified Rodrigues vector"),
    M("avg2-trans-std-mean", "core/handeye/average.py",
      "        return float(np.sqrt(np.mean(self.trans_dev_mm ** 2)))\n",
      "        return float(np.mean(self.trans_dev_mm))\n",
      "the translation spread as a mean, not the documented RMS"),
    M("avg2-min-pairs", "core/handeye/average.py",
      "    if len(Xs) < MIN_PAIRS:\n", "    if len(Xs) <= MIN_PAIRS:\n",
      "exactly MIN_PAIRS usable pairs refused"),
    M("avg2-candidates-count", "core/handeye/average.py",
      "    n_cand = K * (K - 1) // 2\n", "    n_cand = K * K // 2\n",
      "the number of candidate pairs of motions miscounted"),
    # -- core/handeye/budget.py
    M("budget2-camera-units", "core/handeye/budget.py",
      "        c2 = 1e6 * float(np.mean([_centre_variance(s, cameras, px, np.zeros(3))\n",
      "        c2 = 1e3 * float(np.mean([_centre_variance(s, cameras, px, np.zeros(3))\n",
      "the camera part's m^2 -> mm^2 factor 1e3, not 1e6"),
    M("budget2-pnp-rms", "core/handeye/budget.py",
      "        px = float(np.sqrt(np.mean(np.square(pnp))))\n",
      "        px = float(np.mean(pnp))\n",
      "the corners' pixel noise as the mean PnP residual, not the RMS"),
    M("budget2-lever-transpose", "core/handeye/budget.py",
      "                lev.append(s.base_T_ee[:3, :3].T @ (Y[:3, 3] - s.base_T_ee[:3, 3]))\n",
      "                lev.append(s.base_T_ee[:3, :3] @ (Y[:3, 3] - s.base_T_ee[:3, 3]))\n",
      "the board origin's lever arm not rotated into the flange frame"),
    # -- core/handeye/select.py
    M("select2-combine-mm-scale", "core/handeye/select.py",
      "        return ({k: np.hypot(np.asarray(h.px) / ref_px, h.mm / ref_mm)\n",
      "        return ({k: np.hypot(np.asarray(h.px) / ref_px, h.mm)\n",
      "the combined score's board position not divided by its median RMS"),
    M("select2-score-mean", "core/handeye/select.py",
      "    return {k: float(np.sqrt(np.mean(v ** 2))) for k, v in per.items()}, criterion\n",
      "    return {k: float(np.mean(v)) for k, v in per.items()}, criterion\n",
      "the selection score as the mean, not the RMS over the samples"),
    M("select2-reference-not-candidate", "core/handeye/select.py",
      "    if reference not in scores or best == reference:\n",
      "    if best == reference:\n",
      "a reference that is not among the candidates is still compared (and may be written)"),
    M("select2-centre-at-point", "core/handeye/select.py",
      "    return float(np.trace(Jc @ cov @ Jc.T))\n",
      "    return float(np.trace(cov[:3, :3]))\n",
      "the centre variance of the pose's translation, not propagated to the board point"),
    M("select2-eye-to-hand-lever", "core/handeye/select.py",
      "            p_ee = Y[:3, :3] @ c + Y[:3, 3]                      # board on the flange\n",
      "            p_ee = Y[:3, 3]                                      # board on the flange\n",
      "eye-to-hand: the lever arm to the board origin, not the corners' centre"),
    # -- core/handeye/eiv.py
    M("eiv2-prior-block", "core/handeye/eiv.py",
      "    D = prob.per_sample_sum(np.einsum(\"ki,kj->kij\", Ju, Ju)) + np.eye(6)\n",
      "    D = prob.per_sample_sum(np.einsum(\"ki,kj->kij\", Ju, Ju))\n",
      "the corrections' unit prior left out of their normal block"),
    M("eiv2-back-substitution-sign", "core/handeye/eiv.py",
      "    xu = -np.einsum(\"kij,kj->ki\", nm.Dinv, nm.gu + np.einsum(\"kji,j->ki\", nm.B, xg))\n",
      "    xu = -np.einsum(\"kij,kj->ki\", nm.Dinv, nm.gu - np.einsum(\"kji,j->ki\", nm.B, xg))\n",
      "the corrections' back-substitution with the wrong sign of the X, Y step"),
    M("eiv2-settled-tolerance", "core/handeye/eiv.py",
      "        settled = all(abs(new[k] - sig[k]) < max(0.01 * sig[k], _SETTLED_ABS[k]) for k"
      " in sig)\n",
      "        settled = all(abs(new[k] - sig[k]) < max(0.1 * sig[k], _SETTLED_ABS[k]) for k in"
      " sig)\n",
      "noise levels count as settled at 10 % change, not 1 %"),
    M("eiv2-pose-rotation-transpose", "core/handeye/eiv.py",
      "            dR = np.einsum(\"kji,kjl->kil\", self.C[:, :3, :3], C[:, :3, :3])\n",
      "            dR = np.einsum(\"kij,kjl->kil\", self.C[:, :3, :3], C[:, :3, :3])\n",
      "pose pairs: the rotation residual without the transpose of the measured rotation"),
    # -- core/handeye/systematic.py
    M("systematic2-weights-swapped", "core/handeye/systematic.py",
      "    w = np.array([1 / s_t] * 3 + [1 / s_r] * 3)\n",
      "    w = np.array([1 / s_r] * 3 + [1 / s_t] * 3)\n",
      "the residual whitening swaps the translation and rotation levels"),
    M("systematic2-dof-parameters", "core/handeye/systematic.py",
      "        p = 12 + (18 if level > 0 else 0)\n", "        p = 12\n",
      "the first pass's degrees of freedom ignore the 18 systematic parameters"),
    M("systematic2-covariance-block", "core/handeye/systematic.py",
      "    cov = cov_full[:6, :6]\n", "    cov = cov_full[6:12, 6:12]\n",
      "the systematic fit reports Y's covariance as X's"),
    M("systematic2-eye-to-hand-implied", "core/handeye/systematic.py",
      "    return X @ cam_T_board @ np.linalg.inv(Y)\n",
      "    return X @ cam_T_board @ Y\n",
      "eye-to-hand: the implied flange pose without inv(Y)"),
    # -- core/handeye/plan.py
    M("plan2-std-mm-scale", "core/handeye/plan.py",
      "    return 1000.0 * np.sqrt(np.maximum(tt, 0.0)), np.degrees(np.sqrt(np.maximum(tr,"
      " 0.0)))\n",
      "    return np.sqrt(1000.0 * np.maximum(tt, 0.0)), np.degrees(np.sqrt(np.maximum(tr,"
      " 0.0)))\n",
      "std_mm as sqrt(1000 trace), not 1000 sqrt(trace)"),
    M("plan2-rotation-noise", "core/handeye/plan.py",
      "                \"robot_r\": max(float(self.robot_sigma_rot_rad),"
      " SIGMA_FLOORS[\"robot_r\"])}\n",
      "                \"robot_r\": max(float(self.robot_sigma_pos_m),"
      " SIGMA_FLOORS[\"robot_r\"])}\n",
      "the planner's rotation noise taken from the position noise"),
    M("plan2-outline-spacing", "core/handeye/plan.py",
      "    lo, hi = uv.min(axis=0) - spacing, uv.max(axis=0) + spacing\n",
      "    lo, hi = uv.min(axis=0), uv.max(axis=0)\n",
      "the board outline at the outer corners, not one spacing beyond"),
    # -- core/tf.py
    M("tf2-root-not-lowest", "core/tf.py",
      "        ancestor = next(f for f in up_t if f in common)\n",
      "        ancestor = next(f for f in reversed(up_t) if f in common)\n",
      "chains go up to the root, not the lowest common ancestor"),
    M("tf2-loop-check-swapped", "core/tf.py",
      "            if not same_parent and self._is_ancestor(c, p):\n",
      "            if not same_parent and self._is_ancestor(p, c):\n",
      "the loop check asks the wrong way round"),
    M("tf2-expire-static", "core/tf.py",
      "            self.buffer.clear(keep_static=True)\n            self._last_newest = None\n "
      "       return cause\n",
      "            self.buffer.clear(keep_static=False)\n            self._last_newest = None\n"
      "        return cause\n",
      "a stopped stream clears the static transforms too"),
    # -- core/locator.py
    M("locator2-why-furthest", "core/locator.py",
      "                return reasons[min(near)[1]]\n", "                return"
      " reasons[max(near)[1]]\n",
      "a missing blob's reason from the furthest unpaired blob, not the nearest"),
    M("locator2-track-cost-flat", "core/locator.py",
      "                    cost[p, t] = dist\n", "                    cost[p, t] = 0.0\n",
      "blobs matched to known ids regardless of distance within the gate"),
    M("locator2-size-tolerance", "core/locator.py",
      "                if factor > 1.0 + cfg.size_tol:\n", "                if factor >"
      " cfg.size_tol + 0.5:\n",
      "the size gate at factor size_tol + 0.5, not 1 + size_tol"),
    M("locator2-edge-unsquared", "core/locator.py",
      "        e = [max(MIN_PIXEL_SIGMA, d.edge_sigma_px) ** 2 for d in (dl, dr)]\n",
      "        e = [max(MIN_PIXEL_SIGMA, d.edge_sigma_px) for d in (dl, dr)]\n",
      "the edge sigma added to the pixel covariance as a variance unsquared"),
    M("locator2-pixel-sigma-zero", "core/locator.py",
      "        if self.config.pixel_sigma > 0:\n", "        if self.config.pixel_sigma >= 0:\n",
      "pixel_sigma 0 (per-detection) taken as a fixed sigma of 0"),
    # -- core/distances.py
    M("distances2-median", "core/distances.py",
      "            mean = float(d[ok].mean()) if n else math.nan\n",
      "            mean = float(np.median(d[ok])) if n else math.nan\n",
      "the pair distance as the median, not the mean"),
    M("distances2-located-all", "core/distances.py",
      "        located = int(np.all(np.isfinite(P[i]), axis=1).sum())\n",
      "        located = int(P[i].shape[0])\n",
      "every frame counted as located"),
    M("distances2-unmatched", "core/distances.py",
      "    unmatched = [(a, b, m) for a, b, m in known if _pair_key(a, b) in table]\n",
      "    unmatched = []\n",
      "known distances for pairs not measured silently dropped"),
    # -- core/eye_to_hand.py
    M("eye-to-hand2-camera-cov", "core/eye_to_hand.py",
      "        p, cov = target_in_base(_IDENTITY, self.base_T_cam, point_cam, cov_cam=cov_cam,\n",
      "        p, cov = target_in_base(_IDENTITY, self.base_T_cam, point_cam, cov_cam=None,\n",
      "the point's own covariance left out of the base-frame covariance"),
    # -- core/detection.py
    M("detection2-tau-start", "core/detection.py",
      "    tau = 1.0\n", "    tau = 0.0\n",
      "the correlation time without the lag-0 term"),
    M("detection2-blur-linear", "core/detection.py",
      "        blur = math.sqrt(max(width * width - BLUR_W0_PX ** 2, 0.0)) if"
      " math.isfinite(width) \\\n",
      "        blur = max(width - BLUR_W0_PX, 0.0) if math.isfinite(width) \\\n",
      "the unblurred width subtracted linearly, not in quadrature"),
    M("detection2-profile-axis", "core/detection.py",
      "    horiz = np.abs(nrm[:, 0]) >= np.abs(nrm[:, 1])\n",
      "    horiz = np.abs(nrm[:, 0]) < np.abs(nrm[:, 1])\n",
      "edge profiles sampled along the axis further from the normal"),
    M("detection2-residual-mean", "core/detection.py",
      "    res = res - res.mean()\n", "    pass\n",
      "the edge residuals' mean (a size bias) counted as roughness"),
    # -- core/sync.py
    M("sync2-interpolation-order", "core/sync.py",
      "        return interpolate_unchecked(stamp, s0, self._poses[i - 1], s1, self._poses[i])\n",
      "        return interpolate_unchecked(stamp, s0, self._poses[i], s1, self._poses[i - 1])\n",
      "the bracketing poses swapped in the interpolation"),
    M("sync2-age-newest", "core/sync.py",
      "        oldest = min(received)\n", "        oldest = max(received)\n",
      "the receive-age rule checks the newer of the two poses"),
    M("sync2-clock-jump-sign", "core/sync.py",
      "        if self._jump_back is not None and newest - now > self._jump_back:\n",
      "        if self._jump_back is not None and now - newest > self._jump_back:\n",
      "expire: a clock jump detected the wrong way round"),
    # -- core/calibration/detection.py
    M("saddle2-hessian-sign", "core/calibration/detection.py",
      "        Hi = np.stack([np.stack([2 * c, -b], axis=1), np.stack([-b, 2 * a], axis=1)],\n",
      "        Hi = np.stack([np.stack([2 * c, b], axis=1), np.stack([b, 2 * a], axis=1)],\n",
      "the inverse Hessian's off-diagonal sign wrong"),
    M("calib2-spacing-max", "core/calibration/detection.py",
      "    return float(min(dx.min(), dy.min()))\n", "    return float(max(dx.min(), dy.min()))\n",
      "the corner spacing from the wider direction (the subpixel window too large)"),
    # -- io/
    M("bag-samples2-group-drift", "io/bag_samples.py",
      "        if current and not close(current[0][1], T):\n",
      "        if current and not close(current[-1][1], T):\n",
      "a stop compared with its latest pose, not its first (a slow drift stays one stop)"),
    M("config2-flat-covariance", "io/config.py",
      "        if cov.shape == (36,):\n            cov = cov.reshape(6, 6)\n",
      "        if False:\n            cov = cov.reshape(6, 6)\n",
      "a flat 36-number covariance refused"),
    M("config2-sample-count", "io/config.py",
      "    if isinstance(count, bool) or not isinstance(count, int) or count < 0:\n",
      "    if isinstance(count, bool) or not isinstance(count, int) or count < 1:\n",
      "sample_count 0 refused"),
    # -- nodes/
    M("hand-eye2-waits-swapped", "nodes/hand_eye.py",
      "        self.waits = InputWaits(cfg.max_pose_wait_s, cfg.max_target_wait_s)\n",
      "        self.waits = InputWaits(cfg.max_target_wait_s, cfg.max_pose_wait_s)\n",
      "max_pose_wait_s and max_target_wait_s swapped"),
    M("hand-eye-targets2-slash", "nodes/hand_eye_targets.py",
      "            if frame and frame.lstrip(\"/\") != self.config.camera_frame:\n",
      "            if frame and frame != self.config.camera_frame:\n",
      "a point in '/camera_frame' refused"),
    M("detect2-queue-depth-one", "nodes/detect_triangulate.py",
      "        if depth < 1:\n", "        if depth <= 1:\n",
      "queue_depth 1 refused"),
)

# Batch 3: 26 bugs written by a reviewer who had read neither the tests nor the tables above
# (at most 2 per module), run against test/core (+ test/io for io/) and the survivors against
# the rest of the suite: 25 of 26 caught (the survivor, b3-m11, has a test since and its twin
# joined tools/mutation.py as session-frame-not-newer). A record: not re-anchored.
B3: tuple[M, ...] = (
    M('b3-m01', 'core/handeye/select.py',
      '    if float(np.mean(d)) < -2.0 * se:',
      '    if float(np.mean(d)) < 2.0 * se:',
      'choose(): another method replaces the reference only if mean paired difference is ...'),
    M('b3-m02', 'core/handeye/select.py',
      '    excess = float(np.mean(m - 2.0 * rotation_sigma_rad ** 2 * np.asarray(lever_sq)',
      '    excess = float(np.mean(m - 2.0 * rotation_sigma_rad * np.asarray(lever_sq)',
      'held_out_position_sigma(): s_t^2 = max(0, mean(|e|^2 - 2 s_r^2 |l|^2 - v))/3; square ...'),
    M('b3-m03', 'core/handeye/eiv.py',
      '    return bte @ D',
      '    return D @ bte',
      'EIV model: correction applied on the right (flange frame), true = B_i @ ...'),
    M('b3-m04', 'core/handeye/eiv.py',
      '            r_g = float(rows.sum() - h[rows].sum())',
      '            r_g = float(rows.sum())',
      'Forstner variance components: redundancy r_g = n_g - trace(H_gg); trace term dropped ...'),
    M('b3-m05', 'core/handeye/systematic.py',
      '        true = bte @ _se3(corr)',
      '        true = _se3(corr) @ bte',
      'systematic model: true_i = reported_i @ [exp(A_r r_i) | A_t r_i], error on the right ...'),
    M('b3-m06', 'core/handeye/systematic.py',
      '        corr = np.concatenate([r @ A_t.T, r @ A_r.T], axis=1)',
      '        corr = np.concatenate([r @ A_t.T, r @ A_r], axis=1)',
      'systematic model rotation error is A_r r (fit must match RobotPoseCorrection.delta); ...'),
    M('b3-m07', 'core/handeye/average.py',
      '    cos = np.abs(np.einsum("ki,ki->k", axis[pp], axis[qq]))',
      '    cos = np.einsum("ki,ki->k", axis[pp], axis[qq])',
      'usable pairs: axis angle is between axes as lines (in [0, 90] deg); abs dropped so ...'),
    M('b3-m08', 'core/handeye/average.py',
      '            step = Rotation.from_matrix(np.einsum("ji,kjl->kil", M, R)).as_rotvec().mean(axis=0)',  # noqa: E501
      '            step = Rotation.from_matrix(np.einsum("ij,kjl->kil", M, R)).as_rotvec().mean(axis=0)',  # noqa: E501
      'geodesic (Karcher) rotation mean: step from M^T R_k; transposed M gives a wrong mean'),
    M('b3-m09', 'core/handeye/budget.py',
      '        moved = d[:, :3] + np.cross(d[:, 3:], np.asarray(lev))',
      '        moved = d[:, :3] + np.cross(np.asarray(lev), d[:, 3:])',
      'robot_systematic_mm: RMS at board origin of the correction (t + r x lever); cross ...'),
    M('b3-m10', 'core/handeye/kfold.py',
      '    pred = obj @ Y[:3, :3].T + Y[:3, 3]',
      '    pred = obj @ Y[:3, :3] + Y[:3, 3]',
      'predict_view: base-frame corners predicted from the fitted Y, R p + t; transposed rotation'),  # noqa: E501
    M('b3-m11', 'core/handeye/session.py',
      '            if req.frame_stamp_ns is None and (req.after_ns is None or stamp_ns > req.after_ns):',  # noqa: E501
      '            if req.frame_stamp_ns is None and (req.after_ns is None or stamp_ns >= req.after_ns):',  # noqa: E501
      'capture rule 1: the request is answered from the first frame stamped *after* the ...'),
    M('b3-m12', 'core/handeye/session.py',
      '            if d <= cfg.duplicate_translation_m and a <= cfg.duplicate_rotation_rad:',
      '            if d <= cfg.duplicate_translation_m or a <= cfg.duplicate_rotation_rad:',
      "rule 4: duplicate only when within both translation and rotation thresholds; 'or' ..."),
    M('b3-m13', 'core/tf.py',
      '            T = self._edges[child].at(stamp_ns, max_gap_ns) @ T',
      '            T = T @ self._edges[child].at(stamp_ns, max_gap_ns)',
      'lookup composes edges up the chain: ancestor_T_frame = parent_T_child ... ; ...'),
    M('b3-m14', 'core/tf.py',
      '            newest = min(newest, n)',
      '            newest = max(newest, n)',
      'newest_ns: the newest stamp *every* dynamic edge has reached (min over edges); max ...'),
    M('b3-m15', 'core/locator.py',
      '                if factor > 1.0 + cfg.size_tol:',
      '                if factor > cfg.size_tol:',
      'size gate: reject when size/range disagree by more than factor 1 + size_tol; dropped ...'),
    M('b3-m16', 'core/locator.py',
      '            if tr.missed > cfg.track_max_missed:',
      '            if tr.missed >= cfg.track_max_missed:',
      'tracking.max_missed: frames an unseen blob keeps its id reserved; >= retires one frame ...'),  # noqa: E501
    M('b3-m17', 'core/distances.py',
      '            err = 1000.0 * (p.mean_m - m) if p.frames else math.nan',
      '            err = 1000.0 * (m - p.mean_m) if p.frames else math.nan',
      'error_mm = mean(measured - true) (mm); sign reversed for known distances'),
    M('b3-m18', 'core/eye_to_hand.py',
      '        p, cov = target_in_base(_IDENTITY, self.base_T_cam, point_cam, cov_cam=cov_cam,',
      '        p, cov = target_in_base(self.base_T_cam, _IDENTITY, point_cam, cov_cam=cov_cam,',
      'covariance R cov_cam R^T + J cov_hand_eye J^T with J = [I, -[R p]x]; swapping robot ...'),
    M('b3-m19', 'core/localization.py',
      '        J = -Rb @ _skew(p_ee)         # d p_base = -R_b [p_ee]x dr (flange-frame perturbation)',  # noqa: E501
      '        J = -Rb @ _skew(p_base)         # d p_base = -R_b [p_ee]x dr (flange-frame perturbation)',  # noqa: E501
      'robot rotation noise about the flange: lever is p_ee (point in flange frame); wrong ...'),
    M('b3-m20', 'core/localization.py',
      '        pos = max(pos, float(estimated["translation_sigma_m"]))',
      '        pos = min(pos, float(estimated["translation_sigma_m"]))',
      'robot_pose_sigmas: per component the larger of stated and estimated; min lowers the ...'),
    M('b3-m21', 'core/pose_correction.py',
      '        return np.concatenate([r @ self.A_t.T, r @ self.A_r.T], axis=1)',
      '        return np.concatenate([r @ self.A_t, r @ self.A_r.T], axis=1)',
      'delta = [A_t r | A_r r]; A_t transposed in the batch path (apply of N poses, ...'),
    M('b3-m22', 'core/sync.py',
      '        oldest = min(received)',
      '        oldest = max(received)',
      'receive-age rule: refuse a bracket whose *older* pose was received more than ...'),
    M('b3-m23', 'io/config.py',
      '    R_ref = from_xyz_quat(np.zeros(3), q / norm)[:3, :3]',
      '    R_ref = from_xyz_quat(np.zeros(3), q / norm)[:3, :3].T',
      'robot_pose_correction.reference_quat_xyzw is R_ref; loaded transposed -> round trip ...'),
    M('b3-m24', 'io/config.py',
      '                "translation_m_per_rad": [[float(v) for v in row] for row in c.A_t]}',
      '                "translation_m_per_rad": [[float(v) for v in row] for row in c.A_r]}',
      'to_dict writes translation_m_per_rad = A_t; copy-paste writes A_r'),
    M('b3-m25', 'core/detection.py',
      '        shade = shade * (1.0 + SHADE_BLUR_GAIN * blur * blur)',
      '        shade = shade * (1.0 + SHADE_BLUR_GAIN * blur)',
      'shading term grows as SHADE_GAIN (1 + SHADE_BLUR_GAIN b^2) g; b instead of b^2'),
    M('b3-m26', 'core/detection.py',
      '        blur = math.sqrt(max(width * width - BLUR_W0_PX ** 2, 0.0)) if math.isfinite(width) \\',  # noqa: E501
      '        blur = math.sqrt(max(width * width - BLUR_W0_PX, 0.0)) if math.isfinite(width) \\',
      'blur b = sqrt(max(w^2 - BLUR_W0_PX^2, 0)); square of BLUR_W0_PX dropped -> blur ...'),
)


BATCHES = {"1": B1, "2": B2, "3": B3}


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    batch = "2"
    if "--batch" in args:
        i = args.index("--batch")
        batch = args[i + 1]
        del args[i:i + 2]
    if batch not in BATCHES:
        print(f"--batch: one of {', '.join(BATCHES)}")
        return 2
    table = BATCHES[batch]
    # batch 1's survivors joined the table (with their tests); later batches stay apart
    clash = sorted({m.name for m in table} & {m.name for m in mutation.MUTANTS})
    if clash and batch != "1":
        print(f"batch {batch}: names also in tools/mutation.py: {clash}")
        return 2
    mutation.MUTANTS = table
    mutation._run_tests = _run_tests
    mutation.print = _print  # type: ignore[attr-defined]
    mutation.TESTS = {m: broad_tests(m) for m in dict.fromkeys(x.module for x in table)}
    return mutation.main(args)


if __name__ == "__main__":
    sys.exit(main())
