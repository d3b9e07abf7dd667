"""The emitted general 6R kernels (derive.codegen.general6r, templates/general6r.c.j2): every
solution of the arms outside the closed-form classes, checked against the numpy reference
(derive.ik.general6r.solve: the same solution sets), the reference FK (each solution within
1e-10), the generating configuration and, for the Fanuc CRX-10iA, ssik's prebuilt solver."""

import importlib.util
import math
import shutil
import subprocess

import numpy as np
import pytest

import derive
from derive import InputError, reference
from derive.algebra.angles import wrap_angle
from derive.codegen.general6r import c_ik_general
from derive.ik import general6r
from derive.kinematics.fk import pose_error
from conftest import assert_compiles_strict

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

ROBOTS = ["crx10ia", "general-6r", "xarm6", "jaco2-6dof"]


@pytest.fixture(scope="module")
def quick_c():
    """The C backend at -O1 for these tests (quicker to compile; the results do not depend on it)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("DQ_DERIVE_CFLAGS", "-std=c99 -O1")
        yield


def _poses(robot, n, seed):
    robot = derive.load_robot(robot)
    lo = np.maximum(robot.limits[:, 0], -math.pi)
    hi = np.minimum(robot.limits[:, 1], math.pi)
    q = np.random.default_rng(seed).uniform(lo, hi, (n, 6))
    return q, reference.fk(robot, q)


def _jacobian_singular_values(pl, q):
    """Singular values (m, 6) of the geometric Jacobian at configurations q (m, 6), from plain 4x4
    matrices of the plan's chain (independent of the kernels)."""
    frames, end = general6r._chain_frames(pl.c, q)
    axes = frames[:, :, :3, 2]
    return np.linalg.svd(np.concatenate([np.cross(axes, end[:, None, :3, 3] - frames[:, :, :3, 3]), axes], 2),
                         compute_uv=False)


def _contains(sols, q, tol=1e-6):
    return len(sols) > 0 and float(np.min(np.max(np.abs(wrap_angle(sols - q)), axis=1))) < tol


def _same_sets(a, na, b, nb, tol=1e-6):
    """Per pose, whether the two solution sets are equal (each member of one within tol of one of
    the other, in every joint)."""
    out = []
    for i in range(len(na)):
        x, y = a[i, :na[i]], b[i, :nb[i]]
        out.append(na[i] == nb[i] and all(_contains(y, s, tol) for s in x) and all(_contains(x, s, tol) for s in y))
    return np.array(out)


@needs_gcc
@pytest.mark.parametrize("robot", ROBOTS)
def test_c_kernels_give_the_reference_solution_sets(robot, quick_c):
    k = derive.kernels(robot, "c")
    assert k.has_ik and k.max_solutions == 16
    q, P = _poses(robot, 120, 31)
    sols, counts = k.ik(P)
    assert sols.shape == (120, 16, 6)
    ref = general6r.solve(robot, P)
    same = _same_sets(sols, counts, ref.q, ref.counts)
    assert same.all(), np.nonzero(~same)[0][:10]
    for i in range(len(q)):
        s = sols[i, :counts[i]]
        assert np.all(np.isfinite(s)) and np.all(np.isnan(sols[i, counts[i]:]))
        assert _contains(s, q[i]), i
        _assert_on_pose(robot, s, P[i])
    # the single-pose call is the batch of one
    s1, c1 = k.ik(P[3])
    assert c1 == counts[3] and np.array_equal(s1[:c1], sols[3, :c1])


@needs_gcc
@pytest.mark.skipif(importlib.util.find_spec("ssik") is None, reason="needs ssik (test extra)")
def test_c_kernels_contain_every_ssik_solution_of_the_crx(quick_c):
    """ssik.prebuilt's CRX-10iA (its FK is ours: tests/test_vendor_arms.py), 100 poses: every
    solution its native solver returns (wrapped to (-pi, pi]) is among ours."""
    m = importlib.import_module("ssik.prebuilt.fanuc.crx10ia_ik")
    k = derive.kernels("crx10ia", "c")
    q, P = _poses("crx10ia", 100, 7)
    sols, counts = k.ik(P)
    total = 0
    for i in range(len(q)):
        theirs = m.solve(reference.fk_matrix("crx10ia", q[i]), native=True)
        total += len(theirs)              # (ssik lists each winding within the limits)
        for s in theirs:
            assert _contains(sols[i, :counts[i]], np.asarray(s.q, float)), (i, s.q)
    assert total >= 400
    assert counts.max() >= 12                       # more than a Pieper arm's 8


