"""Outside references for the IK of every class, the seven-joint kernels included (issue 30, item 6).

On the same poses (FK of random configurations inside our joint limits), the solution sets of the
generated C kernels (``derive.kernels(robot, "c")``) and of the numpy reference
(``derive.reference.ik_batch``, ``derive.ik.srs.ik_joint``) are compared with solvers written by
others:

* **frankik 1.0.1** (He & Liu 2021, "Analytical inverse kinematics for Franka Emika Panda -- a
  geometrical solver for 7-DOF manipulators with unconventional design", C++ by T. Juelg) for the
  Panda class (``panda``, ``fr3``), q7 given as ours.
* **ssik 8.2.0** (S. Srinivasa, IK-Geo style subproblems, C++ backend):
  - Panda class: its prebuilt ``panda_ik`` / ``fr3_ik`` (built from franka_description's URDF),
    the self-motion charts ``self_motion(T)`` evaluated at q7 (the charts' coordinate is q7);
  - SRS class (``iiwa7``, ``iiwa14``): ssik solves a 7R arm only by sampling its self-motion, so
    joint 3 is locked: a 6R ssik arm (``Manipulator.from_transforms``) whose joint-3 rotation
    at the given value is folded into the fixed transform between joints 2 and 4; compared with
    our kernels with q3 given (``free="q3"``) and ``srs.ik_joint``; our arm-angle kernels are
    checked through it (each of their solutions is in ssik's set at its own q3);
  - 6R classes: the UR family (no other outside IK reference in the suite) and the OPW arms
    irb120 and kr6-r900 (EAIK checks them too, tests/test_spherical.py; ssik's IK-Geo is a second,
    separate implementation), as ``Manipulator.from_axes`` (ssik's product-of-exponentials form:
    our axes and axis points at zero, the same convention as EAIK's ``HPRobot``).

Frames: ssik's ``from_axes`` / ``from_transforms`` end frame has the base orientation at q = 0,
so ``ssik.fk(q) @ R0 = our FK(q)`` with R0 our end rotation at zero; ssik's prebuilt Panda, FR3,
iiwa7 and iiwa14 use our frames (base link 0, flange link 8 / ee, no hand). frankik's ``fk``
returns the Franka Hand's TCP, ``our flange @ HAND`` with HAND = Rz(-pi/4) Tz(0.1034)
(franka_description's hand joint and TCP), while its ``ik_full`` takes the **flange** pose (its
code steps back d7e = 0.107 along z, the flange offset, not 0.2104): we pass our flange pose to
``ik_full`` and check both relations by FK (``test_frankik_frames``).

A set comparison: equal counts, every solution of each side within 1e-9 rad (wrapped) of one of
the other's, the generating configuration in both. What an outside solver leaves out by design is
stated where it is applied (frankik: its own joint limits, one elbow root; ssik's default
``solve``: its joint limits, so we pass ``respect_limits=False``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import derive
from derive import reference
from derive.ik import panda, srs
from derive.model.geometry import numeric_chain

# both are in the `test` extra (PyPI wheels for cp310 and cp311, manylinux x86_64): no skip
import frankik
import ssik

#: Two solutions are the same when every joint agrees within this (rad, compared modulo 2 pi).
SAME = 1e-9
#: A solution reproduces its pose when every entry of the 4x4 matrices agrees within this.
POSE = 1e-9

PANDA = ["panda", "fr3"]
SRS = ["iiwa7", "iiwa14"]
UR = ["ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e"]
OPW = ["irb120", "kr6-r900"]

#: frankik's tool: its fk is the flange followed by the Franka Hand's TCP, Rz(-pi/4) Tz(0.1034)
#: (franka_description: panda_hand joint rpy (0, 0, -pi/4), TCP 0.1034 m along the hand's z).
_C = math.sqrt(0.5)
HAND = np.array([[_C, _C, 0.0, 0.0], [-_C, _C, 0.0, 0.0], [0.0, 0.0, 1.0, 0.1034], [0.0, 0.0, 0.0, 1.0]])


def _wrap(d):
    return (np.asarray(d) + np.pi) % (2 * np.pi) - np.pi


def _configs(name: str, n: int, seed: int) -> np.ndarray:
    lo, hi = np.asarray(derive.load_robot(name).limits, dtype=float).T
    return np.random.default_rng(seed).uniform(lo, hi, (n, len(lo)))


def _distinct(rows: np.ndarray, width: int) -> np.ndarray:
    """Rows (k, width) with the ones equal modulo 2 pi within SAME to an earlier one removed."""
    out: list = []
    for x in np.asarray(rows, dtype=float).reshape(-1, width):
        if not any(np.abs(_wrap(x - u)).max() < SAME for u in out):
            out.append(x)
    return np.array(out).reshape(-1, width)


def _assert_same_set(ours: np.ndarray, theirs: np.ndarray, what: str) -> float:
    """Equal counts and a one-to-one match within SAME modulo 2 pi; returns the largest distance."""
    assert len(ours) == len(theirs), f"{what}: {len(ours)} solutions ours, {len(theirs)} theirs"
    if len(ours) == 0:
        return 0.0
    d = np.abs(_wrap(ours[:, None, :] - theirs[None, :, :])).max(axis=-1)
    assert d.min(axis=1).max() < SAME, f"{what}: ours not in theirs, {d.min(axis=1)}"
    assert d.min(axis=0).max() < SAME, f"{what}: theirs not in ours, {d.min(axis=0)}"
    # one-to-one: with the sets distinct (each side's rows apart by more than 2 SAME) the nearest match is unique
    assert len(set(np.argmin(d, axis=1).tolist())) == len(ours), what
    return float(d.min(axis=1).max())


def _contains(sols: np.ndarray, q: np.ndarray) -> bool:
    return len(sols) > 0 and bool((np.abs(_wrap(sols - q)).max(axis=1) < SAME).any())


def _hp(name: str, n: int):
    """The product-of-exponentials form of our chain (EAIK / IK-Geo / ssik ``from_axes``): axes H
    (n, 3) and offsets P (n + 1, 3) at q = 0, and R0, our end frame's rotation at zero (4x4)."""
    ch = numeric_chain(name)
    pts = ch.start + np.vstack([np.zeros(3), np.cumsum(ch.links, axis=0)])
    t0 = reference.fk_matrix(name, np.zeros(n))
    H = np.array(ch.axes, dtype=float)
    P = np.vstack([pts[0], np.diff(pts[:n], axis=0), t0[:3, 3] - pts[n - 1]])
    r0 = np.eye(4)
    r0[:3, :3] = t0[:3, :3]
    return H, P, r0


