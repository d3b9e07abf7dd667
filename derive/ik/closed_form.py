"""Closed-form inverse kinematics of the UR family (numeric reference).

The chain in thesis form (:mod:`derive.symbolic.chain`): axes z, -y, -y, -y, -z, -y and links
(0, 0, d1), (a2, 0, 0), (a3, -d4, 0), (0, 0, -d5), (0, -d6, 0), 0. The solving order is
the thesis's (section 4.3.5) and the one the extraction finds (:mod:`derive.ik.extract`):

1. theta1 from W.6 (= 4.9): y5 cos t1 - x5 sin t1 = -d4, with the frame-5 point
   p5 = p + d6 R e_y; two roots (4.11);
2. theta5 and theta6 from the rotation: with A = Rz(t1)^T R, row 2 of A is
   (-s5 c6, c5, s5 s6) (B.29-B.32, = 4.14-4.17), a point rotated about axis 6 and e_y about
   axis 5 to meet; two solutions, the sign of sin t5 (the thesis's 4.13 takes t5 by acos,
   which loses accuracy near 0 and pi; its 4.28 divides by cos(t5/2), sin(t5/2) and
   cos((t2+t3+t4)/2)); at the wrist singularity (sin t5 = 0) t6 is free: it is taken from a
   reference configuration when one is given, else chosen for reach (:func:`_free_theta6`),
   and the solution is marked singular;
3. t2 + t3 + t4 from A R_-y(t6)^-1 R_-z(t5)^-1 = R_-y(t2+t3+t4) (exact also when t6 was
   chosen freely);
4. theta3 from C.19, C.21 by the sum of squares (4.37-4.38), two roots;
5. theta2 from C.12, C.14 (4.39-4.41); theta4 = (t2+t3+t4) - t2 - t3 (C.1, C.3, 4.44).

Each step is one subproblem of :mod:`derive.ik.subproblems` (IK-Geo's naming): sp4, sp2, sp1,
sp3, sp1 (:func:`solve_batch`).

Every candidate goes through the finish step of all classes (:mod:`derive.ik.finish`): checked
by the reference forward kinematics, candidates that do not reproduce the pose dropped,
near-duplicates (closer than :data:`MERGE_TOL` in every joint, modulo 2 pi) merged. All angles
are wrapped to (-pi, pi].
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.algebra.angles import wrap_angle
from derive.algebra.rotations import rot_z
from derive.cache import memo
from derive.errors import DeriveError, InputError, as_finite_array
from derive.ik import classes, general6r, panda, parallel3, spherical, srs
from derive.ik.finish import finish, select_one
from derive.ik.parallel3 import P3Geometry
from derive.ik.subproblems import rot
from derive.ik.subproblems.sp1 import _sp1
from derive.ik.subproblems.sp2 import _sp2
from derive.ik.subproblems.sp3 import _sp3
from derive.ik.subproblems.sp4 import _sp4
from derive.ik.spherical import SWGeometry, sw_geometry
from derive.ik.tolerances import MERGE_TOL  # noqa: F401  (read here by derive.codegen.emit)
from derive.ik.tolerances import REACH_TOL, UR_AXIS_TOL, UR_LINK_TOL, WRIST_SINGULAR
from derive.kinematics.pose import as_pose_batch
from derive.kinematics.relate import RELATE_TOL, Relation, _axis_invariants, relate
from derive.model.classify import Classification
from derive.model.classify import classify as geometric_classify
from derive.model.geometry import numeric_chain
from derive.model.robot import list_robots, load_robot

REASON_OK = ""
REASON_WRIST_NEAR_AXIS = ("unreachable: the wrist centre is closer to the base axis than the "
                          "shoulder offset d4 allows")
REASON_ARM_REACH = ("unreachable: the distance from shoulder to wrist is outside the range the "
                    "upper arm and forearm can span (| |a2| - |a3| | .. |a2| + |a3|)")
REASON_NO_CANDIDATE = "unreachable: no candidate reproduces the pose"


@dataclass(frozen=True)
class URGeometry:
    """Numbers of a UR-type chain and the constant end transform G (robot end = chain end * G)."""

    d1: float
    a2: float
    a3: float
    d4: float
    d5: float
    d6: float
    g: np.ndarray          # unit dual quaternion (8,)


def ur_geometry(robot) -> URGeometry:
    """Extract the UR structure from a robot, or raise DeriveError when it does not have it.

    The test runs on the numeric axis-angle chain (:func:`derive.model.geometry.numeric_chain`),
    so it needs no symbolic work; cached per robot identity."""
    robot = load_robot(robot)
    return memo("ur-geometry", robot.id, lambda: _ur_geometry(robot))


#: Axes of the UR chain in thesis form.
UR_AXES = ((0, 0, 1), (0, -1, 0), (0, -1, 0), (0, -1, 0), (0, 0, -1), (0, -1, 0))


def _ur_geometry(robot) -> URGeometry:
    chain = numeric_chain(robot)
    axes, links = chain.axes, chain.links
    ok = (chain.n == 6 and all(t == "revolute" for t in chain.types)
          and np.allclose(chain.start, 0.0, atol=UR_LINK_TOL)
          and all(np.allclose(a, w, atol=UR_AXIS_TOL) for a, w in zip(axes, UR_AXES)))
    if ok:
        d1, a2, (a3, md4), md5, md6 = links[0][2], links[1][0], links[2][:2], links[3][2], links[4][1]
        shape = [(0, 0, d1), (a2, 0, 0), (a3, md4, 0), (0, 0, md5), (0, md6, 0), (0, 0, 0)]
        ok = all(np.allclose(l, s, atol=UR_LINK_TOL) for l, s in zip(links, shape))
    if not ok:
        raise DeriveError(f"{robot.name}: closed-form IK is implemented for the UR family "
                          "(axes z, -y, -y, -y, -z, -y in thesis form); this chain differs")
    g = dq.from_rt(quat.from_matrix(chain.end_rotation), chain.end_translation)
    return URGeometry(d1=float(d1), a2=float(a2), a3=float(a3), d4=float(-md4), d5=float(-md5),
                      d6=float(-md6), g=g)


# --------------------------------------------------------------------------- #
# Batch solver: a composition of subproblems (derive.ik.subproblems)
# --------------------------------------------------------------------------- #
#: Unit vectors and the UR axes of the thesis form, as constants of the composition.
_X, _Y, _Z = np.eye(3)


def _chain_pose(geo: URGeometry, poses: np.ndarray) -> tuple:
    """Rotation matrices (n,3,3) and translations (n,3) of the chain end frame (pose * G^-1)."""
    chain = dq._mul(poses, dq.conj_quaternion(geo.g))
    r = quat._to_matrix(chain[:, :4])
    p = dq._translation(chain)
    return r, p


def _free_theta6(geo: URGeometry, wrist1, n: int) -> np.ndarray:
    """theta6 at the wrist singularity, chosen for reach.

    With sin t5 = 0 any theta6 gives a solution; it moves the wrist-1 point on a circle of
    radius |d5| in the arm plane, so cos t3 = (x4^2 + z4^2 - a2^2 - a3^2) / (2 a2 a3) (C.19,
    C.21) is alpha + beta cos t6 + gamma sin t6. The chosen theta6 solves cos t3 = 0 (elbow
    at a right angle, the middle of the reach) when it can, and otherwise puts the wrist-1
    point as close to that as the circle allows: atan2(gamma, beta) + acos(clip(-alpha / R)),
    R = hypot(beta, gamma). So the singular branch is returned whenever some theta6 reaches.
    The coefficients are sampled at theta6 = 0, pi/2, pi (exact: the form is linear).
    """
    def cos3(t):
        _, v = wrist1(np.full(n, t))
        return (v[:, 0] ** 2 + v[:, 2] ** 2 - geo.a2 ** 2 - geo.a3 ** 2) / (2 * geo.a2 * geo.a3)

    v0, v90, v180 = cos3(0.0), cos3(np.pi / 2), cos3(np.pi)
    alpha = 0.5 * (v0 + v180)
    beta = 0.5 * (v0 - v180)
    gamma = v90 - alpha
    disc = np.clip(beta * beta + gamma * gamma - alpha * alpha, 0.0, None)
    return np.arctan2(gamma, beta) + np.arctan2(np.sqrt(disc), -alpha)


def solve_batch(geo: URGeometry, poses: np.ndarray, q6_ref: np.ndarray | None = None,
                keep_unreachable: bool = False):
    """All 8 candidate branches for n poses: (q (n,8,6), singular (n,8), reason (n,8) codes).

    The steps of the module docstring, each a subproblem of :mod:`derive.ik.subproblems` on the
    thesis-form chain (axes z, -y, -y, -y, -z, -y; A = Rz(t1)^T R):

    1. t1: sp4, e_y^T R(-z, t1) p5 = -d4 (W.6), two roots;
    2. (t6, t5): sp2, R(-y, t6) u = R(z, t5) e_y with u = A^T e_y (row 2 of A: B.29-B.32), two
       solutions (the sign of sin t5); at the wrist singularity t6 is free (module docstring);
    3. t2 + t3 + t4: sp1, R(-y, t234) e_x = A R(-y, t6)^T Rz(t5) e_x;
    4. t3: sp3, ||R(-y, t3) a3 e_x + a2 e_x|| = ||v||, v the wrist-1 point in the arm plane
       (C.19, C.21), two roots;
    5. t2: sp1, R(-y, t2) (a2 e_x + R(-y, t3) a3 e_x) = v (C.12, C.14); t4 by subtraction.

    reason codes: 0 ok, 1 theta1 unreachable, 2 theta3 unreachable (the discriminants of steps 1
    and 4 below -REACH_TOL, relative). Candidates are not yet checked by FK (see :func:`solve`).
    Unreachable branches are NaN unless ``keep_unreachable`` (then the subproblems'
    least-squares roots: the nearest the arm comes, used as seeds by :mod:`derive.refinement`).
    """
    n = poses.shape[0]
    r, p = _chain_pose(geo, poses)
    out = np.full((n, 8, 6), np.nan)
    singular = np.zeros((n, 8), dtype=bool)
    code = np.zeros((n, 8), dtype=np.int8)
    # constant vectors stay (3,): the subproblems' private steps (no input checks, no residuals)
    # broadcast them, and a constant axis enters their products as three numbers
    x, y, z = _X, _Y, _Z
    a3x, ma2x = geo.a3 * _X, -geo.a2 * _X
    # the slots of step 4 in the order sin t3 >= 0, < 0 (slot 0 has the sign of -a2 a3)
    order3 = (0, 1) if geo.a2 * geo.a3 < 0 else (1, 0)

    p5 = p + geo.d6 * r[:, :, 1]
    bad1 = p5[:, 0] ** 2 + p5[:, 1] ** 2 - geo.d4 ** 2 < -REACH_TOL * max(1.0, geo.d4 ** 2)
    s1, _free1 = _sp4(y, -z, p5, np.full(n, -geo.d4))

    def wrist1(t1, a, t5, t6):
        """t2+t3+t4 (sp1) and the wrist-1 point v in the arm plane (C.19, C.21)."""
        m0 = np.einsum("nij,nj->ni", a, rot(-y, -t6, rot(z, t5, x)))
        t234 = _sp1(-y, x, m0)
        p3 = p5 + geo.d5 * rot(z, t1, rot(-y, t234, z))
        v = rot(z, -t1, p3 - geo.d1 * _Z)
        v[:, 1] = 0.0
        return t234, v

    for i1 in range(2):
        t1 = s1[:, i1]
        a = np.einsum("nji,njk->nik", rot_z(t1), r)          # A = Rz(t1)^T R
        s65 = _sp2(-y, z, a[:, 1, :], y)
        sing = np.hypot(a[:, 0, 1], a[:, 2, 1]) < WRIST_SINGULAR
        for i5 in range(2):
            t6, t5 = s65[:, i5].T
            t5 = np.where(sing, np.where(a[:, 1, 1] >= 0, 0.0, np.pi), t5)
            if np.any(sing):
                free = _free_theta6(geo, lambda t: wrist1(t1, a, t5, t), n) if q6_ref is None else q6_ref
                t6 = np.where(sing, free, t6)
            t234, v = wrist1(t1, a, t5, t6)
            vv = np.einsum("ni,ni->n", v, v)
            bad3 = np.abs((vv - geo.a2 ** 2 - geo.a3 ** 2) / (2 * geo.a2 * geo.a3)) > 1 + REACH_TOL
            s3 = _sp3(-y, a3x, ma2x, np.sqrt(vv))
            for i3 in range(2):
                t3 = s3[:, order3[i3]]
                t2 = _sp1(-y, rot(-y, t3, a3x) - ma2x, v)
                t4 = t234 - t2 - t3
                k = 4 * i1 + 2 * i5 + i3
                out[:, k] = wrap_angle(np.stack([t1, t2, t3, t4, t5, t6], -1))
                singular[:, k] = sing
                code[:, k] = np.where(bad1, 1, np.where(bad3, 2, 0))
    if not keep_unreachable:
        out[code > 0] = np.nan
    return out, singular, code


def solve(robot, geo, poses: np.ndarray, q_free: np.ndarray | None = None,
          chunk: int = 20000):
    """Checked, merged solutions: (q (n,8,6) NaN-padded, counts (n,), singular (n,8), reasons list).

    ``geo``: a :class:`URGeometry` (candidates from :func:`solve_batch`; ``q_free`` the
    reference theta6 of the wrist singularity) or a :class:`derive.ik.spherical.SWGeometry`
    (candidates from :func:`derive.ik.spherical.solve_batch`; ``q_free`` the reference q4) or a
    :class:`derive.ik.parallel3.P3Geometry` (:func:`derive.ik.parallel3.solve_batch`; ``q_free``
    the reference configurations (n, 6), whose q1 and q6 are used where those joints are free).
    The candidates go through the finish step (:func:`derive.ik.finish.finish`: FK check, merge,
    compaction)."""
    cls = classes.find("spherical" if isinstance(geo, SWGeometry) else
                       ("parallel3-sp6" if geo.layout == "sp6" else "parallel3")
                       if isinstance(geo, P3Geometry) else "ur")
    batch, why = cls.candidates, cls.reasons
    n = poses.shape[0]
    q_all = np.full((n, 8, 6), np.nan)
    sing_all = np.zeros((n, 8), dtype=bool)
    counts = np.zeros(n, dtype=np.int64)
    reasons = [REASON_OK] * n
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        cand, sing, code = batch(geo, poses[s:e], None if q_free is None else q_free[s:e])
        q_all[s:e], counts[s:e], _, sing_all[s:e], _ = finish(robot, poses[s:e], cand, sing)
        for k in np.nonzero(counts[s:e] == 0)[0]:
            codes = code[k]
            reasons[s + k] = (why[0] if np.all(codes == 1) else
                              why[1] if np.all(codes > 0) else REASON_NO_CANDIDATE)
    return q_all, counts, sing_all, reasons


def _ur_class():
    """The UR family as a member of the class registry (:mod:`derive.ik.classes`)."""
    def candidates(geo, poses, free=None):
        return solve_batch(geo, poses, free)

    return classes.IKClass(
        name="ur", title="UR family (thesis section 4.3.5)", dof=6,
        detect=classes.quiet_detect(ur_geometry), candidates=candidates,
        steps=(("theta1", "sp4: e_y^T R(-z, t1) p5 = -d4 (W.6), two roots"),
               ("theta6, theta5", "sp2: R(-y, t6) u = R(z, t5) e_y, u = row 2 of Rz(t1)^T R; free t6 at sin t5 = 0"),
               ("theta2 + theta3 + theta4", "sp1: R(-y, t234) e_x = Rz(t1)^T R R(-y, t6)^T Rz(t5) e_x"),
               ("theta3", "sp3: ||R(-y, t3) a3 e_x + a2 e_x|| = |v|, v the wrist-1 point (C.19, C.21), two roots"),
               ("theta2, theta4", "sp1: R(-y, t2) (a2 e_x + R(-y, t3) a3 e_x) = v (C.12, C.14), then the sum")),
        branch_labels=("theta1 root (+ / -)", "theta5 sign (+ / -)", "theta3 sign (+ / -)"),
        singular_sets=("wrist, sin t5 = 0: theta6 free (from q_ref, else chosen for reach), marked singular",
                       "shoulder: the two theta1 roots meet (merged)",
                       "elbow stretched or folded, sin t3 = 0: the two theta3 roots meet (merged)"),
        reasons=(REASON_WRIST_NEAR_AXIS, REASON_ARM_REACH), free_joint=5)


classes.register(_ur_class())


# --------------------------------------------------------------------------- #
# Inverse kinematics (closed form, UR family)
# --------------------------------------------------------------------------- #
class IKSolutions(np.ndarray):
    """Solutions (k, dof) of one pose, an ndarray with two attributes:

    ``singular`` (k,) bool: the solution lies on the wrist singularity (theta6 free: from the
    reference configuration if given, else chosen for reach); ``reason``: why there is no
    solution ("" otherwise).
    """

    def __new__(cls, q, singular, reason=""):
        obj = np.asarray(q, dtype=float).view(cls)
        obj.singular = np.asarray(singular, dtype=bool)
        obj.reason = reason
        return obj

    #: per-row attributes, indexed with the rows when the array is indexed
    _ROW_ATTRS = ("singular",)

    def __array_finalize__(self, obj):
        if obj is not None:
            self.singular = getattr(obj, "singular", None)
            self.reason = getattr(obj, "reason", "")

    def __getitem__(self, key):
        """Indexing keeps the per-row attributes (``singular``, ``branch``) with their rows:
        ``sols[1:3].singular`` is ``sols.singular[1:3]``, ``sols[mask]`` keeps the masked rows'.
        A result that is no longer rows of whole solutions (a column, one row, one number) is a
        plain ndarray."""
        out = super().__getitem__(key)
        if not isinstance(out, IKSolutions):
            return out
        rows, cols = ((key[0] if key else Ellipsis), key[1:]) if isinstance(key, tuple) else (key, ())
        whole = all(c is Ellipsis or c == slice(None) for c in cols if not isinstance(c, np.ndarray))
        if rows is None or rows is Ellipsis or not whole or any(isinstance(c, np.ndarray) for c in cols) \
                or out.ndim != 2 or out.shape[1] != self.shape[1]:
            return out if rows is Ellipsis and whole and out.shape == self.shape else out.view(np.ndarray)
        for name in self._ROW_ATTRS:
            value = getattr(self, name, None)
            if value is not None and np.ndim(value) == 1 and len(value) == len(self):
                setattr(out, name, np.asarray(value)[rows])
        return out


def closed_form_relation(robot) -> Relation | None:
    """For a robot without the UR structure in its own frames (a URDF of a UR arm: another
    base frame, tool frame or joint directions), the relation FK_robot(q) = B FK_lib(s q) T
    to a library robot that has the closed form (:func:`derive.kinematics.relate.relate`),
    or None. Cached per robot identity."""
    robot = load_robot(robot)
    return memo("closed-form-relation", robot.id, lambda: _find_relation(robot))


def nominal_relation(robot) -> Relation | None:
    """Like :func:`closed_form_relation`, but the closest library robot within NEAR_RELATE_TOL:
    the nominal geometry of a calibrated arm written without a ``nominal`` key (a calibrated
    URDF), whose closed-form solutions :func:`derive.refine` then polishes. Cached per robot
    identity."""
    robot = load_robot(robot)
    return memo("nominal-relation", robot.id, lambda: _find_relation(robot, NEAR_RELATE_TOL))


#: How far a calibrated arm may be from its nominal library robot: the largest FK mismatch (m,
#: rad) of the fitted relation on random configurations. The UR5 calibrated by millimetres and
#: tenths of a degree (ur5-calibrated.yaml) is 0.016 from the UR5 and 0.050 from the UR5e, the
#: nearest other library robot; the closest match within the tolerance is taken.
NEAR_RELATE_TOL = 0.03


def _find_relation(robot, tol: float = RELATE_TOL) -> Relation | None:
    """The library robot with the closed form related to ``robot`` with the smallest mismatch
    below ``tol``, or None."""
    if robot.dof != 6 or any(j.type != "revolute" for j in robot.joints if not j.is_mimic):
        return None
    try:
        mine = _axis_invariants(robot)
    except DeriveError:                 # mimic joints on the path: relate decides alone
        mine = None
    best = None
    for lib, theirs in _library_ur():
        if lib.id == robot.id:
            continue
        if mine is not None and theirs is not None and not _same_invariants(mine, theirs, max(10 * tol, 1e-6)):
            continue                    # relate's own first test, with the library's kept
        rel = relate(robot, lib, tol=tol)
        if rel is not None and (best is None or rel.error < best.error):
            best = rel
    return best


def _library_ur() -> list:
    """(robot, axis invariants) of the library robots with the UR closed form (exact, 6 joints,
    :func:`ur_geometry`), read once per process: :func:`_find_relation` compares a robot's
    invariants (:func:`derive.kinematics.relate._axis_invariants`) with these before it fits a
    relation, so a search reads no library file twice and fits only the congruent ones."""
    return memo("library-ur", None, _read_library_ur)


def _read_library_ur() -> list:
    out = []
    for name in list_robots():
        lib = load_robot(name)
        if lib.dof != 6 or not lib.exact:
            continue
        try:
            ur_geometry(lib)
        except DeriveError:
            continue
        try:
            inv = _axis_invariants(lib)
        except DeriveError:
            inv = None
        out.append((lib, inv))
    return out


def _same_invariants(mine, theirs, tol: float) -> bool:
    (c1, d1), (c2, d2) = mine, theirs
    if c1.shape != c2.shape or np.abs(c1 - c2).max(initial=0) > tol:
        return False
    both = np.isfinite(d1) & np.isfinite(d2)
    return bool(np.all(np.abs(d1 - d2)[both] <= tol))


def classify(robot) -> Classification:
    """The kinematic class of a robot (:func:`derive.model.classify.classify`), with the closed
    form of dq-derive as it applies: in the robot's own frames, or through a library robot it
    is related to (then ``closed_form_through`` names it with the base and tool transforms).
    Near-class arms (the nominal's closed form + Newton polish) are added by
    :func:`derive.ik.nearclass.classify`, which is ``derive.classify``."""
    robot = load_robot(robot)
    c = geometric_classify(robot)
    if c.closed_form:
        return c
    if robot.dof == 7 and (panda.is_panda_class(robot) or srs.is_srs(robot)):
        notes = [n for n in c.notes if "no closed form" not in n and "7R, redundant" not in n]
        what = ("of the Franka Panda class with q7 (joint 7) as the free parameter (derive.ik.panda, "
                "after He & Liu 2021)" if panda.is_panda_class(robot) else
                "of the SRS class with the arm angle psi as the free parameter (derive.ik.srs, after "
                "Shimizu et al. 2008)")
        return dataclasses.replace(c, closed_form=True, notes=notes + [
            f"closed-form IK {what}: up to 8 solutions per value, derive.reference.ik(robot, pose, "
            "free=v), ik_sweep over the feasible range, nearest for a seed (numpy reference, and "
            "the generated kernels: derive.kernels(robot, 'c').ik(poses, free=v))"])
    geo = spherical_class(robot)
    if geo is not None:
        notes = [n for n in c.notes if "derive.refine" not in n and "no closed form" not in n]
        return dataclasses.replace(c, closed_form=True, notes=notes + [
            "closed-form IK of the spherical-wrist class (derive.ik.spherical): " + spherical.describe(geo)])
    p3 = parallel3_class(robot)
    if p3 is not None:
        notes = [n for n in c.notes if "derive.refine" not in n and "no closed form" not in n
                 and "derive.ik.parallel3" not in n]
        return dataclasses.replace(c, closed_form=True, notes=notes + [
            "closed-form IK of the three-parallel class (derive.ik.parallel3), up to 8 solutions, in "
            "the numpy reference and the generated kernels (derive.kernels(robot).ik"
            + ("" if p3.layout == "intersecting" else "; each kernel solves subproblem 6's quartic")
            + "): " + parallel3.describe(p3)])
    rel = closed_form_relation(robot)
    if rel is None:
        if robot.dof == 6 and all(j.type == "revolute" and not j.is_mimic for j in robot.joints):
            why = general6r.describe(robot)
            if general6r.status(robot) == "degenerate":
                # the derivation found no regular elimination: no claim that it solves the arm
                notes = [n for n in c.notes if "derive.ik.general6r, every solution" not in n]
                return dataclasses.replace(c, notes=notes + [why])
            return dataclasses.replace(c, general6r=why, notes=c.notes + [why])
        return c
    notes = [n for n in c.notes if "derive.refine" not in n and "no closed form" not in n]
    return dataclasses.replace(
        c, closed_form=True,
        notes=notes + [f"closed-form IK through the library robot {rel.other}: " + rel.describe()],
        closed_form_through={"robot": rel.other, "base": rel.base.tolist(), "tool": rel.tool.tolist(),
                             "signs": rel.signs.tolist(), "mismatch": rel.error})


def has_closed_form(robot) -> bool:
    """Whether :func:`ik` solves the robot: the UR structure (in its own frames or related to a
    library robot), the spherical-wrist class or the three-parallel class."""
    robot = load_robot(robot)
    try:
        ur_geometry(robot)
        return True
    except DeriveError:
        return (spherical.is_spherical(robot) or parallel3.is_parallel3(robot)
                or closed_form_relation(robot) is not None)


def _solve_related(robot, poses, q_ref):
    """:func:`solve` on the robot (the 6R class :func:`derive.ik.classes.detect` finds: UR family
    or spherical wrist), or on the library robot it is
    related to (poses moved into that robot's frames, B^-1 P T^-1, and the solutions' joint
    directions mapped back). ``q_ref`` (n, 6) or None: reference configurations whose free joint
    (theta6 of the UR, q4 of the spherical wrist) is used at the wrist singularity."""
    hit = classes.detect(robot, dof=6)
    if hit is not None:
        cls, geo = hit
        return solve(robot, geo, poses, None if q_ref is None else q_ref[:, cls.free_joint])
    rel = closed_form_relation(robot)
    if rel is None:
        # no special class: the general 6R elimination (derive.ik.general6r), up to 16 solutions
        try:
            res = general6r.solve(robot, poses)
        except DeriveError as exc:
            general = str(exc).split(": ", 1)[-1]
        else:
            return res.q, res.counts, res.singular, res.reason
        try:
            ur_geometry(robot)
        except DeriveError as exc:
            first = exc
        raise DeriveError(f"{robot.name}: no closed-form IK: closed forms are implemented for the "
                          "UR family, the spherical-wrist (OPW) class, the three-parallel class "
                          f"and the general 6R, and this chain is in none ({str(first).split(': ', 1)[-1]}; "
                          f"{spherical_reason(robot).split(': ', 1)[-1]}; {general}); "
                          + ("give one joint (derive.ik.free_joint; dq-derive ik --free-joint J --free V) or "
                             if robot.dof == 7 else "") + "use derive.refine")
    lib = load_robot(rel.other)
    q, counts, singular, reasons = solve(lib, ur_geometry(lib), rel.into_other(poses),
                                         None if q_ref is None else q_ref[:, 5] * rel.signs[5])
    return wrap_angle(q * rel.signs), counts, singular, reasons


def _is_ur(robot) -> bool:
    """Whether the robot has the UR family's closed form in its own frames (:func:`ur_geometry`)."""
    try:
        ur_geometry(robot)
        return True
    except DeriveError:
        return False


def spherical_class(robot) -> SWGeometry | None:
    """The spherical-wrist geometry of a robot outside the UR family (whose own closed form
    comes first), or None."""
    robot = load_robot(robot)
    if _is_ur(robot):
        return None
    try:
        return sw_geometry(robot)
    except DeriveError:
        return None


def parallel3_class(robot) -> P3Geometry | None:
    """The three-parallel geometry of a robot (:mod:`derive.ik.parallel3`; the UR family and the
    spherical-wrist class come first), or None."""
    robot = load_robot(robot)
    if spherical_class(robot) is not None or _is_ur(robot):
        return None
    for geometry in (parallel3.p3_geometry, parallel3.p3_sp6_geometry):   # axes 5, 6 meeting or not
        try:
            return geometry(robot)
        except DeriveError:
            pass
    return None


def spherical_reason(robot) -> str:
    """Why the robot is not of the spherical-wrist class ("" if it is)."""
    try:
        sw_geometry(robot)
        return ""
    except DeriveError as exc:
        return str(exc)


def ik_batch(robot, poses, q_ref=None):
    """Closed-form IK of n poses: (solutions (n, 8, 6) NaN-padded, counts (n,)); (n, 16, 6) for
    an arm of no special class, solved by the general 6R elimination (:mod:`derive.ik.general6r`).

    ``poses``: unit dual quaternions (n, 8) or matrices (n, 4, 4) of the robot's end frame.
    ``q_ref`` (n, 6) or (6,): reference configuration(s) whose theta6 is used at the wrist
    singularity (default: theta6 chosen for reach, see :func:`_free_theta6`). Solutions are wrapped to (-pi, pi] and checked by FK.
    """
    robot = load_robot(robot)
    poses, _ = as_pose_batch(poses)
    n = poses.shape[0]
    qr = None
    if q_ref is not None:
        qr = as_finite_array(q_ref, "q_ref", last_dim=robot.dof)
        if qr.ndim > 2 or (qr.ndim == 2 and qr.shape[0] not in (1, n)):
            raise InputError(f"q_ref: expected shape ({robot.dof},) or ({n}, {robot.dof}), got {qr.shape}")
        qr = np.broadcast_to(qr.reshape(-1, robot.dof), (n, robot.dof)).astype(float)
    if n <= BATCH_CHUNK:
        q, counts, _, _ = _solve_related(robot, poses, qr)
        return q, counts
    # in chunks: the solver's temporaries are about 3.6 KB per pose
    q = None
    counts = np.zeros(n, dtype=np.int64)
    for s in range(0, n, BATCH_CHUNK):
        e = min(n, s + BATCH_CHUNK)
        cq, cc, _, _ = _solve_related(robot, poses[s:e], None if qr is None else qr[s:e])
        if q is None:     # 8 solutions per pose for the special classes, 16 for the general 6R
            q = np.full((n, max(8, cq.shape[1]), robot.dof), np.nan)
        q[s:e, :cq.shape[1]], counts[s:e] = cq, cc
    return q, counts


#: Poses per chunk of :func:`ik_batch`.
BATCH_CHUNK = 32768


def ik(robot, pose, q_ref=None, within_limits: bool = False, sort_by=None) -> IKSolutions:
    """Every closed-form IK solution of one pose (thesis section 4.3, UR family).

    pose: a unit dual quaternion (8,) or a 4x4 matrix of the robot's end frame; a pose
    within 1e-6 of unit is normalised, one farther off raises InputError.
    q_ref: reference configuration; its theta6 is used where theta6 is free (wrist
    singularity, marked in ``.singular``); without it theta6 is chosen for reach (the
    elbow nearest to a right angle).
    within_limits: keep only solutions inside the robot's joint limits, adding the
    +-2 pi alternatives of joints whose range allows them.
    sort_by: a configuration; solutions are sorted by their distance to it (each revolute
    joint's difference wrapped to (-pi, pi], or, with ``within_limits``, the plain joint move of
    each winding: :func:`derive.ik.select.sort_order`).
    An unreachable pose gives an empty (0, 6) result whose ``.reason`` says why.
    """
    robot = load_robot(robot)
    poses, single = as_pose_batch(pose)
    if not single:
        raise InputError("pose: ik() takes one pose; use ik_batch() for several")
    qr = None
    if q_ref is not None:
        qr = as_finite_array(q_ref, "q_ref", last_dim=robot.dof).reshape(1, robot.dof)
    q, counts, singular, reasons = _solve_related(robot, poses, qr)
    k = int(counts[0])
    sols, sing, _, reason = select_one(robot, q[0, :k], singular[0, :k], np.full(k, -1), reasons[0],
                                       within_limits, sort_by)
    return IKSolutions(sols.reshape(-1, robot.dof), sing, reason)