@needs_gcc
def test_degenerate_and_singular_poses_give_no_nan(quick_c):
    """Axis-aligned configurations (joint values multiples of pi/2: wrist and elbow singular,
    shared roots, the symmetric CRX pose with a 4-fold q3) and the home pose: counts in 0..16,
    finite solutions that reproduce the pose, NaN only in the padding; the generating
    configuration is found wherever it is regular (not on a singular set, where the solutions
    form a continuum) and the numpy reference finds it."""
    k = derive.kernels("crx10ia", "c")
    grid = np.array(np.meshgrid(*[[0.0, math.pi / 2, -math.pi / 2]] * 4, indexing="ij")).reshape(4, -1).T
    q = np.concatenate([np.zeros((len(grid), 1)), grid[:, :2], grid[:, 2:3], grid[:, 3:4],
                        np.full((len(grid), 1), -math.pi / 2)], axis=1)
    q = np.concatenate([q, [[0.0, math.pi / 2, math.pi / 2, -math.pi / 2, math.pi / 2, -math.pi / 2]]])
    P = reference.fk("crx10ia", q)
    sols, counts = k.ik(P)
    _, _, _, sing = k.ik(P, details=True)
    assert counts.min() >= 0 and counts.max() <= 16
    ref = general6r.solve("crx10ia", P)
    pl = general6r.plan("crx10ia")
    sv = _jacobian_singular_values(pl, q)
    regular = sv[:, -1] > 1e-6 * sv[:, 0]
    assert regular.sum() >= 20
    for i in range(len(q)):
        s = sols[i, :counts[i]]
        assert np.all(np.isfinite(s)) and np.all(np.isnan(sols[i, counts[i]:]))
        assert np.all((sing[i, :counts[i]] == 0) | (sing[i, :counts[i]] == 1))
        if counts[i]:
            dp, dr = pose_error(reference.fk("crx10ia", s), np.broadcast_to(P[i], (len(s), 8)))
            assert dp.max() < 1e-10 and dr.max() < 1e-10
        if regular[i] and _contains(ref.q[i, :ref.counts[i]], q[i]):
            assert _contains(s, q[i]), i      # where the reference finds it, so do the kernels
    # the symmetric pose: four solutions share q3 (Stetter's shift structure separates them)
    last = sols[-1, :counts[-1]]
    assert _contains(last, q[-1])
    assert np.sum(np.abs(wrap_angle(last[:, 2] - q[-1, 2])) < 1e-6) >= 4


@needs_gcc
def test_crx_home_pose_keeps_every_regular_solution(quick_c):
    """`dq-derive ik crx10ia --q 0 0 0 0 0 0`: the numpy reference lists 10 solutions, four regular
    ones and two singular clusters of near-duplicates (within 1.5e-6 rad, which the C merges). The
    C kernels return each regular one (compared modulo 2 pi: the kernels wrap into (-pi, pi], so
    the reference's J1 = J4 = -pi is the kernels' +pi) and a member of each cluster, every one
    within 1e-10 of the pose."""
    k = derive.kernels("crx10ia", "c")
    q = np.zeros((1, 6))
    P = reference.fk("crx10ia", q)
    sols, counts = k.ik(P)
    s = sols[0, :counts[0]]
    ref = general6r.solve("crx10ia", P)
    r = ref.q[0, :ref.counts[0]]
    pl = general6r.plan("crx10ia")
    sv = _jacobian_singular_values(pl, r)
    regular = sv[:, -1] > 1e-6 * sv[:, 0]
    assert regular.sum() == 4 and len(r) >= 8
    for i in np.flatnonzero(regular):
        assert _contains(s, r[i], 1e-9), r[i]
    for i in np.flatnonzero(~regular):
        assert _contains(s, r[i], 1e-5), r[i]
    assert _contains(s, q[0], 1e-5)
    assert any(abs(abs(x[0]) - math.pi) < 1e-9 and abs(x[1] + math.pi / 2) < 1e-9 for x in s)
    dp, dr = pose_error(reference.fk("crx10ia", s), np.broadcast_to(P[0], (len(s), 8)))
    assert dp.max() < 1e-10 and dr.max() < 1e-10