def _axis_rotation(h: np.ndarray, angle: float) -> np.ndarray:
    k = np.array([[0.0, -h[2], h[1]], [h[2], 0.0, -h[0]], [-h[1], h[0], 0.0]])
    out = np.eye(4)
    out[:3, :3] = np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)
    return out


def _ssik_locked(H, P, joint: int, value: float):
    """A 6R ssik arm equal to the 7R chain (H, P) with joint ``joint`` (0-based) fixed at value:
    FK7 = prod_i Tz(P_i) Rot(H_i, q_i) . Trans(P_7); the locked factor Trans(P_j) Rot(H_j, v)
    Trans(P_j+1) becomes one fixed transform of ``from_transforms`` (joint axes in the base
    orientation, since nothing before them rotates the frame but the free joints)."""
    n = len(H)
    T = []
    for i in range(n + 1):
        m = np.eye(4)
        m[:3, 3] = P[i]
        T.append(m)
    merged = T[joint] @ _axis_rotation(H[joint], value) @ T[joint + 1]
    trafos = np.array(T[:joint] + [merged] + T[joint + 2:])
    return ssik.Manipulator.from_transforms(trafos, np.delete(H, joint, axis=0))


def _ssik_set(man, target: np.ndarray, width: int) -> np.ndarray:
    """Every solution ssik returns for a 4x4 target, joint limits off, distinct modulo 2 pi."""
    sols = man.solve(target, respect_limits=False)
    return _distinct(np.array([s.q for s in sols], dtype=float), width)


