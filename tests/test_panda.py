"""Franka Panda / FR3: the robot files against Pinocchio on URDFs, and the closed-form IK with q7
given (derive.ik.panda) against the reference FK, EAIK with joint 7 locked, and the singular sets."""

import math
import sysconfig
from pathlib import Path

import numpy as np
import pytest

import derive
from derive import InputError, reference
from derive import dualquat as DQ
from derive.ik import panda as P
from derive.model.robot import robot_from_dict

DATA = Path(__file__).with_name("data")
ROBOTS = ["panda", "fr3"]

#: Franka's published modified-DH table (alpha_(i-1), a_(i-1), d_i) and the flange d, typed
#: here from the FCI documentation (independent of the robot files).
FRANKA_DH = [(0.0, 0.0, 0.333), (-math.pi / 2, 0.0, 0.0), (math.pi / 2, 0.0, 0.316),
             (math.pi / 2, 0.0825, 0.0), (-math.pi / 2, -0.0825, 0.384), (math.pi / 2, 0.0, 0.0),
             (math.pi / 2, 0.088, 0.0)]
FLANGE_D = 0.107
LIMITS = {
    "panda": [(-2.8973, 2.8973), (-1.7628, 1.7628), (-2.8973, 2.8973), (-3.0718, -0.0698),
              (-2.8973, 2.8973), (-0.0175, 3.7525), (-2.8973, 2.8973)],
    "fr3": [(-2.7437, 2.7437), (-1.7837, 1.7837), (-2.9007, 2.9007), (-3.0421, -0.1518),
            (-2.8065, 2.8065), (0.5445, 4.5169), (-3.0159, 3.0159)],
}

try:
    import pinocchio as pin
except ImportError:                        # a clear failure, not a skip: the test extra has it
    pin = None


# --------------------------------------------------------------------------- #
# Helpers
# --------------------------------------------------------------------------- #
def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _configs(name, n, rng):
    lim = np.array(LIMITS[name])
    return rng.uniform(lim[:, 0], lim[:, 1], size=(n, 7))


def _franka_frames():
    """Axes H (7, 3), their points (7, 3) and the flange at q = 0, from FRANKA_DH by plain 4x4s."""
    def rx(a):
        c, s = math.cos(a), math.sin(a)
        return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])

    def tr(x, z):
        m = np.eye(4)
        m[0, 3], m[2, 3] = x, z
        return m

    t = np.eye(4)
    axes, points = [], []
    for alpha, a, d in FRANKA_DH:
        t = t @ rx(alpha) @ tr(a, 0.0)
        axes.append(t[:3, 2].copy())
        points.append(t[:3, 3].copy())
        t = t @ tr(0.0, d)
    return np.array(axes), np.array(points), t @ tr(0.0, FLANGE_D)


def _reproduces(robot, res, poses):
    """Largest position (m) and rotation (rad) error of every returned solution, through the
    reference FK, and whether every solution row below the count is finite."""
    valid = np.arange(8)[None, :] < res.counts[:, None]
    qs = res.q[valid]
    dp, dr = reference.pose_error(reference.fk(robot, qs), np.repeat(poses, res.counts, axis=0))
    finite = bool(np.all(np.isfinite(qs))) and bool(np.all(np.isnan(res.q[~valid])))
    return float(dp.max(initial=0.0)), float(dr.max(initial=0.0)), finite


def _distance_to(res, q):
    """(n,) smallest largest-joint distance (wrapped) from q[i] to the solutions of pose i."""
    d = np.abs(_wrap(res.q - q[:, None, :])).max(axis=-1)
    return np.where(np.isnan(d), np.inf, d).min(axis=1)


def _pin_fk(path, base, tip, names, q):
    if pin is None:
        pytest.fail("Pinocchio is not installed: `pip install -e '.[test]'` installs pin")
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    fb, ft = (model.getFrameId(n, pin.FrameType.BODY) for n in (base, tip))
    out = []
    for row in q:
        qp = pin.neutral(model)
        for name, v in zip(names, row):
            qp[model.joints[model.getJointId(name)].idx_q] = v
        pin.framesForwardKinematics(model, data, qp)
        out.append((data.oMf[fb].inverse() * data.oMf[ft]).homogeneous)
    return np.array(out)