@needs_gcc
def test_bad_input_raises_input_error_and_unreachable_is_empty(quick_c):
    k = derive.kernels("general-6r", "c")
    with pytest.raises(InputError):
        k.ik(np.full(8, np.nan))
    with pytest.raises(InputError):
        k.ik(np.ones(7))
    with pytest.raises(InputError):
        k.ik(2 * np.eye(4))
    far = derive.pose.from_position_quaternion([50.0, 0.0, 0.0], [0, 0, 0, 1], order="xyzw")
    sols, count = k.ik(far)
    assert count == 0 and np.all(np.isnan(sols))


@needs_gcc
def test_nearest_and_details_on_a_general_arm(quick_c):
    k = derive.kernels("general-6r", "c")
    q, P = _poses("general-6r", 20, 3)
    sols, counts, branch, sing = k.ik(P, details=True)
    for i in range(len(q)):
        assert list(branch[i, :counts[i]]) == list(range(counts[i]))
        assert np.all(branch[i, counts[i]:] == -1)
    near = k.nearest(P, q + 1e-4)
    assert near.found.all()
    assert np.abs(near.q - q).max() < 1e-3


@pytest.mark.parametrize("robot", ["crx10ia", "xarm6"])
def test_numpy_and_python_kernels_give_the_reference_solution_sets(robot):
    """The numpy kernels (batched, numpy.linalg) on 60 poses and the pure-Python ones (the C's
    algorithm transliterated, its own Hessenberg-QR eigen-solver) on 6: the reference's solution
    sets, the generating configuration among them."""
    kn = derive.kernels(robot, "numpy")
    kp = derive.kernels(robot, "python")
    assert kn.has_ik and kp.has_ik and kn.max_solutions == kp.max_solutions == 16
    q, P = _poses(robot, 60, 11)
    ref = general6r.solve(robot, P)
    sols, counts = kn.ik(P)
    assert sols.shape == (60, 16, 6)
    assert _same_sets(sols, counts, ref.q, ref.counts).all()
    assert all(_contains(sols[i, :counts[i]], q[i]) for i in range(len(q)))
    sp, cp = kp.ik(P[:6])
    assert _same_sets(sp, cp, ref.q[:6], ref.counts[:6]).all()
    assert all(_contains(sp[i, :cp[i]], q[i]) for i in range(6))
    with pytest.raises(InputError):
        kp.ik(np.full(8, np.inf))


@pytest.mark.parametrize("robot", ROBOTS)
def test_numpy_kernels_with_the_deflation_give_the_reference_solution_sets(robot):
    """The numpy kernels (the deflation baked in: 16 x 16 eigenproblems, a cut arm's spurious
    roots removed) on 200 poses of every general arm: the reference's solution sets, the
    generating configuration among them, every solution within 1e-10 of its pose."""
    kn = derive.kernels(robot, "numpy")
    q, P = _poses(robot, 200, 23)
    ref = general6r.solve(robot, P)
    sols, counts = kn.ik(P)
    assert _same_sets(sols, counts, ref.q, ref.counts).all()
    assert all(_contains(sols[i, :counts[i]], q[i]) for i in range(len(q)))
    ok = ~np.isnan(sols[..., 0])
    dpos, drot = pose_error(reference.fk(robot, sols[ok]), np.repeat(P, counts, axis=0))
    assert dpos.max() < 1e-10 and drot.max() < 1e-10


@needs_gcc
def test_general_c_source_compiles_as_c99_and_cxx17(tmp_path):
    """The emitted source of a standard-elimination arm (reversed chain, xarm6) and of a cut arm
    (crx10ia), warnings as errors, -Wpedantic, as C99 and C++17."""
    from derive.codegen import emit
    for robot in ("crx10ia", "xarm6"):
        files = emit.render_kernels(robot)
        for name, text in files.values():
            (tmp_path / name).write_text(text)
        src = tmp_path / files["c_source"][0]
        assert_compiles_strict(src, robot)


