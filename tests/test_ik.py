"""Closed-form IK (reference): accuracy on 10^5 configurations per UR robot, singular sets,
unreachable poses, limits, input errors."""

import math

import numpy as np
import pytest
import yaml

from derive import DeriveError, InputError, reference
from derive import dualquat as DQ
from derive.algebra.angles import wrap_angle
from derive.ik.closed_form import solve, ur_geometry
from derive.model.robot import load_robot, robot_from_dict

UR = ["ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e"]


def residuals(robot, pose, q):
    fk = reference.fk(robot, q)
    return reference.pose_error(np.broadcast_to(pose, fk.shape), fk)


def contains(sols, q, tol):
    if len(sols) == 0:
        return False
    return bool(np.min(np.max(np.abs(wrap_angle(np.asarray(sols) - q)), axis=1)) < tol)


def singular_distance(geo, q):
    """Distance of configurations to the singular sets: sin t5 = 0, sin t3 = 0, and the
    shoulder set a2 c2 + a3 c23 + d5 s234 = 0 (both theta1 roots coincide)."""
    t2, t3, t4, t5 = q[:, 1], q[:, 2], q[:, 3], q[:, 4]
    x = geo.a2 * np.cos(t2) + geo.a3 * np.cos(t2 + t3) + geo.d5 * np.sin(t2 + t3 + t4)
    return np.minimum.reduce([np.abs(np.sin(t5)), np.abs(np.sin(t3)), np.abs(x)])


@pytest.mark.parametrize("name", UR)
def test_accuracy_on_100000_random_configurations(name):
    robot = load_robot(name)
    geo = ur_geometry(robot)
    rng = np.random.default_rng(2026)
    q = rng.uniform(-math.pi, math.pi, size=(100_000, 6))
    poses = reference.fk(robot, q)
    sols, counts, singular, reasons = solve(robot, geo, poses)
    valid = ~np.isnan(sols[..., 0])
    assert np.array_equal(valid.sum(axis=1), counts)
    assert not np.any(np.isnan(sols[valid]))
    assert np.all(np.abs(sols[valid]) <= math.pi)
    # every returned solution reproduces the pose
    dp, dr = residuals(robot, np.repeat(poses, 8, axis=0)[valid.ravel()], sols[valid])
    assert dp.max() < 1e-10 and dr.max() < 1e-10, (dp.max(), dr.max())
    # the generating configuration is among the solutions, except near singular sets
    # (joint-space tolerance 1e-6: near several singular sets at once the joint angles are
    # ill-conditioned functions of the pose, e.g. 4e-9 for one ur3 sample at sin t5 = 2e-3,
    # sin t3 = 0.05 and 3e-4 from the shoulder set, while its pose residual is 1e-15)
    d = np.max(np.abs(wrap_angle(sols - q[:, None, :])), axis=-1)
    best = np.nanmin(np.where(np.isnan(d), np.inf, d), axis=1)
    generic = singular_distance(geo, q) > 1e-7
    assert np.all(best[generic] < 1e-6), np.nonzero((best >= 1e-6) & generic)[0][:5]
    assert np.mean(best[generic] < 1e-9) > 0.999
    # every pose of the workspace has a solution; counts are even (branch pairs)
    assert counts.min() >= 2 and np.all(counts[generic] % 2 == 0)
    assert (counts == 8).mean() > 0.6   # 67-79 % across the family (docs/ik.md)


