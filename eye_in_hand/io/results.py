"""The files of ``eye-in-hand process``: every located target per frame, written and read back.

Written by :func:`write_results` into ``OUT`` (a rosbag2 bag with ``results.csv`` and
``summary.json`` beside its files):

* the bag: the messages the live ``detect_triangulate`` and ``hand_eye`` nodes publish for the
  same frames, with the same frames and stamps, built by the nodes' own builders
  (:mod:`eye_in_hand.ros.outputs`): ``/target/point``, ``/target/point_cov``,
  ``/targets/markers``, ``/targets/<id>/point(_cov)`` (left optical frame), ``/target/pose``,
  ``/target/pose_cov``, ``/target/<id>/pose(_cov)``, ``/target/poses``, ``/target/markers``,
  ``/tf`` (``base_frame -> target_<id>``) (base frame), ``/hand_eye/transform`` and
  ``/tf_static`` (at the first frame); and, offline only, ``/target/<id>/ground_truth``
  (PointStamped, base frame: the true target matched to this id, when the input bag had
  ground truth);
* ``results.csv``: one row per stereo pair and target id (:data:`CSV_COLUMNS`; the ``target``
  column is the id), rows of one pair together, targets in :func:`target_order`;
* ``summary.json``: counts and error statistics of the first target (as before), per-target
  figures (``targets``, with how each id was matched to the ground truth) and the pairwise
  distances (``distances``, :mod:`eye_in_hand.core.distances`).

Read back by :func:`load_tracks` (a ``results.csv``, a folder holding one, or an output bag)
for ``eye-in-hand distances``; known distances by :func:`load_known_distances`.

The result types of a run (:class:`TargetResult`, :class:`FrameResult`, :class:`ProcessResult`)
live here, below both this writer and :mod:`eye_in_hand.offline`, which fills them.

No rclpy: messages are built with the bag writer's type store
(:class:`eye_in_hand.ros.outputs.RosbagsTypes`).
"""
from __future__ import annotations

import csv
import dataclasses
import json
import math
import re
from array import array
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from eye_in_hand.core.distances import (
    PairDistance,
    TargetStats,
    apply_known_distances,
    match_truth,
    pairwise_distances,
    target_stats,
)
from eye_in_hand.errors import BagError, ConfigError, InputError
from eye_in_hand.io.bags import (
    BagWriter,
    bag_info,
    default_typestore,
    deserialize,
    iter_messages,
)
from eye_in_hand.io.bags.writing import type_definition
from eye_in_hand.io.spill import SpillList, apply_to
from eye_in_hand.ros.outputs import (
    OutputSettings,
    RosbagsTypes,
    Sphere,
    tf_message,
    transform_stamped,
)
from eye_in_hand.ros.outputs_cdr import (
    point_cdr,
    point_pose_cdr,
    point_stamped_cdr,
    pose_array_cdr,
    sphere_markers_cdr,
    translation_tf_cdr,
)
from eye_in_hand.yamlfile import read_yaml_file

if TYPE_CHECKING:  # annotations only: core.camera imports OpenCV, which `distances` never needs
    from eye_in_hand.core.camera import StereoRig

__all__ = ["TargetResult", "FrameResult", "ProcessResult", "OutputOptions", "CSV_COLUMNS",
           "OFFLINE_ONLY", "output_messages", "compare_outputs", "target_order", "assign_truth",
           "TruthTable", "frame_tracks", "error_figures", "summary_figures", "run_figures",
           "write_results", "prepare_output_types", "load_tracks", "load_known_distances",
           "Tracks"]

#: Columns of ``results.csv``: the first 21 as before per-target rows existed, then ``target``.
CSV_COLUMNS = ["stamp_ns", "status", "x_cam", "y_cam", "z_cam", "residual_px", "left_u",
               "left_v", "right_u", "right_v", "x_base", "y_base", "z_base", "sigma_x_mm",
               "sigma_y_mm", "sigma_z_mm", "gt_x", "gt_y", "gt_z", "error_mm", "reason",
               "target"]


def _error_m(point_base: np.ndarray | None, truth_base: np.ndarray | None) -> float:
    """Distance of a base-frame result to its ground truth (m), NaN when either is missing."""
    if point_base is None or truth_base is None:
        return math.nan
    return float(np.linalg.norm(point_base - truth_base))


@dataclass(slots=True)
class TargetResult:
    """One located target in one stereo pair.

    Attributes:
        id: the target id (``TargetLocation.id``); name: its configured target name.
        point_cam, cov_cam: shape (3,) and (3, 3), left optical frame.
        residual_px: RMS reprojection residual; left_px, right_px: centres, shape (2,).
        status: ``"located"``, then ``"ok"`` (in the base frame) or ``"no_robot_pose"``.
        reason: why it is not in the base frame.
        point_base, cov_base: the base-frame result.
        truth_base: the matched ground-truth target at this stamp.
    """

    id: str
    name: str
    point_cam: np.ndarray
    cov_cam: np.ndarray
    residual_px: float
    left_px: np.ndarray
    right_px: np.ndarray
    status: str = "located"
    reason: str = ""
    point_base: np.ndarray | None = None
    cov_base: np.ndarray | None = None
    truth_base: np.ndarray | None = None

    @property
    def error_m(self) -> float:
        """Distance to the ground truth (m), NaN when either is missing."""
        return _error_m(self.point_base, self.truth_base)