# --------------------------------------------------------------------------------------------
# Panda class against frankik
# --------------------------------------------------------------------------------------------

def _frankik_fk_flange(q: np.ndarray) -> np.ndarray:
    """frankik's own FK of the flange: its fk (the hand's TCP) with HAND taken off."""
    return frankik.fk(np.asarray(q, dtype=float)) @ np.linalg.inv(HAND)


def _polish_on_frankik(q: np.ndarray, target: np.ndarray, steps: int = 4) -> np.ndarray:
    """Newton steps on joints 1-6 (q7 is given) for frankik's own flange FK to reach target:
    position error and the rotation error vee(R^T Rt - Rt^T R) / 2, central-difference Jacobian
    (h = 1e-6). Maps each frankik solution onto the exact root of frankik's model it approximates
    (its IK keeps about 9 digits: constants printed to 12 digits, acos near +-1)."""
    q = np.array(q, dtype=float)

    def res(x):
        t = _frankik_fk_flange(x)
        m = t[:3, :3].T @ target[:3, :3]
        skew = 0.5 * (m - m.T)
        rot = t[:3, :3] @ np.array([skew[2, 1], skew[0, 2], skew[1, 0]])
        return np.concatenate([target[:3, 3] - t[:3, 3], rot])

    for _ in range(steps):
        r = res(q)
        J = np.empty((6, 6))
        for j in range(6):
            e = np.zeros(7)
            e[j] = 1e-6
            J[:, j] = (res(q - e) - res(q + e)) / 2e-6  # -d res/dq, res = target - fk
        q[:6] += np.linalg.solve(J, r)
    return q


def _frankik_domain(name: str, sols: np.ndarray) -> np.ndarray:
    """Which of our solutions frankik can return: inside its joint limits (open intervals, as
    its code tests them; any winding) and on its elbow root. frankik takes q4 = theta246 +
    thetaH46 + theta342 - 2 pi with theta246 = acos(...) in [0, pi] (He & Liu eq. for q4), i.e.
    q4 <= the stretched elbow q4s = thetaH46 + theta342 - pi = -(atan(a4/d5) + atan(a4/d3)),
    with frankik's a4 = 0.0825, d3 = 0.316, d5 = 0.384; the other root (q4 > q4s) it never returns.
    And outside its q2 snap: where |cos q2| > 0.99999 (|q2| < 4.5e-3 rad) its code sets q2 = 0,
    q1 = q_actual[0] instead of solving (those rows are approximations, or dropped by its limit
    tests)."""
    fr3 = name == "fr3"
    lo = np.array(frankik.q_min_fr3 if fr3 else frankik.q_min_panda)
    hi = np.array(frankik.q_max_fr3 if fr3 else frankik.q_max_panda)
    q4s = -(math.atan2(0.0825, 0.384) + math.atan2(0.0825, 0.316))
    ok = (sols[:, 3] <= q4s) & (np.abs(np.cos(sols[:, 1])) <= 0.99999)
    for j in range(7):
        inside = np.zeros(len(sols), dtype=bool)
        for w in (-2 * np.pi, 0.0, 2 * np.pi):
            inside |= (sols[:, j] + w > lo[j]) & (sols[:, j] + w < hi[j])
        ok &= inside
    return ok


