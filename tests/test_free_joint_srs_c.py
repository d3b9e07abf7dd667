"""The C kernels of the SRS arms with joint K in {1, 2, 5, 6, 7} given (issue 31, item 4, the class
routes of ``derive.ik.free_joint.route``): ``derive.kernels(robot, "c", free="qK")`` runs the
class's IK program (``derive.ik.program7.srs_joint_program``, printed by the kernels' template:
``derive.codegen.free_joint.program_source``), checked against the numpy closed form
(``derive.ik.free_joint.solve``: ``srs.ik_joint`` / ``_srs_joint2``), the plain 4x4-matrix FK
(``reference.fk_matrix``), the generating configuration and EAIK with that joint locked."""

import math
import shutil

import numpy as np
import pytest

import derive
from derive import reference
from derive.codegen import free_joint as cfree
from derive.ik import free_joint, program7
from conftest import assert_compiles_strict

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

#: every class route of iiwa14 (d_se != d_ew, so the reversed chain's swapped lengths matter) and
#: one of iiwa7 (its other lengths; tests/test_outside_ik.py compares the same kernel with ssik)
CASES = [("iiwa14", 1), ("iiwa14", 2), ("iiwa14", 5), ("iiwa14", 6), ("iiwa14", 7), ("iiwa7", 2)]


def _wrapped(d):
    return np.abs((np.asarray(d) + math.pi) % (2 * math.pi) - math.pi)


def _configs(robot, n, rng):
    """n configurations inside the limits; the last 100 on the class's singular sets, 25 each:
    q4 = 0 (elbow stretched), q6 = 0 (wrist aligned), q2 = q4 = 0 (wrist centre on axis 1),
    q2 = 0 (axes 1 and 3 in line)."""
    lim = robot.limits
    q = rng.uniform(lim[:, 0], lim[:, 1], (n, 7))
    s = n - 100
    q[s:s + 25, 3] = 0.0
    q[s + 25:s + 50, 5] = 0.0
    q[s + 50:s + 75, [1, 3]] = 0.0
    q[s + 75:, 1] = 0.0
    return q


@pytest.mark.parametrize("name,k", CASES)
def test_c_program_equals_the_numpy_closed_form(name, k):
    """400 configurations (300 random inside the limits, 100 on the singular sets), joint k held
    at its generating value (even rows) or at a random value in its range (odd rows): the C
    kernel returns the closed form's solution set exactly: the same counts, branch ids (in the
    same order) and singular flags, every value within 1e-6 rad (1e-10 on 99 % of them; near the
    elbow stretch joints 3 and 5 are fixed only to about 1e-8 by the pose); every C solution
    reproduces the pose within 1e-10 by the plain matrix FK and holds joint k as given; the
    generating configuration is among them on the random rows at their value; no pose is
    flagged degenerate; nothing but the padding is NaN."""
    robot = derive.load_robot(name)
    assert free_joint.route(robot, k) in cfree.PROGRAM_ROUTES
    kc = derive.kernels(name, "c", free=f"q{k}")
    assert kc.route == free_joint.route(robot, k) and isinstance(kc._c, cfree._CProgram)
    rng = np.random.default_rng(310 + k)
    q = _configs(robot, 400, rng)
    lo, hi = free_joint.joint_range(robot, k)
    v = np.where(np.arange(400) % 2 == 0, q[:, k - 1], rng.uniform(lo, hi, 400))
    poses = reference.fk(robot, q)
    cq, cc, cb, cs = kc.ik(poses, free=v, details=True)
    ref = free_joint.solve(robot, poses, k, v)
    assert not ref.degenerate.any()          # the closed form: nothing for a flag to cover
    np.testing.assert_array_equal(cc, ref.counts)
    assert ref.q.shape[1] == 8 and np.all(cb[:, 8:] == -1) and not cs[:, 8:].any()
    np.testing.assert_array_equal(cb[:, :8], ref.branch)
    np.testing.assert_array_equal(cs[:, :8], ref.singular)
    assert cc.sum() > 1200 and cs.sum() > 50
    valid = np.arange(16)[None] < cc[:, None]
    assert not np.isnan(cq[valid]).any() and np.isnan(cq[~valid]).all()
    d = _wrapped(cq[:, :8][valid[:, :8]] - ref.q[valid[:, :8]]).max(-1)
    assert d.max() < 1e-6 and np.quantile(d, 0.99) < 1e-10
    rows = np.nonzero(valid)[0]
    err = np.abs(reference.fk_matrix(robot, cq[valid]) - reference.fk_matrix(robot, q)[rows]).max()
    assert err < 1e-10
    assert _wrapped(cq[valid][:, k - 1] - v[rows]).max() < 1e-12
    gen = np.nanmin(np.where(valid, _wrapped(cq - q[:, None]).max(-1), np.inf), axis=1)
    assert np.all(gen[:300:2] < 1e-6), np.nonzero(~(gen[:300:2] < 1e-6))[0] * 2
    # one pose per call equals the batch
    for i in (0, 1, 350):
        one, c1 = kc.ik(poses[i], free=float(v[i]))
        assert c1 == cc[i] and np.array_equal(one, cq[i], equal_nan=True)


