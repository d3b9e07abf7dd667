"""Seven-joint arms with any joint K given (issue 31, item 4): ``derive.ik.free_joint``, its
reference entry (``reference.ik(..., free=v, free_name="qK")``) and kernels
(``derive.kernels(robot, backend, free="qK")``).

Checked against: the plain 4x4-matrix FK (``reference.fk_matrix``, no code shared with the
dual-quaternion FK the solver checks on), the generating configuration, and a dense multi-start
of scipy's least squares on the 7R FK with joint K held (an outside solver)."""

import math

import numpy as np
import pytest

import derive
from derive import reference
from derive.errors import DeriveError, InputError
from derive.codegen.free_joint import free_joint_kernels
from derive.ik import free_joint, srs

ARMS = ["xarm7", "gen3", "iiwa14", "panda", "fr3"]
CASES = [(a, k) for a in ARMS for k in range(1, 8) if not (a == "iiwa14" and k == 4)]


def _wrapped(d):
    return np.abs((np.asarray(d) + math.pi) % (2 * math.pi) - math.pi)


def _inside(robot, n, rng):
    lim = np.where(np.isfinite(robot.limits), robot.limits, np.array([-math.pi, math.pi]))
    return rng.uniform(np.maximum(lim[:, 0], -math.pi), np.minimum(lim[:, 1], math.pi), (n, 7))


def _matrix_error(robot, q, target):
    """Largest |4x4 FK(q) - target| entry (lengths in m), by the plain matrix FK."""
    return float(np.abs(reference.fk_matrix(robot, q) - target).max())


@pytest.mark.parametrize("name", ARMS + ["iiwa7"])
def test_chain7_is_the_robot(name):
    """The product form C1 Rz(q1) ... C7 Rz(q7) C8 (lengths scaled back) equals the 4x4 FK."""
    robot = derive.load_robot(name)
    c, scale = free_joint.chain7(robot)
    q = _inside(robot, 50, np.random.default_rng(2))
    m = np.broadcast_to(c[0], (50, 4, 4)).copy()
    for i in range(7):
        ct, st = np.cos(q[:, i]), np.sin(q[:, i])
        rz = np.zeros((50, 4, 4))
        rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1] = ct, -st, st, ct
        rz[:, 2, 2] = rz[:, 3, 3] = 1
        m = m @ rz @ c[i + 1]
    m[:, :3, 3] *= scale
    assert np.abs(m - reference.fk_matrix(robot, q)).max() < 1e-12


@pytest.mark.parametrize("name,k", CASES)
def test_every_joint_of_every_arm(name, k):
    """40 configurations inside the limits, joint k held at its generating value: every
    solution reproduces the pose (1e-10 by the matrix FK), holds joint k, and the generating
    configuration is among them."""
    robot = derive.load_robot(name)
    rng = np.random.default_rng(100 + k)
    q = _inside(robot, 40, rng)
    poses = reference.fk(robot, q)
    r = free_joint.solve(robot, poses, k, q[:, k - 1])
    assert r.counts.min() >= 1
    valid = np.arange(r.q.shape[1])[None] < r.counts[:, None]
    assert np.all(np.isfinite(r.q[valid])) and np.all(np.isnan(r.q[~valid]))
    rows = np.nonzero(valid)[0]
    sols = r.q[valid]
    target = reference.fk_matrix(robot, q)[rows]
    assert _matrix_error(robot, sols, target) < 1e-10
    assert _wrapped(sols[:, k - 1] - q[rows, k - 1]).max() < 1e-12
    gen = np.nanmin(_wrapped(r.q - q[:, None]).max(-1), axis=1)
    assert np.all(gen < 1e-6), (int(np.argmax(gen)), float(gen.max()))
    # no duplicates: two solutions of one pose differ by more than MERGE_TOL in some joint
    for i in range(len(q)):
        s = r.q[i, :r.counts[i]]
        d = _wrapped(s[:, None] - s[None]).max(-1) + np.eye(len(s))
        assert d.min() > 1e-6