@needs_gcc
def test_c_kernels_are_clean_under_address_and_undefined_sanitizers(tmp_path):
    """The CRX's C source with a driver, built with -fsanitize=address,undefined, on axis-aligned
    configurations (singular, shared roots) and random ones: no invalid access, no undefined
    behaviour, the counts within 0..16 and no NaN before the padding. G6_LOCKSTEP=1: the batch's
    lock-step eigen-solver on every group of poses (g6_eigenvalues_lanes)."""
    from derive.codegen import emit
    files = emit.render_kernels("crx10ia")
    for name, text in files.values():
        (tmp_path / name).write_text(text)
    grid = np.array(np.meshgrid(*[[0.0, math.pi / 2, -math.pi / 2, math.pi]] * 3, indexing="ij")).reshape(3, -1).T
    q = np.concatenate([np.zeros((len(grid), 2)), grid, np.full((len(grid), 1), math.pi / 2)], axis=1)
    q = np.concatenate([q, np.random.default_rng(4).uniform(-math.pi, math.pi, (16, 6))])
    P = reference.fk("crx10ia", q)
    rows = ",\n".join("{" + ", ".join(repr(float(v)) for v in p) + "}" for p in P)
    (tmp_path / "main.c").write_text(f"""#include <math.h>
#include <stdio.h>
#include "crx10ia_kinematics.h"
static const double poses[{len(P)}][8] = {{{rows}}};
int main(void) {{
    static double sols[{len(P)} * CRX10IA_IK_MAX * 6];
    static int counts[{len(P)}], branch[{len(P)} * CRX10IA_IK_MAX], singular[{len(P)} * CRX10IA_IK_MAX];
    crx10ia_ik_batch_ex({len(P)}, &poses[0][0], sols, counts, branch, singular);
    int bad = 0;
    for (int i = 0; i < {len(P)}; ++i) {{
        bad += counts[i] < 0 || counts[i] > CRX10IA_IK_MAX;
        for (int k = 0; k < counts[i] * 6; ++k) bad += !isfinite(sols[i * CRX10IA_IK_MAX * 6 + k]);
    }}
    printf("%d\\n", bad);
    return 0;
}}
""")
    res = subprocess.run(["gcc", "-std=c99", "-O1", "-DG6_LOCKSTEP=1", "-Wall", "-Wextra", "-Werror", "-fsanitize=address,undefined",
                          "-fno-sanitize-recover=all", "-o", str(tmp_path / "t"), str(tmp_path / "main.c"),
                          str(tmp_path / "crx10ia_kinematics.c"), "-lm"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    run = subprocess.run([str(tmp_path / "t")], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.split() == ["0"]


@needs_gcc
def test_general_bench_reports_the_one_call_latency(quick_c):
    """`dq-derive bench kernels` of a general arm (derive.bench.general6r): beside the batch
    figures, the one-call latency (k.ik(pose) from Python) of the C and numpy kernels; the C
    batch's solution count is the kernels' own on the same poses. (Times are not asserted:
    only that each was measured.)"""
    from derive.bench.general6r import bench_general, general_report
    r = bench_general("general-6r", n=8, repeats=1, n_peer=2, n_single=4)
    for part in ("c", "numpy", "reference"):
        assert 0 < r[part]["ik_batch_us"] < math.inf
    for part in ("c", "numpy"):
        assert 0 < r[part]["ik_single_us"] < math.inf and r[part]["n_single"] >= 1
    q, P = _poses("general-6r", 8, 0)
    assert r["c"]["mean_count"] == pytest.approx(derive.kernels("general-6r", "c").ik(P)[1].mean())
    text = general_report(r)
    assert "C one call" in text and "numpy one call" in text and "ssik" not in text


def test_numpy_kernels_flag_and_fall_back_as_the_reference_on_axis_aligned_crx_poses():
    """The numpy kernels' flags (ik_general: singular per solution, degenerate per pose) follow
    the reference's rules (derive.ik.general6r.solve): a pose with a near-singular solution (below
    G6_NEAR_SINGULAR) goes through the nearby-pose fallback, and stays degenerate with a
    near-singular or singular solution, a pencil singular for every q3 or an odd count. On 150
    axis-aligned CRX configurations (most on the singular set: merged solutions, continua) the
    kernels flag exactly the poses the reference flags; every pose whose set differs from the
    reference's is flagged; every regular configuration is found, every singular one found to the
    accuracy of a singular solution (1e-4) or flagged; a solution's singular flag is its
    Jacobian's (on plain 4x4 matrices: smallest over largest singular value below 1e-8, outside a
    factor 10 either side: a singular solution is fixed only to about 1e-5, so many fall between). (Before these rules the kernels flagged 20 of these poses, the
    reference 132.)"""
    robot = derive.load_robot("crx10ia")
    q, P = _axis_aligned(robot, 150, 31)
    ref = general6r.solve(robot, P)
    sols, counts, sing, degen = derive.kernels(robot, "numpy")._mod.ik_general(P)
    # the singular set, on plain 4x4 matrices: the geometric Jacobian's relative smallest singular value
    pl = general6r.plan(robot, progress=False)
    sv = _jacobian_singular_values(pl, q)
    regular = sv[:, -1] > 1e-8 * sv[:, 0]
    assert 30 <= regular.sum() <= 120
    ok = ~np.isnan(sols[..., 0])
    svs = _jacobian_singular_values(pl, sols[ok])
    ratio = svs[:, -1] / svs[:, 0]
    clear = (ratio < 1e-9) | (ratio > 1e-7)
    assert np.array_equal(sing[ok][clear], ratio[clear] < 1e-8) and clear.sum() >= 0.5 * ok.sum()
    assert sing.sum() >= 100 and (~sing[ok]).sum() >= 500
    assert np.array_equal(degen, ref.degenerate)
    assert degen.sum() >= 100 and not degen[regular & (counts % 2 == 0)].all()
    same = _same_sets(sols, counts, ref.q, ref.counts)
    assert same.sum() >= 50 and degen[~same].all()
    for i in range(len(q)):
        s = sols[i, :counts[i]]
        _assert_on_pose(robot, s, P[i])
        if regular[i]:
            assert _contains(s, q[i]), i
        else:
            assert degen[i] or _contains(s, q[i], 1e-4), i
    # the double root and the continua of test_general6r_arms (CRX_FOLD, CRX_CONTINUUM): flagged,
    # the double root's configuration found to the accuracy of a double root
    fold = np.array([[2, 1, 2, 1, 2, 1], [-1, -1, -1, 1, -1, 1], [1, 1, -1, 1, -1, 1], [2, -1, -1, 1, 0, 2],
                     [2, 1, -1, 1, 2, 1]]) * (math.pi / 2)
    sols, counts, sing, degen = derive.kernels(robot, "numpy")._mod.ik_general(reference.fk(robot, fold))
    assert degen.all() and _contains(sols[0, :counts[0]], fold[0], 1e-5)


def test_numpy_kernels_flag_every_pose_whose_set_differs_on_axis_aligned_xarm6_poses():
    """300 axis-aligned xArm6 configurations (joints in multiples of pi/2; some poses have
    solutions near a fold, where two or four roots of the eigen-variable lie within 1e-4 and
    their null vectors are nearly parallel): wherever the numpy kernels' set differs from the
    reference's, the pose is flagged degenerate. The near pairs' extra candidates (_near_pairs,
    as the reference's _near_pair_candidates) make that hold: without them three poses lost two
    solutions each with an even count and no flag (10 solutions, the reference 12)."""
    robot = derive.load_robot("xarm6")
    q, P = _axis_aligned(robot, 300, 5)
    ref = general6r.solve(robot, P)
    sols, counts, sing, degen = derive.kernels(robot, "numpy")._mod.ik_general(P)
    same = _same_sets(sols, counts, ref.q, ref.counts)
    assert same.sum() >= 240 and degen[~same].all(), np.nonzero(~same & ~degen)[0]
    assert counts.sum() >= 2600
    for i in range(len(q)):
        s = sols[i, :counts[i]]
        _assert_on_pose(robot, s, P[i])
        if _contains(ref.q[i, :ref.counts[i]], q[i]) and not degen[i]:
            assert _contains(s, q[i]), i


def _assert_on_pose(robot, s, pose):
    """Every solution of s (k, 6) on the pose: position and rotation error of the reference FK
    below 1e-10."""
    if len(s):
        dp, dr = pose_error(reference.fk(robot, s), np.broadcast_to(pose, (len(s), 8)))
        assert dp.max() < 1e-10 and dr.max() < 1e-10


def _c_general(robot, P):
    """The C kernels' whole answer (solutions, counts, singular and degenerate flags; k.ik gives
    no degenerate flag)."""
    return c_ik_general(derive.kernels(robot, "c"), P)


def _axis_aligned(robot, n, seed):
    vals = np.array([-math.pi / 2, 0.0, math.pi / 2, math.pi])
    q = vals[np.random.default_rng(seed).integers(0, 4, (n, 6))]
    return q, reference.fk(robot, q)


@needs_gcc
def test_c_kernels_flag_and_fall_back_as_the_reference_on_axis_aligned_crx_poses(quick_c):
    """The C kernels' flags (g6_solve: singular per solution, degenerate per pose) follow the
    reference's rules (derive.ik.general6r.solve), as the numpy kernels' do: a pose with a
    near-singular solution goes through the nearby poses and stays degenerate with a
    near-singular or singular solution, a pencil singular for every q3 or an odd count. On the
    150 axis-aligned CRX configurations of the numpy test the C flags exactly the poses the
    reference flags and every pose whose
    set differs from the reference's; the regular configurations are found; every solution
    reproduces the pose; a singular flag is set only where the Jacobian (plain 4x4 matrices) is
    near-singular (relative smallest singular value below 1e-6)."""
    robot = derive.load_robot("crx10ia")
    q, P = _axis_aligned(robot, 150, 31)
    ref = general6r.solve(robot, P)
    sols, counts, sing, degen = _c_general(robot, P)
    pl = general6r.plan(robot, progress=False)
    sv = _jacobian_singular_values(pl, q)
    regular = sv[:, -1] > 1e-8 * sv[:, 0]
    assert 30 <= regular.sum() <= 120
    assert np.array_equal(degen, ref.degenerate) and degen.sum() >= 100
    same = _same_sets(sols, counts, ref.q, ref.counts)
    assert same.sum() >= 50 and degen[~same].all()
    ok = ~np.isnan(sols[..., 0])
    assert not np.any(sing[~ok]) and sing.sum() >= 50
    svs = _jacobian_singular_values(pl, sols[ok])
    assert np.all(svs[sing[ok], -1] < 1e-6 * svs[sing[ok], 0])
    for i in range(len(q)):
        s = sols[i, :counts[i]]
        _assert_on_pose(robot, s, P[i])
        if regular[i]:
            assert _contains(s, q[i]), i


@needs_gcc
def test_c_kernels_flag_every_pose_whose_set_differs_on_axis_aligned_xarm6_poses(quick_c):
    """The 300 axis-aligned xArm6 configurations of the numpy test (some poses have two or four
    roots of the eigen-variable within 1e-4, their null vectors nearly parallel): the near pairs'
    and near chains' extra candidates (g6_near_pairs) find the solutions the single null vectors
    miss. Before them three poses had 10 solutions, the reference 12, unflagged; now every pose
    whose set differs from the reference's is flagged degenerate or holds the reference's whole
    set (a superset: every solution reproduces the pose to 1e-10; one pose, where the reference
    has 7, flagged by its odd count), and the flags differ from the reference's on few poses."""
    robot = derive.load_robot("xarm6")
    q, P = _axis_aligned(robot, 300, 5)
    ref = general6r.solve(robot, P)
    sols, counts, sing, degen = _c_general(robot, P)
    same = _same_sets(sols, counts, ref.q, ref.counts)
    superset = np.array([counts[i] > ref.counts[i] and all(_contains(sols[i, :counts[i]], s)
                                                          for s in ref.q[i, :ref.counts[i]]) for i in range(len(q))])
    assert same.sum() >= 250 and (degen | superset)[~same].all(), np.nonzero(~same & ~degen & ~superset)[0]
    assert counts.sum() >= 2630 and np.sum(degen != ref.degenerate) <= 4
    for i in range(len(q)):
        s = sols[i, :counts[i]]
        _assert_on_pose(robot, s, P[i])
        if _contains(ref.q[i, :ref.counts[i]], q[i]) and not degen[i]:
            assert _contains(s, q[i]), i


def test_python_kernels_flag_as_the_reference_on_axis_aligned_poses():
    """The pure-Python kernels (ik_general: the C's g6_solve transliterated) with the same flag
    rules and near-pair candidates as the C: on 10 of the axis-aligned CRX configurations above
    (6 of them degenerate for the reference, 3 with singular solutions) the
    degenerate flags equal the reference's and every pose whose set differs is flagged; on the
    three xArm6 poses where two solutions were lost without a flag (10 solutions, the reference
    12) and three more, every set equals the reference's or is flagged, or holds it whole (pose
    58: 8 solutions, each reproducing the pose, where the reference finds 7 and flags it)."""
    for name, n, seed, pick in (("crx10ia", 150, 31, list(range(10))), ("xarm6", 300, 5, [229, 253, 299, 58, 147, 73])):
        robot = derive.load_robot(name)
        q, P = _axis_aligned(robot, n, seed)
        q, P = q[pick], P[pick]
        ref = general6r.solve(robot, P)
        mod = derive.kernels(robot, "python")._mod
        for i in range(len(P)):
            sols, sing, degen = mod.ik_general(tuple(P[i]))
            s = np.array(sols).reshape(-1, 6)
            _assert_on_pose(robot, s, P[i])
            same = _same_sets(s[None], [len(s)], ref.q[i:i + 1], ref.counts[i:i + 1])[0]
            whole = len(s) > ref.counts[i] and all(_contains(s, r) for r in ref.q[i, :ref.counts[i]])
            assert same or degen or whole, (name, pick[i])
            if name == "crx10ia":
                assert bool(degen) == ref.degenerate[i], pick[i]
            else:
                assert len(s) >= ref.counts[i]


@needs_gcc
def test_kernels_find_every_solution_at_regular_axis_aligned_xarm6_configurations(quick_c):
    """Regular axis-aligned xArm6 configurations (quarter turns) where four roots of the
    eigen-variable fall within 1e-6 (a cluster with fewer null directions than members) or 1e-4:
    12, 12, 8 and 8 solutions (the counts of the multi-starts of test_general6r_arms, on the
    plain 4x4-matrix FK and on the product-form chain). The C, numpy and pure-Python kernels take
    the run as one near chain (its s-dimensional near-null space) and return every solution, the
    reference's set, unflagged; before, the numpy kernels lost two at each and the C at the two
    of 8 solutions, with an even count and no flag."""
    robot = derive.load_robot("xarm6")
    q = np.array([[-1, 1, 0, 0, 2, 0], [1, 1, 0, 0, 2, 1], [0, 0, -1, 0, 2, 0], [2, 0, -1, 0, 2, 2]]) * (math.pi / 2)
    expected = np.array([12, 12, 8, 8])
    P = reference.fk(robot, q)
    ref = general6r.solve(robot, P)
    assert np.array_equal(ref.counts, expected) and not ref.degenerate.any()
    py = derive.kernels(robot, "python")._mod
    answers = {"c": _c_general(robot, P), "numpy": derive.kernels(robot, "numpy")._mod.ik_general(P)}
    rows = [py.ik_general(tuple(p)) for p in P]
    s = np.full((len(P), 16, 6), np.nan)
    for i, (sols, _, _) in enumerate(rows):
        s[i, :len(sols)] = np.array(sols).reshape(-1, 6)
    answers["python"] = (s, np.array([len(r[0]) for r in rows]), None, np.array([bool(r[2]) for r in rows]))
    for name, (sols, counts, _, degen) in answers.items():
        assert np.array_equal(counts, expected) and not degen.any(), name
        assert _same_sets(sols, counts, ref.q, ref.counts).all(), name
        for i in range(len(q)):
            dp, dr = pose_error(reference.fk(robot, sols[i, :counts[i]]), np.broadcast_to(P[i], (counts[i], 8)))
            assert dp.max() < 1e-10 and dr.max() < 1e-10 and _contains(sols[i, :counts[i]], q[i]), (name, i)