@pytest.mark.parametrize("k", [1, 2, 6, 7])
def test_c_program_near_the_elbow_stretch_is_the_closed_form(k):
    """iiwa14, 100 configurations within 0.005 rad of the elbow stretch (q4 = 0), where the general
    elimination's eigenvalues cluster and its C lost solutions (the poses were flagged): the
    program's sets are the closed form's (counts, branch ids, singular flags; values within
    1e-9, joints 3 and 5, nearly in line, within 1e-4), every solution within 1e-10 by the
    matrix FK, the generating configuration among them (within 1e-5: the pose fixes it no better
    there), none flagged."""
    robot = derive.load_robot("iiwa14")
    kc = derive.kernels("iiwa14", "c", free=f"q{k}")
    rng = np.random.default_rng(320 + k)
    lim = robot.limits
    q = rng.uniform(lim[:, 0], lim[:, 1], (100, 7))
    q[:, 3] = rng.uniform(-0.005, 0.005, 100)
    poses = reference.fk(robot, q)
    cq, cc, cb, cs = kc.ik(poses, free=q[:, k - 1], details=True)
    ref = free_joint.solve(robot, poses, k, q[:, k - 1])
    np.testing.assert_array_equal(cc, ref.counts)
    np.testing.assert_array_equal(cb[:, :8], ref.branch)
    np.testing.assert_array_equal(cs[:, :8], ref.singular)
    valid = np.arange(16)[None] < cc[:, None]
    d = _wrapped(cq[:, :8][valid[:, :8]] - ref.q[valid[:, :8]]).max(0)
    # joints 3 and 5 nearly in line: the pose fixes them to about 1e-16 / q4^2 (1.6e-6 measured)
    assert d[[0, 1, 3, 5, 6]].max() < 1e-9 and d[[2, 4]].max() < 1e-4, d
    rows = np.nonzero(valid)[0]
    assert np.abs(reference.fk_matrix(robot, cq[valid]) - reference.fk_matrix(robot, q)[rows]).max() < 1e-10
    gen = np.nanmin(np.where(valid, _wrapped(cq - q[:, None]).max(-1), np.inf), axis=1)
    assert np.all(gen < 1e-5)          # 3.5e-6 at |q4| = 1e-4 (the numpy closed form's: 5e-6)
    assert not kc.ik_degenerate(poses, free=q[:, k - 1]).any()


@pytest.mark.parametrize("k", [1, 2, 5, 6, 7])
def test_c_program_equals_eaik_with_the_joint_locked(k):
    """EAIK (IK-Geo's decompositions) on iiwa14's axes with joint k locked at one value, 150
    configurations inside the limits with that value: the C kernel's set is EAIK's (its exact,
    non-least-squares solutions), each within 1e-6 rad (the sin t = y / v_x double root of q1 and
    q7 given costs both solvers digits in the joints, as tests/test_srs.py says), and the
    generating configuration is among ours."""
    from eaik.IK_HP import HPRobot

    from derive.ik.srs import srs_geometry
    robot = derive.load_robot("iiwa14")
    geo = srs_geometry(robot)
    # EAIK's H, P form of the chain (axes and offsets at zero, as tests/test_outside_ik.py builds it)
    from derive.model.geometry import numeric_chain
    ch = numeric_chain(robot)
    pts = ch.start + np.vstack([np.zeros(3), np.cumsum(ch.links, axis=0)])
    t0 = reference.fk_matrix(robot, np.zeros(7))
    H = np.array(ch.axes, dtype=float)
    P = np.vstack([pts[0], np.diff(pts[:7], axis=0), t0[:3, 3] - pts[6]])
    r0 = np.eye(4)
    r0[:3, :3] = t0[:3, :3]
    rng = np.random.default_rng(330 + k)
    lim = robot.limits
    value = float(rng.uniform(max(lim[k - 1, 0], -2.5), min(lim[k - 1, 1], 2.5)))
    q = rng.uniform(lim[:, 0], lim[:, 1], (150, 7))
    q[:, k - 1] = value
    T = reference.fk_matrix(robot, q)
    theirs = HPRobot(H, P, fixed_axes=[(k - 1, value)]).IK_batched(T @ np.linalg.inv(r0), 1)
    cq, cc = derive.kernels("iiwa14", "c", free=f"q{k}").ik(reference.fk(robot, q), free=value)
    assert geo.d_se > 0 and cc.min() >= 1
    compared = 0
    for i, sol in enumerate(theirs):
        Q = np.asarray(sol.Q, dtype=float).reshape(-1, 7)[~np.asarray(sol.is_LS, bool).reshape(-1)]
        mine = cq[i, :cc[i]]
        assert len(Q) == len(mine), (k, i, len(Q), len(mine))
        d = _wrapped(mine[:, None, :] - Q[None, :, :]).max(-1)
        assert d.min(1).max() < 1e-6 and d.min(0).max() < 1e-6, (k, i)
        assert _wrapped(mine - q[i]).max(-1).min() < 1e-6
        compared += len(Q)
    assert compared >= 150 * 6


