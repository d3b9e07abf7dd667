"""Closed-form IK of SRS arms with the arm angle psi (derive.ik.srs) on the KUKA LBR iiwa 7 and
iiwa 14: robot files against Pinocchio, round trips through the project's reference FK, the
arm angle against its geometric definition (Rodrigues rotation of the elbow, from the reference
FK's joint positions), solution sets with q3 or q1 locked against EAIK, the singular sets, the
feasible psi intervals against dense sampling, and the input errors. Fixed seeds.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import derive
from derive import InputError, reference
from derive import dualquat as DQ
from derive.algebra.angles import wrap_angle
from derive.ik import srs
from derive.model.classify import classify

try:
    import pinocchio as pin
except ImportError:                        # a clear failure, not a skip: the test extra has it
    pin = None
try:
    from eaik.IK_HP import HPRobot
except ImportError:
    HPRobot = None

SEED = 1717
N = 10_000
N_EAIK = 500
ROBOTS = ["iiwa7", "iiwa14"]
DATA = Path(__file__).parent / "data"
#: KUKA's published dimensions (m): d_bs, d_se, d_ew, d_wf (flange).
PUBLISHED = {"iiwa7": (0.34, 0.40, 0.40, 0.126), "iiwa14": (0.36, 0.42, 0.40, 0.126)}
LIMITS_DEG = [170, 120, 170, 120, 170, 120, 175]
#: The axes at the zero pose and the points between them, written here from the published numbers
#: (EAIK's H, P form: P[0] base -> axis 1, P[i] axis i -> axis i+1, P[7] axis 7 -> flange).
AXES = np.array([[0, 0, 1], [0, 1, 0], [0, 0, 1], [0, -1, 0], [0, 0, 1], [0, 1, 0], [0, 0, 1]], float)


def _hp(name):
    d_bs, d_se, d_ew, d_wf = PUBLISHED[name]
    return AXES, np.array([[0, 0, 0], [0, 0, d_bs], [0, 0, 0], [0, 0, d_se], [0, 0, 0],
                           [0, 0, d_ew], [0, 0, 0], [0, 0, d_wf]], float)


def _within(robot, n, rng):
    lim = robot.limits
    return rng.uniform(lim[:, 0], lim[:, 1], size=(n, robot.dof))


def _rows(res):
    """(solutions (k, 7), pose index (k,), branch (k,)) of the valid rows."""
    valid = res.branch >= 0
    return res.q[valid], np.nonzero(valid)[0], res.branch[valid]


def _assert_exact(robot, poses, res, tol=1e-10):
    """Valid rows are finite and reproduce their pose through the reference FK; padding is NaN."""
    q, rows, _ = _rows(res)
    assert np.all(np.isfinite(q))
    assert np.all(np.isnan(res.q[res.branch < 0]))
    assert np.array_equal(res.count, (res.branch >= 0).sum(1))
    dp, dr = reference.pose_error(reference.fk(robot, q), poses[rows])
    assert dp.max() < tol and dr.max() < tol, (dp.max(), dr.max())


def _has(res, q, tol):
    """Whether each configuration q (n, 7) is among its pose's solutions (wrapped)."""
    d = np.abs(wrap_angle(res.q - q[:, None, :])).max(-1)
    return np.nanmin(np.where(res.branch >= 0, d, np.inf), 1) < tol