@pytest.mark.parametrize("name", PANDA)
def test_frankik_frames(name):
    """frankik.fk = our flange FK @ HAND to 1e-12 on 200 configurations, and ik_full solves the
    flange pose: given our flange pose and q7 it returns the generating configuration whenever
    that is in its domain (its limits, its elbow root) and its q2 is away from its snap."""
    q = _configs(name, 200, seed=3001)
    ours = reference.fk_matrix(name, q)
    theirs = np.array([frankik.fk(x) for x in q])
    assert np.abs(theirs - ours @ HAND).max() < 1e-12
    dom = _frankik_domain(name, q) & (np.abs(q[:, 1]) > 0.01)
    assert dom.sum() > 50
    for i in np.nonzero(dom)[0]:
        f = frankik.ik_full(ours[i], None, float(q[i, 6]), name == "fr3")
        f = f[~np.isnan(f).any(axis=1)]
        assert np.abs(_wrap(f - q[i])).max(axis=1).min() < 1e-6, i


@pytest.mark.parametrize("name", PANDA)
def test_panda_class_solution_sets_equal_frankik(name):
    """300 configurations inside our limits, q7 given as the generating value. frankik's
    ik_full (flange pose) against our C kernels and numpy reference:

    * every row frankik returns reproduces the pose on its own FK within 1e-9 except its q2
      snap: where |cos q2| > 0.99999 its code sets q2 = 0, q1 = q_actual[0] (0), exact only when
      q2 = 0 exactly (rows with q2 == 0.0 miss the pose by up to 1e-3 on about 0.3 % of random
      poses; they are left out, and so are our solutions in that zone, see ``_frankik_domain``);
    * frankik's rows, after Newton steps on frankik's own FK (its IK keeps about 9 digits, so the
      raw rows agree with ours to 1e-7 only), equal our solutions inside frankik's domain
      (``_frankik_domain``): equal counts, each within 1e-9 modulo 2 pi;
    * the generating configuration is in ours always, and in frankik's wherever in its domain.
    """
    fr3 = name == "fr3"
    q = _configs(name, 300, seed=3002)
    mats = reference.fk_matrix(name, q)
    poses = reference.fk(name, q)
    k_sols, k_counts = derive.kernels(name, "c").ik(poses, free=q[:, 6])
    r_sols, r_counts = reference.ik_batch(name, poses, free=q[:, 6])
    np.testing.assert_array_equal(k_counts, r_counts)
    snapped = gen_found = raw_max = polish_max = 0
    for i in range(len(q)):
        ours = k_sols[i, :k_counts[i]]
        _assert_same_set(ours, r_sols[i, :r_counts[i]], f"{name} pose {i}: kernel vs reference")
        assert _contains(ours, q[i])
        f = frankik.ik_full(mats[i], None, float(q[i, 6]), fr3)
        f = f[~np.isnan(f).any(axis=1)]
        snap = f[:, 1] == 0.0  # its snap sets q2 to 0.0 exactly (q1 to q_actual[0]): left out
        snapped += int(snap.any())
        f = f[~snap]
        err = [np.abs(_frankik_fk_flange(x) - mats[i]).max() for x in f]
        assert max(err, default=0.0) < POSE, (name, i, err)
        theirs = _distinct(np.array([_polish_on_frankik(x, mats[i]) for x in f]), 7)
        expected = ours[_frankik_domain(name, ours)]
        polish_max = max(polish_max, _assert_same_set(expected, theirs, f"{name} pose {i}"))
        if len(expected):
            d = np.abs(_wrap(expected[:, None] - _distinct(f, 7)[None])).max(-1)
            raw_max = max(raw_max, float(d.min(axis=0).max()))
        if _frankik_domain(name, q[i:i + 1])[0]:
            assert _contains(theirs, q[i]), (name, i)
            gen_found += 1
    print(f"{name}: {len(q)} poses, {snapped} with frankik's q2 snap, generating configuration in "
          f"frankik's set on {gen_found}; raw frankik vs ours {raw_max:.1e} rad, polished {polish_max:.1e} rad")
    assert snapped <= 10
    assert gen_found >= 50
    assert raw_max < 1e-6  # frankik's precision, before the polish