def _erd_panda() -> Path:
    for base in {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}:
        path = Path(base) / "cmeel.prefix/share/example-robot-data/robots/panda_description/urdf/panda.urdf"
        if path.is_file():
            return path
    pytest.fail("example-robot-data is not installed: `pip install -e '.[test]'` installs it")


# --------------------------------------------------------------------------- #
# Robot files
# --------------------------------------------------------------------------- #
def test_panda_file_fk_equals_pinocchio_on_example_robot_data_urdf(rng):
    robot = derive.load_robot("panda")
    q = rng.uniform(-math.pi, math.pi, size=(500, 7))
    names = [f"panda_joint{i}" for i in range(1, 8)]
    gap = np.abs(reference.fk_matrix(robot, q) - _pin_fk(_erd_panda(), "panda_link0", "panda_link8", names, q))
    assert gap.max() < 1e-12
    urdf = derive.load_robot(_erd_panda(), base="panda_link0", tip="panda_link8")
    assert np.array_equal(urdf.limits, robot.limits)


def test_fr3_file_fk_equals_pinocchio_on_the_franka_description_numbers(rng):
    robot = derive.load_robot("fr3")
    path = DATA / "fr3-kinematics.urdf"
    q = rng.uniform(-math.pi, math.pi, size=(500, 7))
    names = [f"fr3_joint{i}" for i in range(1, 8)]
    gap = np.abs(reference.fk_matrix(robot, q) - _pin_fk(path, "fr3_link0", "fr3_link8", names, q))
    assert gap.max() < 1e-12
    assert np.array_equal(derive.load_robot(path, base="fr3_link0", tip="fr3_link8").limits, robot.limits)


@pytest.mark.parametrize("name", ROBOTS)
def test_files_hold_the_published_table_and_limits(name, rng):
    robot = derive.load_robot(name)
    assert robot.exact and robot.default_end == "flange" and robot.dof == 7
    assert robot.limits.tolist() == [list(x) for x in LIMITS[name]]
    # FK at the zero pose: the flange at (a3 + a4 + a6, 0, d1 + d3 + d5 - d7), pointing down
    _, _, t0 = _franka_frames()
    assert np.abs(reference.fk_matrix(robot, np.zeros(7)) - t0).max() < 1e-15
    assert np.allclose(t0[:3, 3], [0.088, 0, 0.926], atol=1e-15)
    geo = P.panda_geometry(robot)
    assert geo.values == {"d1": 0.333, "d3": 0.316, "a3": 0.0825, "a4": -0.0825, "d5": 0.384,
                          "a6": 0.088, "d7": 0.107}
    assert np.array_equal(geo.base, DQ.IDENTITY) and np.array_equal(geo.tool, DQ.IDENTITY)
    assert P.q7_interval(robot) == LIMITS[name][6]


# --------------------------------------------------------------------------- #
# Round trips
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("name", ROBOTS)
def test_round_trip_10k_configurations(name):
    rng = np.random.default_rng({"panda": 1701, "fr3": 1702}[name])
    robot = derive.load_robot(name)
    q = _configs(name, 10_000, rng)
    poses = reference.fk(robot, q)
    res = P.ik_q7(robot, poses, q[:, 6])
    assert res.q.shape == (10_000, 8, 7) and res.branches.shape == (10_000, 8)
    assert np.all(res.counts >= 1) and all(r == "" for r in res.reasons)
    dp, dr, finite = _reproduces(robot, res, poses)
    assert finite and dp < 1e-10 and dr < 1e-10, (dp, dr)
    assert np.max(_distance_to(res, q)) < 1e-8
    # q7 is the given value in every solution; branch ids distinct in 0..7, -1 in the padding
    valid = np.arange(8)[None, :] < res.counts[:, None]
    assert np.all(res.q[valid][:, 6] == np.repeat(q[:, 6], res.counts))
    b = np.where(valid, res.branches, -1)
    assert np.all(res.branches[~valid] == -1) and np.all((b[valid] >= 0) & (b[valid] < 8))
    srt = np.sort(np.where(valid, b, 99 + np.arange(8)), axis=1)
    assert np.all(np.diff(srt, axis=1) > 0)
    assert not np.any(res.singular)
    # the generating configuration lies within the limits, so it is among within_limits' solutions
    # (its per-pose loop is slow: the first 1000 poses)
    part = res.rows(slice(0, 1000))
    ql, cl, bl, _ = P.within_limits(robot, part)
    lim = robot.limits
    inside = np.all((ql >= lim[:, 0] - 1e-12) & (ql <= lim[:, 1] + 1e-12), axis=-1)
    assert np.all(inside | np.isnan(ql[..., 0])) and np.all((bl >= 0) == ~np.isnan(ql[..., 0]))
    d = np.abs(ql - q[:1000, None, :]).max(axis=-1)
    assert np.all(np.where(np.isnan(d), np.inf, d).min(axis=1) < 1e-8)
    assert np.all(cl <= part.counts)         # every limit range is narrower than 2 pi


