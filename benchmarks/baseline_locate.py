"""Time another checkout's ``StereoLocator.locate`` on pairs handed over in a file: the child
process of ``bench_detection.py --baseline OTHER_CHECKOUT``.

Run by ``bench_detection.py`` with the checkout first on ``PYTHONPATH`` (never by hand)::

    python benchmarks/baseline_locate.py PAIRS.npz PARAMS.yaml CALIBRATION_DIR CV_THREADS

It imports only what every release of the package has (``core.camera.StereoRig.load``, the
locator and its parameter-file reader, under the module names of either layout), builds the
locator from the parameter file and the calibration directory, locates two pairs to warm up
and prints ``ready``. Then, for each line ``REPEATS PERIOD_S`` on its standard input, it
locates ``REPEATS`` pairs (the k-th pair of the file, cycled, as ``bench_detection.per_pair``
does) back to back, or one every ``PERIOD_S`` seconds when it is positive, and prints the
wall and CPU seconds per pair of that round (its own process). It exits at the end of its
input.
"""
from __future__ import annotations

import sys
import time

import cv2
import numpy as np


def _load_config(path: str):
    try:
        from eye_in_hand.core.locator_params import load_locator_config
    except ImportError:       # the first releases: the parameters beside the locator
        from eye_in_hand.core.locator import load_locator_config  # type: ignore[no-redef]
    return load_locator_config(path)


def main(argv: list[str]) -> int:
    pairs_path, params, calibration, threads = argv
    if int(threads) >= 0:
        cv2.setNumThreads(int(threads))
    from eye_in_hand.core.camera import StereoRig
    from eye_in_hand.core.locator import StereoLocator

    with np.load(pairs_path) as data:
        lefts, rights = data["left"], data["right"]
    imgs = [(np.ascontiguousarray(lefts[k]), np.ascontiguousarray(rights[k]))
            for k in range(len(lefts))]
    locator = StereoLocator(StereoRig.load(calibration), _load_config(params))
    for left, right in imgs[:2]:
        locator.locate(left, right)
    print("ready", flush=True)
    for line in sys.stdin:
        repeats, period_s = int(line.split()[0]), float(line.split()[1])
        wall = cpu = 0.0
        if period_s > 0:
            for k in range(repeats):
                c0, t0 = time.process_time(), time.perf_counter()
                locator.locate(*imgs[k % len(imgs)])
                dt = time.perf_counter() - t0
                wall, cpu = wall + dt, cpu + time.process_time() - c0
                time.sleep(max(0.0, period_s - dt))
        else:
            c0, t0 = time.process_time(), time.perf_counter()
            for k in range(repeats):
                locator.locate(*imgs[k % len(imgs)])
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        print(f"{wall / repeats!r} {cpu / repeats!r}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