@pytest.mark.parametrize("name", PANDA)
def test_panda_class_solution_sets_equal_ssik_charts(name):
    """ssik's prebuilt arm (franka_description's URDF; its FK equals ours, checked) gives the
    self-motion as closed-form charts q(t) whose coordinate t is q7: every chart evaluated at the
    generating q7 (NaN where the branch does not exist) is, without limits, our whole solution
    set at that q7 -- both elbow roots, which frankik does not return."""
    man = ssik.Manipulator.from_prebuilt({"panda": "panda_ik", "fr3": "fr3_ik"}[name])
    q = _configs(name, 200, seed=3003)
    mats = reference.fk_matrix(name, q)
    assert max(np.abs(man.fk(q[i]) - mats[i]).max() for i in range(len(q))) < 1e-12
    k_sols, k_counts = derive.kernels(name, "c").ik(reference.fk(name, q), free=q[:, 6])
    for i in range(len(q)):
        rows = np.array([c.q(q[i, 6]) for c in man.self_motion(mats[i])], dtype=float).reshape(-1, 7)
        theirs = _distinct(rows[~np.isnan(rows).any(axis=1)], 7)
        ours = k_sols[i, :k_counts[i]]
        _assert_same_set(ours, theirs, f"{name} pose {i}")
        assert _contains(theirs, q[i]) and _contains(ours, q[i])


# --------------------------------------------------------------------------------------------
# SRS class against ssik (joint 3 locked)
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", SRS)
def test_ssik_prebuilt_arms_have_our_fk(name):
    """ssik's prebuilt iiwa arms (KUKA's URDFs) have our FK to 1e-12: the same frames."""
    man = ssik.Manipulator.from_prebuilt(f"{name}_ik")
    q = _configs(name, 200, seed=3004)
    mats = reference.fk_matrix(name, q)
    assert max(np.abs(man.fk(q[i]) - mats[i]).max() for i in range(len(q))) < 1e-12


@pytest.mark.parametrize("name", SRS)
def test_srs_solution_sets_with_q3_given_equal_ssik(name):
    """200 configurations inside the limits, joint 3 given as the generating value: the C kernels
    with ``free="q3"`` and ``srs.ik_joint(robot, poses, 3, q3)`` against ssik's 6R arm with joint
    3 locked at that value (its FK checked against ours first): equal sets within 1e-9, the
    generating configuration in both."""
    H, P, r0 = _hp(name, 7)
    q = _configs(name, 200, seed=3005)
    mats = reference.fk_matrix(name, q)
    poses = reference.fk(name, q)
    k_sols, k_counts = derive.kernels(name, "c", free="q3").ik(poses, free=q[:, 2])
    ref = srs.ik_joint(name, poses, 3, q[:, 2])
    np.testing.assert_array_equal(k_counts, ref.count)
    for i in range(len(q)):
        man = _ssik_locked(H, P, 2, float(q[i, 2]))
        if i < 5:
            qq = np.delete(q[i], 2)
            assert np.abs(man.fk(qq) @ r0 - mats[i]).max() < 1e-12
        theirs = _ssik_set(man, mats[i] @ np.linalg.inv(r0), 6)
        theirs = np.insert(theirs, 2, q[i, 2], axis=1)
        ours = k_sols[i, :k_counts[i]]
        _assert_same_set(ours, theirs, f"{name} pose {i}")
        _assert_same_set(ref.q[i, :ref.count[i]], theirs, f"{name} pose {i}, ik_joint")
        assert _contains(ours, q[i]) and _contains(theirs, q[i])


