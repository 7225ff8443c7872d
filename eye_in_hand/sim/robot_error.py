"""Robot error model of the simulator: the true arm differs from the nominal one.

A real arm's controller computes the flange pose from its nominal kinematic model and its
encoders; the arm itself has slightly different link lengths, offsets, twists and joint zeros,
and its encoders are noisy. The simulator reproduces that:

* the **true arm** is the nominal :class:`~eye_in_hand.core.kinematics.DHChain` with every DH
  parameter perturbed once (``d`` and ``a`` by ``N(0, link_sigma_m)``, ``alpha`` by
  ``N(0, twist_sigma_rad)``, the joint zero ``theta_offset`` by ``N(0, joint_offset_sigma_rad)``),
  drawn from ``np.random.default_rng(seed)``: ``seed`` is the arm's "serial number", the same
  for every recording of one world, so that calibration and localization see the same arm;
* the images come from the true arm at the true joint vector ``q``;
* the robot reports ``q_reported = q + N(0, encoder_sigma_rad)`` per sample (``/joint_states``)
  and the nominal FK of it (``/ee_pose``, ``/tf``);
* optionally the image stamped ``t`` shows the arm at robot time ``t + time_offset_s`` (an
  uncompensated camera latency / clock offset).

:meth:`RobotErrorSpec.default` is the realistic default (per-pose flange error of a few tenths
of a millimetre and a few hundredths of a degree, as an uncalibrated industrial arm;
measured figures in ``docs/simulator.md``); :meth:`RobotErrorSpec.none` is the ideal arm.

Pure functions for other code (benchmarks)::

    spec = RobotErrorSpec.default()
    true_arm = draw_true_arm(nominal, spec)                   # or spec with another seed
    q_rep = reported_joints(q, spec, rng)                     # encoder noise, (n,) or (K, n)
    base_T_ee_true, base_T_ee_rep = flange_poses(nominal, true_arm, q, q_rep)
    dt_m, dr_rad = flange_errors(nominal, true_arm, qs)       # per pose, no encoder noise
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from eye_in_hand.core.kinematics import DHChain
from eye_in_hand.core.transforms import invert, rotation_angle
from eye_in_hand.errors import ConfigError

__all__ = [
    "RobotErrorSpec",
    "draw_true_arm",
    "reported_joints",
    "flange_poses",
    "flange_errors",
    "pose_error",
]


@dataclass(frozen=True)
class RobotErrorSpec:
    """How the true arm differs from the nominal one (1-sigma values; 0 switches a part off).

    Attributes:
        link_sigma_m: DH ``d`` and ``a`` errors (link offsets and lengths), metres.
        twist_sigma_rad: DH ``alpha`` errors (axis misalignment), radians.
        joint_offset_sigma_rad: joint zero (``theta_offset``) errors, radians.
        encoder_sigma_rad: white noise on every reported joint sample, radians.
        time_offset_s: the image stamped ``t`` shows the arm at robot time ``t + time_offset_s``.
        seed: seed of the true arm's draw (the same arm for every recording of the world).
    """

    link_sigma_m: float = 0.0
    twist_sigma_rad: float = 0.0
    joint_offset_sigma_rad: float = 0.0
    encoder_sigma_rad: float = 0.0
    time_offset_s: float = 0.0
    seed: int = 1

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "seed":
                if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                    raise ConfigError(f"robot_error.seed: expected an integer >= 0, got {v!r}")
                object.__setattr__(self, "seed", int(v))
                continue
            try:
                fv = float(v)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"robot_error.{f.name}: expected a number, got {v!r}") from exc
            if not math.isfinite(fv) or (f.name != "time_offset_s" and fv < 0):
                raise ConfigError(f"robot_error.{f.name}: expected a finite number"
                                  f"{'' if f.name == 'time_offset_s' else ' >= 0'}, got {v!r}")
            if f.name == "time_offset_s" and abs(fv) > 1.0:
                raise ConfigError(f"robot_error.time_offset_s: {fv} s is beyond +-1 s")
            object.__setattr__(self, f.name, fv)

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def none(cls) -> RobotErrorSpec:
        """The ideal arm: reported = true, no encoder noise, no time offset."""
        return cls()

    @classmethod
    def default(cls) -> RobotErrorSpec:
        """The realistic default: an uncalibrated industrial arm (per-pose flange error
        ~0.2-0.5 mm and ~0.02-0.05 deg, see docs/simulator.md), fine encoders, no time
        offset."""
        return cls(link_sigma_m=1.5e-4, twist_sigma_rad=1.5e-4, joint_offset_sigma_rad=2.5e-4,
                   encoder_sigma_rad=1.0e-5, time_offset_s=0.0, seed=1)

    @property
    def is_ideal(self) -> bool:
        """True when the reported arm is exactly the true arm."""
        return (self.link_sigma_m == self.twist_sigma_rad == self.joint_offset_sigma_rad
                == self.encoder_sigma_rad == self.time_offset_s == 0.0)

    def scaled(self, factor: float) -> RobotErrorSpec:
        """Every sigma and the time offset multiplied by ``factor`` (>= 0); same seed."""
        if not (math.isfinite(factor) and factor >= 0):
            raise ConfigError(f"robot error scale must be a finite number >= 0, got {factor}")
        return replace(self, link_sigma_m=self.link_sigma_m * factor,
                       twist_sigma_rad=self.twist_sigma_rad * factor,
                       joint_offset_sigma_rad=self.joint_offset_sigma_rad * factor,
                       encoder_sigma_rad=self.encoder_sigma_rad * factor,
                       time_offset_s=self.time_offset_s * factor)

    def to_dict(self) -> dict[str, Any]:
        """The ``robot_error`` section of ``world.yaml``."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Any, where: str = "robot_error") -> RobotErrorSpec:
        """Read the ``robot_error`` section: a mapping of the fields (missing ones are 0,
        ``seed`` 1), or a number: the realistic default scaled by it (``0`` = ideal).

        Raises:
            ConfigError: unknown keys or bad values (the message names ``where``).
        """
        if isinstance(data, bool):
            raise ConfigError(f"{where}: expected a mapping or a scale number, got {data!r}")
        if isinstance(data, (int, float)):
            return cls.default().scaled(float(data))
        if not isinstance(data, Mapping):
            raise ConfigError(f"{where}: expected a mapping or a scale number, got {data!r}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(str(k) for k in data if k not in known)
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)} "
                              f"(known: {', '.join(sorted(known))})")
        try:
            return cls(**dict(data))
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from exc

    @classmethod
    def parse(cls, text: str, base: RobotErrorSpec | None = None) -> RobotErrorSpec:
        """Parse ``--robot-error``: ``0`` (ideal), ``default``, a scale of the default
        (``2`` = twice the default errors), or comma-separated ``key=value`` overrides of
        ``base`` (default: the realistic default), e.g. ``time_offset_s=0.004,seed=3``; a
        scale may come first: ``2,seed=5``.

        Raises:
            ConfigError: malformed text (the message shows it).
        """
        spec = base if base is not None else cls.default()
        text = text.strip()
        if not text:
            raise ConfigError("--robot-error: empty value (use 0, default, a scale or key=value)")
        updates: dict[str, Any] = {}
        for i, part in enumerate(p.strip() for p in text.split(",")):
            if i == 0 and part == "default":
                spec = cls.default()
                continue
            if i == 0 and re.fullmatch(r"[0-9.eE+-]+", part):
                try:
                    spec = cls.default().scaled(float(part))
                except ValueError as exc:
                    raise ConfigError(f"--robot-error: bad scale {part!r}") from exc
                continue
            key, eq, value = part.partition("=")
            if not eq:
                raise ConfigError(f"--robot-error: expected key=value, got {part!r} "
                                  "(use 0, default, a scale or key=value,...)")
            key = key.strip()
            if key not in {f.name for f in fields(cls)}:
                raise ConfigError(f"--robot-error: unknown key {key!r} (known: "
                                  f"{', '.join(f.name for f in fields(cls))})")
            try:
                updates[key] = int(value) if key == "seed" else float(value)
            except ValueError as exc:
                raise ConfigError(f"--robot-error: bad value for {key}: {value!r}") from exc
        return replace(spec, **updates)

    def describe(self) -> str:
        """One line for summaries."""
        if self.is_ideal:
            return "robot error: none (ideal arm)"
        return (f"robot error: links {self.link_sigma_m * 1e3:.3g} mm, twists "
                f"{math.degrees(self.twist_sigma_rad):.3g} deg, joint zeros "
                f"{math.degrees(self.joint_offset_sigma_rad):.3g} deg, encoders "
                f"{math.degrees(self.encoder_sigma_rad):.2g} deg, time offset "
                f"{self.time_offset_s * 1e3:.3g} ms (seed {self.seed})")


