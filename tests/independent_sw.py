"""An independent numpy inverse kinematics for 6R arms of the OPW class, for the tests.

OPW: axis 1 perpendicular to axis 2, axes 2 and 3 parallel, axes 4, 5, 6 meeting in one point
(a spherical wrist). This module is a check of the project's closed-form IK written without
it: it imports nothing from ``derive.ik``, ``derive.codegen`` or ``derive.symbolic`` and uses
only numpy, ``derive.load_robot`` and the forward kinematics ``derive.reference.fk_matrix``
(``derive/kinematics/fk.py``). (Importing the ``derive`` package runs its ``__init__``, which
loads those layers too; nothing of them is called here.)

Geometry (:func:`geometry`), taken from FK alone, never from the robot file: for joint i the
relative transform ``FK(e_i) FK(0)^-1`` (a finite rotation of t = 1 rad, not a derivative) is
``exp(xi_i)``, a rotation about a fixed line; its axis h_i is read off the skew part of the
rotation, its point p_i (the foot of the perpendicular from the base origin) solves
``(I - R) p = d`` by least squares. The rotation angle must be 1 rad (joint multiplier +-1) and
the translation along the axis 0 (a revolute joint). With T0 = FK(0) the arm is the product of
exponentials ``FK(q) = exp(xi_1 q1) ... exp(xi_6 q6) T0``.

IK (:func:`ik_all`, :func:`ik_all_batch`): product of exponentials and the Paden-Kahan
subproblems, in the manner of IK-Geo (Elias and Wen 2022, "IK-Geo: unified robot inverse
kinematics using subproblem decomposition"); the code is our own.

* W0, the common point of axes 4, 5, 6 at zero, is fixed by exp(xi_4..6), so the wrist centre
  of the pose T is ``p_W = t + R_d (W0 - t0)`` with ``R_d = R R0^T``, and
  ``p_W = exp(xi_1 q1) exp(xi_2 q2) exp(xi_3 q3) W0``.
* q1 (subproblem 4): R2 and R3 rotate about h2 (h3 = +-h2), so
  ``h2 . R1^T (p_W - p1) = h2 . (W0 - p1) = delta`` (delta the lateral offset):
  ``(R(h1, q1) h2) . x = delta``, x = p_W - p1; 0, 1 or 2 roots.
* q3 (subproblem 3): ``u = R1^T x - (p2 - p1) = R2 (p3 - p2 + R3 (W0 - p3))`` and R2 keeps
  lengths: ``|R(h3, q3) (W0 - p3) - (p2 - p3)| = |u|``; 0, 1 or 2 roots.
* q2 (subproblem 1): ``R(h2, q2) v = u``, v = p3 - p2 + R3 (W0 - p3).
* wrist: ``R_w = (R1 R2 R3)^T R_d = R4 R5 R6``. (q4, q5) by subproblem 2 ``R4^T R_w h6 = R5 h6``,
  split as subproblem 4 for q5 (``h4 . R(h5, q5) h6 = h4 . R_w h6``) and subproblem 1 for q4
  (``R(h4, q4) R5 h6 = R_w h6``); q6 by subproblem 1 on a unit vector e normal to h6
  (``R(h6, q6) e = (R4 R5)^T R_w e``).

Every candidate (2 x 2 x 2 slots per pose) is checked with
``derive.reference.fk_matrix`` (position error in m and rotation angle error in rad both at most
``tol``); the survivors are wrapped to (-pi, pi] and merged when closer than 1e-6 rad in every
joint. Joint limits are NOT applied: every solution modulo 2 pi is returned.

Degenerate cases (no NaN anywhere: every arccos is clipped, every angle comes from atan2):

* wrist singularity (axes 4 and 6 aligned, R5 h6 = +-h4, e.g. q5 = 0): the q5 equation is
  tangent and arccos(c) would lose half the digits near it (an error of 1e-16 in c moves the
  roots by 1e-8 rad, a first-order rotation error). Where the geometry lets axes 4 and 6 align
  we therefore take psi from the angle beta between h4 and R_w h6 (an atan2) by the half-angle
  identities r (1 -+ cos psi) = 1 -+ cos beta, exact to rounding. When R5 h6 is aligned with h4
  within 1e-12 we set q4 = 0 and solve q6 (the q4 + q6 family is represented by q4 = 0); the
  two q5 roots then coincide: one solution per arm branch.
* shoulder singularity (p_W on axis 1, within 1e-10 m; possible only when delta = 0): every q1
  works. We take the two representatives q1 = 0 and q1 = pi, each with its elbow and wrist
  branches (so up to 8 solutions are reported for a pose with a one-parameter family).
* elbow at full stretch or full fold: the two q3 roots coincide. Rounding makes the arccos
  argument c = 1 -+ 1e-15 at an exact stretch, roots ~1e-7 rad apart (the joint-space
  conditioning there is sqrt(eps), intrinsically), so for |c| >= 1 - 1e-13 we take the single
  tangent root (position error ~1e-14 m) and for 1 < |c| <= 1 + 1e-9 clip it. The same for the
  tangent of the q1 equation (a lateral offset, p_W at distance |delta| from axis 1).
* p_W on axis 2 (any q2 works; needs equal upper-arm and forearm lengths): atan2(0, 0) = 0 takes
  q2 = 0.
* an unreachable pose gives an empty (0, 6) array.

Near a singular set the joint values are as well determined as the problem allows, not
better: the pose is reproduced to ~1e-15, but with q5 = s near the wrist singularity q4 - q6 is
known to ~1e-16 / s only (for s < ~1e-9 the generating q4 is not recovered within 1e-6, though
the pose is), and within ~4.5e-7 rad of full stretch the two elbow roots are reported as one.

Also here: :func:`eaik_solutions` (the same poses solved by EAIK, for the comparison test) and
:func:`singular_configs` (random configurations within the limits that lie exactly on the
wrist, shoulder or elbow singular set).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

import derive
from derive.reference import fk_matrix

#: Two joint vectors closer than this in every joint (rad, modulo 2 pi) are one solution.
MERGE_TOL = 1e-6
#: p_W within this distance (m) of axis 1 is the shoulder singularity.
SHOULDER_EPS = 1e-10
#: An arccos argument within this of [-1, 1] is clipped (a tangent, double root).
CLIP_EPS = 1e-9
#: |c| >= 1 - SNAP_EPS: the double root of a tangent (q1, q3; roots closer than 9e-7 rad).
#: At an exact full stretch rounding alone puts |c| at 1 -+ 1e-15, i.e. roots ~1e-7 apart.
SNAP_EPS = 1e-13
#: |h4 x R5 h6| below this: axes 4 and 6 aligned (wrist singularity), q4 = 0.
ALIGN_EPS = 1e-12
#: Candidate slots per pose: q1 root x q3 root x q5 root.
NSLOT = 8
#: Tolerance of the structure tests of :func:`geometry` (rad / m).
GEOM_TOL = 1e-9

_I3 = np.eye(3)


class NotOPW(ValueError):
    """The robot is not a 6R arm of the OPW class."""


class SingularSetUnreachable(ValueError):
    """:func:`singular_configs` cannot place a configuration of that kind within the limits."""


# --------------------------------------------------------------------------- #
# Small numeric helpers
# --------------------------------------------------------------------------- #
def wrap(a):
    """Angles wrapped to (-pi, pi]."""
    a = np.asarray(a, dtype=float)
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def _skew(k):
    k = np.asarray(k, dtype=float)
    z = np.zeros(k.shape[:-1])
    x, y, w = k[..., 0], k[..., 1], k[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1),
                     np.stack([-y, x, z], -1)], -2)


def rot(k, th):
    """Rotation matrices (..., 3, 3) about the unit axis k (3,) by the angles th (...)."""
    th = np.asarray(th, dtype=float)
    K = _skew(k)
    s, c = np.sin(th)[..., None, None], np.cos(th)[..., None, None]
    return _I3 + s * K + (1.0 - c) * (K @ K)


def _dot(a, b):
    return np.sum(a * b, axis=-1)


def _mv(M, v):
    """Matrix (..., 3, 3) times vector (..., 3)."""
    return np.einsum("...ij,...j->...i", M, v)


def sp1(k, p, q):
    """Subproblem 1: the angle th with R(k, th) p = q (least squares: the best rotation of the
    components normal to k). atan2(0, 0) = 0 when p or q lies on the axis."""
    k = np.asarray(k, dtype=float)
    pp = p - _dot(k, p)[..., None] * k              # the normal components, formed first: no
    qp = q - _dot(k, q)[..., None] * k              # cancellation when p, q are close to k
    return np.arctan2(_dot(k, np.cross(pp, qp)), _dot(pp, qp))


def _harmonic(A, B, C):
    """Roots of A cos th + B sin th = C: (th (..., 2), ok (..., 2), c = C / hypot(A, B)).

    th = phi +- arccos(c), phi = atan2(B, A); the argument is clipped to [-1, 1] and the roots
    count as valid while |c| <= 1 + CLIP_EPS; within SNAP_EPS of +-1 the two roots are made one
    (the tangent root; used for q1 and q3, whose position error is then second order). For A = B = 0, c = +-inf (or 0 if C = 0 too) and
    no root is valid: the caller handles that degenerate case."""
    A, B, C = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (A, B, C)))
    r = np.hypot(A, B)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(r > 0, C / np.where(r > 0, r, 1.0), np.where(C == 0, 0.0, np.inf * np.sign(C)))
    phi = np.arctan2(B, A)
    psi = np.arccos(np.clip(c, -1.0, 1.0))
    psi = np.where(np.abs(c) >= 1.0 - SNAP_EPS, np.where(c > 0, 0.0, np.pi), psi)
    th = np.stack([phi + psi, phi - psi], -1)
    ok = np.broadcast_to((np.abs(c) <= 1.0 + CLIP_EPS) & (r > 0), th.shape[:-1])[..., None]
    return th, np.broadcast_to(ok, th.shape).copy(), c


def _sp4_coeffs(h, k, p, d):
    """Subproblem 4, h^T R(k, th) p = d, as A cos th + B sin th = C."""
    kp = _dot(k, p)
    A = _dot(h, p - kp[..., None] * k) if np.ndim(kp) else _dot(h, p - kp * k)
    B = _dot(h, np.cross(k, p))
    C = d - kp * _dot(k, h)
    return A, B, C


def _normal(v):
    """A unit vector normal to the unit vector v."""
    e = np.eye(3)[int(np.argmin(np.abs(v)))]
    e = e - np.dot(e, v) * v
    return e / np.linalg.norm(e)


# --------------------------------------------------------------------------- #
# Geometry from FK
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class Geometry:
    """The arm at the zero configuration, from FK alone.

    H: (6, 3) unit joint axes; P: (6, 3) a point of each axis (the foot of the perpendicular
    from the base origin); T0: (4, 4) the end frame at zero; W0: (3,) the common point of axes
    4, 5, 6; delta: the lateral offset h2 . (W0 - p1) (m); spread: the largest distance from W0
    to axes 4, 5, 6 (m); limits: (6, 2)."""

    name: str
    H: np.ndarray
    P: np.ndarray
    T0: np.ndarray
    W0: np.ndarray
    delta: float
    spread: float
    limits: np.ndarray

    def fk(self, q) -> np.ndarray:
        """Product of exponentials exp(xi_1 q1) ... exp(xi_6 q6) T0, (n, 4, 4) (for the tests)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        T = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
        for i in range(6):
            E = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
            R = rot(self.H[i], q[:, i])
            E[:, :3, :3] = R
            E[:, :3, 3] = self.P[i] - _mv(R, self.P[i])
            T = T @ E
        return T @ self.T0

    def wrist_centre(self, q) -> np.ndarray:
        """The wrist centre (n, 3) at the configurations q (n, 6)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        x = np.broadcast_to(self.W0, (len(q), 3))
        for i in (2, 1, 0):
            x = self.P[i] + _mv(rot(self.H[i], q[:, i]), x - self.P[i])
        return x


_GEOMETRY: dict = {}


def _key(robot):
    return (robot.name, robot.id, robot.path)


def geometry(robot) -> Geometry:
    """The OPW geometry of ``robot`` (a name or a Robot), cached. Raises NotOPW when the robot
    is not 6R, a joint is not a revolute joint of multiplier +-1, or the OPW structure does not
    hold within GEOM_TOL."""
    robot = derive.load_robot(robot)
    key = _key(robot)
    if key in _GEOMETRY:
        return _GEOMETRY[key]
    if robot.dof != 6:
        raise NotOPW(f"{robot.name}: {robot.dof} joint variables, not 6")
    q = np.vstack([np.zeros(6), np.eye(6)])          # zero, then t = 1 rad on each joint
    T = fk_matrix(robot, q)
    T0 = T[0]
    T0inv = np.linalg.inv(T0)
    H, P = np.zeros((6, 3)), np.zeros((6, 3))
    for i in range(6):
        G = T[i + 1] @ T0inv                        # exp(xi_i * 1 rad)
        R, d = G[:3, :3], G[:3, 3]
        w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2.0
        angle = math.atan2(np.linalg.norm(w), (np.trace(R) - 1.0) / 2.0)
        if abs(angle - 1.0) > 1e-9:
            raise NotOPW(f"{robot.name}: joint {i + 1} turns by {angle:.6g} rad for 1 rad of its "
                         "variable (not a revolute joint of multiplier +-1)")
        h = w / np.linalg.norm(w)
        if abs(np.dot(h, d)) > 1e-9:
            raise NotOPW(f"{robot.name}: joint {i + 1} translates along its axis (a screw)")
        p, *_ = np.linalg.lstsq(_I3 - R, d, rcond=None)
        p = p - np.dot(p, h) * h
        if np.linalg.norm((_I3 - R) @ p - d) > 1e-9:
            raise NotOPW(f"{robot.name}: joint {i + 1} is not a rotation about a fixed line")
        H[i], P[i] = h, p
    h1, h2, h3 = H[:3]
    if abs(np.dot(h1, h2)) > GEOM_TOL:
        raise NotOPW(f"{robot.name}: axes 1 and 2 are not perpendicular")
    if np.linalg.norm(np.cross(h2, h3)) > GEOM_TOL:
        raise NotOPW(f"{robot.name}: axes 2 and 3 are not parallel")
    if np.linalg.norm(np.cross(h2, P[2] - P[1])) <= GEOM_TOL:
        raise NotOPW(f"{robot.name}: axes 2 and 3 coincide")
    proj = [_I3 - np.outer(h, h) for h in H[3:]]
    W0 = np.linalg.solve(sum(proj), sum(m @ p for m, p in zip(proj, P[3:])))
    spread = max(float(np.linalg.norm(m @ (W0 - p))) for m, p in zip(proj, P[3:]))
    if spread > GEOM_TOL:
        raise NotOPW(f"{robot.name}: axes 4, 5, 6 do not meet in one point "
                     f"(spread {spread:.3g} m)")
    lim = np.asarray(robot.limits, dtype=float)
    g = Geometry(name=robot.name, H=H, P=P, T0=T0, W0=W0, delta=float(np.dot(h2, W0 - P[0])),
                 spread=spread, limits=lim)
    _GEOMETRY[key] = g
    return g


# --------------------------------------------------------------------------- #
# IK
# --------------------------------------------------------------------------- #
def _candidates(g: Geometry, T: np.ndarray):
    """Candidate solutions (n, 8, 6) and their validity (n, 8) for the poses T (n, 4, 4).

    Slots: q1 root (2) x q3 root (2) x q5 root (2)."""
    n = T.shape[0]
    h1, h2, h3, h4, h5, h6 = g.H
    p1, p2, p3 = g.P[:3]
    Rd = T[:, :3, :3] @ g.T0[:3, :3].T
    pW = T[:, :3, 3] + _mv(Rd, g.W0 - g.T0[:3, 3])
    x = pW - p1                                                     # (n, 3)

    # q1: (R(h1, q1) h2) . x = delta  (subproblem 4)
    A, B, C = _sp4_coeffs(x, h1, h2, g.delta)
    q1, ok1, _ = _harmonic(A, B, C)                                 # (n, 2)
    shoulder = np.hypot(A, B) < SHOULDER_EPS                        # p_W on axis 1
    q1[shoulder] = (0.0, np.pi)
    ok1[shoulder] = (np.abs(C[shoulder]) < SHOULDER_EPS)[:, None]

    # q3: |R(h3, q3) a - b| = |u|  (subproblem 3)
    u = _mv(rot(h1, -q1), x[:, None, :]) - (p2 - p1)                # (n, 2, 3)
    a, b = g.W0 - p3, p2 - p3
    ka, kb = np.dot(h3, a), np.dot(h3, b)
    A3 = np.dot(a - ka * h3, b - kb * h3)
    B3 = np.dot(b, np.cross(h3, a))
    C3 = (np.dot(a, a) + np.dot(b, b) - _dot(u, u)) / 2.0 - ka * kb
    q3, ok3, _ = _harmonic(A3, B3, C3)                              # (n, 2, 2)
    ok3 &= ok1[:, :, None]

    # q2: R(h2, q2) v = u  (subproblem 1)
    R3 = rot(h3, q3)                                                # (n, 2, 2, 3, 3)
    v = (p3 - p2) + _mv(R3, a)
    uu = np.broadcast_to(u[:, :, None, :], v.shape)
    q2 = sp1(h2, v, uu)                                             # (n, 2, 2)
    q1b = np.broadcast_to(q1[:, :, None], q2.shape)

    # wrist: R_w = (R1 R2 R3)^T R_d = R4 R5 R6
    R123 = rot(h1, q1b) @ rot(h2, q2) @ R3
    Rw = np.swapaxes(R123, -1, -2) @ Rd[:, None, None]              # (n, 2, 2, 3, 3)
    u6 = _mv(Rw, h6)
    A5, B5, C5 = _sp4_coeffs(h4, h5, h6, _dot(h4, u6))              # h4 . R(h5, q5) h6 = h4 . u6
    _, ok5, c5 = _harmonic(A5, B5, C5)                              # (n, 2, 2, 2)
    r5, phi5 = math.hypot(A5, B5), math.atan2(B5, A5)
    D5 = np.dot(h5, h6) * np.dot(h5, h4)
    psi = np.arccos(np.clip(c5, -1.0, 1.0))
    # near the wrist singularity arccos(c5) loses half the digits; where axes 4 and 6 can
    # align, the half-angle forms of the angle beta between h4 and u6 are exact identities:
    # r (1 - cos psi) = 1 - cos beta  (r + D = 1)  and  r (1 + cos psi) = 1 + cos beta  (D - r = -1)
    beta = np.arctan2(np.linalg.norm(np.cross(h4, u6), axis=-1), _dot(h4, u6))
    if abs(r5 + D5 - 1.0) < 1e-12:
        psi = np.where(c5 >= 0, 2.0 * np.arcsin(np.minimum(1.0, np.sin(beta / 2) / math.sqrt(r5))),
                       psi)
    if abs(D5 - r5 + 1.0) < 1e-12:
        psi = np.where(c5 < 0, 2.0 * np.arccos(np.minimum(1.0, np.cos(beta / 2) / math.sqrt(r5))),
                       psi)
    q5 = np.stack([phi5 + psi, phi5 - psi], -1)                     # (n, 2, 2, 2)
    ok = ok5 & ok3[..., None]

    R5 = rot(h5, q5)                                                # (n, 2, 2, 3, 3, 3)
    w = _mv(R5, h6)
    u6b = np.broadcast_to(u6[..., None, :], w.shape)
    aligned = np.linalg.norm(np.cross(h4, w), axis=-1) < ALIGN_EPS
    q4 = np.where(aligned, 0.0, sp1(h4, w, u6b))
    R45 = rot(h4, q4) @ R5
    e = _normal(h6)
    Rwb = np.broadcast_to(Rw[..., None, :, :], R45.shape)
    q6 = sp1(h6, e, _mv(np.swapaxes(R45, -1, -2) @ Rwb, e))

    shape = q5.shape
    Q = np.stack([np.broadcast_to(q1b[..., None], shape), np.broadcast_to(q2[..., None], shape),
                  np.broadcast_to(q3[..., None], shape), q4, q5, q6], -1)
    return Q.reshape(n, NSLOT, 6), ok.reshape(n, NSLOT)


def pose_errors(Ta, Tb):
    """(position error m, rotation angle error rad) between homogeneous matrices (..., 4, 4)."""
    dp = np.linalg.norm(Ta[..., :3, 3] - Tb[..., :3, 3], axis=-1)
    M = np.swapaxes(Ta[..., :3, :3], -1, -2) @ Tb[..., :3, :3]
    s = np.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0],
                  M[..., 1, 0] - M[..., 0, 1]], -1)
    ang = np.arctan2(np.linalg.norm(s, axis=-1) / 2.0,
                     (M[..., 0, 0] + M[..., 1, 1] + M[..., 2, 2] - 1.0) / 2.0)
    return dp, np.abs(ang)


def _dedupe(sols: np.ndarray) -> np.ndarray:
    """Merge rows closer than MERGE_TOL in every joint modulo 2 pi (the first one is kept)."""
    keep = []
    for s in sols:
        if not any(np.all(np.abs(wrap(s - k)) < MERGE_TOL) for k in keep):
            keep.append(s)
    return np.array(keep).reshape(-1, 6)


def ik_all_batch(robot, Ts, tol: float = 1e-9) -> list:
    """All distinct IK solutions of each pose in Ts (n, 4, 4): a list of n arrays (k_i, 6),
    angles wrapped to (-pi, pi], each reproducing its pose within ``tol`` (m and rad, by
    ``derive.reference.fk_matrix``), sorted lexicographically. Joint limits are not applied."""
    robot = derive.load_robot(robot)
    g = geometry(robot)
    Ts = np.asarray(Ts, dtype=float).reshape(-1, 4, 4)
    n = len(Ts)
    Q, ok = _candidates(g, Ts)
    Q = wrap(Q)
    ok &= np.all(np.isfinite(Q), axis=-1)
    idx = np.nonzero(ok)
    if len(idx[0]):
        Tq = fk_matrix(robot, Q[idx])
        dp, dr = pose_errors(Tq, Ts[idx[0]])
        good = (dp <= tol) & (dr <= tol)
        ok[idx] = good
    # merge duplicates, vectorised over poses: slot j goes when an earlier valid slot is close
    d = np.abs(wrap(Q[:, :, None, :] - Q[:, None, :, :]))           # (n, 8, 8, 6)
    close = np.all(d < MERGE_TOL, axis=-1) & ok[:, :, None] & ok[:, None, :]
    earlier = np.tril(np.ones((NSLOT, NSLOT), dtype=bool), -1)             # [j, i]: i < j
    dup = np.any(close & earlier[None], axis=-1)
    keep = ok & ~dup
    out = []
    for i in range(n):
        s = Q[i][keep[i]]
        out.append(s[np.lexsort(s.T[::-1])] if len(s) > 1 else s)
    return out


def ik_all(robot, T, tol: float = 1e-9) -> np.ndarray:
    """All distinct IK solutions (k, 6) of the pose T (4, 4); (0, 6) when unreachable."""
    return ik_all_batch(robot, np.asarray(T, dtype=float)[None], tol)[0]


def count(robot, T, tol: float = 1e-9) -> int:
    """Number of distinct IK solutions of the pose T."""
    return len(ik_all(robot, T, tol))


# --------------------------------------------------------------------------- #
# EAIK, for the comparison test
# --------------------------------------------------------------------------- #
_EAIK: dict = {}


def eaik_robot(robot):
    """EAIK's HPRobot built from the FK geometry: H the axes, P[0] = p1, P[i] = p_(i+1) - p_i,
    P[6] = t0 - p6 (EAIK's end frame has the base orientation at zero; :func:`eaik_solutions`
    converts the pose)."""
    from eaik.IK_HP import HPRobot

    robot = derive.load_robot(robot)
    key = _key(robot)
    if key not in _EAIK:
        g = geometry(robot)
        P = np.vstack([g.P[0], np.diff(g.P, axis=0), g.T0[:3, 3] - g.P[5]])
        _EAIK[key] = HPRobot(g.H.copy(), P)
    return _EAIK[key]


def _eaik_pose(g, T):
    Te = np.array(T, dtype=float)
    Te[..., :3, :3] = Te[..., :3, :3] @ g.T0[:3, :3].T
    return Te


def _eaik_exact(sol) -> np.ndarray:
    Q = np.asarray(sol.Q, dtype=float).reshape(-1, 6)
    ls = np.asarray(sol.is_LS, dtype=bool).reshape(-1)
    exact = wrap(Q[~ls]) if len(Q) else Q
    return _dedupe(exact)


def eaik_solutions(robot, T) -> np.ndarray:
    """EAIK's exact solutions (k, 6) of the pose T (4, 4), least-squares ones dropped, in the
    robot's joint convention (the FK geometry's PoE), wrapped to (-pi, pi], merged within
    MERGE_TOL."""
    g = geometry(robot)
    return _eaik_exact(eaik_robot(robot).IK(_eaik_pose(g, T)))


def eaik_solutions_batch(robot, Ts, threads: int = 4) -> list:
    g = geometry(robot)
    Te = _eaik_pose(g, np.asarray(Ts, dtype=float).reshape(-1, 4, 4))
    return [_eaik_exact(s) for s in eaik_robot(robot).IK_batched(Te, threads)]


# --------------------------------------------------------------------------- #
# Configurations on the singular sets
# --------------------------------------------------------------------------- #
def random_configs(robot, n, rng) -> np.ndarray:
    """n configurations uniform within the limits (an infinite limit taken as +-pi)."""
    lim = geometry(robot).limits
    lo = np.where(np.isfinite(lim[:, 0]), lim[:, 0], -np.pi)
    hi = np.where(np.isfinite(lim[:, 1]), lim[:, 1], np.pi)
    return rng.uniform(lo, hi, size=(n, 6))


def _into_limits(q, lo, hi):
    """q shifted by a multiple of 2 pi into [lo, hi] (the smallest shift first), or nan when no
    shift fits."""
    q = np.asarray(q, dtype=float)
    out = np.full(q.shape, np.nan)
    for m in (0, -1, 1, -2, 2, -3, 3):
        c = q + 2.0 * np.pi * m
        fit = np.isnan(out) & (c >= lo) & (c <= hi)
        out = np.where(fit, c, out)
    return out


def wrist_singular_q5(g: Geometry) -> np.ndarray:
    """The q5 values (wrapped) where axes 4 and 6 are aligned, R(h5, q5) h6 = +-h4: the
    extremes of h4 . R(h5, q5) h6 = A cos + B sin + D when they reach +-1."""
    h4, h5, h6 = g.H[3:]
    A, B, _ = _sp4_coeffs(h4, h5, h6, 0.0)
    D = np.dot(h5, h6) * np.dot(h5, h4)
    r, phi = math.hypot(A, B), math.atan2(B, A)
    out = []
    if abs(r + D - 1.0) < 1e-12:
        out.append(phi)
    if abs(D - r + 1.0) < 1e-12:
        out.append(phi + np.pi)
    return wrap(np.array(out))


def elbow_stretch_q3(g: Geometry) -> float:
    """q3 (wrapped) of full stretch: R(h3, q3) a_perp points along -b_perp (a = W0 - p3,
    b = p2 - p3), so the distance from axis 2 to the wrist centre is the largest."""
    h3 = g.H[2]
    a, b = g.W0 - g.P[2], g.P[1] - g.P[2]
    ap, bp = a - np.dot(a, h3) * h3, b - np.dot(b, h3) * h3
    return float(wrap(sp1(h3, ap, -bp)))


def singular_configs(robot, kind: str, n: int, rng) -> np.ndarray:
    """n random configurations (n, 6) within the limits on a singular set:

    * "wrist": q5 one of :func:`wrist_singular_q5` (axes 4 and 6 aligned);
    * "shoulder": the wrist centre on axis 1: a random point X of axis 1 within reach, q3 by
      subproblem 3 (|exp(xi_2 q2) exp(xi_3 q3) W0 - p2| = |X - p2|, either root) and q2 by
      subproblem 1; possible only with no lateral offset (delta = 0);
    * "elbow": q3 = :func:`elbow_stretch_q3` (full stretch).

    The other joints are uniform within the limits. Raises SingularSetUnreachable when the set
    cannot be reached within the limits."""
    g = geometry(robot)
    lo, hi = g.limits[:, 0], g.limits[:, 1]
    q = random_configs(robot, n, rng)
    if kind == "wrist":
        vals = [v for v in _into_limits(wrist_singular_q5(g), lo[4], hi[4]) if np.isfinite(v)]
        if not vals:
            raise SingularSetUnreachable(f"{g.name}: axes 4 and 6 never align within the limits")
        q[:, 4] = rng.choice(vals, size=n)
        return q
    if kind == "elbow":
        v = _into_limits(elbow_stretch_q3(g), lo[2], hi[2])
        if not np.isfinite(v):
            raise SingularSetUnreachable(f"{g.name}: full stretch q3 outside the limits")
        q[:, 2] = v
        return q
    if kind != "shoulder":
        raise ValueError(f"kind must be 'wrist', 'shoulder' or 'elbow', got {kind!r}")
    if abs(g.delta) > GEOM_TOL:
        raise SingularSetUnreachable(f"{g.name}: lateral offset {g.delta:.6g} m, the wrist centre "
                                     "is never on axis 1")
    h1, h2, h3 = g.H[:3]
    p1, p2, p3 = g.P[:3]
    a, b = g.W0 - p3, p2 - p3
    ka, kb = np.dot(h3, a), np.dot(h3, b)
    A3, B3 = np.dot(a - ka * h3, b - kb * h3), np.dot(b, np.cross(h3, a))
    reach = np.linalg.norm(a) + np.linalg.norm(b)
    s0 = np.dot(h1, p2 - p1)
    found = []
    for _ in range(200):
        m = 4 * n
        s = rng.uniform(s0 - reach, s0 + reach, size=m)
        X = p1 + s[:, None] * h1
        dX = X - p2
        C3 = (np.dot(a, a) + np.dot(b, b) - _dot(dX, dX)) / 2.0 - ka * kb
        q3r, ok3, _ = _harmonic(A3, B3, C3)
        pick = rng.integers(0, 2, size=m)
        q3 = q3r[np.arange(m), pick]
        v = (p3 - p2) + _mv(rot(h3, q3), a)
        q2 = sp1(h2, v, dX)
        q2l, q3l = _into_limits(q2, lo[1], hi[1]), _into_limits(q3, lo[2], hi[2])
        good = ok3[np.arange(m), pick] & np.isfinite(q2l) & np.isfinite(q3l)
        found += list(zip(q2l[good], q3l[good]))
        if len(found) >= n:
            q[:, 1:3] = np.array(found[:n])
            return q
    raise SingularSetUnreachable(f"{g.name}: no configuration within the limits puts the wrist "
                                 "centre on axis 1")


def jacobian_fd(robot, q, h: float = 1e-5) -> np.ndarray:
    """Spatial Jacobians (n, 6, 6) [omega; v at the base origin] by central differences of
    derive.reference.fk_matrix."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = len(q)
    steps = np.concatenate([np.eye(6), -np.eye(6)]) * h
    Tq = fk_matrix(robot, q)
    Tp = fk_matrix(robot, (q[:, None, :] + steps[None]).reshape(-1, 6)).reshape(n, 12, 4, 4)
    dT = (Tp[:, :6] - Tp[:, 6:]) / (2.0 * h)                        # (n, 6, 4, 4)
    R, p = Tq[:, None, :3, :3], Tq[:, None, :3, 3]
    W = dT[..., :3, :3] @ np.swapaxes(R, -1, -2)
    om = np.stack([W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0],
                   W[..., 1, 0] - W[..., 0, 1]], -1) / 2.0
    vel = dT[..., :3, 3] - np.cross(om, p)
    return np.swapaxes(np.concatenate([om, vel], -1), -1, -2)


def sigma_min(robot, q) -> np.ndarray:
    """Smallest singular value (n,) of the finite-difference Jacobian."""
    return np.linalg.svd(jacobian_fd(robot, q), compute_uv=False)[:, -1]
