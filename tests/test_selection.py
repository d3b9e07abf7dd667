"""Choosing among IK solutions and the low-overhead C path (issue: IK that picks a solution):
within_limits against a brute-force enumeration, nearest with noisy seeds and along a
trajectory, branch ids stable along a path, single and batch calls bit for bit, the tool
offset at run time, pose forms, and the input contract of the C extension."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import derive
from derive import InputError, dualquat, reference
from derive.codegen.loader import Kernels, kernels

SEED = 16


def _wrapped(a):
    return np.abs(np.mod(a + math.pi, 2 * math.pi) - math.pi)


def _brute(sols, count, limits):
    """Every in-limit value q + 2 pi k (|k| <= 3) of each solution: the distinct rows, sorted."""
    out = []
    for s in sols[:count]:
        per = []
        for j, (lo, hi) in enumerate(limits):
            vals = [s[j] + 2 * math.pi * k for k in range(-3, 4)]
            per.append([v for v in vals if lo - 1e-12 <= v <= hi + 1e-12])
        out += list(itertools.product(*per))
    return np.unique(np.round(np.array(out).reshape(-1, len(limits)), 9), axis=0)


@pytest.mark.parametrize("robot", ["ur5", "kr6-r900", "irb120"])
def test_within_limits_equals_brute_force(robot):
    """ur5 (+-2 pi), kr6-r900 (narrow limits: -190..45 deg on A2, +-120 deg on A5, ...) and
    irb120 (narrow, but +-400 deg on axis 6)."""
    r = derive.load_robot(robot)
    k = kernels(r, "c")
    rng = np.random.default_rng(SEED)
    lo, hi = (np.clip(np.array(v), -math.pi, math.pi) for v in zip(*r.limits))
    q = rng.uniform(lo, hi, size=(1000, 6))
    poses = reference.fk(r, q)
    sols, counts = k.ik(poses)
    wl, wc, wb, ws = k.ik(poses, within_limits=True, details=True)
    assert wl.shape[0] == 1000 and np.all(np.isnan(wl[np.arange(wl.shape[1])[None] >= wc[:, None]]))
    for i in range(1000):
        want = _brute(sols[i], counts[i], r.limits)
        got = np.unique(np.round(wl[i, :wc[i]], 9), axis=0)
        assert got.shape == want.shape and np.array_equal(got, want), (robot, i)
        assert len(got) == wc[i]                       # no solution listed twice
        assert np.all(wb[i, :wc[i]] >= 0)
    if robot == "ur5":            # +-2 pi: two values per joint for almost every angle
        assert np.median(wc / np.maximum(counts, 1)) == 64


@pytest.mark.parametrize("robot", ["ur5", "kr6-r900"])
def test_nearest_returns_the_generating_configuration_from_a_noisy_seed(robot):
    k = kernels(robot, "c")
    r = derive.load_robot(robot)
    rng = np.random.default_rng(SEED + 1)
    lo, hi = (np.array(v) for v in zip(*r.limits))
    q = rng.uniform(np.maximum(lo, -math.pi) + 0.06, np.minimum(hi, math.pi) - 0.06, size=(1000, 6))
    poses = reference.fk(robot, q)
    seed = q + rng.uniform(-0.05, 0.05, size=q.shape)
    res = k.nearest(poses, seed)
    assert np.all(res.found)
    # where another solution is within 0.1 rad of the generating one (near a singular set) it can
    # be the nearer to the seed: there "nearest" is the right answer and not the generating one
    sols, counts = k.ik(poses)
    gap = np.abs(sols - q[:, None, :]).max(axis=-1)
    others = np.sort(np.where(np.isnan(gap), np.inf, gap), axis=1)[:, 1]
    clear = others > 0.1
    assert clear.sum() >= 950
    assert np.abs(res.q - q)[clear].max() < 1e-8
    assert np.all(res.max_move <= np.abs(q - seed).max(axis=1) + 1e-12)
    assert np.allclose(res.max_move[clear], np.abs(q - seed).max(axis=1)[clear], atol=1e-8)
    assert np.allclose(res.total_move[clear], np.abs(q - seed).sum(axis=1)[clear], atol=1e-7)
    tight = k.nearest(poses, seed, tol=0.01)
    assert np.array_equal(tight.found, res.max_move <= 0.01) and np.all(np.isnan(tight.q[~tight.found]))


@pytest.mark.parametrize("robot", ["ur5", "kr6-r900", "irb120"])
def test_nearest_in_c_equals_the_numpy_rule(robot):
    """The kernel's one-pass nearest (IK, duplicates, windings clamped to the limits, all in C)
    against derive.ik.select.nearest (numpy, three windings per joint) on the merged solutions
    of k.ik: the same choice (branch), the same joints and moves, on 2000 poses with seeds
    anywhere in the limits (windings other than the nearest are often needed there), with
    singular poses among them (theta5 = 0, and joint 5 at 0 for the OPW arms)."""
    from derive.ik import select
    k = kernels(robot, "c")
    r = derive.load_robot(robot)
    rng = np.random.default_rng(SEED + 5)
    lo, hi = (np.array(v) for v in zip(*r.limits))
    q = rng.uniform(np.maximum(lo, -math.pi), np.minimum(hi, math.pi), size=(2000, 6))
    q[:200, 4] = 0.0
    seeds = rng.uniform(np.maximum(lo, -2 * math.pi), np.minimum(hi, 2 * math.pi), size=q.shape)
    poses = reference.fk(r, q)
    gq, gmx, gtt, gbr, gsg = k._ext.nearest(poses, seeds)     # the C pass itself (k.nearest then
    sols, counts, branch, sing = k.ik(poses, details=True)    # re-solves singular choices)
    want = select.nearest(sols, counts, seeds, r.limits, r.revolute, branch, sing)
    f = gbr >= 0
    assert np.array_equal(f, want.found) and f.sum() > 1500
    assert np.allclose(gmx[f], want.max_move[f], atol=1e-12)
    assert np.allclose(gtt[f], want.total_move[f], atol=1e-12)
    # the same choice, except at exact ties: two solutions of an elbow pair whose moves of joints
    # 2-4 have one sign have the same summed move (theta2 + theta3 + theta4 is common to both),
    # and then the last bit of the two sums decides
    same = gbr == want.branch
    assert (~same).sum() <= 10, np.nonzero(~same)
    assert np.abs(gq[same & f] - want.q[same & f]).max() < 1e-12
    assert np.array_equal(gsg[same & f] != 0, want.singular[same & f]) and want.singular.sum() > 50
    for i in np.nonzero(~same)[0]:           # a tie: the C choice is another solution, as near
        row = np.nonzero(branch[i] == gbr[i])[0]
        assert len(row) == 1
        assert np.abs(_wrapped(gq[i] - sols[i, row[0]])).max() < 1e-12
    assert np.all(np.isnan(gq[~f])) and np.all(np.isnan(gmx[~f]))
    for i in range(0, 2000, 97):                             # single = batch, bit for bit
        one = k._ext.nearest(poses[i], seeds[i])
        assert one[3] == gbr[i] and np.array_equal(one[0], gq[i], equal_nan=True)
        assert one[1] == gmx[i] or (np.isnan(one[1]) and np.isnan(gmx[i]))


@pytest.mark.parametrize("robot", ["ur5", "irb120"])
def test_nearest_along_a_trajectory_keeps_the_generating_branch(robot):
    """A smooth random trajectory of 1000 steps that stays away from the singular sets (every
    other solution at least 0.2 rad from the generating one, so the branch is well defined):
    nearest, seeded with the previous step's choice, follows the generating configuration and
    its branch index never changes."""
    k = kernels(robot, "c")
    r = derive.load_robot(robot)
    lo, hi = (np.clip(np.array(v), -math.pi, math.pi) for v in zip(*r.limits))
    rng = np.random.default_rng(SEED + 2)
    t = np.linspace(0, 1, 1000)[:, None]
    for _ in range(100):
        a = rng.uniform(lo + 0.6, hi - 0.6, size=(1, 6))
        b, c = rng.uniform(-0.4, 0.4, size=(2, 1, 6))
        q = a + b * np.sin(3 * t) + c * t * t
        poses = reference.fk(robot, q)
        sols, counts = k.ik(poses)
        gap = np.abs(_wrapped(sols - q[:, None, :])).max(axis=-1)
        others = np.sort(np.where(np.isnan(gap), np.inf, gap), axis=1)[:, 1]
        if others.min() > 0.2:
            break
    else:
        pytest.fail("no trajectory away from the singular sets")
    seed = q[0]
    branches = []
    for i in range(len(q)):
        res = k.nearest(poses[i], seed)
        assert res.found and np.abs(res.q - q[i]).max() < 1e-8, i
        branches.append(int(res.branch))
        seed = res.q
    assert len(set(branches)) == 1


@pytest.mark.parametrize("robot", ["ur5", "kr6-r900"])
def test_single_and_batch_calls_agree_bit_for_bit(robot):
    k = kernels(robot, "c")
    rng = np.random.default_rng(SEED + 3)
    q = rng.uniform(-3, 3, size=(500, 6))
    poses = reference.fk(robot, q)
    F = k.fk(q)
    S, C, B, G = k.ik(poses, details=True)
    for i in range(500):
        assert np.array_equal(k.fk(q[i]), F[i])
        s, c, b, g = k.ik(poses[i], details=True)
        assert c == C[i] and np.array_equal(s, S[i], equal_nan=True)
        assert np.array_equal(b, B[i]) and np.array_equal(g, G[i])
        s2, c2 = k.ik(list(poses[i]))
        assert c2 == C[i] and np.array_equal(s2, S[i], equal_nan=True)


def test_bound_fk_and_ik_are_the_methods_without_a_python_frame():
    """With the extension, k.fk / k.ik are bound C callables (Kernels._bind): each call, plain or
    not, gives what the method gives, bit for bit, also with a tool set at run time, and the same
    errors; calls they do not take themselves (keywords, matrices) reach the method."""
    k = kernels("ur5", "c")
    assert type(k.ik).__name__ == "builtin_function_or_method" and k.ik is not Kernels.ik.__get__(k)
    tool = derive.dualquat.from_rt(derive.quaternion.from_axis_angle([1, 0, 0], 0.4), [0.0, 0.03, 0.1])
    rng = np.random.default_rng(SEED + 9)
    q = rng.uniform(-3, 3, size=(40, 6))
    for kk in (k, k.with_tool(tool), k.with_tool(tool).with_tool(None)):
        fk_m, ik_m = Kernels.fk.__get__(kk), Kernels.ik.__get__(kk)
        for i in range(40):
            f = kk.fk(q[i])
            assert np.array_equal(f, fk_m(q[i])) and np.array_equal(kk.fk(Q=q[i]), f)
            s, c = kk.ik(f)
            s_m, c_m = ik_m(f)
            assert c == c_m and type(c) is type(c_m) and np.array_equal(s, s_m, equal_nan=True)
            assert c >= 1 and np.abs(_wrapped(s[:c] - q[i])).max(axis=1).min() < 1e-9
            s_k, c_k = kk.ik(f, within_limits=False, details=False)
            assert c_k == c and np.array_equal(s_k, s, equal_nan=True)
            s_d, c_d, _, _ = kk.ik(f, details=True)                      # to the method
            assert c_d == c and np.array_equal(s_d, s, equal_nan=True)
            m = dualquat.to_matrix(f)                                    # NotImplemented in C
            s_x, c_x = kk.ik(m)
            assert c_x == c and np.allclose(s_x[:c], s[:c], atol=1e-9)
    assert np.array_equal(k.with_tool(tool).fk(q[0]), dualquat._mul(k.fk(q[0])[None], tool[None])[0])
    for bad, match in (([1, 2], "got shape"), (np.ones(8), "not a unit dual quaternion")):
        with pytest.raises(InputError, match=match):
            k.ik(bad)
        with pytest.raises(InputError, match=match):
            Kernels.ik(k, bad)
    with pytest.raises(InputError, match="no free parameter"):
        k.ik(k.fk(q[0]), free=0.1)
    with pytest.raises(TypeError):
        k.ik()
    with pytest.raises(InputError, match="Q: contains NaN"):
        k.fk([0, 0, float("nan"), 0, 0, 0])
    p = kernels("panda", "c")
    qp = np.array([0.1, 0.2, 0.3, -1.2, 0.1, 1.0, 0.4])
    fp = p.fk(qp)
    s, c = p.ik(fp, free=0.4)
    s_m, c_m = Kernels.ik(p, fp, free=0.4)
    assert c == c_m >= 1 and np.array_equal(s, s_m, equal_nan=True)
    with pytest.raises(InputError, match="needs free="):
        p.ik(fp)


def test_branch_ids_are_stable_and_singular_flags_set():
    k = kernels("ur5", "c")
    assert k.branch_labels == ["theta1", "theta5 sign", "theta3"]
    assert kernels("irb120", "c").branch_labels == ["theta1, shoulder", "theta3, elbow", "theta5, wrist"]
    rng = np.random.default_rng(SEED + 4)
    q = rng.uniform(-3, 3, size=(200, 6))
    q[:50, 4] = 0.0
    poses = reference.fk("ur5", q)
    S, C, B, G = k.ik(poses, details=True)
    assert np.all(G[:50].sum(axis=1) >= 1) and not G[50:].any()
    # the same root, perturbed pose: the same branch index keeps the solution continuous
    P2 = reference.fk("ur5", q[50:] + 1e-6)
    S2, C2, B2, _ = k.ik(P2, details=True)
    for i in range(150):
        for j in range(C[50 + i]):
            jj = list(B2[i, :C2[i]]).index(B[50 + i, j])
            assert _wrapped(S2[i, jj] - S[50 + i, j]).max() < 1e-4


def test_tool_offset_at_run_time():
    tool = derive.dualquat.from_rt(derive.quaternion.from_axis_angle([0, 1, 0], 0.3), [0.01, 0.02, 0.15])
    for robot, backend in (("ur5", "c"), ("ur5", "numpy"), ("irb120", "c")):
        k = kernels(robot, backend)
        kt = k.with_tool(tool)
        q = np.random.default_rng(SEED + 5).uniform(-3, 3, size=(300, 6))
        want = derive.dualquat.mul(reference.fk(robot, q), tool)
        got = kt.fk(q)
        sign = np.sign(np.sum(got[:, :4] * want[:, :4], axis=1))[:, None]
        assert np.abs(got * sign - want).max() < 1e-14
        sols, counts = kt.ik(want)
        rows, cols = np.nonzero(np.arange(8)[None] < counts[:, None])
        dp, dr = reference.pose_error(kt.fk(sols[rows, cols]), want[rows])
        assert dp.max() < 1e-10 and dr.max() < 1e-10
        assert np.all(counts == k.ik(reference.fk(robot, q))[1])
    assert np.array_equal(k.with_tool(None).fk(q), k.fk(q))


def test_pose_forms_agree():
    pose = derive.pose
    q = np.array([0.3, -1.1, 1.4, -0.2, 1.2, 0.5])
    P = reference.fk("ur5", q)
    M = reference.fk_matrix("ur5", q)
    t, qx = pose.to_position_quaternion(P, "xyzw")
    t2, qw = pose.to_position_quaternion(P, "wxyz")
    assert np.allclose(qx[[3, 0, 1, 2]], qw) and np.allclose(t, M[:3, 3])
    forms = [P, M, (M[:3, :3], M[:3, 3]), pose.from_position_quaternion(t, qx, "xyzw"),
             pose.from_position_quaternion(t2, qw, "wxyz")]
    scipy = pytest.importorskip("scipy.spatial.transform")
    rot, tt = pose.to_scipy(P)
    assert np.allclose(rot.as_matrix(), M[:3, :3])
    forms += [(rot, tt), pose.from_scipy(scipy.Rotation.from_matrix(M[:3, :3]), M[:3, 3])]
    k = kernels("ur5", "c")
    ref = k.ik(P)
    for f in forms:
        d = pose.as_pose(f)
        assert derive.dualquat.equal_pose(d, P)
        s, c = k.ik(d)
        assert c == ref[1] and np.allclose(s[:c], ref[0][:c], atol=1e-12)
    with pytest.raises(InputError, match="order"):
        pose.from_position_quaternion(t, qx, "zyxw")
    with pytest.raises(InputError, match="not unit"):
        pose.from_position_quaternion(t, 2 * qx, "xyzw")


def test_c_extension_input_contract():
    k = kernels("ur5", "c")
    assert k._ext is not None, "the CPython extension did not build"
    q = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    for bad, msg in ((q[:5] + [True], "bool"), (q[:5] + [1j], "complex"), (q[:5] + ["1"], "str"),
                     (q[:5] + [1e17], "accuracy range"), (q[:5] + [float("nan")], "NaN"),
                     (q[:5] + [float("inf")], "inf"), (q[:5], "expected shape"),
                     (np.array(q, dtype=complex), "dtype")):
        with pytest.raises(InputError, match=msg):
            k.fk(bad)
    P = reference.fk("ur5", q)
    with pytest.raises(InputError, match="not a unit dual quaternion"):
        k.ik(0.9 * P)
    off = P.copy()
    off[4:] += 0.01 * P[:4]
    with pytest.raises(InputError, match="<real, dual>"):
        k.ik(off)
    s, c = k.ik(P * (1 + 1e-9))           # within 1e-6 of unit: normalised
    assert c >= 1
    with pytest.raises(InputError, match="q_seed"):
        k.nearest(P, q[:5])
    with pytest.raises(InputError, match="q_seed"):
        k.nearest(P, q[:5] + [True])
    with pytest.raises(InputError, match="q_seed"):
        k.nearest(P, q[:5] + [float("nan")])
    with pytest.raises(InputError, match="tol"):
        k.nearest(P, q, tol=float("nan"))
    with pytest.raises(InputError, match="not a unit dual quaternion"):
        k.nearest(0.9 * P, q)


def test_docs_example_runs():
    """docs/examples/select_and_tool.py, the documented example of selection and tool offsets."""
    import runpy
    from pathlib import Path
    path = Path(__file__).resolve().parent.parent / "docs" / "examples" / "select_and_tool.py"
    runpy.run_path(str(path), run_name="__main__")