def _numeric_solutions(robot, pose, restarts=96, seed=0):
    """Independent IK: damped Newton from random starts, distinct converged solutions."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-math.pi, math.pi, size=(restarts, 6))
    target = DQ.to_matrix(pose)

    def err(qs):
        m = reference.fk_matrix(robot, qs)
        return np.concatenate([(m[:, :3, 3] - target[:3, 3]), (m[:, :3, :3] - target[:3, :3]).reshape(-1, 9)], 1)

    for _ in range(60):
        e = err(x)
        jac = np.empty((restarts, 12, 6))
        for k in range(6):
            dx = np.zeros(6)
            dx[k] = 1e-7
            jac[:, :, k] = (err(x + dx) - e) / 1e-7
        jt = np.swapaxes(jac, 1, 2)
        h = jt @ jac + 1e-9 * np.eye(6)
        x = x - np.linalg.solve(h, (jt @ e[..., None]))[..., 0]
    good = np.max(np.abs(err(x)), axis=1) < 1e-9
    found = []
    for s in wrap_angle(x[good]):
        if not any(np.max(np.abs(wrap_angle(s - f))) < 1e-6 for f in found):
            found.append(s)
    return found


@pytest.mark.parametrize("name", ["ur5", "ur10e"])
def test_solution_count_matches_an_independent_numeric_search(name):
    robot = load_robot(name)
    rng = np.random.default_rng(11)
    for q in rng.uniform(-math.pi, math.pi, size=(12, 6)):
        pose = reference.fk(robot, q)
        closed = reference.ik(robot, pose)
        numeric = _numeric_solutions(robot, pose)
        assert len(closed) == len(numeric), (q, len(closed), len(numeric))
        for s in numeric:
            assert contains(closed, s, 1e-6)


# --- singular and boundary sets ---------------------------------------------------
def _configs_on(rng, n, **fixed):
    q = rng.uniform(-math.pi, math.pi, size=(n, 6))
    for k, v in fixed.items():
        q[:, int(k[1]) - 1] = v
    return q


def _assert_theta6_mid_reach(robot, pose, sols):
    """The chosen theta6 puts the elbow nearest to a right angle: no theta6 on a grid, fed as
    the reference, gives a singular solution with |cos theta3| smaller."""
    grid = np.linspace(-math.pi, math.pi, 181)
    q_ref = np.zeros((len(grid), 6))
    q_ref[:, 5] = grid
    q_all, counts = reference.ik_batch(robot, np.tile(pose, (len(grid), 1)), q_ref=q_ref)[:2]
    t5 = q_all[..., 4]
    on_grid = np.abs(np.sin(np.nan_to_num(t5, nan=1.0))) < 1e-12
    best_grid = np.min(np.abs(np.cos(q_all[..., 2][on_grid]))) if np.any(on_grid) else np.inf
    chosen = np.abs(np.cos(np.asarray(sols)[sols.singular][:, 2]))
    assert chosen.min() <= best_grid + 1e-9


@pytest.mark.parametrize("t5", [0.0, math.pi, -math.pi])
def test_wrist_singularity(t5, rng):
    robot = load_robot("ur5")
    for q in _configs_on(rng, 20, t5=t5):
        pose = reference.fk(robot, q)
        sols = reference.ik(robot, pose)
        assert not np.any(np.isnan(sols))
        # theta6 is free on the singular branch; without a reference it is chosen for reach,
        # so the singular branch of the generating configuration is always returned
        assert np.any(sols.singular)
        _assert_theta6_mid_reach(robot, pose, sols)
        if len(sols):
            dp, dr = residuals(robot, pose, np.asarray(sols))
            assert dp.max() < 1e-10 and dr.max() < 1e-10
        # with the generating configuration as reference, it is found exactly
        sols_ref = reference.ik(robot, pose, q_ref=q)
        assert contains(sols_ref, q, 1e-9)
        assert np.any(sols_ref.singular)
        assert np.all(sols_ref[sols_ref.singular][:, 5] == wrap_angle(q[5]))
        if len(sols):
            dp, dr = residuals(robot, pose, np.asarray(sols_ref))
            assert dp.max() < 1e-10 and dr.max() < 1e-10


def test_shoulder_singularity_no_duplicates(rng):
    robot = load_robot("ur10")
    geo = ur_geometry(robot)
    for _ in range(20):
        q = rng.uniform(-math.pi, math.pi, 6)
        # choose t4 so that a2 c2 + a3 c23 + d5 s234 = 0 (wrist point over the shoulder axis)
        q[1], q[2] = -math.pi / 2 + rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05)
        s = -(geo.a2 * math.cos(q[1]) + geo.a3 * math.cos(q[1] + q[2])) / geo.d5
        q[3] = math.asin(s) - q[1] - q[2]
        pose = reference.fk(robot, q)
        sols = reference.ik(robot, pose)
        assert not np.any(np.isnan(sols)) and len(sols) <= 4
        diffs = [np.max(np.abs(wrap_angle(a - b))) for i, a in enumerate(sols) for b in sols[i + 1:]]
        assert all(d > 1e-6 for d in diffs)
        dp, dr = residuals(robot, pose, np.asarray(sols))
        assert dp.max() < 1e-10 and dr.max() < 1e-10
        assert contains(sols, q, 1e-6)


@pytest.mark.parametrize("t3", [0.0, math.pi])
def test_elbow_stretched_or_folded(t3, rng):
    robot = load_robot("ur3e")
    for q in _configs_on(rng, 20, t3=t3):
        pose = reference.fk(robot, q)
        sols = reference.ik(robot, pose)
        assert not np.any(np.isnan(sols)) and 1 <= len(sols) <= 7   # the stretched branch counts once
        diffs = [np.max(np.abs(wrap_angle(a - b))) for i, a in enumerate(sols) for b in sols[i + 1:]]
        assert all(d > 1e-6 for d in diffs)
        dp, dr = residuals(robot, pose, np.asarray(sols))
        assert dp.max() < 1e-10 and dr.max() < 1e-10
        assert contains(sols, q, 1e-6)


@pytest.mark.parametrize("t234", [math.pi, -math.pi, 0.0])
def test_half_angle_sets_of_the_thesis_are_solved_like_any_other(t234, rng):
    # 4.28 divides by cos((t2+t3+t4)/2), 4.14-4.17 by cos(t5/2) and sin(t5/2); the
    # implementation uses none of these divisions.
    robot = load_robot("ur16e")
    for q in rng.uniform(-math.pi, math.pi, size=(30, 6)):
        q[3] = t234 - q[1] - q[2]
        if abs(math.sin(q[4])) < 0.05:
            continue
        pose = reference.fk(robot, q)
        sols = reference.ik(robot, pose)
        assert contains(sols, q, 1e-9)
        dp, dr = residuals(robot, pose, np.asarray(sols))
        assert dp.max() < 1e-10 and dr.max() < 1e-10


# --- unreachable, input ---------------------------------------------------------
def test_unreachable_poses_give_no_solution_and_a_reason():
    far = reference.ik("ur5", DQ.from_rt([1, 0, 0, 0], [2.0, 0.3, 0.1]))
    assert far.shape == (0, 6) and "unreachable" in far.reason and "upper arm" in far.reason
    near = reference.ik("ur5", DQ.from_rt([1, 0, 0, 0], [0.0, 0.0, 0.3]))
    assert near.shape == (0, 6) and "d4" in near.reason
    q, counts = reference.ik_batch("ur5", np.stack([DQ.from_rt([1, 0, 0, 0], [2.0, 0, 0]),
                                                    reference.fk("ur5", np.zeros(6))]))
    assert counts.tolist()[0] == 0 and counts[1] > 0 and np.all(np.isnan(q[0]))


def test_pose_input_forms_and_errors():
    q = np.array([0.2, -1.0, 1.3, -0.5, 0.7, 0.1])
    Q = reference.fk("ur5", q)
    a = reference.ik("ur5", Q)
    b = reference.ik("ur5", reference.fk_matrix("ur5", q))
    assert np.allclose(a, b, atol=1e-12)
    near_unit = Q * (1 + 5e-7)
    assert np.allclose(reference.ik("ur5", near_unit), a, atol=1e-9)
    with pytest.raises(InputError, match="not a unit dual quaternion"):
        reference.ik("ur5", Q * 1.01)
    with pytest.raises(InputError, match="NaN"):
        reference.ik("ur5", np.r_[np.nan, Q[1:]])
    with pytest.raises(InputError, match="inf"):
        reference.ik("ur5", np.r_[Q[:7], np.inf])
    bad = np.eye(4)
    bad[0, 0] = 2
    with pytest.raises(InputError, match="not a rotation matrix"):
        reference.ik("ur5", bad)
    with pytest.raises(InputError, match="expected a dual quaternion"):
        reference.ik("ur5", np.zeros(7))
    with pytest.raises(DeriveError, match="no closed-form IK.*UR family.*spherical-wrist.*general 6R"):
        reference.ik("kunze-2r", reference.fk("kunze-2r", np.zeros(2)))


def test_joint_limits_and_sorting(tmp_path):
    data = yaml.safe_load(open(load_robot("ur5").path))
    for j in data["joints"]:
        j["limits"] = ["-pi/2", "pi/2"]
    robot = robot_from_dict(data)
    q = np.array([0.2, -1.0, 1.3, -0.5, 0.7, 0.1])
    pose = reference.fk(robot, q)
    every = reference.ik(robot, pose)
    inside = reference.ik(robot, pose, within_limits=True)
    assert 1 <= len(inside) < len(every)
    assert np.all(np.abs(inside) <= math.pi / 2 + 1e-12)
    assert contains(inside, q, 1e-9)
    # +-2 pi alternatives for joints with a 360-degree range either side
    full = reference.ik("ur5", pose, within_limits=True)
    assert len(full) == len(every) * 2 ** 6
    assert np.all(np.abs(full) <= 2 * math.pi)
    dp, dr = residuals("ur5", pose, np.asarray(full))
    assert dp.max() < 1e-10 and dr.max() < 1e-10
    ref = q + np.array([0, 0, 0, 0, 0, -2 * math.pi])   # theta6 = 0.1 - 2 pi, inside +-2 pi
    ordered = reference.ik("ur5", pose, within_limits=True, sort_by=ref)
    assert np.allclose(ordered[0], ref, atol=1e-9)
    d = np.linalg.norm(np.asarray(ordered) - ref, axis=1)
    assert np.all(np.diff(d) >= 0)
    none = reference.ik(robot, reference.fk(robot, [2.5, -1.0, 1.3, -0.5, 0.7, 0.1]), within_limits=True)
    assert len(none) == 0 and "joint limits" in none.reason


def test_sort_by_wraps_each_joint_and_slices_keep_their_rows():
    """A seed near pi ranks the generating solution first, although its values sit near -pi
    (the closed form's (-pi, pi]): without windings the distance wraps each joint. With
    ``within_limits`` every winding is a move the arm makes, so the plain move ranks. Indexing
    the result keeps ``singular`` (and ``branch``) with their rows."""
    q = np.array([-3.1, -1.0, 1.3, -0.5, 0.7, -3.05])
    pose = reference.fk("ur5", q)
    seed = np.array([3.1, -1.0, 1.3, -0.5, 0.7, 3.1])            # 0.083 and 0.133 rad from q, wrapped
    ranked = reference.ik("ur5", pose, sort_by=seed)
    assert len(ranked) == 8
    assert np.allclose(ranked[0], q, atol=1e-9)
    d = np.linalg.norm(wrap_angle(np.asarray(ranked) - seed), axis=1)
    assert np.all(np.diff(d) >= 0)
    # with windings: q + 2 pi on joints 1 and 6 is the configuration next to the seed
    inside = reference.ik("ur5", pose, within_limits=True, sort_by=seed)
    near = q + np.array([2 * math.pi, 0, 0, 0, 0, 2 * math.pi])
    assert np.allclose(inside[0], near, atol=1e-9)
    # slicing keeps the per-row attributes aligned (theta5 = 0: the rows with theta5 = 0 are singular)
    wrist = reference.ik("ur5", reference.fk("ur5", [0.3, -1.0, 1.3, -0.5, 0.0, 0.2]), q_ref=np.zeros(6))
    mixed = reference.ik("ur5", pose)
    for sols in (wrist, mixed):
        assert np.array_equal(sols[2:5].singular, np.asarray(sols.singular)[2:5])
        mask = np.asarray(sols)[:, 0] > 0
        assert np.array_equal(sols[mask].singular, np.asarray(sols.singular)[mask])
        assert len(sols[::-1].singular) == len(sols)
    assert wrist.singular.any() and not wrist.singular.all() and not mixed.singular.any()
    assert type(mixed[:, 0]) is np.ndarray and type(mixed[0]) is np.ndarray
    r = reference.ik("panda", reference.fk("panda", [0.3, 0.5, 0.2, -1.0, 0.1, 1.2, 0.4]), free=0.4)
    assert np.array_equal(r[1:].branch, np.asarray(r.branch)[1:]) and r[1:].free == 0.4