def draw_true_arm(nominal: DHChain, spec: RobotErrorSpec,
                  rng: np.random.Generator | None = None) -> DHChain:
    """The true arm: ``nominal`` with its DH parameters perturbed as ``spec`` says.

    Args:
        nominal: the nominal chain.
        spec: the error spec (its sigmas; its ``seed`` when ``rng`` is None).
        rng: random generator to draw from (default ``np.random.default_rng(spec.seed)``).

    Returns:
        A :class:`DHChain` with the same names and limits (the nominal one when the kinematic
        sigmas are all 0).
    """
    if spec.link_sigma_m == spec.twist_sigma_rad == spec.joint_offset_sigma_rad == 0.0:
        return nominal
    g = rng if rng is not None else np.random.default_rng(spec.seed)
    n = nominal.n_joints
    # one draw order, whatever the sigmas: the same seed gives the same arm shape at any scale
    z = g.standard_normal((4, n))
    return replace(nominal,
                   d=nominal.d + spec.link_sigma_m * z[0],
                   a=nominal.a + spec.link_sigma_m * z[1],
                   alpha=nominal.alpha + spec.twist_sigma_rad * z[2],
                   theta_offset=nominal.theta_offset + spec.joint_offset_sigma_rad * z[3])


def reported_joints(q: np.ndarray | Sequence[float], spec: RobotErrorSpec,
                    rng: np.random.Generator) -> np.ndarray:
    """The encoder reading of the true joint vector(s) ``q`` ((n,) or (K, n)): ``q`` plus
    white noise of ``spec.encoder_sigma_rad`` per joint and sample (a copy of ``q`` if 0)."""
    qv = np.array(q, dtype=np.float64)
    if spec.encoder_sigma_rad > 0:
        qv = qv + spec.encoder_sigma_rad * rng.standard_normal(qv.shape)
    return qv