def test_unchecked_candidates_are_the_checked_solutions_on_regular_poses(rng):
    """check=False skips the FK filter; away from the singular sets nothing is filtered, so the
    results are the same."""
    robot = derive.load_robot("panda")
    q = _configs("panda", 500, rng)
    poses = reference.fk(robot, q)
    a, b = P.ik_q7(robot, poses, q[:, 6]), P.ik_q7(robot, poses, q[:, 6], check=False)
    assert np.array_equal(a.q, b.q, equal_nan=True) and np.array_equal(a.counts, b.counts)
    assert np.array_equal(a.branches, b.branches)


def test_a_urdf_of_the_panda_with_the_hand_frame_has_the_closed_form(rng):
    """Another end frame (the hand, Rz(-pi/4) after the flange) goes into the tool transform."""
    robot = derive.load_robot(_erd_panda(), base="panda_link0", tip="panda_hand")
    geo = P.panda_geometry(robot)
    assert not np.allclose(geo.tool, DQ.IDENTITY)
    q = _configs("panda", 300, rng)
    poses = reference.fk(robot, q)
    res = P.ik_q7(robot, poses, q[:, 6])
    dp, dr, finite = _reproduces(robot, res, poses)
    assert finite and dp < 1e-10 and dr < 1e-10
    assert np.max(_distance_to(res, q)) < 1e-8


# --------------------------------------------------------------------------- #
# EAIK with joint 7 locked: the same solution sets
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("name", ROBOTS)
def test_solution_sets_equal_eaik_with_joint_7_locked(name):
    from eaik.IK_HP import HPRobot

    rng = np.random.default_rng({"panda": 77, "fr3": 78}[name])
    robot = derive.load_robot(name)
    axes, points, t0 = _franka_frames()
    p_vec = np.vstack([points[0], np.diff(points, axis=0), t0[:3, 3] - points[-1]])
    n_q7, per = 20, 25                      # 500 poses, 20 values of q7
    q7s = rng.uniform(*LIMITS[name][6], size=n_q7)
    compared = total_eaik = 0
    for q7 in q7s:
        q = _configs(name, per, rng)
        q[:, 6] = q7
        poses = reference.fk(robot, q)
        res = P.ik_q7(robot, poses, q7)
        # EAIK's end frame has the base orientation at zero: R_eaik = R R0^T
        m = DQ.to_matrix(poses)
        m[:, :3, :3] = m[:, :3, :3] @ t0[:3, :3].T
        eaik = HPRobot(axes, p_vec, fixed_axes=[(6, float(q7))])
        for i, sol in enumerate(eaik.IK_batched(m, 1)):
            qe = np.asarray(sol.Q, dtype=float).reshape(-1, 7)[~np.asarray(sol.is_LS, dtype=bool)]
            qe = qe[:, [0, 1, 2, 3, 4, 5]]
            # merge EAIK's duplicates as ours (1e-6 in every joint)
            uniq = []
            for row in qe:
                if not any(np.abs(_wrap(row - u)).max() < 1e-6 for u in uniq):
                    uniq.append(row)
            ours = res.q[i, :res.counts[i], :6]
            assert len(uniq) == res.counts[i], (name, q7, i, len(uniq), res.counts[i])
            for row in uniq:
                assert np.abs(_wrap(ours - row)).max(axis=1).min() < 1e-7
            compared += 1
            total_eaik += len(uniq)
    assert compared == n_q7 * per and total_eaik >= 4 * compared