def _multistart(robot, k, value, target, starts=256, iters=80, seed=0):
    """Dense multi-start: damped Gauss-Newton on the 7R's 4x4 matrix FK (reference.fk_matrix,
    forward-difference Jacobian) with joint k held at ``value``, from ``starts`` uniform random
    configurations of the other six; returns the converged ones (residual < 1e-11), (m, 7)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-math.pi, math.pi, (starts, 6))

    def resid(x):
        full = np.insert(x, k - 1, value, axis=1)
        return (reference.fk_matrix(robot, full) - target)[:, :3].reshape(len(x), 12)

    for _ in range(iters):
        r = resid(x)
        h = 1e-7
        jac = np.stack([(resid(x + h * np.eye(6)[j]) - r) / h for j in range(6)], 2)
        jt = np.swapaxes(jac, 1, 2)
        a = jt @ jac + 1e-9 * np.eye(6)
        dx = np.linalg.solve(a, -(jt @ r[..., None]))[..., 0]
        big = np.abs(dx).max(1, keepdims=True)
        x = x + np.where(big > 0.5, dx * 0.5 / np.maximum(big, 0.5), dx)
    ok = np.abs(resid(x)).max(1) < 1e-11
    return np.insert(x[ok], k - 1, value, axis=1)


@pytest.mark.parametrize("name,k", [("panda", 3), ("fr3", 6), ("iiwa14", 2), ("xarm7", 4)])
def test_contains_every_solution_of_a_dense_multistart(name, k):
    """Every configuration a dense multi-start (256 starts of damped Gauss-Newton on the matrix
    FK with joint k held) converges to is among ours, on 2 poses."""
    robot = derive.load_robot(name)
    q = _inside(robot, 2, np.random.default_rng(7 * k))
    poses = reference.fk(robot, q)
    for i in range(2):
        target = reference.fk_matrix(robot, q[i])
        ours = free_joint.solve(robot, poses[i], k, q[i, k - 1])
        sols = ours.q[0, :ours.counts[0]]
        found = _multistart(robot, k, q[i, k - 1], target, seed=i)
        assert len(found) > 20
        d = _wrapped(found[:, None] - sols[None]).max(-1).min(1)
        assert d.max() < 1e-6, f"{name} q{k} pose {i}: the multi-start found {found[np.argmax(d)]} not among ours"


@pytest.mark.parametrize("name,module,k", [("xarm7", "ssik.prebuilt.ufactory.xarm7_ik", 2),
                                           ("gen3", "ssik.prebuilt.kinova.gen3_ik", 5)])
def test_contains_every_solution_of_ssik_jointlock(name, module, k):
    """ssik's joint-lock 7R solver (ssik.solvers.jointlock.seven_r, the 6R of the other joints
    by its own subproblem / Raghavan-Roth solvers) at the same held value: every solution it
    returns (FK within 1e-8 by its own FK) is among ours, on 3 poses. Its FK equals ours
    (tests/test_vendor_arms.py)."""
    import importlib

    ssik_arm = importlib.import_module(module)
    from ssik.solvers.jointlock import seven_r

    robot = derive.load_robot(name)
    q = _inside(robot, 3, np.random.default_rng(11 * k))
    poses = reference.fk(robot, q)
    theirs_total = 0
    for i in range(3):
        target = reference.fk_matrix(robot, q[i])
        theirs, _ = seven_r.solve(ssik_arm._KB, target, lock_samples=[q[i, k - 1]], lock_idx=k - 1,
                                  allow_refinement=True)
        ours = free_joint.solve(robot, poses[i], k, q[i, k - 1])
        sols = ours.q[0, :ours.counts[0]]
        for s in theirs:
            t = np.asarray(s.q, dtype=float)
            if np.abs(ssik_arm.fk(t) - target).max() > 1e-8:
                continue
            theirs_total += 1
            assert _wrapped(sols - t).max(-1).min() < 1e-6, f"{name} q{k} pose {i}: ssik's {t} not among ours"
    assert theirs_total >= 6


def test_class_routes_and_refusals():
    """The SRS class answers joints 1, 3, 5, 7 by srs.ik_joint, 2 and 6 by its own closed form,
    and refuses joint 4 (it alone fixes the shoulder-wrist distance); the Panda class answers q7 by its closed form; other
    joints go to the general 6R; a 6R arm and a joint outside 1..7 are refused."""
    assert [free_joint.route("iiwa14", k) for k in (1, 2, 3, 5, 6, 7)] == \
        ["srs", "srs-2", "srs", "srs", "srs-2", "srs"]
    assert free_joint.route("panda", 7) == "panda" and free_joint.route("panda", 1) == "general"
    assert {free_joint.route("xarm7", k) for k in range(1, 8)} == {"general"}
    with pytest.raises(InputError, match="joint 4 alone sets the shoulder-wrist distance"):
        free_joint.route("iiwa7", 4)
    with pytest.raises(InputError, match="seven-joint"):
        free_joint.route("ur5", 2)
    with pytest.raises(InputError, match="q1 .. q7"):
        free_joint.route("xarm7", 8)
    robot = derive.load_robot("iiwa14")
    q = _inside(robot, 20, np.random.default_rng(5))
    poses = reference.fk(robot, q)
    r = free_joint.solve(robot, poses, 5, q[:, 4])
    ref = srs.ik_joint(robot, poses, 5, q[:, 4])
    np.testing.assert_array_equal(r.counts, ref.count)
    np.testing.assert_allclose(r.q, ref.q, atol=1e-12)


@pytest.mark.parametrize("k", [2, 6])
def test_srs_joint2_closed_form_equals_the_general_route(k):
    """Two independent paths on the iiwa7 with q2 / q6 given: the SRS closed form (route
    "srs-2") and the general 6R elimination of the same locked chain (forced): the same
    solution sets on 60 regular configurations."""
    robot = derive.load_robot("iiwa7")
    q = _inside(robot, 60, np.random.default_rng(40 + k))
    poses = reference.fk(robot, q)
    closed = free_joint.solve(robot, poses, k, q[:, k - 1])
    general = free_joint._general(robot, free_joint.plan(robot, k), poses, q[:, k - 1])
    assert np.all(closed.counts == 8)
    same = 0
    for i in range(60):
        a, b = closed.q[i, :closed.counts[i]], general.q[i, :general.counts[i]]
        d = _wrapped(a[:, None] - b[None]).max(-1)
        if len(b) == 8 and d.min(1).max() < 1e-7 and d.min(0).max() < 1e-7:
            same += 1
        else:      # the general route may lose a root at shared roots; never adds a wrong one
            assert len(b) == 0 or d.min(0).max() < 1e-7
    assert same >= 58


def test_unreachable_pose_has_no_solution_and_says_why():
    """A pose beyond reach: no solution, a reason, no NaN in the counts."""
    robot = derive.load_robot("xarm7")
    pose = np.eye(4)
    pose[:3, 3] = [3.0, 0, 0]
    r = free_joint.solve(robot, pose, 4, 1.0)
    assert r.counts.tolist() == [0] and "unreachable with q4 given" in r.reason[0]
    assert len(reference.ik(robot, pose, free=1.0, free_name="q4")) == 0


def test_reference_entry_points():
    """reference.ik / ik_batch / ik_sweep / nearest with free_name="qK"."""
    robot = derive.load_robot("xarm7")
    q = _inside(robot, 6, np.random.default_rng(9))
    poses = reference.fk(robot, q)
    one = reference.ik(robot, poses[0], free=q[0, 2], free_name="q3", within_limits=True, sort_by=q[0])
    assert _wrapped(one[0] - q[0]).max() < 1e-8 and one.free == q[0, 2]
    sols, counts = reference.ik_batch(robot, poses, free=q[:, 2], free_name="q3")
    assert sols.shape == (6, 16, 7) and counts.min() >= 1
    with pytest.raises(InputError, match="needs free="):
        reference.ik(robot, poses[0], free_name="q3")
    sw = reference.ik_sweep(robot, poses[:2], 9, free_name="q6")
    lo, hi = robot.limits[5]
    assert sw.free.shape == (2, 9) and np.allclose(sw.free[0], np.linspace(lo, hi, 9))
    ok = sw.q[np.isfinite(sw.q[..., 0])]
    assert np.all(np.abs(ok[:, 5][:, None] - sw.free.reshape(-1)[None]).min(1) < 1e-12)
    assert np.all((ok >= robot.limits[:, 0] - 1e-9) & (ok <= robot.limits[:, 1] + 1e-9))
    near = reference.nearest(robot, poses[0], q[0] + 0.02, free_name="q6")
    assert near.found and near.max_move <= 0.02 * 1.5 + 1e-9


def test_nearest_follows_a_path():
    """A smooth trajectory of the gen3, joint 3 chosen for the path; each step's seed is the
    previous answer: every answer reproduces its pose (1e-10), lies inside the limits, and its
    largest move is at most 1.5 times the generating step's (the bound of redundant.nearest's
    SLACK). (Not q4: on the gen3, a nominal SRS arm, q4 nearly fixes the shoulder-wrist
    distance, so a pose has solutions only in a narrow window of q4.)"""
    robot = derive.load_robot("gen3")
    t = np.linspace(0, 0.6, 5)[:, None]
    q = np.array([0.3, 0.6, -0.2, 1.4, 0.5, 0.8, -0.4]) + 0.25 * np.sin(3 * t + np.arange(7))
    poses = reference.fk(robot, q)
    seed = q[0].copy()
    for i in range(1, len(q)):
        r = free_joint.nearest(robot, poses[i], 3, seed)
        assert r.found
        assert _matrix_error(robot, r.q, reference.fk_matrix(robot, q[i])) < 1e-10
        step = np.abs(q[i] - seed).max()
        assert r.max_move <= 1.5 * step + 1e-9, (i, r.max_move, step)
        assert np.all((r.q >= robot.limits[:, 0]) & (r.q <= robot.limits[:, 1]))
        seed = r.q


def test_kernels_with_any_joint(monkeypatch):
    """derive.kernels(robot, backend, free="qK"): numpy and python give the reference's
    solutions; fk is the backend's; free= is required; C refuses the SRS class's q4, solves an
    SRS class route by the class's program without a general-6R plan, and where the general route
    has no plan raises its error; q3 of the SRS class and q7 of the Panda class stay the
    generated kernels."""
    robot = derive.load_robot("xarm7")
    q = _inside(robot, 8, np.random.default_rng(4))
    kn = derive.kernels("xarm7", "numpy", free="q5")
    kp = derive.kernels("xarm7", "python", free="q5")
    assert kn.free == "q5" and kn.dof == 7
    poses = kn.fk(q)
    np.testing.assert_allclose(poses, kp.fk(q), atol=1e-14)
    ref, rc = reference.ik_batch(robot, poses, free=q[:, 4], free_name="q5")
    for k in (kn, kp):
        sols, counts = k.ik(poses, free=q[:, 4])
        np.testing.assert_array_equal(counts, rc)
        np.testing.assert_allclose(sols, ref, atol=1e-12)
        gen = np.nanmin(_wrapped(sols - q[:, None]).max(-1), axis=1)
        assert np.all(gen < 1e-6)
    s1, c1 = kn.ik(poses[0], free=q[0, 4])
    assert s1.shape == (16, 7) and c1 == rc[0]
    with pytest.raises(InputError, match="need free="):
        kn.ik(poses)
    # the default kernels of a seven-revolute arm outside the classes have no IK: the error names
    # the free="qK" kernels (whose solutions above hold the pose's configuration)
    with pytest.raises(DeriveError, match=r"derive.kernels\('xarm7', 'numpy', free='qK'\)"):
        derive.kernels("xarm7", "numpy").ik(poses[0])
    # C on a class route runs the class's IK program (test_free_joint_srs_c), with no general-6R
    # plan; the SRS q4 stays refused
    with pytest.raises(InputError, match="joint 4 alone sets the shoulder-wrist distance"):
        derive.kernels("iiwa14", "c", free="q4")

    def no_plan(robot, joint):
        raise DeriveError(f"{robot.name} with q{joint} given: the general 6R elimination degenerates")

    monkeypatch.setattr(free_joint, "plan", no_plan)
    from derive.codegen.loader import _compile
    kc = free_joint_kernels(derive.load_robot("iiwa14"), "c", 2, derive.kernels("iiwa14", "c"), _compile)
    qi = np.array([0.3, 0.5, -0.4, 1.1, 0.2, -0.7, 0.4])
    s2, c2 = kc.ik(reference.fk("iiwa14", qi), free=0.5)
    assert c2 == 8 and _wrapped(s2[:c2] - qi).max(-1).min() < 1e-9
    with pytest.raises(DeriveError, match="the general 6R elimination degenerates"):
        free_joint_kernels(derive.load_robot("xarm7"), "c", 2, None)
    monkeypatch.undo()
    assert type(derive.kernels("iiwa14", "numpy", free="q3")).__name__ == "Kernels"
    assert type(derive.kernels("panda", "numpy", free="q7")).__name__ == "Kernels"
    sw = kn.ik_sweep(poses[:2], 4)
    assert sw.q.shape[:2] == (2, 4)
    nr = kn.nearest(poses[:2], q[:2] + 0.01)
    assert np.all(nr.found) and np.all(nr.max_move <= 0.015 + 1e-9)


def test_cli_ik_with_any_joint_given(capsys):
    """dq-derive ik ARM --q Q --free V --free-joint J (and --seed with --free-joint J): the
    generating configuration among the solutions, each with joint J = V."""
    import json

    from derive.cli import main

    q = [0.3, 0.6, -0.2, 1.4, 0.5, 0.8, -0.4]
    assert main(["ik", "xarm7", "--q", *map(str, q), "--free", "1.4", "--free-joint", "4", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    sols = np.array([s["q"] for s in out["solutions"]])
    assert out["free_parameter"]["name"] == "q4" and out["count"] == len(sols) >= 2
    assert np.all(np.abs(sols[:, 3] - 1.4) < 1e-12) and _wrapped(sols - np.array(q)).max(-1).min() < 1e-8
    seed = [0.31, 0.6, -0.2, 1.4, 0.5, 0.8, -0.4]
    assert main(["ik", "xarm7", "--q", *map(str, q), "--seed", *map(str, seed), "--free-joint", "2", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["count"] == 1 and _wrapped(np.array(out["solutions"][0]["q"]) - np.array(seed)).max() <= 0.015
    assert main(["ik", "xarm7", "--q", *map(str, q), "--free-joint", "2"]) == 2
    assert "give exactly one of --free V" in capsys.readouterr().err