@dataclass(slots=True)
class FrameResult:
    """One stereo pair's outcome.

    Attributes:
        stamp_ns: the image stamp.
        status: ``"ok"``, ``"no_target"`` (with the locator's reason in ``reason``),
            ``"no_robot_pose"`` (located in the camera, but no robot pose brackets the stamp),
            or ``"bad_image"`` (an image that does not decode, or of the wrong size; counted in
            ``bad_messages``).
        point_cam, cov_cam, residual_px, left_px, right_px: the triangulation (when located).
        point_base, cov_base: the base-frame result (status ok).
        truth_base: the ground-truth target at this stamp, when the bag has it.
        targets: every located target (:class:`TargetResult`), the first target (the one of
            the fields above) first when it was located.
        missing: target name (or id) -> why it was not located.
        truth_by_id: target id -> its matched ground-truth target at this stamp, for every
            matched id, located here or not (set by :func:`eye_in_hand.io.results.
            assign_truth`; the ``gt_*`` columns of a target's ``no_target`` rows).
    """

    stamp_ns: int
    status: str
    reason: str = ""
    point_cam: np.ndarray | None = None
    cov_cam: np.ndarray | None = None
    residual_px: float = math.nan
    left_px: np.ndarray | None = None
    right_px: np.ndarray | None = None
    point_base: np.ndarray | None = None
    cov_base: np.ndarray | None = None
    truth_base: np.ndarray | None = None
    targets: list[TargetResult] = field(default_factory=list)
    missing: dict[str, str] = field(default_factory=dict)
    truth_by_id: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def error_m(self) -> float:
        """Distance to the ground truth (m), NaN when either is missing."""
        return _error_m(self.point_base, self.truth_base)


@dataclass
class ProcessResult:
    """All frames, counters, and what the bag covered.

    ``frames``: every stereo pair's outcome in stamp order; ``process`` keeps them in a
    :class:`~eye_in_hand.io.spill.SpillList` (the older ones in a temporary file on long bags:
    read them by iterating, and change them with :func:`~eye_in_hand.io.spill.apply_to`).

    ``located_in_processes``: pairs located by worker processes (the rest in this process);
    ``workers_forked``: those processes were forked from this one (else fresh interpreters,
    or none: :class:`eye_in_hand.workers.ProcessPool`'s ``fork``).
    ``damage``: the damaged parts of the bag that were skipped (a
    :class:`eye_in_hand.io.bags.DamageLog`: chunks, truncated tails, messages that could not
    be read; messages of the processed topics read but not decodable are
    ``counts['bad_messages']``).
    ``target_ids``: every target id, in :func:`eye_in_hand.io.results.target_order`;
    ``truth_match``: id -> matched ground-truth index (:func:`eye_in_hand.io.results.
    assign_truth`).
    """

    frames: list[FrameResult] | SpillList[FrameResult] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    duration_s: float = 0.0
    rig: StereoRig | None = None
    located_in_processes: int = 0
    workers_forked: bool = False
    damage: Any = None
    loss: dict[str, Any] = field(default_factory=dict)
    target_ids: list[str] = field(default_factory=list)
    truth_match: dict[str, dict[str, Any]] = field(default_factory=dict)


class OutputOptions(Protocol):
    """What :func:`write_results` reads of the run's options
    (:class:`eye_in_hand.offline.ProcessOptions`)."""

    @property
    def outputs(self) -> OutputSettings: ...

    @property
    def camera_frame(self) -> str: ...

    @property
    def base_frame(self) -> str: ...


def _natural(text: str) -> list[Any]:
    return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", text)]


def target_order(frames: Iterable[FrameResult], names: Sequence[str], *,
                 seen: Mapping[str, set[str]] | None = None) -> list[str]:
    """Every target id of a run: ids located in any frame, in the order of the configured
    target names (then natural order: ``red_2`` before ``red_10``); a configured name never
    located appears as its own id (so the first target always has rows).

    ``seen``: target name -> the ids located under it, in the order the names first
    appeared, collected as the frames were taken (``process``); the frames are then not
    read."""
    by_name: dict[str, set[str]] = {n: set() for n in names}
    if seen is None:
        for f in frames:
            for t in f.targets:
                by_name.setdefault(t.name, set()).add(t.id)
    else:
        for name, found in seen.items():
            by_name.setdefault(name, set()).update(found)
    out: list[str] = []
    for name, ids in by_name.items():
        out += sorted(ids, key=_natural) if ids else [name]
    return out