# --------------------------------------------------------------------------- #
# Singular sets and unreachable poses: exact solutions or empty with a reason, never NaN
# --------------------------------------------------------------------------- #
def _elbow_constants():
    (_, _, _), (_, _, _), (_, _, d3), (_, a3, _), (_, a4, d5) = FRANKA_DH[:5]
    return a3, d3, a4, d5


def _away_from_stretch(name, n, rng):
    """Configurations within the limits with q4 at least 0.05 rad from the elbow stretch: each
    singular-set test below isolates one set (where two meet, the double roots of one step are
    only as accurate as the other step's noise allows)."""
    a3, d3, a4, d5 = _elbow_constants()
    stretch = math.atan2(a4 * d3 - a3 * d5, a3 * a4 + d3 * d5)
    q = _configs(name, 4 * n, rng)
    return q[np.abs(q[:, 3] - stretch) > 0.05][:n]


def _check_exact(robot, res, poses):
    dp, dr, finite = _reproduces(robot, res, poses)
    assert finite and dp < 1e-10 and dr < 1e-10, (dp, dr)


@pytest.mark.parametrize("name", ROBOTS)
def test_elbow_stretched_gives_the_merged_pairs(name, rng):
    a3, d3, a4, d5 = _elbow_constants()
    q = _configs(name, 200, rng)
    q[:, 3] = math.atan2(a4 * d3 - a3 * d5, a3 * a4 + d3 * d5)      # S, O4, O5 on one line
    robot = derive.load_robot(name)
    poses = reference.fk(robot, q)
    res = P.ik_q7(robot, poses, q[:, 6])
    _check_exact(robot, res, poses)
    assert np.all((res.counts >= 1) & (res.counts <= 4))
    assert np.max(_distance_to(res, q)) < 1e-6
    # 1 mm farther than the stretched arm (the pose moved along S -> O6, so O6 moves with it for
    # the same q7): no solution, and the reason names the elbow
    o6 = reference.joint_positions(robot, q)[:, 6]
    u = (o6 - [0, 0, 0.333]) / np.linalg.norm(o6 - [0, 0, 0.333], axis=1, keepdims=True)
    far = DQ.mul(DQ.from_rt(np.tile([1.0, 0, 0, 0], (200, 1)), 1e-3 * u), poses)
    r = P.ik_q7(robot, far, q[:, 6])
    assert np.all(r.counts == 0) and set(r.reasons) == {P.REASON_ELBOW}
    r = P.ik_q7(robot, DQ.translation([2.0, 0, 0]), 0.3)
    assert r.counts.tolist() == [0] and r.reasons == [P.REASON_ELBOW]
    assert np.all(np.isnan(r.q)) and np.all(r.branches == -1)


@pytest.mark.parametrize("name", ROBOTS)
def test_shoulder_on_axis_5_q4_zero_takes_q5_from_the_reference(name, rng):
    q = _away_from_stretch(name, 100, rng)
    q[:, 3] = 0.0                           # axes 3 and 5 on one line through the shoulder
    robot = derive.load_robot(name)
    poses = reference.fk(robot, q)
    res = P.ik_q7(robot, poses, q[:, 6], q_ref=q)
    _check_exact(robot, res, poses)
    assert np.max(_distance_to(res, q)) < 1e-8
    on = np.abs(res.q[..., 3]) < 1e-9
    assert np.any(on) and np.all(res.singular[on])
    assert np.allclose(res.q[..., 4][on], np.broadcast_to(q[:, None, 4], on.shape)[on], atol=0)
    plain = P.ik_q7(robot, poses, q[:, 6])          # without q_ref the free q5 is 0
    _check_exact(robot, plain, poses)
    on = np.abs(plain.q[..., 3]) < 1e-9
    assert np.all(plain.q[..., 4][on] == 0.0)


