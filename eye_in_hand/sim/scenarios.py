"""Arm motions for the synthetic world: calibration poses and localization trajectories.

* :func:`calibration_poses` -- N diverse still poses looking at the chessboard (board fully in
  both views, reachable within the joint limits), consecutive poses 20-40 degrees apart in
  rotation with varied rotation axes, as a hand-eye calibration needs.
* :func:`localization_trajectory` -- a smooth continuous motion of the camera around the
  target(s) at 0.3-0.6 m range, keeping the target(s) in both views.
* :func:`calibration_timeline` -- the time line of a calibration recording: hold still at each
  pose for some frames, move between poses (joint-space, smooth velocity profile).

Everything is deterministic for a given seed (``np.random.default_rng(seed)``).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from eye_in_hand.core.transforms import compose, invert, rotation_angle
from eye_in_hand.errors import InputError, KinematicsError
from eye_in_hand.sim.render import board_in_view, sphere_silhouette
from eye_in_hand.sim.world import World

__all__ = [
    "HOME_Q",
    "look_at",
    "calibration_poses",
    "localization_trajectory",
    "calibration_timeline",
    "camera_pose_ok",
]

#: UR5e joint vector with the tool pointing down in front of the base (+x of ``base_link``,
#: i.e. -x of the DH frame ``base``), the IK seed.
HOME_Q = np.array([0.0, -1.9, 1.9, -1.57, -1.57, 0.0])


def look_at(target: np.ndarray, eye: np.ndarray, roll: float = 0.0) -> np.ndarray:
    """``base_T_cam`` (4, 4) of an optical frame at ``eye`` whose z axis points at ``target``,
    image x as horizontal as possible, then rotated by ``roll`` about the optical axis."""
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.999 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = math.cos(roll), math.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def _inside(px: np.ndarray, w: int, h: int, margin: float) -> bool:
    return bool(np.all(np.isfinite(px)) and np.all(px[:, 0] >= margin)
                and np.all(px[:, 1] >= margin) and np.all(px[:, 0] <= w - 1 - margin)
                and np.all(px[:, 1] <= h - 1 - margin))


def camera_pose_ok(world: World, base_T_cam: np.ndarray, *, board: bool = False,
                   targets: bool = False, margin_px: float = 20.0) -> bool:
    """Whether the board (see :func:`~eye_in_hand.sim.render.board_in_view`; at least
    ``margin_px`` inside) and/or every target silhouette (``margin_px`` inside) is in both
    images, for a left camera at ``base_T_cam``."""
    cam_T_base = invert(base_T_cam)
    W, H = world.image_size
    for cam, T in ((world.rig.left, cam_T_base),
                   (world.rig.right, compose(world.rig.right_T_left, cam_T_base))):
        if board:
            cam_T_board = compose(T, world.base_T_board)
            pts = world.board_points() @ cam_T_board[:3, :3].T + cam_T_board[:3, 3]
            if np.any(pts[:, 2] <= 0.05):
                return False
            if not board_in_view(cam, cam_T_board, cam.project(pts), world.board.cols,
                                 world.board.rows, margin_px):
                return False
        if targets:
            for tgt in world.targets:
                c = T[:3, :3] @ tgt.center_base + T[:3, 3]
                poly = sphere_silhouette(cam, c, tgt.radius_m, n=64)
                if poly is None or not _inside(poly, W, H, margin_px):
                    return False
    return True


def _solve(world: World, base_T_cam: np.ndarray, seeds: Sequence[np.ndarray],
           attempts: int = 1) -> np.ndarray:
    base_T_ee = compose(base_T_cam, invert(world.ee_T_cam))
    last: KinematicsError | None = None
    for seed_q in seeds:
        try:
            q = world.arm.ik(base_T_ee, seed_q, attempts=attempts)
        except KinematicsError as exc:
            last = exc
            continue
        if np.max(np.abs(q - seed_q)) < 2.5:  # stay on the seed's branch
            return q
    raise last if last is not None else KinematicsError("no IK solution near the seeds")


def _axis_rot(axis: int, angle: float) -> np.ndarray:
    """Rotation by ``angle`` about coordinate axis ``axis`` (0 = x, 1 = y, 2 = z)."""
    c, s = math.cos(angle), math.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


def _candidate_camera(world: World, rng: np.random.Generator, centre: np.ndarray,
                      frame: tuple[np.ndarray, np.ndarray, np.ndarray],
                      distance: tuple[float, float], max_tilt_deg: float,
                      image_spread: float) -> np.ndarray:
    """A random ``base_T_cam`` of :func:`calibration_poses`: looking at a point near the board
    centre from a direction within ``max_tilt_deg`` of its normal (``frame``: the normal and
    two axes across it), then turned so that the board centre lands off the principal
    point."""
    normal, e1, e2 = frame
    tilt = math.radians(max_tilt_deg) * math.sqrt(rng.uniform(0.0, 1.0))
    az = rng.uniform(0.0, 2 * math.pi)
    d = rng.uniform(*distance)
    direction = (math.cos(tilt) * normal
                 + math.sin(tilt) * (math.cos(az) * e1 + math.sin(az) * e2))
    aim = centre + rng.uniform(-0.03, 0.03, size=3) * np.array([1.0, 1.0, 0.0])
    base_T_cam = look_at(aim, aim + d * direction, roll=rng.uniform(-0.6, 0.6))
    if image_spread > 0:
        cam = world.rig.left
        du = rng.uniform(-image_spread, image_spread) * cam.width / 2
        dv = rng.uniform(-image_spread, image_spread) * cam.height / 2
        turn = np.eye(4)
        turn[:3, :3] = (_axis_rot(1, -math.atan2(du, cam.fx))
                        @ _axis_rot(0, math.atan2(dv, cam.fy)))
        base_T_cam = base_T_cam @ turn
    return base_T_cam


def _step_axis(cams: list[np.ndarray], base_T_cam: np.ndarray, last_axis: np.ndarray | None,
               step_deg: tuple[float, float]) -> np.ndarray | None:
    """The rotation axis of the step from the last accepted camera pose to ``base_T_cam``;
    None when the step is refused: its angle outside ``step_deg``, within 10 degrees of an
    earlier pose, or its axis within 30 degrees of the previous step's."""
    R_rel = cams[-1][:3, :3].T @ base_T_cam[:3, :3]
    angle = math.degrees(rotation_angle(R_rel))
    if not step_deg[0] <= angle <= step_deg[1]:
        return None
    if min(math.degrees(rotation_angle(c[:3, :3].T @ base_T_cam[:3, :3]))
           for c in cams) < 10.0:
        return None
    axis = Rotation.from_matrix(R_rel).as_rotvec()
    axis /= np.linalg.norm(axis)
    if last_axis is not None and abs(float(axis @ last_axis)) > math.cos(
            math.radians(30.0)):
        return None
    return axis