class TruthTable(Mapping[int, list[np.ndarray]]):
    """The ground truth of a run as :func:`assign_truth` reads it: image stamp -> the true
    target centres at that stamp (base frame), in the order they were added.

    Held as two columns (24 bytes of coordinates and 8 of stamp a point, instead of about
    300 bytes in a dict of lists of arrays: 5 MB less on a 10-minute bag at 30 Hz); the
    stamps are sorted once, at the first lookup after an :meth:`add`. Each lookup gives a new
    list of (3,) arrays (read-only views of the table).
    """

    def __init__(self) -> None:
        self._stamps = array("q")
        self._xyz = array("d")
        self._sorted: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] \
            | None = None

    def add(self, stamp_ns: int, xyz: np.ndarray) -> None:
        """One true target centre at ``stamp_ns``, after those already there at that stamp."""
        x, y, z = (float(v) for v in xyz)
        self._stamps.append(stamp_ns)
        self._xyz.extend((x, y, z))
        self._sorted = None

    def _index(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(distinct stamps in first-added order, the same sorted, where each sorted one's
        rows start in ``order`` (one more: the end), ``order``: the rows sorted by stamp,
        those of a stamp in the order added, the points (N, 3) read-only), built once after
        the last add."""
        if self._sorted is None:
            points = np.array(self._xyz, dtype=np.float64).reshape(-1, 3)
            points.flags.writeable = False
            stamps = np.array(self._stamps, dtype=np.int64)
            order = np.argsort(stamps, kind="stable")
            by_stamp = stamps[order]
            keys, starts = np.unique(by_stamp, return_index=True)
            first = order[starts]                   # each stamp's first row
            added = keys[np.argsort(first, kind="stable")]
            self._sorted = (added, keys, np.append(starts, len(by_stamp)), order, points)
        return self._sorted

    def __getitem__(self, stamp_ns: int) -> list[np.ndarray]:
        _, keys, bounds, order, points = self._index()
        i = int(np.searchsorted(keys, stamp_ns))
        if i == len(keys) or keys[i] != stamp_ns:
            raise KeyError(stamp_ns)
        return [points[j] for j in order[bounds[i]:bounds[i + 1]]]

    def __iter__(self) -> Iterator[int]:
        return iter(int(k) for k in self._index()[0])

    def __len__(self) -> int:
        return len(self._index()[1])


def assign_truth(frames: Iterable[FrameResult], truth: Mapping[int, list[np.ndarray]],
                 ids: Sequence[str], *, located: Mapping[str, Sequence[Any]] | None = None
                 ) -> dict[str, dict[str, Any]]:
    """Match the ground-truth targets to the located ids and set every ``truth_base``.

    ``truth``: image stamp -> the true target centres at it (base frame, the simulator's
    ``world.targets`` order). Each id's median base-frame position over the frames where it
    was localized is matched to the median of each true target over the stamps (the
    assignment with the smallest sum of distances, :func:`~eye_in_hand.core.distances.
    match_truth`; no distance limit, so a gross error shows as one). Each target's
    ``truth_base`` is then its matched true target at the frame's stamp; the frame's own
    ``truth_base`` (the first target's, for the summary's first-target figures) is the first
    target's match, or true target 0 when the first target was never localized. Every
    matched id's true target at the stamp also goes into the frame's ``truth_by_id``, located
    there or not (the ``gt_*`` columns of its ``no_target`` rows, as with one target before).
    The frames are changed with :func:`~eye_in_hand.io.spill.apply_to` (a
    :class:`~eye_in_hand.io.spill.SpillList`'s frames in its file as they are read).
    ``located``: id -> its base-frame positions (3-vectors, or their coordinates one after
    the other), collected as the frames were located (``process``); else they are read from
    the frames.

    Returns:
        id -> ``{"truth_index": k, "distance_mm": median distance}`` for the matched ids.
    """
    if not truth:
        return {}
    k_max = max(len(v) for v in truth.values())
    true_med = np.array([np.median([v[k] for v in truth.values() if len(v) > k], axis=0)
                         for k in range(k_max)])
    if located is None:
        positions: dict[str, Any] = {i: [] for i in ids}
        for f in frames:
            for t in f.targets:
                if t.point_base is not None:
                    positions.setdefault(t.id, []).append(t.point_base)
    else:                                   # the ids' order, as when read from the frames
        positions = {i: located.get(i, []) for i in ids}
        for i, p in located.items():
            positions.setdefault(i, p)
    med = {i: np.median(np.asarray(p, dtype=np.float64).reshape(-1, 3), axis=0)
           for i, p in positions.items() if len(p)}
    match = match_truth(med, true_med)
    first = ids[0] if ids else ""

    def set_truth(f: FrameResult) -> None:
        at = truth.get(f.stamp_ns)
        if at is None:
            return
        f.truth_by_id = {i: at[k] for i, k in match.items() if k < len(at)}
        for t in f.targets:
            t.truth_base = f.truth_by_id.get(t.id)
        if f.targets and f.status in ("located", "ok", "no_robot_pose"):
            k0 = match.get(f.targets[0].id)     # the first target's id in this frame
        else:
            k0 = match.get(first, None if match else 0)
        f.truth_base = at[k0] if k0 is not None and k0 < len(at) else None

    apply_to(frames, set_truth)
    return {i: {"truth_index": k, "distance_mm": 1000.0 * float(np.linalg.norm(med[i] -
                                                                             true_med[k]))}
            for i, k in match.items()}


Tracks = dict[str, np.ndarray]


def frame_tracks(frames: Sequence[FrameResult], ids: Sequence[str]) -> tuple[Tracks, Tracks]:
    """Base-frame positions and ground truth per id, shape (N frames, 3), NaN where none."""
    pos, true, _, _ = _scan(frames, ids)
    return pos, true


def _scan(frames: Sequence[FrameResult], ids: Sequence[str]
          ) -> tuple[Tracks, Tracks, dict[str, int], np.ndarray]:
    """One pass over the frames: :func:`frame_tracks`' tracks, how many frames located each id
    in the camera, and the first target's error to its ground truth in each frame that has
    both (m)."""
    n = len(frames)
    pos = {i: np.full((n, 3), np.nan) for i in ids}
    true = {i: np.full((n, 3), np.nan) for i in ids}
    in_camera = {i: 0 for i in ids}
    errs = []
    for r, f in enumerate(frames):
        for t in f.targets:
            in_camera[t.id] = in_camera.get(t.id, 0) + 1
            if t.id not in pos:
                continue
            if t.point_base is not None:
                pos[t.id][r] = t.point_base
            if t.truth_base is not None:
                true[t.id][r] = t.truth_base
        for i, g in f.truth_by_id.items():      # the truth where an id was not located
            if i in true and not np.isfinite(true[i][r]).all():
                true[i][r] = g
        err = f.error_m
        if math.isfinite(err):
            errs.append(err)
    return (pos, {i: v for i, v in true.items() if np.isfinite(v).any()}, in_camera,
            np.array(errs))


def error_figures(errs_m: np.ndarray) -> dict[str, float] | None:
    """RMS, p95, max and mean of errors given in m, in mm, with their count (None if none):
    ``summary.json``'s ``error``."""
    if errs_m.size == 0:
        return None
    return {"frames": int(errs_m.size),
            "rms_mm": 1000.0 * float(np.sqrt(np.mean(errs_m ** 2))),
            "p95_mm": 1000.0 * float(np.percentile(errs_m, 95)),
            "max_mm": 1000.0 * float(errs_m.max()), "mean_mm": 1000.0 * float(errs_m.mean())}


def summary_figures(tracks: Tracks, truth: Tracks,
                    known: Sequence[tuple[str, str, float]] = ()
                    ) -> tuple[list[PairDistance], list[TargetStats],
                               list[tuple[str, str, float]]]:
    """Pairwise distances (truth: ``known`` where given, else the ground truth) and per-target
    figures; also the known entries that name no measured pair."""
    pairs = pairwise_distances(tracks, truth or None)
    unmatched: list[tuple[str, str, float]] = []
    if known:
        pairs, unmatched = apply_known_distances(pairs, known)
    return pairs, target_stats(tracks, truth or None), unmatched


def run_figures(result: ProcessResult, known: Sequence[tuple[str, str, float]] = ()
                ) -> tuple[dict[str, Any], list[PairDistance], list[TargetStats],
                           list[tuple[str, str, float]]]:
    """The per-target and distance figures of a run, for ``summary.json`` and the table, from
    one pass over its frames.

    Returns:
        ``(summary keys, pairs, per-target stats, known entries naming no measured pair)``:
        the keys are ``error`` (the first target's error statistics, :func:`error_figures`),
        ``targets`` (id -> ``located`` (in the camera), ``localized`` (in the base frame),
        ``truth_frames``, ``rms_mm``, ``max_mm``, ``truth_index``, ``truth_distance_mm``) and
        ``distances`` (one entry per pair, see
        :meth:`~eye_in_hand.core.distances.PairDistance.to_dict`).
    """
    ids = list(result.target_ids)
    tracks, truth, in_camera, errs = _scan(result.frames, ids)
    pairs, stats, unmatched = summary_figures(tracks, truth, known)
    targets: dict[str, Any] = {}
    for st in stats:
        d = st.to_dict()
        match = result.truth_match.get(st.id, {})
        targets[st.id] = {"located": in_camera.get(st.id, 0), "localized": d.pop("located"),
                          **d, "truth_index": match.get("truth_index"),
                          "truth_distance_mm": match.get("distance_mm")}
    return ({"error": error_figures(errs), "targets": targets,
             "distances": [p.to_dict() for p in pairs]}, pairs, stats, unmatched)


def _topic_id(target_id: str) -> str:
    """The id as a ROS name token (characters other than letters, digits and _ become _)."""
    token = re.sub(r"[^A-Za-z0-9_]", "_", target_id)
    return token if token and not token[0].isdigit() else f"t_{token}"


def write_results(out: str | Path, result: ProcessResult, opts: OutputOptions | None = None,
                  *, storage: str = "mcap", summary_extra: Mapping[str, Any] | None = None
                  ) -> dict[str, Path]:
    """Write ``OUT`` as a bag with ``OUT/results.csv`` and ``OUT/summary.json`` (module
    docstring). ``summary_extra``: more keys for ``summary.json`` (``error``, the first
    target's error statistics; the figures of :func:`run_figures`).

    Raises:
        BagError: OUT exists or cannot be written.
    """
    out = Path(out)
    if out.exists():
        raise BagError(f"{out}: output exists already (choose a new -o)")
    ids = list(result.target_ids)
    csv_path = out / "results.csv"
    # one pass over the frames (on a long bag most are read back from a temporary file); the
    # shared Jazzy type store (nothing is registered in it: every output type is Jazzy's),
    # whose definitions and serializers prepare_output_types may have made already
    with BagWriter(out, storage=storage, typestore=default_typestore()) as writer, \
            csv_path.open("w", newline="") as fh:
        topics = _Topics(writer, getattr(opts, "outputs", None) or OutputSettings())
        camera_frame = getattr(opts, "camera_frame", "camera_left_optical_frame")
        base_frame = getattr(opts, "base_frame", "base_link")
        w = csv.writer(fh)
        w.writerow(CSV_COLUMNS)
        first = True
        for f in result.frames:
            for row in _rows(f, ids):
                w.writerow(row)
            if f.status == "bad_image":
                continue    # the live detector publishes nothing for a pair whose image is bad
            if first:
                topics.static(f.stamp_ns, camera_frame)
                first = False
            topics.frame(f, camera_frame, base_frame)
    summary = {"counts": result.counts, "bag_duration_s": result.duration_s,
               "error": None,        # the first target's statistics: the caller's
               "damage": result.damage.to_dict() if result.damage is not None else None}
    summary.update(summary_extra or {})
    summary_path = out / "summary.json"
    summary_path.write_text(json.dumps(summary, indent=2))
    return {"bag": out, "csv": csv_path, "summary": summary_path}


def prepare_truth_matching() -> None:
    """Load now what :func:`assign_truth` loads at its first ``np.median``: NumPy's
    ``numpy.ma`` (the median's NaN check asks for it; about 8 ms the first time in a process).
    ``process`` runs it while it waits for its worker processes, so that the ground-truth
    matching after the pass does not wait for it."""
    import numpy.ma  # noqa: F401  (local: loaded for its side effect, once)


def prepare_output_types() -> None:
    """Generate now what :func:`write_results` needs once per process, in the shared type
    store it writes with: each output type's definition (stored in the bag per topic) and the
    serializers of the messages built as ``rosbags`` objects (``/hand_eye/transform``,
    ``/tf_static``); about 15 ms of code generation. And the writer's modules, and the
    ``rosbags`` version its MCAP header names (``importlib.metadata``: 5-8 ms the first time
    in a process, 0.3 ms after). ``process`` runs it while it waits for its worker processes,
    so that the output files do not wait for it after the pass."""
    from importlib.metadata import version  # local: only the output files need it

    from eye_in_hand.io.bags.writing import writer_class

    writer_class()
    version("rosbags")
    store = default_typestore()
    for msgtype in dict.fromkeys(_FRAME_TOPICS.values()):
        type_definition(store, msgtype)
    for msgtype in _BUILT_TYPES:
        store.get_msgdef(msgtype)


#: Topic -> message type of the output bag (per-target topics: ``{id}`` in the name).
_FRAME_TOPICS = {
    "/target/point": "geometry_msgs/msg/PointStamped",
    "/target/point_cov": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "/targets/markers": "visualization_msgs/msg/MarkerArray",
    "/targets/{id}/point": "geometry_msgs/msg/PointStamped",
    "/targets/{id}/point_cov": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "/target/pose": "geometry_msgs/msg/PoseStamped",
    "/target/pose_cov": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "/target/{id}/pose": "geometry_msgs/msg/PoseStamped",
    "/target/{id}/pose_cov": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "/target/poses": "geometry_msgs/msg/PoseArray",
    "/target/markers": "visualization_msgs/msg/MarkerArray",
    "/hand_eye/transform": "geometry_msgs/msg/TransformStamped",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/target/{id}/ground_truth": "geometry_msgs/msg/PointStamped",
}
#: The output types written as ``rosbags`` message objects (:meth:`_Topics.static`), not bytes
_BUILT_TYPES = ("geometry_msgs/msg/TransformStamped", "tf2_msgs/msg/TFMessage")


class _Topics:
    """The output bag: the messages the live ``detect_triangulate`` and ``hand_eye`` publish
    for the same frames (the bytes they publish, :mod:`eye_in_hand.ros.outputs_cdr`; the
    latched ones built by :mod:`eye_in_hand.ros.outputs`), plus the ground truth."""

    def __init__(self, writer: Any, settings: OutputSettings) -> None:
        self.w = writer
        self.s = settings
        self.T = RosbagsTypes(writer.typestore)
        self.added: set[str] = set()

    def write(self, topic: str, stamp: int, msg: Any) -> None:
        if topic not in self.added:
            key = re.sub(r"^(/targets?/)[^/]+/(point|point_cov|pose|pose_cov|ground_truth)$",
                         r"\1{id}/\2", topic)
            self.w.add_topic(topic, _FRAME_TOPICS[key])
            self.added.add(topic)
        self.w.write(topic, stamp, msg)

    def static(self, stamp: int, camera_frame: str) -> None:
        """``/hand_eye/transform`` and ``/tf_static`` at the first frame (hand_eye latches both
        at the first image stamp it receives)."""
        s, T = self.s, self.T
        if s.hand_eye_T is None:
            return
        self.write("/hand_eye/transform", stamp, transform_stamped(
            T, s.hand_eye_T, stamp, s.camera_parent, camera_frame))
        if not s.publish_tf:
            return
        edges = [(s.camera_parent, camera_frame, stamp, s.hand_eye_T)]
        if s.stereo_T is not None:
            edges.insert(0, (camera_frame, s.right_camera_frame, stamp, s.stereo_T))
        self.write("/tf_static", stamp, tf_message(T, edges))

    def frame(self, f: FrameResult, camera_frame: str, base_frame: str) -> None:
        """One frame's messages, as CDR bytes (:mod:`eye_in_hand.ros.outputs_cdr`: the bytes
        of :mod:`eye_in_hand.ros.outputs`' messages, what the live nodes publish)."""
        s, stamp = self.s, f.stamp_ns
        # detect_triangulate: the first target, every target, the frame's list
        if f.point_cam is not None and f.cov_cam is not None:
            cov_msg, point_msg = point_cdr(f.point_cam, f.cov_cam, stamp, camera_frame)
            self.write("/target/point_cov", stamp, cov_msg)
            self.write("/target/point", stamp, point_msg)
        spheres = []
        for t in f.targets:
            tid = _topic_id(t.id)
            cov_msg, point_msg = point_cdr(t.point_cam, t.cov_cam, stamp, camera_frame)
            self.write(f"/targets/{tid}/point_cov", stamp, cov_msg)
            self.write(f"/targets/{tid}/point", stamp, point_msg)
            spheres.append(Sphere(t.id, t.point_cam, *s.style(t.name)))
        self.write("/targets/markers", stamp, sphere_markers_cdr(
            spheres, stamp, camera_frame, s.camera_markers_lifetime_s))
        # hand_eye: the first target, every target, the frame's lists, /tf
        if f.point_base is not None and f.cov_base is not None:
            pose_msg, cov_msg = point_pose_cdr(f.point_base, f.cov_base, stamp, base_frame)
            self.write("/target/pose", stamp, pose_msg)
            self.write("/target/pose_cov", stamp, cov_msg)
            if s.publish_tf and s.target_frame:
                self.write("/tf", stamp, translation_tf_cdr(
                    [(base_frame, s.target_frame, stamp, f.point_base)]))
        located, edges = [], []
        for t, sphere in zip(f.targets, spheres, strict=True):
            if t.point_base is None or t.cov_base is None:
                continue
            tid = _topic_id(t.id)
            pose_msg, cov_msg = point_pose_cdr(t.point_base, t.cov_base, stamp, base_frame)
            self.write(f"/target/{tid}/pose_cov", stamp, cov_msg)
            self.write(f"/target/{tid}/pose", stamp, pose_msg)
            located.append(Sphere(t.id, t.point_base, sphere.diameter_m, sphere.rgba))
            if s.target_frame_prefix:
                edges.append((base_frame, s.target_frame_prefix + t.id, stamp, t.point_base))
        self.write("/target/poses", stamp, pose_array_cdr([x.xyz for x in located], stamp,
                                                          base_frame))
        self.write("/target/markers", stamp, sphere_markers_cdr(
            located, stamp, base_frame, s.target_markers_lifetime_s))
        if edges and s.publish_tf:
            self.write("/tf", stamp, translation_tf_cdr(edges))
        for t in f.targets:
            if t.truth_base is not None:
                self.write(f"/target/{_topic_id(t.id)}/ground_truth", stamp,
                           point_stamped_cdr(t.truth_base, stamp, base_frame))


def _rows(f: FrameResult, ids: Sequence[str]) -> list[list[Any]]:
    """The CSV rows of one stereo pair: one per target id."""
    def cols(v: np.ndarray | None, n: int) -> list[str]:
        return [repr(float(x)) for x in v] if v is not None else [""] * n

    by_id = {t.id: t for t in f.targets}
    rows = []
    for i in ids:
        t = by_id.get(i)
        if t is None:
            status = "bad_image" if f.status == "bad_image" else "no_target"
            reason = f.reason if f.status == "bad_image" else f.missing.get(
                i, f.missing.get(i.rpartition("_")[0], ""))
            # the truth of a target not located here, when known: its match, or (one
            # target, never localized) the frame's truth, as results.csv always had it
            gt = f.truth_by_id.get(i)
            if gt is None and len(ids) == 1:
                gt = f.truth_base
            rows.append([f.stamp_ns, status, *[""] * 14, *cols(gt, 3), "", reason, i])
            continue
        sig = ([f"{1000.0 * math.sqrt(max(t.cov_base[k, k], 0.0)):.6f}" for k in range(3)]
               if t.cov_base is not None else [""] * 3)
        err = t.error_m
        rows.append([f.stamp_ns, t.status, *cols(t.point_cam, 3),
                     "" if math.isnan(t.residual_px) else f"{t.residual_px:.6f}",
                     *cols(t.left_px, 2), *cols(t.right_px, 2), *cols(t.point_base, 3), *sig,
                     *cols(t.truth_base, 3), "" if math.isnan(err) else f"{1000 * err:.6f}",
                     t.reason, i])
    return rows


# -- reading back ----------------------------------------------------------------------------
def _float(text: str, where: str) -> float:
    try:
        return float(text) if text != "" else math.nan
    except ValueError as exc:
        raise InputError(f"{where}: not a number: {text!r}") from exc


def _read_csv(path: Path) -> tuple[Tracks, Tracks]:
    try:
        fh = path.open(newline="")
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    with fh:
        reader = csv.DictReader(fh)
        need = {"stamp_ns", "status", "x_base", "y_base", "z_base"}
        header = set(reader.fieldnames or ())
        if not need <= header:
            raise InputError(f"{path}: not a results.csv of eye-in-hand process (missing "
                             f"columns {', '.join(sorted(need - header))})")
        if "target" not in header:
            raise InputError(f"{path}: no 'target' column (written before per-target rows): "
                             "one target, no distances")
        frames: list[dict[str, tuple[np.ndarray, np.ndarray]]] = []
        last_stamp = None
        for n, row in enumerate(reader, start=2):
            where = f"{path}:{n}"
            tid, stamp = row["target"], row["stamp_ns"]
            if not tid:
                raise InputError(f"{where}: empty target")
            if not frames or stamp != last_stamp or tid in frames[-1]:
                frames.append({})
            last_stamp = stamp
            p = np.array([_float(row[k], where) for k in ("x_base", "y_base", "z_base")])
            if row["status"] != "ok":
                p[:] = math.nan
            g = np.array([_float(row.get(k) or "", where) for k in ("gt_x", "gt_y", "gt_z")])
            frames[-1][tid] = (p, g)
    return _stack(frames, str(path))


def _stack(frames: list[dict[str, tuple[np.ndarray, np.ndarray]]],
           source: str) -> tuple[Tracks, Tracks]:
    ids: list[str] = []
    for fr in frames:
        ids += [i for i in fr if i not in ids]
    pos = {i: np.full((len(frames), 3), np.nan) for i in ids}
    true = {i: np.full((len(frames), 3), np.nan) for i in ids}
    for r, fr in enumerate(frames):
        for i, (p, g) in fr.items():
            pos[i][r], true[i][r] = p, g
    if not ids:
        raise InputError(f"{source}: no results")
    return pos, {i: v for i, v in true.items() if np.isfinite(v).any()}


def _read_bag(path: Path) -> tuple[Tracks, Tracks]:
    info = bag_info(path)
    pat = re.compile(r"^/target/([A-Za-z0-9_]+)/(pose|ground_truth)$")
    topics = {t: m for t in info.topics if (m := pat.match(t))}
    if not any(m.group(2) == "pose" for m in topics.values()):
        raise InputError(f"{path}: no /target/<id>/pose topics (not an output bag of "
                         "eye-in-hand process, or written before per-target topics)")
    by_stamp: dict[int, dict[str, list[np.ndarray]]] = {}
    for topic, msgtype, _t, raw in iter_messages(path, list(topics)):
        m = topics[topic]
        msg = deserialize(raw, msgtype)
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        p = msg.pose.position if m.group(2) == "pose" else msg.point
        entry = by_stamp.setdefault(stamp, {}).setdefault(
            m.group(1), [np.full(3, np.nan), np.full(3, np.nan)])
        entry[0 if m.group(2) == "pose" else 1] = np.array([p.x, p.y, p.z])
    frames = [{i: (v[0], v[1]) for i, v in by_stamp[s].items()} for s in sorted(by_stamp)]
    return _stack(frames, str(path))


def load_tracks(path: str | Path) -> tuple[Tracks, Tracks, str]:
    """Base-frame tracks and ground truth per target from a ``results.csv``, an output folder
    of ``process`` (its ``results.csv``) or an output bag (its ``/target/<id>/pose`` and
    ``/target/<id>/ground_truth`` topics, frames by stamp).

    Returns:
        ``(tracks, truth, what was read)``, each id -> shape (N, 3), NaN where none.

    Raises:
        InputError: missing path, not a results file or output bag, malformed rows.
        BagError: a bag that cannot be read.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: not found")
    if p.is_dir() and (p / "results.csv").is_file():
        return (*_read_csv(p / "results.csv"), str(p / "results.csv"))
    if p.is_file() and p.suffix == ".csv":
        return (*_read_csv(p), str(p))
    try:
        return (*_read_bag(p), str(p))
    except BagError as exc:
        raise InputError(f"{p}: neither a results.csv nor a readable output bag ({exc})"
                         ) from exc


def load_known_distances(path: str | Path) -> list[tuple[str, str, float]]:
    """Known distances between target centres, from YAML::

        distances:
          - {a: red, b: blue, m: 0.1234}     # target ids, metres (> 0)

    Raises:
        ConfigError: missing file, not YAML, wrong layout, a bad entry (named by index), a
            pair given twice.
    """
    data = read_yaml_file(path, "known-distances file")
    if not isinstance(data, Mapping) or not isinstance(data.get("distances"), list):
        raise ConfigError(f"{path}: expected a mapping with a 'distances' list of "
                          "{a: ID, b: ID, m: METRES}")
    out: list[tuple[str, str, float]] = []
    seen: set[frozenset[str]] = set()
    for k, entry in enumerate(data["distances"]):
        where = f"{path}: distances[{k}]"
        if not isinstance(entry, Mapping) or set(entry) != {"a", "b", "m"}:
            raise ConfigError(f"{where}: expected exactly the keys a, b, m")
        a, b, m = entry["a"], entry["b"], entry["m"]
        if not (isinstance(a, str) and isinstance(b, str) and a and b):
            raise ConfigError(f"{where}: a and b must be target ids (text)")
        if a == b:
            raise ConfigError(f"{where}: a and b are the same target ({a})")
        if isinstance(m, bool) or not isinstance(m, (int, float)) or not (
                math.isfinite(m) and m > 0):
            raise ConfigError(f"{where}: m must be a positive number of metres, got {m!r}")
        if frozenset((a, b)) in seen:
            raise ConfigError(f"{where}: the pair {a} - {b} is given twice")
        seen.add(frozenset((a, b)))
        out.append((a, b, float(m)))
    if not out:
        raise ConfigError(f"{path}: 'distances' is empty")
    return out


#: Topics of an output bag that the live nodes do not publish (offline only).
OFFLINE_ONLY = re.compile(r"^/target/[^/]+/ground_truth$")


def _plain(msg: Any) -> Any:
    """A message as nested dicts and lists of plain numbers and strings (comparable with ==)."""
    if dataclasses.is_dataclass(msg):
        return {f.name: _plain(getattr(msg, f.name)) for f in dataclasses.fields(msg)}
    if isinstance(msg, np.ndarray):
        return msg.tolist()
    if isinstance(msg, (list, tuple)):
        return [_plain(x) for x in msg]
    return msg


def output_messages(path: str | Path, topics: Sequence[str] | None = None
                    ) -> dict[str, list[tuple[int, Any]]]:
    """The messages of an output bag (of ``process``, or a recording of the live nodes' outputs)
    by topic: ``(header stamp ns, message as plain data)`` in stamp order (messages without a
    header: their first transform's stamp). Offline-only topics (:data:`OFFLINE_ONLY`) are left
    out."""
    info = bag_info(path)
    wanted = [t for t in (topics if topics is not None else info.topics)
              if t in info.topics and not OFFLINE_ONLY.match(t)]
    out: dict[str, list[tuple[int, Any]]] = {t: [] for t in wanted}
    for topic, msgtype, _t, raw in iter_messages(path, wanted):
        msg = _plain(deserialize(raw, msgtype))
        head = msg.get("header") or (msg.get("transforms") or msg.get("markers") or
                                     [{}])[0].get("header") or {}
        stamp = head.get("stamp", {})
        out[topic].append((int(stamp.get("sec", 0)) * 1_000_000_000 +
                           int(stamp.get("nanosec", 0)), msg))
    for msgs in out.values():
        msgs.sort(key=lambda m: (m[0], json.dumps(m[1], sort_keys=True, default=str)))
    return out


def compare_outputs(live: Mapping[str, list[tuple[int, Any]]],
                    offline: Mapping[str, list[tuple[int, Any]]],
                    stamps: set[int] | None = None) -> list[str]:
    """Differences between two sets of output messages (:func:`output_messages`): topics in
    one only, and per topic the stamps with different messages. ``stamps``: compare only
    messages of these stamps (the frames both runs saw); None: all. Empty: identical."""
    problems = []
    for topic in sorted(set(live) ^ set(offline)):
        problems.append(f"{topic}: only {'live' if topic in live else 'offline'}")
    for topic in sorted(set(live) & set(offline)):
        a = [m for m in live[topic] if stamps is None or m[0] in stamps]
        b = [m for m in offline[topic] if stamps is None or m[0] in stamps]
        if a != b:
            bad = sorted({s for s, _ in a} ^ {s for s, _ in b}) or sorted(
                {s for (s, x), (_, y) in zip(a, b, strict=False) if x != y})
            problems.append(f"{topic}: {len(a)} live and {len(b)} offline messages differ "
                            f"(first at {bad[0] if bad else '?'} ns)")
    return problems