def flange_poses(nominal: DHChain, true_arm: DHChain, q_true, q_reported=None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``(base_T_ee_true, base_T_ee_reported)``, each (4, 4): the true arm at ``q_true`` and
    the nominal arm at ``q_reported`` (default ``q_true``: kinematic error only)."""
    q_rep = q_true if q_reported is None else q_reported
    return true_arm.fk(q_true), nominal.fk(q_rep)


def pose_error(T_true: np.ndarray, T_reported: np.ndarray) -> tuple[float, float]:
    """``(translation error m, rotation error rad)`` between two (4, 4) poses."""
    D = invert(T_reported) @ T_true
    return float(np.linalg.norm(T_true[:3, 3] - T_reported[:3, 3])), rotation_angle(D[:3, :3])


def flange_errors(nominal: DHChain, true_arm: DHChain, qs,
                  q_reported=None) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose flange errors reported vs true.

    Args:
        nominal, true_arm: the two chains.
        qs: true joint vectors, shape (K, n).
        q_reported: reported joint vectors (K, n) (default ``qs``: kinematic error only).

    Returns:
        ``(translation errors (K,) m, rotation errors (K,) rad)``.
    """
    qs = np.atleast_2d(np.asarray(qs, dtype=np.float64))
    qr = qs if q_reported is None else np.atleast_2d(np.asarray(q_reported, dtype=np.float64))
    out = np.array([pose_error(*flange_poses(nominal, true_arm, a, b))
                    for a, b in zip(qs, qr, strict=False)])
    return out[:, 0], out[:, 1]
