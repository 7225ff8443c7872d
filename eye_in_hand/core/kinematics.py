"""Serial-arm kinematics: forward kinematics from DH parameters or a URDF chain, numerical IK.

Two chain models share one small interface (:class:`KinematicChain`):

* :class:`DHChain` -- standard (distal) Denavit-Hartenberg parameters, one revolute joint per
  row: ``i-1_T_i = Rz(theta_i + offset_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``.
  :meth:`DHChain.ur5e` gives the published UR5e parameters and ur_description's frames: the DH
  chain is expressed in UR's controller frame ``base`` (DH frame 0), ``fk`` gives poses in
  ``base_link`` = ``Rz(pi) base`` (``base_T_dh``, as ur_description's fixed joint
  ``base_link`` -> ``base``), and the last frame is ``tool0`` (the flange frame).
* :class:`UrdfChain` -- the chain of joints between a base link and a tip link of a URDF file
  (``revolute``, ``continuous``, ``prismatic`` and ``fixed`` joints; ``origin xyz/rpy`` and
  ``axis``), parsed with :mod:`xml.etree.ElementTree`.

Both give ``fk(q) -> base_T_tip`` (4, 4) and ``fk_frames(q)`` (every intermediate frame, for
``/tf``), and both can be inverted with :func:`solve_ik` (``chain.ik(...)``): a seeded, bounded
:func:`scipy.optimize.least_squares` solve with random restarts that raises
:class:`~eye_in_hand.errors.KinematicsError` when the pose is out of reach.

Conventions: metres, radians, ``a_T_b`` maps points in frame b into frame a.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from eye_in_hand.core.transforms import as_transform, rotation_angle, rotation_class
from eye_in_hand.errors import InputError, KinematicsError

__all__ = [
    "JointIndex",
    "MissingJointsError",
    "KinematicChain",
    "DHChain",
    "UrdfJoint",
    "UrdfChain",
    "solve_ik",
    "rpy_to_matrix",
    "UR5E_DH",
    "UR5E_JOINT_NAMES",
    "UR5E_LINK_NAMES",
    "UR_BASE_LINK_T_BASE",
]

#: Published UR5e standard-DH parameters (Universal Robots, "DH parameters for calculations of
#: kinematics and dynamics"): d, a, alpha per joint; theta offsets are zero.
UR5E_DH: dict[str, tuple[float, ...]] = {
    "d": (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996),
    "a": (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0),
    "alpha": (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0),
}
UR5E_JOINT_NAMES: tuple[str, ...] = (
    "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
    "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
)
#: Frame names of the DH frames 1..6 (frame 0 is the chain's base frame); the last one is tool0.
#: ur_description's fixed joint ``base_link`` -> ``base``: Rz(pi) (UR's controller frame ``base``
#: is the DH frame 0; the URDF's ``base_link`` is rotated by pi about z from it).
UR_BASE_LINK_T_BASE: np.ndarray = np.diag([-1.0, -1.0, 1.0, 1.0])
UR_BASE_LINK_T_BASE.setflags(write=False)
UR5E_LINK_NAMES: tuple[str, ...] = (
    "shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "tool0",
)


class MissingJointsError(InputError):
    """A joint state message lacks joints of the kinematic chain."""


class JointIndex:
    """A chain's joint positions out of ``sensor_msgs/JointState`` name and position lists:
    any order, extra joints ignored; the index is rebuilt whenever a message's names differ
    from the previous message's. The one rule of the ``hand_eye`` node, ``process`` and
    ``calibrate handeye --bag`` for ``joint_states``.

    Args:
        joint_names: the chain's joint names, in the order of its ``q``.
    """

    def __init__(self, joint_names: Sequence[str]) -> None:
        self.joint_names = tuple(joint_names)
        self._names: tuple[str, ...] | None = None
        self._index = np.zeros(0, dtype=np.intp)

    def positions(self, names: Sequence[str], position: Sequence[float]) -> np.ndarray:
        """The chain's ``q`` (n,) from one message.

        Raises:
            MissingJointsError: a joint of the chain is not in ``names`` (the message's names
                are listed).
            InputError: ``position`` does not have one value per name, or a value of the
                chain's joints is NaN or infinite.
        """
        names = tuple(names)
        if names != self._names:
            missing = [n for n in self.joint_names if n not in names]
            if missing:
                raise MissingJointsError(f"joint_states lacks joint(s) {', '.join(missing)} "
                                         f"(has {', '.join(names) or 'none'})")
            self._index = np.array([names.index(n) for n in self.joint_names], dtype=np.intp)
            self._names = names
        pos = np.asarray(position, dtype=np.float64)
        if pos.shape != (len(names),):
            raise InputError(f"joint_states: {pos.size} positions for {len(names)} names")
        q: np.ndarray = pos[self._index]
        if not np.all(np.isfinite(q)):
            raise InputError("joint_states: joint positions are not finite")
        return q


class KinematicChain(Protocol):
    """What :func:`solve_ik` and the simulator need of a chain."""

    @property
    def joint_names(self) -> tuple[str, ...]: ...

    @property
    def lower(self) -> np.ndarray: ...

    @property
    def upper(self) -> np.ndarray: ...

    def fk(self, q: Sequence[float] | np.ndarray) -> np.ndarray:  # pragma: no cover - protocol
        ...


def _as_q(q, n: int, name: str = "q") -> np.ndarray:
    try:
        arr = np.asarray(q, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: expected {n} joint values") from exc
    if arr.shape != (n,):
        raise InputError(f"{name}: expected {n} joint values, got shape {np.shape(q)}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: contains NaN or infinite values")
    return arr


def rpy_to_matrix(rpy: Sequence[float] | np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes X, then Y, then Z) to a rotation matrix (3, 3)."""
    r, p, y = (float(v) for v in rpy)
    return rotation_class().from_euler("xyz", [r, p, y]).as_matrix()


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    return rotation_class().from_rotvec(axis * angle).as_matrix()