@pytest.mark.parametrize("name,joint", [("iiwa14", 1), ("iiwa14", 2), ("iiwa14", 5), ("iiwa7", 2)])
def test_srs_c_class_routes_with_a_joint_given_equal_ssik(name, joint):
    """The C kernels of the SRS class routes (``free="qK"``: the class's IK program,
    tests/test_free_joint_srs_c.py) on 40 configurations inside the limits with joint K given as
    the generating value, against ssik's 6R arm with joint K locked at that value: equal sets
    (counts, each solution within 2e-6 modulo 2 pi, the median within 1e-9), the generating
    configuration in both. Joint 5 is locked on the reversed chain (FK^-1: axes and offsets read
    backwards, offsets negated, q' = -q reversed), where ssik takes its fast path (locked on the
    forward chain, joints 5-7 take it 40-70 s a pose; EAIK compares every K,
    tests/test_free_joint_srs_c.py)."""
    H, P, r0 = _hp(name, 7)
    q = _configs(name, 40, seed=3200 + joint)
    mats = reference.fk_matrix(name, q)
    sols, counts = derive.kernels(name, "c", free=f"q{joint}").ik(reference.fk(name, q), free=q[:, joint - 1])
    rev = joint > 4
    for i in range(len(q)):
        v = float(q[i, joint - 1])
        if rev:
            man = _ssik_locked(H[::-1].copy(), -P[::-1].copy(), 7 - joint, -v)
            theirs = _ssik_set(man, r0 @ np.linalg.inv(mats[i]), 6)
            theirs = -np.insert(theirs, 7 - joint, -v, axis=1)[:, ::-1]
        else:
            man = _ssik_locked(H, P, joint - 1, v)
            theirs = np.insert(_ssik_set(man, mats[i] @ np.linalg.inv(r0), 6), joint - 1, v, axis=1)
        theirs = _distinct_within(theirs, 7, 1e-6)
        ours = sols[i, :counts[i]]
        assert len(ours) == len(theirs), (name, joint, i, ours, theirs)
        d = np.abs(_wrap(ours[:, None] - theirs[None])).max(-1)
        assert d.min(axis=0).max() < 2e-6 and d.min(axis=1).max() < 2e-6, (name, joint, i)
        assert np.median(d.min(axis=1)) < SAME
        assert _contains(ours, q[i]) and _contains(theirs, q[i])


@pytest.mark.parametrize("name", SRS)
def test_srs_arm_angle_solutions_are_in_ssik_sets(name):
    """The arm-angle kernels (the default, psi given): on 25 poses at the generating psi, every
    solution q reproduces the pose by the FK of ssik's prebuilt arm (1e-9) and is in ssik's
    solution set with joint 3 locked at q's own q3; the generating configuration is among ours."""
    H, P, r0 = _hp(name, 7)
    man_fk = ssik.Manipulator.from_prebuilt(f"{name}_ik")
    q = _configs(name, 25, seed=3006)
    mats = reference.fk_matrix(name, q)
    psi = srs.arm_angle(name, q)
    k_sols, k_counts = derive.kernels(name, "c").ik(reference.fk(name, q), free=psi)
    r_sols, r_counts = reference.ik_batch(name, reference.fk(name, q), free=psi)
    target = mats @ np.linalg.inv(r0)
    checked = 0
    for i in range(len(q)):
        ours = k_sols[i, :k_counts[i]]
        _assert_same_set(ours, r_sols[i, :r_counts[i]], f"{name} pose {i}: kernel vs reference")
        assert _contains(ours, q[i])
        for x in ours:
            assert np.abs(man_fk.fk(x) - mats[i]).max() < POSE
            theirs = _ssik_set(_ssik_locked(H, P, 2, float(x[2])), target[i], 6)
            assert _contains(np.insert(theirs, 2, x[2], axis=1), x), (name, i)
            checked += 1
    assert checked >= 150