@pytest.mark.parametrize("name", ROBOTS)
def test_axes_1_and_3_aligned_take_q1_from_the_reference(name, rng):
    q = _away_from_stretch(name, 100, rng)
    q[:, 1] = 0.0
    robot = derive.load_robot(name)
    poses = reference.fk(robot, q)
    res = P.ik_q7(robot, poses, q[:, 6], q_ref=q)
    _check_exact(robot, res, poses)
    assert np.max(_distance_to(res, q)) < 1e-8
    on = np.abs(np.sin(res.q[..., 1])) < 1e-9
    assert np.any(on) and np.all(res.singular[on])
    plain = P.ik_q7(robot, poses, q[:, 6])
    _check_exact(robot, plain, poses)
    assert np.all(plain.q[..., 0][np.abs(np.sin(plain.q[..., 1])) < 1e-9] == 0.0)


@pytest.mark.parametrize("name", ROBOTS)
@pytest.mark.parametrize("joint, value", [(4, math.pi / 2), (4, -math.pi / 2), (5, 0.0),
                                          (5, math.pi / 2), (5, math.pi), (3, -math.pi / 2)])
def test_wrist_values_q5_double_root_and_q6_special_values(name, joint, value, rng):
    """q5 = +-pi/2: the two q6 roots of eq. W2 coincide (merged); q6 = 0, pi/2, pi and
    q4 = -pi/2 are regular for this construction."""
    q = _away_from_stretch(name, 100, rng)
    q[:, joint] = value
    robot = derive.load_robot(name)
    poses = reference.fk(robot, q)
    res = P.ik_q7(robot, poses, q[:, 6])
    _check_exact(robot, res, poses)
    assert np.all(res.counts >= 1)
    assert np.max(_distance_to(res, q)) < (1e-6 if joint == 4 else 1e-8)
    if joint == 4:
        assert np.all(res.counts <= 6)


def test_shoulder_never_on_axis_6():
    """S on axis 6 needs Z(q4) = a3 s4 - d3 c4 - d5 = 0, impossible when hypot(a3, d3) < d5."""
    a3, d3, a4, d5 = _elbow_constants()
    assert math.hypot(a3, d3) < d5
    q4 = np.linspace(-math.pi, math.pi, 100_001)
    assert np.abs(a3 * np.sin(q4) - d3 * np.cos(q4) - d5).min() > 0.05


@pytest.mark.parametrize("name", ROBOTS)
def test_wrist_centre_on_axis_1_is_regular(name, rng):
    """O6 on axis 1: random q1, q4..q7, then q3 and q2 turn O6 onto axis 1 (with q1 = q2 = q3 = 0
    frame 3 is the base frame, so S -> O6 = u in frame 3; Rz(q3) takes u into the x-z plane and
    Ry(q2) onto z; R3 = Rz(q1) Ry(q2) Rz(q3))."""
    robot = derive.load_robot(name)
    q = _configs(name, 200, rng)
    zero = q.copy()
    zero[:, :3] = 0.0
    u = reference.joint_positions(robot, zero)[:, 6] - [0, 0, 0.333]
    q[:, 2] = np.arctan2(-u[:, 1], u[:, 0])
    q[:, 1] = np.arctan2(-np.hypot(u[:, 0], u[:, 1]), u[:, 2])
    o6 = reference.joint_positions(robot, q)[:, 6]
    assert np.abs(o6[:, :2]).max() < 1e-15
    poses = reference.fk(robot, q)
    res = P.ik_q7(robot, poses, q[:, 6])
    _check_exact(robot, res, poses)
    assert np.all(res.counts >= 1) and not np.any(res.singular)
    assert np.max(_distance_to(res, q)) < 1e-8


