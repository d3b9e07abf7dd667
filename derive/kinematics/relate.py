"""The same arm described two ways: constant base and tool transforms between two robots.

A URDF and a DH table of one arm usually differ by a constant base transform (ROS's
``base_link`` is the DH base turned by pi about z for the Universal Robots), a constant tool
transform (``tool0`` against DH frame 6), and sometimes joint directions. :func:`relate` finds

    FK_robot(q) = B  FK_other(s * q)  T        (B, T constant unit dual quaternions, s_i = +-1)

by the hand-eye equation: with A_k = FK_robot(q_k) FK_robot(0)^-1 and C_k = FK_other(s q_k)
FK_other(0)^-1, every A_k = B C_k B^-1 (Park and Martin, "Robot sensor calibration: solving
AX = XB on the Euclidean group", 1994: the rotation vectors satisfy alpha_k = R_B beta_k, the
translations (R_A - I) t_B = R_B t_C - t_A), and T = FK_other(0)^-1 B^-1 FK_robot(0). A
relation is accepted when it reproduces FK_robot on random configurations within ``tol``
(default 1e-9 m and rad: the rounding of printed constants such as URDF's 1.57079632679, not
a calibration's deviations, which need derive.refine).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.errors import DeriveError
from derive.kinematics.fk import _pose_error, fk
from derive.model.geometry import numeric_chain
from derive.model.robot import load_robot

#: A relation must reproduce the robot's FK within this (m, rad).
RELATE_TOL = 1e-9


@dataclass(frozen=True)
class Relation:
    """FK_robot(q) = base * FK_other(signs * q) * tool (unit dual quaternions); ``error`` is the
    largest position / rotation mismatch seen on the check configurations."""

    robot: str
    other: str
    base: np.ndarray        # (8,)
    tool: np.ndarray        # (8,)
    signs: np.ndarray       # (dof,) of +-1
    error: float

    def into_other(self, poses: np.ndarray) -> np.ndarray:
        """Poses (n, 8) of the robot's end frame as poses of the other robot's: B^-1 P T^-1."""
        return dq._mul(dq._mul(dq.conj_quaternion(self.base)[None], poses), dq.conj_quaternion(self.tool)[None])

    def describe(self) -> str:
        def pose(d):
            r, t = dq.to_rt(d)
            angle = 2.0 * np.arctan2(np.linalg.norm(r[1:]), abs(r[0]))
            return (f"rotation (w x y z) [{', '.join(f'{v + 0.0:.6g}' for v in r)}] "
                    f"({np.degrees(angle):.6g} deg), translation [{', '.join(f'{v + 0.0:.6g}' for v in t)}] m")
        flips = [i + 1 for i, s in enumerate(self.signs) if s < 0]
        return (f"{self.robot} = base * {self.other} * tool, joints "
                f"{'as they are' if not flips else 'reversed: ' + ', '.join(map(str, flips))}\n"
                f"  base: {pose(self.base)}\n  tool: {pose(self.tool)}\n"
                f"  largest mismatch {self.error:.2g} (m / rad) on random configurations")


def _rotvec(r: np.ndarray) -> np.ndarray:
    """Rotation vectors (n, 3) of unit quaternions (n, 4)."""
    r = np.where(r[:, :1] < 0, -r, r)
    vn = np.linalg.norm(r[:, 1:], axis=1)
    angle = 2.0 * np.arctan2(vn, r[:, 0])
    return r[:, 1:] * np.where(vn > 0, angle / np.where(vn > 0, vn, 1.0), 0.0)[:, None]


def _kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The rotation R minimising |R src_k - dst_k| (rows of src, dst)."""
    u, _, vt = np.linalg.svd(dst.T @ src)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def _hand_eye(a: np.ndarray, c: np.ndarray) -> np.ndarray:
    """B (8,) with a_k B = B c_k for unit dual quaternions a, c (n, 8)."""
    alpha, beta = _rotvec(a[:, :4]), _rotvec(c[:, :4])
    rb = _kabsch(beta, alpha)
    ra, ta = quat._to_matrix(a[:, :4]), dq._translation(a)
    tc = dq._translation(c)
    lhs = (ra - np.eye(3)).reshape(-1, 3)
    rhs = (tc @ rb.T - ta).reshape(-1)
    tb = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return dq.from_rt(quat.from_matrix(rb), tb)