# --------------------------------------------------------------------------------------------
# 6R classes against ssik
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", UR + OPW)
def test_six_joint_solution_sets_equal_ssik(name):
    """200 configurations inside the limits per arm: the C kernels and the numpy reference equal
    ssik's solution set (``solve(T, respect_limits=False)`` on ssik's ``from_axes`` arm of our
    chain, its FK checked against ours): equal counts, each within 1e-9 modulo 2 pi, the
    generating configuration in both."""
    H, P, r0 = _hp(name, 6)
    man = ssik.Manipulator.from_axes(H, P)
    q = _configs(name, 200, seed=3007)
    mats = reference.fk_matrix(name, q)
    poses = reference.fk(name, q)
    assert max(np.abs(man.fk(q[i]) @ r0 - mats[i]).max() for i in range(len(q))) < 1e-12
    k_sols, k_counts = derive.kernels(name, "c").ik(poses)
    r_sols, r_counts = reference.ik_batch(name, poses)
    np.testing.assert_array_equal(k_counts, r_counts)
    for i in range(len(q)):
        theirs = _ssik_set(man, mats[i] @ np.linalg.inv(r0), 6)
        ours = k_sols[i, :k_counts[i]]
        _assert_same_set(ours, theirs, f"{name} pose {i}")
        _assert_same_set(r_sols[i, :r_counts[i]], theirs, f"{name} pose {i}, reference")
        assert _contains(ours, q[i]) and _contains(theirs, q[i])


# --------------------------------------------------------------------------------------------
# The numpy solvers of the 7R classes as compositions of subproblems (derive.ik.srs, panda),
# on random poses and on their singular sets, against ssik and frankik
# --------------------------------------------------------------------------------------------

def _with_singular_rows(name: str, n: int, seed: int) -> np.ndarray:
    """n configurations inside the limits; rows 0-3 of every 8 put on a singular set or a double
    root of the composed steps: q2 = 0 (shoulder), q4 = 0 (SRS elbow stretched; Panda X = 0,
    q5 free), q6 = 0 (SRS wrist), q5 = +-pi/2 (Panda's wrist double root; SRS with joint 1 or 7
    given: the sin t3 = +-1 double root)."""
    q = _configs(name, n, seed)
    for k, (j, v) in enumerate(((1, 0.0), (3, 0.0), (5, 0.0), (4, math.pi / 2))):
        q[k::8, j] = v
    return q


def _distinct_within(rows: np.ndarray, width: int, tol: float) -> np.ndarray:
    out: list = []
    for x in np.asarray(rows, dtype=float).reshape(-1, width):
        if not any(np.abs(_wrap(x - u)).max() < tol for u in out):
            out.append(x)
    return np.array(out).reshape(-1, width)


@pytest.mark.parametrize("name", SRS)
def test_srs_numpy_composition_equals_ssik(name):
    """derive.ik.srs (sp3 elbow, sp1 + sp1 reference plane, ZYZ; sp4 + sp1 with a joint given)
    on 40 poses, half of them on a singular set: with joint 3 given (``ik_joint``) and with
    joint 1 given, every solution on the pose (FK of ssik's prebuilt arm), the generating
    configuration among them, and where no joint is free the same solution sets as ssik's 6R arm
    with that joint locked (distinct within MERGE_TOL on both sides, each solution within 1e-9
    of one of the other's, 2e-6 on the rows at a double root, where ssik's roots carry the square
    root of its rounding); at the generating arm angle
    (``ik_psi``) every solution on the pose, the generating configuration among them, and on
    the regular rows every solution in ssik's set at its own q3 (1e-9)."""
    H, P, r0 = _hp(name, 7)
    q = _with_singular_rows(name, 40, seed=3101)
    mats = reference.fk_matrix(name, q)
    poses = reference.fk(name, q)
    target = mats @ np.linalg.inv(r0)
    man_fk = ssik.Manipulator.from_prebuilt(f"{name}_ik")
    by_psi = srs.ik_psi(name, poses, srs.arm_angle(name, q), q_ref=q)
    compared = 0
    for joint in (3, 1):
        res = srs.ik_joint(name, poses, joint, q[:, joint - 1], q_ref=q)
        for i in range(len(q)):
            ours = res.q[i, :res.count[i]]
            assert _contains(ours, q[i]), (name, joint, i)
            assert max(np.abs(man_fk.fk(x) - mats[i]).max() for x in ours) < POSE
            if res.singular[i].any():
                continue          # a free joint (q_ref's value here): a continuum in ssik's set
            man = _ssik_locked(H, P, joint - 1, float(q[i, joint - 1]))
            theirs = np.insert(_ssik_set(man, target[i], 6), joint - 1, q[i, joint - 1], axis=1)
            theirs = _distinct_within(theirs, 7, 1e-6)
            assert len(ours) == len(theirs), (name, joint, i, ours, theirs)
            compared += 1
            d = np.abs(_wrap(ours[:, None] - theirs[None])).max(-1)
            tol = SAME if i % 8 >= 4 else 2e-6
            assert d.min(axis=0).max() < tol and d.min(axis=1).max() < tol, (name, joint, i)
    assert compared >= 55
    for i in range(len(q)):
        ours = by_psi.q[i, :by_psi.count[i]]
        assert _contains(ours, q[i]), (name, i)
        assert max(np.abs(man_fk.fk(x) - mats[i]).max() for x in ours) < POSE
        if i % 8 < 4:
            continue      # ssik's roots at the elbow stretch are off by up to 1e-5 (q4 = 0 rows)
        for x in ours:
            theirs = _ssik_set(_ssik_locked(H, P, 2, float(x[2])), target[i], 6)
            assert _contains(np.insert(theirs, 2, x[2], axis=1), x), (name, i)