@needs_gcc
@pytest.mark.parametrize("k", [1, 6])
def test_c_program_source_compiles_as_c99_and_cxx17(k, tmp_path):
    """The emitted source (the kernels' template with the header inlined), warnings as errors,
    -Wpedantic, as C99 and C++17."""
    src = tmp_path / f"iiwa14_q{k}.c"
    src.write_text(cfree.c_source("iiwa14", k))
    assert f"iiwa14_free_q{k}_ik_batch_ex(" in src.read_text()
    assert_compiles_strict(src)


def test_programs_are_compositions_of_named_subproblems_and_q3_is_unchanged():
    """Each class route's program names its subproblems in its steps; the joint-3 program is the
    same program as before (srs_joint3_program is srs_joint_program(robot, 3)); joints 4 and 8
    have none."""
    for k, names in ((1, ("subproblem 4", "subproblem 1")), (2, ("subproblem 4", "subproblem 1")),
                     (5, ("subproblem 2",)), (6, ("subproblem 4", "subproblem 1")),
                     (7, ("subproblem 4", "subproblem 1"))):
        prog = program7.srs_joint_program("iiwa14", k)
        patterns = " ".join(p for _, p, _ in prog.steps)
        assert all(n in patterns for n in names), (k, patterns)
        assert prog.free == f"q{k}" and prog.branches == 8
        assert ("reversed" in prog.steps_source) == (k > 4)
    for bad in (4, 8):
        with pytest.raises(derive.DeriveError, match="cannot be given"):
            program7.srs_joint_program("iiwa14", bad)


def test_c_program_sweep_nearest_and_tool_equal_the_numpy_kernels():
    """iiwa14 with q6 given: ik_sweep over q6's range, nearest (q6 chosen for the path) and the IK
    of a tool frame through the C program equal the numpy kernels' (the closed form): the same
    counts, branch ids and values (nearest: the same branches, values within 1e-6, on the pose)."""
    robot = derive.load_robot("iiwa14")
    kc, kn = derive.kernels("iiwa14", "c", free="q6"), derive.kernels("iiwa14", "numpy", free="q6")
    q = np.random.default_rng(340).uniform(robot.limits[:, 0], robot.limits[:, 1], (4, 7))
    poses = kn.fk(q)
    sc, sn = kc.ik_sweep(poses, 6), kn.ik_sweep(poses, 6)
    np.testing.assert_array_equal(sc.counts, sn.counts)
    np.testing.assert_array_equal(sc.branch[..., :8], sn.branch[..., :sc.branch[..., :8].shape[-1]])
    assert sc.counts.sum() > 20 and np.nanmax(_wrapped(sc.q[..., :8, :] - sn.q[..., :8, :])) < 1e-9
    nc, nn = kc.nearest(poses, q + 0.01), kn.nearest(poses, q + 0.01)
    assert np.all(nc.found) and np.all(nc.max_move <= 0.015 + 1e-9)
    np.testing.assert_array_equal(nc.branch, nn.branch)
    # the 1-D search's refinement stops at a tolerance: the q6 chosen agree to about 1e-8
    assert np.abs(nc.q - nn.q).max() < 1e-6
    np.testing.assert_allclose(kc.fk(nc.q), poses, atol=1e-9)
    tool = reference.fk("iiwa14", np.full(7, 0.2))         # any unit pose as a tool
    tc, tn = kc.with_tool(tool), kn.with_tool(tool)
    pt = tn.fk(q)
    s1, c1, b1, _ = tc.ik(pt, free=q[:, 5], details=True)
    s2, c2, b2, _ = tn.ik(pt, free=q[:, 5], details=True)
    np.testing.assert_array_equal(c1, c2)
    np.testing.assert_array_equal(b1[:, :8], b2[:, :8])
    assert np.nanmax(_wrapped(s1[:, :8] - s2[:, :8])) < 1e-9