def test_unreachable_for_this_q7_says_so(rng):
    """A reachable pose at other values of q7 can have none at some q7: empty, with a reason."""
    robot = derive.load_robot("panda")
    q = _configs("panda", 40, rng)
    values, sweep = P.ik_sweep(robot, reference.fk(robot, q), 64)
    empty = sweep.counts == 0
    assert np.any(empty) and np.any(~empty)
    reasons = {r for row, e in zip(sweep.reasons, empty) for r, k in zip(row, e) if k}
    assert reasons <= {P.REASON_ELBOW, P.REASON_WRIST} and P.REASON_WRIST in reasons
    assert np.all(np.isnan(sweep.q[empty])) and all(r == "" for row, e in zip(sweep.reasons, empty)
                                                     for r, k in zip(row, e) if not k)


def test_sweep_equals_single_calls_and_finds_the_generating_configuration(rng):
    robot = derive.load_robot("fr3")
    values, sweep = P.ik_sweep(robot, reference.fk(robot, _configs("fr3", 3, rng)), 9)
    assert np.allclose(values, np.linspace(-3.0159, 3.0159, 9), atol=0)
    q = _configs("fr3", 3, rng)
    q[:, 6] = values[[2, 4, 7]]
    values, sweep = P.ik_sweep(robot, reference.fk(robot, q), 9)
    assert sweep.q.shape == (3, 9, 8, 7) and sweep.counts.shape == (3, 9)
    for i, k in enumerate([2, 4, 7]):
        one = P.ik_q7(robot, reference.fk(robot, q[i]), values[k])
        assert np.array_equal(one.q[0], sweep.q[i, k], equal_nan=True)
        d = np.abs(_wrap(sweep.q[i, k] - q[i])).max(axis=1)
        assert np.nanmin(d) < 1e-8


# --------------------------------------------------------------------------- #
# Bad input
# --------------------------------------------------------------------------- #
def test_bad_input_raises_input_error(rng):
    robot = derive.load_robot("panda")
    pose = reference.fk(robot, _configs("panda", 1, rng)[0])
    cases = [
        (lambda: P.ik_q7(robot, pose[:7], 0.1), "pose: expected"),
        (lambda: P.ik_q7(robot, np.where(np.arange(8) == 2, np.nan, pose), 0.1), "NaN"),
        (lambda: P.ik_q7(robot, 1.1 * pose, 0.1), "unit"),
        (lambda: P.ik_q7(robot, pose, np.nan), "q7: contains NaN"),
        (lambda: P.ik_q7(robot, pose, [0.1, 0.2]), "q7: expected a number or an array of shape (1,)"),
        (lambda: P.ik_q7(robot, np.stack([pose, pose]), np.zeros((2, 1))), "q7: expected"),
        (lambda: P.ik_q7(robot, pose, 0.1, q_ref=np.zeros(6)), "q_ref: expected last dimension 7"),
        (lambda: P.ik_q7(robot, np.stack([pose] * 3), 0.1, q_ref=np.zeros((2, 7))), "q_ref: expected shape"),
        (lambda: P.ik_q7("ur5", pose, 0.1), "ur5: not of the Franka Panda class"),
        (lambda: P.ik_sweep(robot, pose, 0), "n: a positive number"),
        (lambda: P.ik_q7(robot, "x", 0.1), "pose"),
    ]
    for call, text in cases:
        with pytest.raises(InputError) as err:
            call()
        assert text in str(err.value), (text, str(err.value))


def test_arms_not_of_the_class_are_named_with_what_differs():
    with pytest.raises(InputError, match="6 joints, the class has 7"):
        P.panda_geometry("ur5")
    data = {"name": "panda-offset", "convention": "modified_dh",
            "joints": [{"name": f"j{i + 1}", "alpha": al, "a": a, "theta": 0.3 if i == 1 else 0, "d": d}
                       for i, (al, a, d) in enumerate(FRANKA_DH)]}
    with pytest.raises(InputError, match="at the zero pose axis 3 is"):
        P.panda_geometry(robot_from_dict(data))
    data["joints"][1]["theta"] = 0
    data["joints"][2]["a"] = 0.01            # axis 3 misses the shoulder
    with pytest.raises(InputError, match="axis 3 does not pass through"):
        P.panda_geometry(robot_from_dict(data))
    data["joints"][2]["a"] = 0
    assert P.is_panda_class(robot_from_dict(data)) and not P.is_panda_class("ur5")