def _dh_matrix(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    ct, st = math.cos(theta), math.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    return np.array([
        [ct, -st * ca, st * sa, a * ct],
        [st, ct * ca, -ct * sa, a * st],
        [0.0, sa, ca, d],
        [0.0, 0.0, 0.0, 1.0],
    ])


@dataclass(frozen=True)
class DHChain:
    """A serial arm of revolute joints in standard DH convention.

    Attributes:
        d, a, alpha, theta_offset: arrays of shape (n,) (metres, metres, radians, radians).
        lower, upper: joint limits, shape (n,), radians.
        joint_names: n joint names (used in ``/joint_states``).
        link_names: n frame names of DH frames 1..n (the last is the tool frame).
        base_frame: the frame ``fk`` is expressed in.
        dh_frame: name of DH frame 0 ('' = ``base_frame``: no fixed base transform).
        base_T_dh: (4, 4) fixed transform ``base_frame`` -> DH frame 0 (identity by default;
            ``Rz(pi)`` for the UR arms: ``base_link`` -> ``base``).
    """

    d: np.ndarray
    a: np.ndarray
    alpha: np.ndarray
    theta_offset: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    joint_names: tuple[str, ...]
    link_names: tuple[str, ...]
    base_frame: str = "base_link"
    dh_frame: str = ""
    base_T_dh: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        base_T_dh = as_transform(self.base_T_dh, "DHChain.base_T_dh").copy()
        base_T_dh.setflags(write=False)
        object.__setattr__(self, "base_T_dh", base_T_dh)
        object.__setattr__(self, "dh_frame", str(self.dh_frame or self.base_frame))
        n = len(self.joint_names)
        if n < 1:
            raise InputError("DHChain: needs at least one joint")
        for name in ("d", "a", "alpha", "theta_offset", "lower", "upper"):
            arr = _as_q(getattr(self, name), n, f"DHChain.{name}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if len(self.link_names) != n:
            raise InputError(f"DHChain: {len(self.link_names)} link names for {n} joints")
        if np.any(self.lower >= self.upper):
            raise InputError("DHChain: every lower joint limit must be below its upper limit")
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        object.__setattr__(self, "link_names", tuple(self.link_names))

    @classmethod
    def ur5e(cls, *, base_frame: str = "base_link", dh_frame: str = "base",
             limit: float = 2.0 * math.pi) -> DHChain:
        """The UR5e with its published DH parameters and +-``limit`` joint limits, in
        ur_description's frames: DH frame 0 is ``dh_frame`` (``base``), ``fk`` is in
        ``base_frame`` (``base_link`` = Rz(pi) ``base``)."""
        n = 6
        return cls(
            d=np.array(UR5E_DH["d"]), a=np.array(UR5E_DH["a"]),
            alpha=np.array(UR5E_DH["alpha"]), theta_offset=np.zeros(n),
            lower=np.full(n, -limit), upper=np.full(n, limit),
            joint_names=UR5E_JOINT_NAMES, link_names=UR5E_LINK_NAMES, base_frame=base_frame,
            dh_frame=dh_frame, base_T_dh=UR_BASE_LINK_T_BASE,
        )

    @classmethod
    def from_dict(cls, data: dict) -> DHChain:
        """Build from a mapping with keys d, a, alpha [, theta_offset, lower, upper,
        joint_names, link_names, base_frame, dh_frame, base_T_dh] (the ``arm`` section of
        ``world.yaml``; ``base_T_dh`` as ``{translation: [x, y, z], quat_xyzw: [x, y, z, w]}``,
        default identity).

        Raises:
            InputError: a key is missing or has the wrong length.
        """
        try:
            d = np.asarray(data["d"], dtype=float)
            a = np.asarray(data["a"], dtype=float)
            alpha = np.asarray(data["alpha"], dtype=float)
        except KeyError as exc:
            raise InputError(f"DH arm: missing key {exc.args[0]!r} (need d, a, alpha)") from exc
        n = d.size
        base_T_dh = np.eye(4)
        if data.get("base_T_dh") is not None:
            node = data["base_T_dh"]
            try:
                base_T_dh[:3, :3] = rotation_class().from_quat(
                    np.asarray(node["quat_xyzw"], dtype=float)).as_matrix()
                base_T_dh[:3, 3] = np.asarray(node["translation"], dtype=float)
            except (KeyError, TypeError, ValueError) as exc:
                raise InputError("DH arm: base_T_dh needs translation [x, y, z] and quat_xyzw "
                                 f"[x, y, z, w] ({exc})") from exc
        names = data.get("joint_names") or [f"joint_{i + 1}" for i in range(n)]
        links = data.get("link_names") or [f"link_{i + 1}" for i in range(n)]
        return cls(
            d=d, a=a, alpha=alpha,
            theta_offset=np.asarray(data.get("theta_offset", np.zeros(n)), dtype=float),
            lower=np.asarray(data.get("lower", np.full(n, -2 * math.pi)), dtype=float),
            upper=np.asarray(data.get("upper", np.full(n, 2 * math.pi)), dtype=float),
            joint_names=tuple(names), link_names=tuple(links),
            base_frame=str(data.get("base_frame", "base_link")),
            dh_frame=str(data.get("dh_frame", "") or ""), base_T_dh=base_T_dh,
        )

    def to_dict(self) -> dict:
        """Plain-Python mapping that :meth:`from_dict` reads back."""
        return {
            "d": self.d.tolist(), "a": self.a.tolist(), "alpha": self.alpha.tolist(),
            "theta_offset": self.theta_offset.tolist(),
            "lower": self.lower.tolist(), "upper": self.upper.tolist(),
            "joint_names": list(self.joint_names), "link_names": list(self.link_names),
            "base_frame": self.base_frame,
            "dh_frame": self.dh_frame,
            "base_T_dh": {"translation": self.base_T_dh[:3, 3].tolist(),
                          "quat_xyzw": rotation_class().from_matrix(self.base_T_dh[:3, :3])
                          .as_quat().tolist()},
        }

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def tip_frame(self) -> str:
        return self.link_names[-1]

    @property
    def reach(self) -> float:
        """Upper bound on the distance from the base origin to the tip origin (m)."""
        return float(np.sum(np.hypot(self.a, self.d)) + np.linalg.norm(self.base_T_dh[:3, 3]))

    def joint_transforms(self, q) -> list[np.ndarray]:
        """The n joint transforms ``i-1_T_i`` (each (4, 4)) at joint vector ``q`` (n,)."""
        qv = _as_q(q, self.n_joints)
        return [_dh_matrix(qv[i] + self.theta_offset[i], self.d[i], self.a[i], self.alpha[i])
                for i in range(self.n_joints)]

    def fk_frames(self, q) -> list[np.ndarray]:
        """``base_T_i`` for i = 1..n (list of n (4, 4) arrays, in ``base_frame``, ``base_T_dh``
        included); the last one is ``fk(q)``."""
        out = []
        T = np.array(self.base_T_dh)
        for A in self.joint_transforms(q):
            T = T @ A
            out.append(T.copy())
        return out

    def fk(self, q) -> np.ndarray:
        """Forward kinematics: ``base_T_tip`` (4, 4) for joint vector ``q`` (n,), radians.

        Raises:
            InputError: ``q`` has the wrong length or non-finite values.
        """
        return self.fk_frames(q)[-1]

    def ik(self, base_T_tip, seed_q=None, **kwargs) -> np.ndarray:
        """Inverse kinematics; see :func:`solve_ik` for the keyword options."""
        return solve_ik(self, base_T_tip, seed_q, **kwargs)


@dataclass(frozen=True)
class UrdfJoint:
    """One URDF joint: ``parent_T_child(q) = origin @ motion(q)``."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float
    upper: float

    @property
    def movable(self) -> bool:
        return self.type != "fixed"

    def transform(self, value: float) -> np.ndarray:
        """``parent_T_child`` (4, 4) at joint position ``value`` (rad or m; ignored if fixed)."""
        M = np.eye(4)
        if self.type in ("revolute", "continuous"):
            M[:3, :3] = _axis_rotation(self.axis, value)
        elif self.type == "prismatic":
            M[:3, 3] = self.axis * value
        return self.origin @ M


def _parse_floats(text: str | None, n: int, default: Sequence[float], where: str) -> np.ndarray:
    if text is None:
        return np.asarray(default, dtype=float)
    try:
        vals = np.array([float(v) for v in text.split()])
    except ValueError as exc:
        raise InputError(f"{where}: cannot parse numbers from {text!r}") from exc
    if vals.shape != (n,):
        raise InputError(f"{where}: expected {n} numbers, got {text!r}")
    return vals


@dataclass(frozen=True)
class UrdfChain:
    """The joints from ``base_link`` to ``tip_link`` of a URDF, in order.

    Attributes:
        joints: every joint on the path (fixed ones included), base to tip.
        joint_names: names of the movable joints (the order of ``q``).
        lower, upper: limits of the movable joints (continuous joints: +-inf).
        base_link, tip_link: the chain's end links.
    """

    joints: tuple[UrdfJoint, ...]
    base_link: str
    tip_link: str
    joint_names: tuple[str, ...] = field(init=False)
    lower: np.ndarray = field(init=False)
    upper: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        movable = [j for j in self.joints if j.movable]
        object.__setattr__(self, "joint_names", tuple(j.name for j in movable))
        object.__setattr__(self, "lower", np.array([j.lower for j in movable], dtype=float))
        object.__setattr__(self, "upper", np.array([j.upper for j in movable], dtype=float))

    @classmethod
    def from_file(cls, path: str | Path, base_link: str, tip_link: str) -> UrdfChain:
        """Parse the chain ``base_link`` -> ``tip_link`` of a URDF file.

        Raises:
            KinematicsError: the file cannot be read or is not valid URDF, a joint is malformed
                or of an unsupported type, a link is unknown, or the tip is not below the base.
        """
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except OSError as exc:
            raise KinematicsError(f"URDF {p}: cannot read ({exc.strerror})") from exc
        except UnicodeDecodeError as exc:
            raise KinematicsError(f"URDF {p}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} "
                                  f"at offset {exc.start})") from exc
        return cls.from_string(text, base_link, tip_link, source=str(p))

    @classmethod
    def from_string(cls, text: str, base_link: str, tip_link: str, *,
                    source: str = "<string>") -> UrdfChain:
        """Parse the chain ``base_link`` -> ``tip_link`` from URDF XML text.

        Args:
            text: the URDF document.
            base_link, tip_link: link names; the tip must be a descendant of the base.
            source: name used in error messages (a file path).

        Raises:
            KinematicsError: as :meth:`from_file`.
        """
        try:
            root = ET.fromstring(text)
        except ET.ParseError as exc:
            raise KinematicsError(f"URDF {source}: not valid XML ({exc})") from exc
        if root.tag != "robot":
            raise KinematicsError(f"URDF {source}: root element is <{root.tag}>, not <robot>")
        by_child: dict[str, UrdfJoint] = {}
        for el in root.findall("joint"):
            joint = cls._parse_joint(el, source)
            if joint.child in by_child:
                raise KinematicsError(
                    f"URDF {source}: link {joint.child!r} is the child of two joints")
            by_child[joint.child] = joint
        links = {el.get("name") for el in root.findall("link")}
        for name, role in ((base_link, "base"), (tip_link, "tip")):
            if name not in links:
                raise KinematicsError(f"URDF {source}: {role} link {name!r} not found "
                                      f"(links: {', '.join(sorted(filter(None, links)))})")
        path: list[UrdfJoint] = []
        link = tip_link
        while link != base_link:
            above = by_child.get(link)
            if above is None:
                raise KinematicsError(
                    f"URDF {source}: tip link {tip_link!r} is not below base link {base_link!r}")
            path.append(above)
            link = above.parent
            if len(path) > len(by_child):
                raise KinematicsError(f"URDF {source}: joint graph has a cycle")
        return cls(joints=tuple(reversed(path)), base_link=base_link, tip_link=tip_link)

    @staticmethod
    def _parse_joint(el: ET.Element, source: str) -> UrdfJoint:
        name = el.get("name") or "<unnamed>"
        where = f"URDF {source}: joint {name!r}"
        jtype = el.get("type")
        if jtype not in ("revolute", "continuous", "prismatic", "fixed"):
            raise KinematicsError(f"{where}: unsupported joint type {jtype!r} "
                                  "(supported: revolute, continuous, prismatic, fixed)")
        parent = el.find("parent")
        child = el.find("child")
        if parent is None or child is None or not parent.get("link") or not child.get("link"):
            raise KinematicsError(f"{where}: needs <parent link=...> and <child link=...>")
        origin_el = el.find("origin")
        try:
            xyz = _parse_floats(origin_el.get("xyz") if origin_el is not None else None, 3,
                                (0, 0, 0), f"{where} origin xyz")
            rpy = _parse_floats(origin_el.get("rpy") if origin_el is not None else None, 3,
                                (0, 0, 0), f"{where} origin rpy")
            axis_el = el.find("axis")
            axis = _parse_floats(axis_el.get("xyz") if axis_el is not None else None, 3,
                                 (1, 0, 0), f"{where} axis")
        except InputError as exc:
            raise KinematicsError(str(exc)) from exc
        norm = float(np.linalg.norm(axis))
        if jtype != "fixed" and norm < 1e-12:
            raise KinematicsError(f"{where}: axis has zero length")
        origin = np.eye(4)
        origin[:3, :3] = rpy_to_matrix(rpy)
        origin[:3, 3] = xyz
        lower, upper = -math.inf, math.inf
        limit = el.find("limit")
        if jtype in ("revolute", "prismatic"):
            if limit is None:
                raise KinematicsError(f"{where}: {jtype} joint needs a <limit> element")
            try:
                lower = float(limit.get("lower", "0"))
                upper = float(limit.get("upper", "0"))
            except ValueError as exc:
                raise KinematicsError(f"{where}: bad <limit> values") from exc
            if lower > upper:
                raise KinematicsError(f"{where}: limit lower {lower} > upper {upper}")
        return UrdfJoint(name=name, type=jtype, parent=parent.get("link", ""),
                         child=child.get("link", ""), origin=origin,
                         axis=axis / norm if norm > 0 else axis, lower=lower, upper=upper)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def reach(self) -> float:
        """Upper bound on the distance from the base origin to the tip origin (m)."""
        total = 0.0
        for j in self.joints:
            total += float(np.linalg.norm(j.origin[:3, 3]))
            if j.type == "prismatic":
                total += max(abs(j.lower), abs(j.upper))
        return total

    def fk_frames(self, q) -> list[tuple[str, str, np.ndarray]]:
        """Every joint's ``(parent, child, parent_T_child)`` at ``q``, base to tip (for /tf)."""
        qv = _as_q(q, self.n_joints)
        out = []
        k = 0
        for joint in self.joints:
            value = 0.0
            if joint.movable:
                value = float(qv[k])
                k += 1
            out.append((joint.parent, joint.child, joint.transform(value)))
        return out

    def fk(self, q) -> np.ndarray:
        """``base_T_tip`` (4, 4) at the movable-joint vector ``q`` (n,) (rad / m).

        Raises:
            InputError: ``q`` has the wrong length or non-finite values.
        """
        T = np.eye(4)
        for _, _, A in self.fk_frames(q):
            T = T @ A
        return T

    def ik(self, base_T_tip, seed_q=None, **kwargs) -> np.ndarray:
        """Inverse kinematics; see :func:`solve_ik`."""
        return solve_ik(self, base_T_tip, seed_q, **kwargs)


def _pose_residual(q: np.ndarray, chain: KinematicChain, target: np.ndarray,
                   rot_weight: float) -> np.ndarray:
    T = chain.fk(q)
    dp = T[:3, 3] - target[:3, 3]
    dR = rotation_class().from_matrix(target[:3, :3].T @ T[:3, :3]).as_rotvec()
    return np.concatenate([dp, rot_weight * dR])


def solve_ik(chain: KinematicChain, base_T_tip, seed_q=None, *, seed: int = 0,
             attempts: int = 12, position_tol: float = 1e-6,
             rotation_tol: float = 1e-6, rot_weight: float = 0.2) -> np.ndarray:
    """Numerical inverse kinematics within the chain's joint limits.

    Solves ``fk(q) == base_T_tip`` with :func:`scipy.optimize.least_squares` (trust-region
    reflective, bounded by the joint limits) from ``seed_q`` first, then from random restarts
    drawn with ``np.random.default_rng(seed)``; among converged solutions the one closest to
    ``seed_q`` is returned, so consecutive calls along a path stay on one branch.

    Args:
        chain: a :class:`DHChain` or :class:`UrdfChain` (anything with fk, lower, upper).
        base_T_tip: the requested tool pose, array-like (4, 4).
        seed_q: start joint vector (n,); default the middle of the limits (zeros if infinite).
        seed: seed of the random restarts (deterministic).
        attempts: number of starts, the seed included.
        position_tol: accepted position error (m).
        rotation_tol: accepted rotation error (rad).
        rot_weight: metres per radian when mixing rotation into the residual.

    Returns:
        Joint vector (n,) within the limits.

    Raises:
        InputError: malformed pose or seed.
        KinematicsError: no start converged (pose unreachable or outside the limits).
    """
    target = as_transform(base_T_tip, "base_T_tip")
    n = len(chain.joint_names)
    lower = np.where(np.isfinite(chain.lower), chain.lower, -2 * math.pi)
    upper = np.where(np.isfinite(chain.upper), chain.upper, 2 * math.pi)
    if seed_q is None:
        q0 = np.clip(0.5 * (lower + upper), lower, upper)
    else:
        q0 = np.clip(_as_q(seed_q, n, "seed_q"), lower, upper)
    reach = getattr(chain, "reach", math.inf)
    distance = float(np.linalg.norm(target[:3, 3]))
    if distance > reach + position_tol:
        raise KinematicsError(
            f"inverse kinematics: pose at {np.round(target[:3, 3], 4).tolist()} m is "
            f"{distance:.3f} m from the base, beyond the arm's reach of {reach:.3f} m")
    # scipy.optimize costs 0.8 s at import (python -X importtime); only inverse kinematics
    # needs it, not forward kinematics of joint states (the nodes, `process`)
    from scipy.optimize import least_squares

    rng = np.random.default_rng(seed)
    best: np.ndarray | None = None
    best_dist = math.inf
    best_err = (math.inf, math.inf)
    for k in range(max(1, attempts)):
        start = q0 if k == 0 else rng.uniform(lower, upper)
        sol = least_squares(_pose_residual, start, args=(chain, target, rot_weight),
                            bounds=(lower, upper), method="trf", xtol=1e-14, ftol=1e-14,
                            gtol=1e-14, max_nfev=60 * n)
        q = np.clip(sol.x, lower, upper)
        T = chain.fk(q)
        pos_err = float(np.linalg.norm(T[:3, 3] - target[:3, 3]))
        rot_err = rotation_angle(target[:3, :3].T @ T[:3, :3])
        if pos_err + rot_err < sum(best_err):
            best_err = (pos_err, rot_err)
        if pos_err <= position_tol and rot_err <= rotation_tol:
            dist = float(np.linalg.norm(q - q0))
            if dist < best_dist:
                best, best_dist = q, dist
            if k == 0:
                break  # the seed converged: keep the branch of the caller
    if best is None:
        raise KinematicsError(
            f"inverse kinematics: pose at {np.round(target[:3, 3], 4).tolist()} m is not "
            f"reachable within the joint limits (best of {attempts} starts: "
            f"{best_err[0] * 1e3:.3g} mm, {math.degrees(best_err[1]):.3g} deg)")
    return best
