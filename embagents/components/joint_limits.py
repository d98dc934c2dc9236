"""Joint limits (from a URDF or a dict) and the clipping every arm command goes through.

A URDF is read with ``urdf_parser_py`` (ROS's own parser, package
``urdfdom-py``), as bytes (xacro's and vendors' files declare their encoding),
without its transmission and gazebo tags (not needed for limits): each
revolute or prismatic joint gives ``lower``, ``upper`` (rad or m) and
``velocity`` (rad/s or m/s). A dict gives the same per joint and wins over the URDF. :class:`Clipper` makes one command safe: positions
inside the limits and no faster than the velocity limit allows over one
control period; velocities within the limit and never pushing past a
position limit. Each joint clipped is logged once.

Example::

    >>> limits = {"j1": JointLimit(-1.0, 1.0, 0.5)}
    >>> clip = Clipper(["j1"], limits, period_s=0.1)
    >>> clip.position([2.0], previous=[0.0]).tolist()     # at most 0.5 rad/s x 0.1 s per step
    [0.05]
    >>> clip.velocity([-3.0], position=[-1.0]).tolist()   # at the lower limit: no further down
    [0.0]
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

__all__ = ["Clipper", "JointLimit", "limits_from_urdf", "merge_limits"]


class JointLimit(NamedTuple):
    """One joint's limits: position ``lower`` / ``upper`` and the largest speed ``velocity``."""

    lower: float
    upper: float
    velocity: float


def limits_from_urdf(path: str) -> dict[str, JointLimit]:
    """The limits of every revolute and prismatic joint of the URDF at ``path`` (a file or a pybullet_data name).

    Continuous joints get +-inf positions. Raises ``ValueError`` for a file that is not a URDF.
    """
    from lxml import etree  # urdf_parser_py's own XML library
    from urdf_parser_py import urdf as urdf_py
    from urdf_parser_py.xml_reflection import core

    from embagents.components.sim import robot_path  # lazy: a cycle

    full = robot_path(path)
    saved = core.on_error
    core.on_error = lambda _msg: None  # the parser's hook: it prints every tag it does not model (materials, contacts)
    try:
        with open(full, "rb") as f:  # bytes: lxml refuses a str with an <?xml ... encoding="utf-8"?> declaration
            root = etree.fromstring(f.read())
        # Limits need joints only: transmissions and gazebo tags (often xacro leftovers, such as pybullet_data's
        # xArm6 <mechanicalReduction>reduction</mechanicalReduction>) must not make a good robot unreadable.
        for tag in root.findall("transmission") + root.findall("gazebo"):
            root.remove(tag)
        robot = urdf_py.URDF.from_xml_string(etree.tostring(root))
    except Exception as exc:
        raise ValueError(f"{full!r} is not a URDF urdf_parser_py can read: {exc}") from exc
    finally:
        core.on_error = saved
    out: dict[str, JointLimit] = {}
    for j in robot.joints:
        if j.type == "continuous":
            out[j.name] = JointLimit(-np.inf, np.inf, float(j.limit.velocity) if j.limit else np.inf)
        elif j.type in ("revolute", "prismatic") and j.limit is not None:
            out[j.name] = JointLimit(float(j.limit.lower), float(j.limit.upper), float(j.limit.velocity))
    return out


def merge_limits(urdf: str | None, overrides: Mapping[str, Mapping[str, float]] | None) -> dict[str, JointLimit]:
    """Limits from ``urdf`` (if any), with ``overrides`` per joint (``{"lower", "upper", "velocity"}``, any of them).

    >>> merge_limits(None, {"j": {"lower": -1, "upper": 1, "velocity": 2}})["j"]
    JointLimit(lower=-1.0, upper=1.0, velocity=2.0)
    """
    limits = limits_from_urdf(urdf) if urdf else {}
    for name, spec in (overrides or {}).items():
        base = limits.get(name, JointLimit(-np.inf, np.inf, np.inf))
        unknown = set(spec) - set(JointLimit._fields)
        if unknown:
            raise ValueError(f"joint_limits[{name!r}] has keys {sorted(unknown)}; use lower, upper, velocity")
        limits[name] = base._replace(**{k: float(v) for k, v in spec.items()})
    return limits


class Clipper:
    """Clips commands for ``joints`` (in order) to ``limits``; ``period_s`` is the control period."""

    def __init__(self, joints: Sequence[str], limits: Mapping[str, JointLimit], period_s: float,
                 logger: logging.Logger | None = None, label: str = "") -> None:
        missing = [j for j in joints if j not in limits]
        if missing:
            raise ValueError(f"no limits for joints {missing}: give a URDF that has them or joint_limits for them")
        self.joints = list(joints)
        self.lower = np.array([limits[j].lower for j in joints])
        self.upper = np.array([limits[j].upper for j in joints])
        self.vmax = np.array([limits[j].velocity for j in joints])
        self.period = float(period_s)
        self.logger = logger or logging.getLogger("embagents.safety")
        self.label = label
        self.logged: set[str] = set()
        #: How many commands were clipped, per joint.
        self.counts: dict[str, int] = dict.fromkeys(joints, 0)

    def _note(self, wanted: np.ndarray, got: np.ndarray, unit: str, why: Any) -> None:
        for i in np.flatnonzero(~np.isclose(wanted, got, rtol=0, atol=1e-9)):
            name = self.joints[i]
            self.counts[name] += 1
            if name not in self.logged:  # once per joint: a policy pushing at a limit would flood the log
                self.logged.add(name)
                self.logger.warning("%s: command for joint %s clipped: %.4f -> %.4f %s (%s); logged once per joint",
                                    self.label, name, wanted[i], got[i], unit, why(i))

    def position(self, target: Sequence[float] | np.ndarray, previous: Sequence[float] | np.ndarray) -> np.ndarray:
        """``target`` positions inside the limits, at most ``velocity * period`` from ``previous``."""
        want = np.asarray(target, np.float64)
        prev = np.asarray(previous, np.float64)
        step = self.vmax * self.period
        got = np.clip(np.clip(want, prev - step, prev + step), self.lower, self.upper)
        self._note(want, got, "rad", lambda i: f"limits [{self.lower[i]:.4f}, {self.upper[i]:.4f}], "
                                               f"{self.vmax[i]:.3f}/s")
        return got

    def velocity(self, target: Sequence[float] | np.ndarray, position: Sequence[float] | np.ndarray) -> np.ndarray:
        """``target`` velocities within the limit, and none that would cross a position limit within a period."""
        want = np.asarray(target, np.float64)
        q = np.asarray(position, np.float64)
        room_up = np.maximum(self.upper - q, 0.0) / self.period
        room_down = np.maximum(q - self.lower, 0.0) / self.period
        got = np.clip(want, np.maximum(-self.vmax, -room_down), np.minimum(self.vmax, room_up)) + 0.0  # no -0.0
        self._note(want, got, "rad/s", lambda i: f"speed limit {self.vmax[i]:.3f}, position "
                                                 f"[{self.lower[i]:.4f}, {self.upper[i]:.4f}]")
        return got