def relate(robot, other, tol: float = RELATE_TOL, samples: int = 12, seed: int = 7) -> Relation | None:
    """The relation FK_robot(q) = B FK_other(s q) T between two robots of the same number of
    joints (module docstring), or None when there is none within ``tol``."""
    robot, other = load_robot(robot), load_robot(other)
    n = robot.dof
    if other.dof != n or not _congruent_axes(robot, other, max(10 * tol, 1e-6)):
        return None
    rng = np.random.default_rng(seed)
    q = rng.uniform(-np.pi, np.pi, size=(samples, n))
    check = rng.uniform(-np.pi, np.pi, size=(samples, n))
    f_r0 = fk(robot, np.zeros(n))
    f_r = fk(robot, q)
    f_rc = fk(robot, check)
    a = dq._mul(f_r, dq.conj_quaternion(f_r0)[None])
    f_o0 = fk(other, np.zeros(n))
    inv_o0 = dq.conj_quaternion(f_o0)
    combos = np.array(list(itertools.product((1.0, -1.0), repeat=n)))
    m = len(combos)
    c_all = dq._mul(fk(other, (combos[:, None, :] * q[None]).reshape(-1, n)), inv_o0[None]).reshape(m, samples, 8)
    o_check = fk(other, (combos[:, None, :] * check[None]).reshape(-1, n)).reshape(m, samples, 8)
    best = None
    for k in range(m):
        b = _tidy(_hand_eye(a, c_all[k]))
        t = _tidy(dq._mul(dq._mul(inv_o0[None], dq.conj_quaternion(b)[None]), f_r0[None])[0])
        pred = dq._mul(dq._mul(np.broadcast_to(b, (samples, 8)), o_check[k]), np.broadcast_to(t, (samples, 8)))
        dp, dr = _pose_error(pred, f_rc)
        err = float(max(dp.max(), dr.max()))
        if best is None or err < best.error:
            best = Relation(robot.name, other.name, b, t, combos[k].copy(), err)
    return best if best is not None and best.error < tol else None


def _axis_invariants(robot) -> tuple:
    """|cos| of the angle between every two joint axes at q = 0, and the distance between the
    two lines where they are far from parallel (sin > 0.1; near parallel lines have no stable
    common normal): unchanged by a base transform, a tool transform and joint directions, so
    two related robots have the same (the joints' screw axes at zero map onto each other by B)."""
    c = numeric_chain(robot)
    points = c.start + np.vstack([np.zeros(3), np.cumsum(c.links, axis=0)[:-1]])
    n = c.n
    cos, dist = np.zeros((n, n)), np.full((n, n), np.nan)
    for i in range(n):
        for j in range(i + 1, n):
            a, b = c.axes[i], c.axes[j]
            cos[i, j] = abs(float(a @ b))
            cr = np.cross(a, b)
            if np.linalg.norm(cr) > 0.1:
                dist[i, j] = abs((points[j] - points[i]) @ cr) / np.linalg.norm(cr)
    return cos, dist


def _congruent_axes(robot, other, tol: float) -> bool:
    try:
        (c1, d1), (c2, d2) = _axis_invariants(robot), _axis_invariants(other)
    except DeriveError:                  # mimic joints on the path: no quick test
        return True
    if c1.shape != c2.shape or np.abs(c1 - c2).max(initial=0) > tol:
        return False
    both = np.isfinite(d1) & np.isfinite(d2)
    return bool(np.all(np.abs(d1 - d2)[both] <= tol))


def _tidy(d: np.ndarray) -> np.ndarray:
    """A unit dual quaternion with its rotation and translation rounded to 1e-10 (the noise of
    the fit; printed constants are far coarser), the real part's sign made canonical."""
    r, t = dq.to_rt(d)
    r = np.round(r, 10)
    r = r / np.linalg.norm(r)
    lead = r[np.argmax(np.abs(r) > 0)]
    return dq.from_rt(r if lead > 0 else -r, np.round(t, 10) + 0.0)
