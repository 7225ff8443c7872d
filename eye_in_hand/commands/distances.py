"""``eye-in-hand distances``: pairwise target distances from the results of ``process``.

Example::

    eye-in-hand distances out/                      # out/results.csv of eye-in-hand process
    eye-in-hand distances out/results.csv --truth known.yaml --json

Reads the base-frame position of every target per frame from a ``results.csv`` (or a
``process`` output folder, or an output bag's ``/target/<id>/pose`` topics) and prints, for
every pair of targets, the mean and standard deviation of their distance over the frames where
both were located, with the error against the ground truth recorded in the results or against
known distances (``--truth FILE``), and each target's base-frame RMS error when the truth is
there.
"""
from __future__ import annotations

import argparse
import json
import sys

from eye_in_hand.core.distances import distance_table
from eye_in_hand.errors import InputError
from eye_in_hand.io.results import load_known_distances, load_tracks, summary_figures

HELP = "pairwise target distances (mean, std, error against the truth) from process results"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``eye-in-hand distances``."""
    parser.add_argument("results", metavar="RESULTS",
                        help="results.csv of eye-in-hand process, its output folder, or its "
                             "output bag")
    parser.add_argument("--truth", metavar="FILE",
                        help="YAML of known distances (distances: [{a: ID, b: ID, m: METRES}]);"
                             " default: the ground truth in the results, if any")
    parser.add_argument("--json", action="store_true",
                        help="print JSON (pairs, targets) instead of the table")


def run(args: argparse.Namespace) -> int:
    """Print the distance table; one error line for unusable input."""
    known = load_known_distances(args.truth) if args.truth else []
    tracks, truth, source = load_tracks(args.results)
    if len(tracks) < 2:
        raise InputError(f"{source}: one target ({', '.join(tracks)}): no distances to "
                         "compute")
    pairs, stats, unmatched = summary_figures(tracks, truth, known)
    if unmatched:
        a, b, _m = unmatched[0]
        raise InputError(f"{args.truth}: no target pair {a} - {b} in {source} (targets: "
                         f"{', '.join(tracks)})")
    frames = len(next(iter(tracks.values())))
    if args.json:
        print(json.dumps({"source": source, "frames": frames,
                          "truth": str(args.truth) if known else
                          ("ground_truth" if truth else None),
                          "distances": [p.to_dict() for p in pairs],
                          "targets": {s.id: s.to_dict() for s in stats}}, indent=2))
        return 0
    what = (f"truth from {args.truth}" if known else
            "truth from the recorded ground truth" if truth else "no truth")
    print(f"{source}: {len(tracks)} targets over {frames} frames; {what}")
    for line in distance_table(pairs, stats):
        print(line)
    if not any(p.frames for p in pairs):
        print("warning: no frame has two targets located", file=sys.stderr)
    return 0
