"""Mutation testing of the core, io and offline layers: plant known bugs, see which the tests catch.

Each mutant is a small, realistic bug (a frame left unrotated, a tie rule flipped, a sort
removed, a term dropped): one exact text replacement in one source file, and the test files
that ought to catch it. For each mutant the file is changed, those tests run (``pytest -x``),
and the file is restored, whatever happens (also on Ctrl-C). A mutant is *caught* when the tests
fail, *survives* when they pass, and is *stale* when its text is no longer in the file (the code
moved on: update the mutant).

Usage::

    make mutation                        # every mutant
    .venv/bin/python tools/mutation.py -k sync -v

Prints one line per mutant and the score (caught / live mutants). Exit status 1 when a mutant
survives or is stale, so a release check can insist on a full score.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Mutant:
    name: str
    path: str          # relative to the repository root
    old: str           # exact text, must occur exactly once
    new: str
    tests: tuple[str, ...]
    what: str


MUTANTS: tuple[Mutant, ...] = (
    Mutant("triangulation-frame", "eye_in_hand/core/triangulation.py",
           "    cov = R1.T @ cov_rect @ R1\n", "    cov = cov_rect\n",
           ("test/core/test_triangulation_covariance.py", "test/core/test_triangulation.py"),
           "covariance left in the rectified frame instead of the left optical frame"),
    Mutant("triangulation-rectification-jacobian", "eye_in_hand/core/triangulation.py",
           "    return out[0], out[1], J\n", "    return out[0], out[1], np.eye(4)\n",
           ("test/core/test_triangulation_covariance.py",),
           "pixel noise not propagated through the rectification"),
    Mutant("sync-tie-rule", "eye_in_hand/core/sync.py",
           "            if gap <= abs(a2 - b):\n", "            if gap < abs(a2 - b):\n",
           ("test/core/test_sync_rules.py", "test/core/test_sync.py"),
           "stereo pairing tie goes to the later frame"),
    Mutant("sync-repeated-stamp", "eye_in_hand/core/sync.py",
           "if last_side is not None and stamp <= last_side:",
           "if last_side is not None and stamp < last_side:",
           ("test/core/test_sync_rules.py", "test/core/test_sync.py"),
           "a repeated stamp on one side is queued instead of dropped"),
    Mutant("detection-half-pixel", "eye_in_hand/core/detection.py",
           "    minor = 2.0 * math.sqrt(max(lam_min, 0.0)) + 0.5\n",
           "    minor = 2.0 * math.sqrt(max(lam_min, 0.0))\n",
           ("test/core/test_detection_minor_axis.py", "test/core/test_detection.py"),
           "half-pixel edge term of the silhouette's minor axis dropped"),
    Mutant("slerp-shorter-arc", "eye_in_hand/core/transforms.py",
           "    if sum(a * b for a, b in zip(q0, q1)) < 0.0:\n", "    if False:\n",
           ("test/core/test_transforms.py", "test/core/test_sync.py"),
           "pose interpolation takes the longer arc when quaternion signs differ"),
    Mutant("lerp-weights", "eye_in_hand/core/transforms.py",
           "    out[:3, 3] = (1.0 - s) * A[:3, 3] + s * B[:3, 3]\n",
           "    out[:3, 3] = s * A[:3, 3] + (1.0 - s) * B[:3, 3]\n",
           ("test/core/test_transforms.py", "test/core/test_sync.py"),
           "translation interpolation weights swapped"),
    Mutant("localization-handeye-jacobian", "eye_in_hand/core/localization.py",
           "J = Rb @ np.hstack([np.eye(3), -_skew(q)])", "J = Rb @ np.hstack([np.eye(3), _skew(q)])",
           ("test/core/test_localization_sources.py", "test/core/test_localization.py"),
           "sign of the hand-eye rotation term in the base-frame covariance"),
    Mutant("localization-robot-rotation", "eye_in_hand/core/localization.py",
           "        cov += robot_sigma_rot_rad ** 2 * (J @ J.T)\n", "        pass\n",
           ("test/core/test_localization_sources.py", "test/core/test_localization.py"),
           "robot rotation uncertainty left out of the base-frame covariance"),
    Mutant("handeye-translation", "eye_in_hand/core/handeye/solvers.py",
           "    rhs = (m.B[:, :3, 3] @ R.T - m.A[:, :3, 3]).reshape(3 * K)\n",
           "    rhs = (m.B[:, :3, 3] @ R - m.A[:, :3, 3]).reshape(3 * K)\n",
           ("test/core/test_handeye_solvers.py",),
           "hand-eye translation solved with the transposed rotation"),
    Mutant("scan-chunk-order", "eye_in_hand/io/bags/reading.py",
           "            msgs.sort(key=lambda r: r[1][1])\n", "            pass\n",
           ("test/io/test_mcap_recovery_order.py", "test/io/test_bags.py"),
           "messages recovered from an interrupted MCAP file not sorted by time"),
    Mutant("mcap-chunk-order", "eye_in_hand/io/mcap_chunks.py",
           "    infos.sort(key=lambda c: (c.message_start_time, c.chunk_start_offset))\n",
           "    infos.sort(key=lambda c: c.chunk_start_offset)\n",
           ("test/io/test_mcap_recovery_order.py", "test/io/test_mcap_chunks.py"),
           "MCAP chunks read in file order instead of time order"),
    Mutant("cdr-height-width", "eye_in_hand/io/cdr.py",
           "    height, width = _HW.unpack_from(body, pos)\n",
           "    width, height = _HW.unpack_from(body, pos)\n",
           ("test/io/test_cdr.py",),
           "image height and width swapped when decoding CDR"),
    Mutant("player-rate", "eye_in_hand/nodes/bag_player.py",
           "            rate = self.config.rate\n", "            rate = 1.0\n",
           ("test/commands/test_play.py",),
           "bag player ignores --rate"),
    Mutant("pose-receive-age", "eye_in_hand/core/sync.py",
           "        if now - oldest > max_age_ns:\n", "        if False:\n",
           ("test/core/test_sync.py",),
           "a robot pose received long ago is used (stale pose)"),
    Mutant("tf-receive-age", "eye_in_hand/core/tf.py",
           "        self._receipts.check_age(stamp_ns, now_ns, max_age_ns)\n", "",
           ("test/core/test_tf_staleness.py", "test/core/test_tf.py"),
           "the TF robot pose skips the receive-age rule"),
    Mutant("tf-interpolation", "eye_in_hand/core/tf.py",
           "        return self.history.lookup(stamp_ns, max_gap_ns)\n",
           "        return self.history.lookup(self.history.newest_ns, max_gap_ns)\n",
           ("test/core/test_tf.py",),
           "a TF edge answers with its newest sample instead of interpolating at the stamp"),
    Mutant("offline-unpaired-count", "eye_in_hand/offline.py",
           '        self.count("unpaired_left", sync.stats.dropped_left + pl)\n',
           '        self.count("unpaired_left", pl)\n',
           ("test/test_offline.py",),
           "left images dropped by the stereo pairing missing from the loss ledger"),
    Mutant("atomic-overwrite-mixes", "eye_in_hand/io/atomic.py",
           "    elif _exchange(staged, out):\n        _remove(staged)  # now the old folder\n",
           "    elif True:\n        for f in staged.iterdir():\n            os.replace(f, out / f.name)\n",
           ("test/io/test_atomic.py",),
           "--overwrite merges the new files into the old folder instead of replacing it whole"),
)


def _run_tests(tests: tuple[str, ...], timeout_s: float) -> tuple[bool, float]:
    """Run the tests; (passed, seconds)."""
    t0 = time.monotonic()
    try:
        proc = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p",
                               "no:cacheprovider", *tests], cwd=ROOT, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, timeout=timeout_s,
                              env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})
        passed = proc.returncode == 0
    except subprocess.TimeoutExpired:
        passed = False  # a mutant that hangs the tests is caught (by the time-out)
    return passed, time.monotonic() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-k", default="", help="only mutants whose name contains this")
    parser.add_argument("-v", action="store_true", help="say what each mutant does")
    parser.add_argument("--timeout", type=float, default=600.0, help="per mutant, seconds")
    args = parser.parse_args(argv)
    caught = survived = stale = 0
    for m in MUTANTS:
        if args.k not in m.name:
            continue
        path = ROOT / m.path
        original = path.read_text()
        if original.count(m.old) != 1:
            stale += 1
            print(f"STALE    {m.name}: its text is not (once) in {m.path}", flush=True)
            continue
        try:
            path.write_text(original.replace(m.old, m.new))
            passed, secs = _run_tests(m.tests, args.timeout)
        finally:
            path.write_text(original)
        if passed:
            survived += 1
        else:
            caught += 1
        label = "SURVIVED" if passed else "caught  "
        print(f"{label} {m.name} ({secs:.0f} s)" + (f": {m.what}" if args.v or passed else ""),
              flush=True)
    live = caught + survived
    print(f"mutation score: {caught}/{live} caught" + (f", {stale} stale" if stale else ""))
    return 0 if survived == 0 and stale == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