def calibration_poses(world: World, n: int, seed: int = 0, *,
                      distance: tuple[float, float] = (0.30, 0.48),
                      max_tilt_deg: float = 38.0,
                      step_deg: tuple[float, float] = (20.0, 40.0),
                      image_spread: float = 0.6,
                      max_candidates: int = 4000) -> list[np.ndarray]:
    """N reachable joint vectors that see the whole board in both cameras.

    Candidate camera poses look at points near the board centre from a cap of directions up
    to ``max_tilt_deg`` off the board normal, at ``distance`` (m), with a random roll about the
    optical axis. Each accepted pose is 20-40 degrees (``step_deg``) of rotation from the
    previous one, its relative rotation axis at least 30 degrees from the previous step's,
    and at least 10 degrees from every earlier pose. The camera is then turned about its own
    axes so that the board centre lands anywhere within ``image_spread`` of the half image
    size from the principal point (0 = always centred): boards spread over the image constrain
    the principal point and the distortion far better than centred ones.

    Args:
        world: the world.
        n: number of poses (>= 1).
        seed: random seed.
        image_spread: how far off-centre the board may appear (fraction of half the image).

    Returns:
        n joint vectors (each shape (6,)).

    Raises:
        InputError: n < 1.
        KinematicsError: fewer than n poses found in ``max_candidates`` tries.
    """
    if n < 1:
        raise InputError(f"calibration_poses: n must be >= 1, got {n}")
    rng = np.random.default_rng(seed)
    centre = world.board_center_base()
    normal = -world.base_T_board[:3, 2]  # the printed face's outward normal
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(normal, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    poses: list[np.ndarray] = []
    cams: list[np.ndarray] = []
    last_axis: np.ndarray | None = None
    home = HOME_Q.copy()
    for _ in range(max_candidates):
        if len(poses) == n:
            break
        base_T_cam = _candidate_camera(world, rng, centre, (normal, e1, e2), distance,
                                       max_tilt_deg, image_spread)
        axis = None
        if cams:
            axis = _step_axis(cams, base_T_cam, last_axis, step_deg)
            if axis is None:
                continue
        if not camera_pose_ok(world, base_T_cam, board=True):
            continue
        seeds = [poses[-1], home] if poses else [home]
        try:
            q = _solve(world, base_T_cam, seeds)
        except KinematicsError:
            continue
        poses.append(q)
        cams.append(base_T_cam)
        last_axis = axis
    if len(poses) < n:
        raise KinematicsError(
            f"calibration_poses: found only {len(poses)} of {n} reachable poses that see the "
            f"whole board in both cameras ({max_candidates} candidates, seed {seed})")
    return poses


def _smoothstep(s: np.ndarray | float) -> np.ndarray | float:
    return s * s * (3.0 - 2.0 * s)


def calibration_timeline(poses: Sequence[np.ndarray], *, hold_s: float = 0.2,
                         move_s: float = 1.0, rate_hz: float = 125.0,
                         start_ns: int = 0) -> list[tuple[int, np.ndarray, bool]]:
    """Joint samples of a calibration recording: hold, move, hold, ...

    Args:
        poses: the still poses (from :func:`calibration_poses`).
        hold_s: time still at each pose, seconds.
        move_s: time to move between consecutive poses (smooth-step in joint space).
        rate_hz: sampling rate of the returned samples.
        start_ns: stamp of the first sample.

    Returns:
        ``(stamp_ns, q (6,), still)`` tuples; ``still`` is True while holding a pose.
    """
    if rate_hz <= 0 or hold_s <= 0 or move_s <= 0:
        raise InputError("calibration_timeline: rate_hz, hold_s and move_s must be positive")
    out: list[tuple[int, np.ndarray, bool]] = []
    period_ns = int(round(1e9 / rate_hz))
    t_ns = start_ns
    n_hold = max(1, int(round(hold_s * rate_hz)))
    n_move = max(1, int(round(move_s * rate_hz)))
    for i, q in enumerate(poses):
        q = np.asarray(q, float)
        if i > 0:
            q_prev = np.asarray(poses[i - 1], float)
            for k in range(1, n_move):
                s = _smoothstep(k / n_move)
                out.append((t_ns, q_prev + (q - q_prev) * s, False))
                t_ns += period_ns
        for _ in range(n_hold):
            out.append((t_ns, q.copy(), True))
            t_ns += period_ns
    return out


def localization_trajectory(world: World, duration_s: float, rate_hz: float, seed: int = 0,
                            *, range_m: tuple[float, float] = (0.3, 0.6),
                            start_ns: int = 0) -> list[tuple[int, np.ndarray]]:
    """A continuous camera motion around the target(s), sampled at ``rate_hz``.

    The camera circles the targets' centroid on a tilted orbit (azimuth sweep, elevation and
    range oscillating within ``range_m``), looking at it with a slow roll; every sample keeps
    all targets inside both images. The orbit's phase, speed and amplitudes come from
    ``seed``; joint vectors are solved by IK along the path, each seeded with the previous one.

    Args:
        world: the world (at least one target).
        duration_s: length in seconds (> 0).
        rate_hz: sampling rate (> 0).
        seed: random seed.
        range_m: (min, max) camera-to-target distance, metres.
        start_ns: stamp of the first sample.

    Returns:
        ``(stamp_ns, q (6,))`` tuples.

    Raises:
        InputError: bad arguments or a world without targets.
        KinematicsError: no reachable orbit was found for this seed.
    """
    if duration_s <= 0 or rate_hz <= 0:
        raise InputError("localization_trajectory: duration_s and rate_hz must be positive")
    if not world.targets:
        raise InputError("localization_trajectory: the world has no targets")
    rng = np.random.default_rng(seed)
    centre = world.target_centers_base().mean(axis=0)
    n = max(1, int(round(duration_s * rate_hz)) + 1)
    period_ns = int(round(1e9 / rate_hz))
    lo, hi = range_m
    for _attempt in range(40):
        az0 = rng.uniform(0, 2 * math.pi)
        az_rate = rng.choice([-1.0, 1.0]) * rng.uniform(0.25, 0.45)   # rad/s
        el0 = rng.uniform(math.radians(45), math.radians(65))
        el_amp = rng.uniform(math.radians(4), math.radians(10))
        r_mid = rng.uniform(lo + 0.06, hi - 0.06)
        r_amp = min(r_mid - lo, hi - r_mid) * rng.uniform(0.3, 0.9)
        w1, w2 = rng.uniform(0.6, 1.2, size=2)
        roll0, roll_amp = rng.uniform(-0.4, 0.4), rng.uniform(0.05, 0.2)
        out: list[tuple[int, np.ndarray]] = []
        q_prev = None
        try:
            for k in range(n):
                t = k / rate_hz
                az = az0 + az_rate * t
                el = el0 + el_amp * math.sin(w1 * t)
                r = r_mid + r_amp * math.sin(w2 * t + 1.0)
                eye = centre + r * np.array([math.cos(el) * math.cos(az),
                                             math.cos(el) * math.sin(az), math.sin(el)])
                base_T_cam = look_at(centre, eye, roll=roll0 + roll_amp * math.sin(0.7 * t))
                if not camera_pose_ok(world, base_T_cam, targets=True, margin_px=10.0):
                    raise KinematicsError("target leaves the view")
                seeds = [q_prev] if q_prev is not None else [HOME_Q, HOME_Q + [1.0, 0, 0, 0, 0, 0],
                                                             HOME_Q - [1.0, 0, 0, 0, 0, 0]]
                q = _solve(world, base_T_cam, seeds)
                if q_prev is not None and np.max(np.abs(q - q_prev)) > 0.2:
                    raise KinematicsError("IK branch jump")
                out.append((start_ns + k * period_ns, q))
                q_prev = q
        except KinematicsError:
            continue
        return out
    raise KinematicsError(
        f"localization_trajectory: no reachable orbit around {np.round(centre, 3).tolist()} "
        f"at {lo}-{hi} m for seed {seed}")