def _rodrigues(axis, angle):
    k = np.zeros(axis.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -axis[..., 2], axis[..., 1], -axis[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


# --------------------------------------------------------------------------- #
# Robot files
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("name", ROBOTS)
def test_robot_file_numbers_and_fk_equal_pinocchio_of_the_vendor_urdf(name):
    robot = derive.load_robot(name)
    assert robot.dof == 7 and robot.default_end == "flange"
    assert [robot.parameters[k] for k in ("d_bs", "d_se", "d_ew", "d_wf")] == list(PUBLISHED[name])
    assert np.allclose(robot.limits, np.radians(np.c_[-np.array(LIMITS_DEG), LIMITS_DEG]), atol=1e-15)
    if pin is None:
        pytest.fail("Pinocchio is not installed: `pip install -e '.[test]'` installs pin")
    model = pin.buildModelFromUrdf(str(DATA / f"{name}.urdf"))
    data = model.createData()
    tip = model.getFrameId("link_ee", pin.FrameType.BODY)
    q = _within(robot, 500, np.random.default_rng(SEED))
    ours = reference.fk_matrix(robot, q)
    for i, row in enumerate(q):
        qp = np.zeros(model.nq)
        for jn, v in zip(robot.variable_names, row):
            qp[model.joints[model.getJointId(jn)].idx_q] = v
        pin.framesForwardKinematics(model, data, qp)
        assert np.abs(data.oMf[tip].homogeneous - ours[i]).max() < 1e-12
    # the URDF's limits are the file's
    assert np.allclose(model.upperPositionLimit, robot.limits[:, 1], atol=1e-12)


def test_the_library_s_srs_arms_are_the_iiwas_and_classify_agrees():
    found = [n for n in derive.list_robots() if srs.is_srs(n)]
    assert found == ["iiwa14", "iiwa7"]
    assert all(classify(n).cls == "SRS" for n in found)


def test_srs_geometry_of_the_iiwa():
    g = srs.srs_geometry("iiwa14")
    assert (g.d_bs, g.d_se, g.d_ew, g.d_wf) == pytest.approx(PUBLISHED["iiwa14"], abs=1e-12)
    assert g.signs.tolist() == [1, 1, 1, -1, 1, 1, 1]
    assert classify("iiwa14").cls == "SRS"


# --------------------------------------------------------------------------- #
# Round trips
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("name", ROBOTS)
def test_ik_psi_round_trip_on_random_configurations(name):
    robot = derive.load_robot(name)
    q = _within(robot, N, np.random.default_rng(SEED))
    poses = reference.fk(robot, q)
    psi = srs.arm_angle(robot, q)
    res = srs.ik_psi(robot, poses, psi)
    # away from the singular sets a pose and an arm angle have 8 distinct solutions
    assert np.all(res.count == 8) and not res.singular.any() and np.all(res.reason == "")
    _assert_exact(robot, poses, res)
    assert np.all(_has(res, q, 1e-8))
    # every solution has the arm angle it was solved for
    sol, rows, _ = _rows(res)
    assert np.abs(wrap_angle(srs.arm_angle(robot, sol) - psi[rows])).max() < 1e-9


@pytest.mark.parametrize("name", ROBOTS)
def test_ik_with_q3_given_round_trip(name):
    robot = derive.load_robot(name)
    q = _within(robot, N, np.random.default_rng(SEED + 1))
    poses = reference.fk(robot, q)
    res = srs.ik_joint(robot, poses, 3, q[:, 2])
    assert np.all(res.count == 8)
    _assert_exact(robot, poses, res)
    assert np.all(_has(res, q, 1e-8))
    sol, rows, _ = _rows(res)
    assert np.abs(sol[:, 2] - q[rows, 2]).max() < 1e-15


def test_arm_angle_is_the_rotation_of_the_elbow_about_the_shoulder_wrist_line():
    """Geometric definition, checked with the reference FK's joint positions: at psi = 0 the
    elbow lies in the plane of axis 1 and the shoulder-wrist line and q3 is 0 or pi; at psi the
    elbow is the psi = 0 elbow of its elbow branch turned by psi about that line."""
    robot = derive.load_robot("iiwa7")
    rng = np.random.default_rng(SEED + 2)
    q = _within(robot, 2000, rng)
    poses = reference.fk(robot, q)
    psi = rng.uniform(-math.pi, math.pi, 2000)
    at0, atpsi = srs.ik_psi(robot, poses, 0.0), srs.ik_psi(robot, poses, psi)
    assert np.all(at0.count == 8) and np.all(atpsi.count == 8)
    sol0, rows0, br0 = _rows(at0)
    assert np.all(np.abs(np.sin(sol0[:, 2])) < 1e-9)
    pos0 = reference.joint_positions(robot, sol0)
    s, e, w = pos0[:, 1], pos0[:, 3], pos0[:, 5]
    normal = np.cross([0.0, 0.0, 1.0], w - s)
    assert np.abs(np.sum(normal * (e - s), -1)).max() < 1e-12
    # branch k: elbow sign from bit 1; compare branch k at psi with branch k at 0
    order0 = np.argsort(at0.branch, 1)
    orderp = np.argsort(atpsi.branch, 1)
    q0 = np.take_along_axis(at0.q, order0[..., None], 1)
    qp = np.take_along_axis(atpsi.q, orderp[..., None], 1)
    p0 = reference.joint_positions(robot, q0.reshape(-1, 7)).reshape(2000, 8, -1, 3)
    pp = reference.joint_positions(robot, qp.reshape(-1, 7)).reshape(2000, 8, -1, 3)
    s, e0, w, ep = p0[:, :, 1], p0[:, :, 3], p0[:, :, 5], pp[:, :, 3]
    assert np.abs(pp[:, :, 5] - w).max() < 1e-12
    x = (w - s) / np.linalg.norm(w - s, axis=-1, keepdims=True)
    turned = (_rodrigues(x, np.broadcast_to(psi[:, None], (2000, 8))) @ (e0 - s)[..., None])[..., 0]
    assert np.abs(turned - (ep - s)).max() < 1e-12


def test_eaik_with_q3_locked_finds_the_same_solution_sets():
    if HPRobot is None:
        pytest.fail("EAIK is not installed: `pip install -e '.[test]'` installs eaik")
    for k, name in enumerate(ROBOTS):
        robot = derive.load_robot(name)
        rng = np.random.default_rng(SEED + 3 + k)
        q3 = float(rng.uniform(-2.5, 2.5))
        q = _within(robot, N_EAIK, rng)
        q[:, 2] = q3
        T = reference.fk_matrix(robot, q)
        H, P = _hp(name)
        theirs = HPRobot(H, P, fixed_axes=[(2, q3)]).IK_batched(T, 1)
        ours = srs.ik_joint(robot, DQ.from_matrix(T), 3, q3)
        for i, sol in enumerate(theirs):
            Q = np.asarray(sol.Q, dtype=float).reshape(-1, 7)[~np.asarray(sol.is_LS, bool).reshape(-1)]
            assert len(Q) == ours.count[i], (name, i)
            mine = ours.q[i, :ours.count[i]]
            d = np.abs(wrap_angle(mine[:, None, :] - Q[None, :, :])).max(-1)
            assert d.min(1).max() < 1e-8 and d.min(0).max() < 1e-8, (name, i)


@pytest.mark.parametrize("joint, tol", [(1, 1e-6), (5, 1e-8), (7, 1e-6)])
def test_eaik_with_joint_1_5_or_7_locked_finds_the_same_solution_sets(joint, tol):
    """q1 and q7 given meet sin t = y / v_x, whose double root (|y| = |v_x|) costs both solvers
    digits in the joints (not in the pose): hence 1e-6 there."""
    if HPRobot is None:
        pytest.fail("EAIK is not installed: `pip install -e '.[test]'` installs eaik")
    robot = derive.load_robot("iiwa14")
    rng = np.random.default_rng(SEED + 5 + joint)
    value = float(rng.uniform(-2.5, 2.5))
    q = _within(robot, 300, rng)
    q[:, joint - 1] = value
    T = reference.fk_matrix(robot, q)
    H, P = _hp("iiwa14")
    theirs = HPRobot(H, P, fixed_axes=[(joint - 1, value)]).IK_batched(T, 1)
    poses = DQ.from_matrix(T)
    ours = srs.ik_joint(robot, poses, joint, value)
    _assert_exact(robot, poses, ours)
    assert np.all(_has(ours, q, tol))
    sol, rows, _ = _rows(ours)
    assert np.abs(sol[:, joint - 1] - value).max() < 1e-15
    for i, sol in enumerate(theirs):
        Q = np.asarray(sol.Q, dtype=float).reshape(-1, 7)[~np.asarray(sol.is_LS, bool).reshape(-1)]
        assert len(Q) == ours.count[i]
        d = np.abs(wrap_angle(ours.q[i, :ours.count[i], None, :] - Q[None, :, :])).max(-1)
        assert d.min(1).max() < tol and d.min(0).max() < tol


# --------------------------------------------------------------------------- #
# Singular sets
# --------------------------------------------------------------------------- #
def _singular_configs(robot, kind, n, rng):
    """n configurations on one singular set, away from the elbow's stretch (|q4| >= 0.1) unless
    that is the set, so that one singularity is tested at a time."""
    q = _within(robot, n, rng)
    q[:, 3] = np.where(np.abs(q[:, 3]) < 0.1, np.sign(q[:, 3]) * 0.1 + q[:, 3], q[:, 3])
    if kind == "elbow stretched":
        q[:, 3] = 0.0
    elif kind == "shoulder aligned":
        q[:, 1] = 0.0
    elif kind == "wrist aligned":
        q[:, 5] = 0.0
    elif kind == "wrist centre on axis 1":
        g = srs.srs_geometry(robot)
        q[:, 2] = 0.0
        a = rng.uniform(-1.0, 1.0, n)
        q[:, 1] = a
        # W_x = d_se sin q2 + d_ew sin(q2 - q4) = 0 (A4 turns about -y)
        q[:, 3] = a + np.arcsin(g.d_se * np.sin(a) / g.d_ew)
    return q


@pytest.mark.parametrize("name", ROBOTS)
@pytest.mark.parametrize("kind, count, n_singular", [
    ("elbow stretched", 4, 4),          # the two elbow branches coincide
    ("shoulder aligned", 6, 2),         # on the generating elbow branch GC2 = +- coincide
    ("wrist aligned", 6, 2),            # the same for GC6; the other elbow branch is regular
    ("wrist centre on axis 1", 8, 0)])  # the reference plane is the x-z plane; all regular
def test_singular_sets_give_exact_solutions(name, kind, count, n_singular):
    robot = derive.load_robot(name)
    q = _singular_configs(robot, kind, 500, np.random.default_rng(SEED + 7))
    poses = reference.fk(robot, q)
    if kind == "wrist centre on axis 1":
        w = reference.joint_positions(robot, q)[:, 5]
        assert np.hypot(w[:, 0], w[:, 1]).max() < 1e-13
    psi = srs.arm_angle(robot, q)
    for q_ref in (None, q):
        res = srs.ik_psi(robot, poses, psi, q_ref=q_ref)
        assert np.all(res.count == count), np.bincount(res.count)
        assert np.all(res.reason == "")
        _assert_exact(robot, poses, res)
        assert np.all(res.singular.sum(1) == n_singular)
        if q_ref is not None or kind in ("elbow stretched", "wrist centre on axis 1"):
            assert np.all(_has(res, q, 1e-8))           # the free joint came from q_ref
        elif kind == "shoulder aligned":             # q1 = 0 where free
            assert np.all(res.q[res.singular][:, 0] == 0.0)
        else:
            assert np.all(res.q[res.singular][:, 4] == 0.0)
    for joint in (3, 5):
        res = srs.ik_joint(robot, poses, joint, q[:, joint - 1], q_ref=q)
        assert np.all(res.count >= 1) and np.all(res.reason == "")
        _assert_exact(robot, poses, res)
        # on the aligned sets the subproblem's acos has a double root: 1e-6 in the joints
        assert np.all(_has(res, q, 1e-6))


def test_wrist_centre_on_axis_1_fixes_the_reference_plane_at_q1_zero():
    """There the arm angle is measured from the plane of axis 1 and the base x axis."""
    robot = derive.load_robot("iiwa7")
    q = _singular_configs(robot, "wrist centre on axis 1", 200, np.random.default_rng(SEED + 8))
    q[:, 0] = 0.0
    assert np.abs(srs.arm_angle(robot, q)).max() < 1e-9   # q3 = 0, arm in the x-z plane


def test_unreachable_and_folded_poses_are_empty_with_a_reason():
    robot = derive.load_robot("iiwa7")
    far = DQ.translation([2.0, 0.0, 0.5])
    res = srs.ik_psi(robot, far, 0.3)
    assert res.count == 0 and "unreachable" in res.reason and np.all(np.isnan(res.q))
    assert np.all(res.branch == -1)
    res = srs.ik_joint(robot, far, 3, 0.3)
    assert res.count == 0 and "unreachable" in res.reason
    # the iiwa 7 has d_se = d_ew: with q4 = pi the wrist centre folds onto the shoulder
    folded = reference.fk(robot, [0.1, 0.2, 0.3, math.pi, 0.2, 0.4, 0.5])
    res = srs.ik_psi(robot, folded, 0.0)
    assert res.count == 0 and "shoulder" in res.reason
    assert srs.psi_intervals(robot, far)[0].shape == (0, 2)
    # q3 given: with the wrist centre on axis 1 and the elbow bent, q3 = pi/2 turns the forearm
    # out of every plane through axis 1 (|W_z| = |W| > |v_z|)
    q = np.array([0.0, 0.5, 0.0, 0.5 + math.asin(math.sin(0.5)), 0.0, 0.3, 0.0])
    res = srs.ik_joint(robot, reference.fk(robot, q), 3, math.pi / 2)
    assert res.count == 0 and "given joint value" in res.reason


# --------------------------------------------------------------------------- #
# Feasible arm angles
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("name", ROBOTS)
def test_psi_intervals_agree_with_dense_sampling(name):
    robot = derive.load_robot(name)
    rng = np.random.default_rng(SEED + 9)
    q = _within(robot, 6, rng)
    poses = reference.fk(robot, q)
    grid = np.linspace(-math.pi, math.pi, 4001)
    lim = robot.limits
    for i in range(len(q)):
        iv = srs.psi_intervals(robot, poses[i])
        res = srs.ik_psi(robot, np.repeat(poses[i:i + 1], len(grid), 0), grid)
        assert np.all(res.count == 8)
        # the generating configuration's arm angle is feasible on its branch
        psi0 = float(srs.arm_angle(robot, q[i]))
        gen = srs.ik_psi(robot, poses[i], psi0)
        k0 = gen.branch[np.argmin(np.abs(wrap_angle(gen.q - q[i])).max(-1))]
        assert np.any((iv[k0][:, 0] <= psi0) & (psi0 <= iv[k0][:, 1]))
        for k in range(8):
            rows, cols = np.nonzero(res.branch == k)
            assert len(rows) == len(grid)
            qk = res.q[rows, cols]
            feasible = np.all((qk >= lim[:, 0]) & (qk <= lim[:, 1]), -1)
            inside = np.zeros(len(grid), dtype=bool)
            near = np.zeros(len(grid), dtype=bool)
            for lo, hi in iv[k]:
                inside |= (grid >= lo) & (grid <= hi)
                near |= (np.abs(grid - lo) < 1e-9) | (np.abs(grid - hi) < 1e-9)
            assert np.array_equal(feasible[~near], inside[~near]), (i, k)
            # at every boundary inside (-pi, pi) a joint of the branch is at a limit
            ends = iv[k].reshape(-1)
            ends = ends[np.abs(ends) < math.pi - 1e-12]
            if len(ends):
                at = srs.ik_psi(robot, np.repeat(poses[i:i + 1], len(ends), 0), ends)
                qb = at.q[at.branch == k].reshape(len(ends), 7)
                gap = np.min(np.minimum(np.abs(qb - lim[:, 0]), np.abs(qb - lim[:, 1])), -1)
                assert gap.max() < 1e-9, (i, k, ends, gap)


def test_ik_sweep_returns_solutions_within_limits_over_the_feasible_range():
    robot = derive.load_robot("iiwa14")
    q = _within(robot, 20, np.random.default_rng(SEED + 10))
    poses = reference.fk(robot, q)
    sw = srs.ik_sweep(robot, poses, 16)
    assert sw.psi.shape == (20, 16) and sw.q.shape == (20, 16, 8, 7)
    assert np.all(np.isfinite(sw.psi)) and np.all(sw.count >= 1)
    valid = sw.branch >= 0
    sol = sw.q[valid]
    assert np.all(srs.within_limits(robot, sol))
    rows = np.nonzero(valid)[0]
    dp, dr = reference.pose_error(reference.fk(robot, sol), poses[rows])
    assert dp.max() < 1e-10 and dr.max() < 1e-10
    psi_rows = np.broadcast_to(sw.psi[..., None], valid.shape)[valid]
    assert np.abs(wrap_angle(srs.arm_angle(robot, sol) - psi_rows)).max() < 1e-9
    for i in range(3):
        iv = np.concatenate(srs.psi_intervals(robot, poses[i]))
        assert np.all([np.any((iv[:, 0] <= p) & (p <= iv[:, 1])) for p in sw.psi[i]])
    one = srs.ik_sweep(robot, poses[0], 4)
    assert one.psi.shape == (4,) and one.q.shape == (4, 8, 7)


# --------------------------------------------------------------------------- #
# Bad input
# --------------------------------------------------------------------------- #
def _iiwa_with_elbow_offset():
    return derive.model.robot.robot_from_dict({
        "name": "srs-offset", "convention": "axis_angle",
        "joints": [{"name": f"j{i + 1}", "axis": ax, "link": ln} for i, (ax, ln) in enumerate([
            ([0, 0, 1], [0, 0, 0.34]), ([0, 1, 0], [0, 0, 0]), ([0, 0, 1], [0.02, 0, 0.4]),
            ([0, 1, 0], [0, 0, 0]), ([0, 0, 1], [-0.02, 0, 0.4]), ([0, 1, 0], [0, 0, 0]),
            ([0, 0, 1], [0, 0, 0.1])])]})


def test_bad_input_raises_input_error_naming_the_problem():
    pose = reference.fk("iiwa7", np.full(7, 0.3))
    cases = [
        (lambda: srs.ik_psi("ur5", pose, 0.0), "6 joints, the class has 7"),
        (lambda: srs.ik_psi(_iiwa_with_elbow_offset(), pose, 0.0),
         "not an SRS arm .*axis 5 does not lie on the shoulder-wrist line"),
        (lambda: srs.ik_psi("iiwa7", pose[:7], 0.0), "poses"),
        (lambda: srs.ik_psi("iiwa7", np.zeros((2, 2, 8)), 0.0), "poses"),
        (lambda: srs.ik_psi("iiwa7", np.where(np.arange(8) == 2, np.nan, pose), 0.0), "NaN"),
        (lambda: srs.ik_psi("iiwa7", 2 * pose, 0.0), "unit dual quaternion"),
        (lambda: srs.ik_psi("iiwa7", pose, [0.0, 1.0]), "psi"),
        (lambda: srs.ik_psi("iiwa7", pose, math.inf), "psi"),
        (lambda: srs.ik_psi("iiwa7", pose, 0.0, q_ref=np.zeros(6)), "q_ref"),
        (lambda: srs.ik_joint("iiwa7", pose, 2, 0.0), "joint 1, 3, 5 or 7"),
        (lambda: srs.ik_joint("iiwa7", pose, True, 0.0), "joint 1, 3, 5 or 7"),
        (lambda: srs.ik_joint("iiwa7", pose, 3, [0.1, 0.2]), "value"),
        (lambda: srs.arm_angle("iiwa7", np.zeros(6)), "q"),
        (lambda: srs.arm_angle("iiwa7", [0, 0, 0, math.pi, 0, 0, 0]), "wrist centre at the shoulder"),
        (lambda: srs.psi_intervals("iiwa7", np.stack([pose, pose])), "one pose"),
        (lambda: srs.ik_sweep("iiwa7", pose, 0), "positive integer"),
    ]
    for call, text in cases:
        with pytest.raises(InputError, match=text):
            call()
    with pytest.raises(derive.UnknownRobotError):
        srs.ik_psi("no-such-robot", pose, 0.0)