@pytest.mark.parametrize("name", PANDA)
def test_panda_numpy_composition_equals_ssik_and_frankik(name):
    """derive.ik.panda.ik_q7 (sp3 elbow, sp2 wrist, ZYZ shoulder) on 48 poses, half of them on a
    singular set or a double root (q2 = 0, q4 = 0 with q5 free, q5 = +-pi/2), q7 the generating
    value: every solution on the pose (FK of ssik's prebuilt arm), the generating configuration
    among them; where no joint is free the same solution sets as ssik's self-motion charts at q7
    (distinct within MERGE_TOL; 1e-9, 2e-6 on the rows at a double root); and on the regular
    rows, inside frankik's domain, frankik's polished solutions equal ours (1e-9)."""
    fr3 = name == "fr3"
    man = ssik.Manipulator.from_prebuilt({"panda": "panda_ik", "fr3": "fr3_ik"}[name])
    q = _with_singular_rows(name, 48, seed=3102)
    mats = reference.fk_matrix(name, q)
    res = panda.ik_q7(name, reference.fk(name, q), q[:, 6], q_ref=q)
    compared = singular = 0
    for i in range(len(q)):
        ours = res.q[i, :res.counts[i]]
        assert _contains(ours, q[i]), (name, i)
        rows = np.array([c.q(q[i, 6]) for c in man.self_motion(mats[i])], dtype=float).reshape(-1, 7)
        theirs = _distinct_within(rows[~np.isnan(rows).any(axis=1)], 7, 1e-6)
        assert max(np.abs(man.fk(x) - mats[i]).max() for x in ours) < POSE
        if res.singular[i].any():
            singular += 1
            continue      # a free joint (q_ref's value here): a continuum in ssik's charts
        assert len(ours) == len(theirs), (name, i, ours, theirs)
        d = np.abs(_wrap(ours[:, None] - theirs[None])).max(-1)
        tol = SAME if i % 8 >= 4 else 2e-6
        assert d.min(axis=0).max() < tol and d.min(axis=1).max() < tol, (name, i)
        if i % 8 >= 4:                                   # regular rows: frankik too
            f = frankik.ik_full(mats[i], None, float(q[i, 6]), fr3)
            f = f[~np.isnan(f).any(axis=1) & (f[:, 1] != 0.0)]
            polished = _distinct(np.array([_polish_on_frankik(x, mats[i]) for x in f]), 7)
            _assert_same_set(ours[_frankik_domain(name, ours)], polished, f"{name} pose {i}")
            compared += 1
    assert compared == 24 and singular <= 12
