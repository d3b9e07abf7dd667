"""The three-parallel class with axes 5 and 6 not meeting (IK-Geo's "three parallel" with
subproblem 6, derive.ik.parallel3.solve_batch_sp6) on a test arm of that layout
(tests/data/ur5-wrist-offset.yaml: the UR5 with a5 = 0.05 m): its file against EAIK's DH model,
its classification, and the numpy reference's solution sets against EAIK's solver (family
6R-THREE_INNER_PARALLEL); its kernels (C, numpy, pure Python: the IK program of
derive.ik.program_parallel3.parallel3_sp6_program) against the reference branch by branch, EAIK
and ssik, and the root finder of the program's roots4 line in each printed language."""

import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from eaik.IK_DH import DhRobot    # EAIK is in the test extra: a missing one fails

import derive
from derive import dualquat as DQ
from derive import reference
from derive.errors import DeriveError
from derive.ik import classes, parallel3
from derive.ik.program import ik_program
from derive.ik.subproblems._common import _trig_roots

HERE = Path(__file__).resolve().parent
ARM = str(HERE / "data" / "ur5-wrist-offset.yaml")
N_POSES = 300
#: the arm's standard DH table as EAIK takes it (alpha, a, d), written here from the file's numbers
ALPHA = np.array([math.pi / 2, 0, 0, math.pi / 2, -math.pi / 2, 0])
A = np.array([0, -0.425, -0.39225, 0, 0.05, 0])
D = np.array([0.089159, 0, 0, 0.10915, 0.09465, 0.0823])


@pytest.fixture(scope="module")
def arm():
    return derive.load_robot(ARM)


@pytest.fixture(scope="module")
def eaik():
    return DhRobot(ALPHA, A, D)


@pytest.fixture(scope="module")
def poses(arm):
    rng = np.random.default_rng(20261205)
    q = rng.uniform(-math.pi, math.pi, size=(N_POSES, 6))
    return q, reference.fk(arm, q)


def _wrapped(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + math.pi) % (2 * math.pi) - math.pi)


def _same_set(a, b, tol) -> bool:
    a, b = np.asarray(a).reshape(-1, 6), np.asarray(b).reshape(-1, 6)
    if len(a) != len(b):
        return False
    return all(_wrapped(x, b).max(-1).min() < tol for x in a) and \
        all(_wrapped(y, a).max(-1).min() < tol for y in b)


def _eaik_exact(eaik, m, fk_tol=1e-8, merge=1e-6):
    """EAIK's solutions whose FK (EAIK's own) is within fk_tol of the matrix m, duplicates merged.
    EAIK flags some exact solutions least-squares (its sp6 threshold), so the FK decides here."""
    out = []
    for q in eaik.IK(m).Q:
        if np.abs(eaik.fwdKin(q) - m).max() < fk_tol and all(_wrapped(q, o).max() > merge for o in out):
            out.append(q)
    return np.array(out).reshape(-1, 6)


def test_file_is_the_dh_table_eaik_takes(arm, eaik):
    q = np.random.default_rng(1).uniform(-math.pi, math.pi, size=(200, 6))
    ours = reference.fk_matrix(arm, q)
    assert max(np.abs(eaik.fwdKin(q[i]) - ours[i]).max() for i in range(200)) < 1e-12
    assert eaik.hasKnownDecomposition() and eaik.getKinematicFamily() == "6R-THREE_INNER_PARALLEL"


def test_classified_as_three_parallel_with_subproblem_6(arm):
    c = derive.classify(arm)
    assert c.cls == "three parallel" and c.closed_form
    assert "neither intersecting nor parallel" in c.test
    geo = parallel3.p3_sp6_geometry(arm)
    assert geo.layout == "sp6" and geo.error < 1e-12
    # p5: the common normal of axes 5 and 6 (0.05 m) plus the offset along axis 6 (d6)
    assert abs(np.linalg.norm(geo.p[5]) - math.hypot(0.05, 0.0823)) < 1e-12
    with pytest.raises(DeriveError, match="axes 5 and 6 do not intersect"):
        parallel3.p3_geometry(arm)
    cls, found = classes.detect(arm, dof=6)
    assert cls.name == "parallel3-sp6" and found.layout == "sp6"
    # the Z1 (axes 5 and 6 meeting) stays in the two-intersecting layout
    with pytest.raises(DeriveError, match="axes 5 and 6 intersect"):
        parallel3.p3_sp6_geometry("z1")
    assert classes.detect("z1", dof=6)[0].name == "parallel3"


def test_reference_is_eaiks_solution_set(arm, eaik, poses):
    q, P = poses
    sols, counts = reference.ik_batch(arm, P)
    assert set(np.unique(counts)) <= {2, 4, 6, 8} and counts.min() >= 2
    mats = DQ.to_matrix(P)
    differ = []
    for i in range(N_POSES):
        ours = sols[i, :counts[i]]
        theirs = _eaik_exact(eaik, mats[i])
        # every exact EAIK solution is one of ours; where the sets differ, ours has more (EAIK
        # missed 4 of pose 106's 8, which the general 6R elimination finds as well, below)
        assert all(_wrapped(y, ours).max(-1).min() < 1e-6 for y in theirs), i
        if not _same_set(ours, theirs, 1e-6):
            differ.append(i)
        # the generating configuration among them (near the wrist singularity sin q5 = 0 to 1e-6:
        # there the pose moves by the square of a step along the coupled q6 + q2 + q3 + q4)
        assert _wrapped(ours, q[i]).max(-1).min() < (1e-9 if abs(math.sin(q[i, 4])) > 1e-2 else 1e-6), i
    rows = np.concatenate([sols[i, :counts[i]] for i in range(N_POSES)])
    dp, dr = reference.pose_error(reference.fk(arm, rows), np.repeat(P, counts, axis=0))
    assert dp.max() < 1e-10 and dr.max() < 1e-10
    assert len(differ) <= 3      # pose 106 with numpy 2 and EAIK as installed
    from derive.ik import general6r
    g = general6r.solve(arm, P[differ])
    assert all(_same_set(sols[i, :counts[i]], g.q[k, :g.counts[k]], 1e-6) for k, i in enumerate(differ))


def test_counts_match_the_general_6r_elimination(arm, poses):
    """Two independent closed forms of the same arm: subproblem 6 and Raghavan-Roth."""
    from derive.ik import general6r
    _, P = poses
    sols, counts = reference.ik_batch(arm, P[:40])
    g = general6r.solve(arm, P[:40])
    assert np.array_equal(counts, g.counts)
    assert all(_same_set(sols[i, :counts[i]], g.q[i, :g.counts[i]], 1e-6) for i in range(40))


def test_unreachable_pose_says_why(arm):
    pose = DQ.from_rt([1.0, 0.0, 0.0, 0.0], [2.0, 0.0, 0.2])
    sols = reference.ik(arm, pose)
    assert len(sols) == 0 and sols.reason in (parallel3.REASON_SP6, parallel3.REASON_REACH)


def test_reference_is_ssiks_solution_set(arm, poses, tmp_path):
    """ssik's solver built from the arm's URDF export (a second outside solver; it returns every
    winding within the +-2 pi limits, merged here)."""
    import ssik
    from derive.cli import main
    urdf = tmp_path / "arm.urdf"
    assert main(["export", ARM, "--urdf", str(urdf)]) == 0
    solver = ssik.Manipulator.from_urdf(str(urdf), base="base_link", ee="flange")
    _, P = poses
    n = 20          # ssik's general solver takes about 25 ms per pose (300 poses agreed once)
    sols, counts = reference.ik_batch(arm, P[:n])
    mats = DQ.to_matrix(P[:n])
    for i in range(n):
        theirs = []
        for s in solver.solve(mats[i]):
            if all(_wrapped(s.q, o).max() > 1e-6 for o in theirs):
                theirs.append(s.q)
        assert _same_set(sols[i, :counts[i]], theirs, 1e-6), i


# --- the kernels: the IK program of the layout (derive.ik.program_parallel3.parallel3_sp6_program)

@pytest.fixture(scope="module")
def kernel_sols(arm, poses):
    """{language: (solutions (n, 8, 6), counts (n,))} of the C, numpy and pure Python kernels on
    the module's poses and 12 on the wrist singularity (q5 = 0), and the C kernels' branch ids."""
    q, P = poses
    qs = np.random.default_rng(9).uniform(-math.pi, math.pi, size=(12, 6))
    qs[:, 4] = 0.0
    P = np.concatenate([P, reference.fk(arm, qs)])
    out = {}
    S, C, B, G = derive.kernels(arm, "c").ik(P, details=True)
    out["c"] = (S, C)
    out["numpy"] = derive.kernels(arm, "numpy").ik(P)
    kp = derive.kernels(arm, "python")
    rows = [kp.ik(P[i]) for i in range(len(P))]
    out["python"] = (np.stack([r[0] for r in rows]), np.array([r[1] for r in rows]))
    return P, out, B, G


def test_kernels_have_the_ik_program_and_no_casadi_ik(arm):
    prog = ik_program(arm)
    assert prog.branches == 8 and sum(op.kind == "roots4" for op in prog.ops) == 1
    assert prog.branch_labels[:2] == ["sp6 solution (bit 2 of 2)", "sp6 solution (bit 1 of 2)"]
    from derive.refinement.functions import _ik_function
    assert _ik_function(arm) is None            # a quartic's roots have no CasADi SX form
    from derive.cli import _robot_row
    row = _robot_row(ARM)
    assert row["ik"] == "three parallel (sp6)" and row["kernels"].startswith("FK+IK")
    assert row["casadi"].startswith("fk, residual,") and ", ik" not in row["casadi"]
    assert "generated kernels" in " ".join(derive.classify(arm).notes)


@pytest.mark.parametrize("lang", ["c", "numpy", "python"])
def test_kernels_are_the_numpy_reference_branch_by_branch(arm, poses, kernel_sols, lang):
    """Every kernel's solutions are solve_batch_sp6's candidates, in the same branch order
    (k = 2 i6 + i3): the C kernels' branch ids index the reference's rows; the numpy and Python
    kernels list the same solutions in the same order as the C ones. FK within 1e-10, the
    generating configuration among them (away from the wrist singularity), no NaN before the
    padding, and the counts of the reference."""
    q, _ = poses
    P, out, branch, sing = kernel_sols
    geo = parallel3.p3_sp6_geometry(arm)
    ref, ref_sing, _ = parallel3.solve_batch_sp6(geo, P)
    ref_q, ref_c = reference.ik_batch(arm, P)
    S, C = out[lang]
    Sc, Cc = out["c"]
    P, S, C, Sc, Cc, branch, sing = P[:N_POSES], S[:N_POSES], C[:N_POSES], Sc[:N_POSES], Cc[:N_POSES], \
        branch[:N_POSES], sing[:N_POSES]
    ref, ref_sing, ref_q, ref_c = ref[:N_POSES], ref_sing[:N_POSES], ref_q[:N_POSES], ref_c[:N_POSES]
    assert np.array_equal(C, ref_c) and np.array_equal(C, Cc)
    for i in range(len(P)):
        s = S[i, :C[i]]
        # near the wrist singularity q6 and q2 + q3 + q4 move together by the rounding / sin q5
        tol = 1e-9 if abs(math.sin(q[i, 4])) > 1e-2 else 1e-6
        assert not np.isnan(s).any() and np.isnan(S[i, C[i]:]).all(), i
        assert _wrapped(s, Sc[i, :C[i]]).max(initial=0) < tol, i         # the C order
        assert _wrapped(s, ref[i, branch[i, :C[i]]]).max(initial=0) < tol, i
        assert _same_set(s, ref_q[i, :ref_c[i]], tol), i
        assert _wrapped(s, q[i]).max(-1).min() < tol, i
    # the kernels' singular flag: the reference's, and also where q1 is a near-double root of the
    # quartic (flag singular_dr, which the reference does not have: its FK check at 1e-10 drops
    # an inexact candidate instead): two solutions nearly merge there, so the configuration is
    # near a singular one (the Jacobian's smallest singular value over its largest below 1e-2;
    # 2.3e-4 at most on 2000 random poses), and few are
    got = sing[branch >= 0].astype(bool)
    want = ref_sing[np.arange(len(P))[:, None], np.maximum(branch, 0)][branch >= 0]
    rows = np.concatenate([S[i, :C[i]] for i in range(len(P))])
    assert not (want & ~got).any() and (got & ~want).mean() < 0.03
    from derive.ik.nearclass import fk_jacobian
    sv = np.linalg.svd(fk_jacobian(arm, rows[got & ~want])[1], compute_uv=False)
    assert (sv[:, -1] < 1e-2 * sv[:, 0]).all()
    dp, dr = reference.pose_error(reference.fk(arm, rows), np.repeat(P, C, axis=0))
    assert dp.max() < 1e-10 and dr.max() < 1e-10


@pytest.mark.parametrize("lang", ["c", "numpy", "python"])
def test_kernels_on_the_wrist_singularity(arm, kernel_sols, lang):
    """Poses of configurations with q5 = 0, where axis 6 is parallel to axes 2-4 and subproblem
    6's quartic has a double root in q1 (its second equation is even in q5): a double root is
    only defined to about the square root of the rounding, so the program flags the solutions of
    such a slot singular (flag singular_dr, |F'(q1)| below SP6_DOUBLE_ROOT of the quartic's
    scale): every unflagged solution is within 1e-10 of the pose, a flagged one within 1e-6 (the
    numpy reference, which checks every candidate by FK at 1e-10, drops some of them: then the
    kernels have more solutions). The numpy and Python kernels list the C kernels' solutions in
    the same order, so the C kernels' flags are theirs (the Python and numpy kernels do not
    return flags). Joints 1 and 5 of every solution of the reference and of the generating
    configuration are among the kernels', no NaN."""
    P, out, _, sing = kernel_sols
    P, (S, C), (Sc, Cc), sing = P[N_POSES:], (x[N_POSES:] for x in out[lang]), \
        (x[N_POSES:] for x in out["c"]), sing[N_POSES:]
    qs = np.random.default_rng(9).uniform(-math.pi, math.pi, size=(12, 6))
    qs[:, 4] = 0.0
    ref_q, ref_c = reference.ik_batch(arm, P)
    assert np.array_equal(C, Cc)
    flagged = 0
    for i in range(len(P)):
        s = S[i, :C[i]]
        assert not np.isnan(s).any() and C[i] >= ref_c[i] and C[i] >= 2, i
        # (q6 and q2 + q3 + q4 are one rotation there: only q1 and q5 are compared)
        assert _wrapped(s[:, [0, 4]], Sc[i, :C[i]][:, [0, 4]]).max() < 1e-6, i      # the C order
        assert all(_wrapped(y[[0, 4]], s[:, [0, 4]]).max(-1).min() < 1e-6 for y in ref_q[i, :ref_c[i]]), i
        assert _wrapped(s[:, [0, 4]], qs[i, [0, 4]]).max(-1).min() < 1e-6, i
        dp, dr = reference.pose_error(reference.fk(arm, s), np.repeat(P[i:i + 1], C[i], axis=0))
        err, flag = np.maximum(dp, dr), sing[i, :C[i]].astype(bool)
        assert err[~flag].max(initial=0) <= 1e-10 and err.max() < 1e-6, i
        flagged += flag.sum()
    assert flagged >= len(P)          # each pose has a double root, so flagged solutions


def test_c_kernels_hold_every_eaik_solution(eaik, poses, kernel_sols):
    """EAIK (IK-Geo's three parallel) against the C kernels directly: each exact EAIK solution is
    one of the kernels', and the sets are equal on all but at most 3 poses (EAIK misses 4 of 8 on
    one pose of these, test_reference_is_eaiks_solution_set)."""
    _, P = poses
    _, out, _, _ = kernel_sols
    S, C = out["c"]
    mats = DQ.to_matrix(P)
    differ = 0
    for i in range(N_POSES):
        theirs = _eaik_exact(eaik, mats[i])
        assert all(_wrapped(y, S[i, :C[i]]).max(-1).min() < 1e-6 for y in theirs), i
        differ += not _same_set(S[i, :C[i]], theirs, 1e-6)
    assert differ <= 3


def test_c_kernels_are_ssiks_solution_set(arm, poses, kernel_sols, tmp_path):
    import ssik
    from derive.cli import main
    urdf = tmp_path / "arm.urdf"
    assert main(["export", ARM, "--urdf", str(urdf)]) == 0
    solver = ssik.Manipulator.from_urdf(str(urdf), base="base_link", ee="flange")
    _, P = poses
    _, out, _, _ = kernel_sols
    S, C = out["c"]
    mats = DQ.to_matrix(P[:20])
    for i in range(20):
        theirs = []
        for s in solver.solve(mats[i]):
            if all(_wrapped(s.q, o).max() > 1e-6 for o in theirs):
                theirs.append(s.q)
        assert _same_set(S[i, :C[i]], theirs, 1e-6), i


# --- the root finder of the IK program's "roots4" line, in each printed language ------------

def _known_roots(rng, n, spread=0.3):
    """Coefficients (A0, A1, B1, A2, B2) of F(t) = k prod_j sin((t - t_j) / 2) (a trigonometric
    polynomial of degree 2) with four roots t_j at least ``spread`` apart, and the roots."""
    coefs, roots = [], []
    s = np.linspace(0, 2 * math.pi, 16, endpoint=False)
    basis = np.stack([np.ones_like(s), np.cos(s), np.sin(s), np.cos(2 * s), np.sin(2 * s)], axis=-1)
    while len(coefs) < n:
        t = np.sort(rng.uniform(-math.pi, math.pi, 4))
        gaps = np.diff(np.concatenate([t, t[:1] + 2 * math.pi]))
        if gaps.min() < spread:
            continue
        f = np.prod(np.sin((s[:, None] - t) / 2), axis=-1) * 10.0 ** rng.uniform(-3, 3)
        coefs.append(np.linalg.lstsq(basis, f, rcond=None)[0])
        roots.append(t)
    return np.array(coefs), np.array(roots)


def _root_cases():
    """Random coefficients, four known roots (one at pi too), two (F = a cos t + b), none (F
    constant), F = 0, a double root, and tiny and huge scales."""
    rng = np.random.default_rng(30)
    known, _ = _known_roots(rng, 200)
    close, _ = _known_roots(rng, 40, spread=0.01)             # roots 0.01 rad apart or more
    special = [[0.0, 0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0, 0.0], [0.3, 1.0, 0.0, 0.0, 0.0],
               [1.0, 1.0, 0.0, 0.0, 0.0],                     # 1 + cos t: a double root at pi
               [0.0, 0.0, 0.0, 1.0, 0.0],                     # cos 2t: +-pi/4, +-3 pi/4
               [1e-150, 2e-150, 0.5e-150, -1e-150, 0.3e-150], [1e150, 2e150, 0.5e150, -1e150, 0.3e150]]
    return np.concatenate([rng.normal(size=(300, 5)), known, close, np.array(special)])


def _sorted_roots(coef):
    """numpy's _trig_roots (derive.ik.subproblems), slots as the program orders them."""
    t, ok = _trig_roots(coef)
    t = np.where(ok, t, 0.0)
    order = np.argsort(np.where(ok, t, np.inf), axis=-1, kind="stable")
    return np.take_along_axis(t, order, -1), np.take_along_axis(ok, order, -1)


def _check_roots(coef, t, ok):
    """The slots of a roots4 line against _trig_roots: the same number of real roots (but at the
    double root's threshold), the same angles, every real root a zero of F, no NaN."""
    assert np.isfinite(t).all() and np.isin(ok, (0.0, 1.0)).all()
    ref_t, ref_ok = _sorted_roots(coef)
    a0, a1, b1, a2, b2 = coef.T
    f = (a0[:, None] + a1[:, None] * np.cos(t) + b1[:, None] * np.sin(t) + a2[:, None] * np.cos(2 * t)
         + b2[:, None] * np.sin(2 * t))
    scale = np.abs(coef).max(-1, initial=0)[:, None]
    assert (np.abs(f)[ok > 0.5] <= 1e-9 * scale.repeat(4, 1)[ok > 0.5]).all()
    assert (t[ok < 0.5] == 0).all()
    same = (ok > 0.5).sum(-1) == ref_ok.sum(-1)
    assert same.mean() > 0.99
    for i in np.flatnonzero(same):
        assert _wrapped(t[i][ok[i] > 0.5], ref_t[i][ref_ok[i]]).max(initial=0) < 1e-6, i


@pytest.fixture(scope="module")
def kernel_texts(arm):
    from derive.codegen.emit import render_kernels
    return render_kernels(arm)


@pytest.mark.parametrize("role", ["python", "numpy"])
def test_roots4_of_the_python_kernels(kernel_texts, role):
    ns: dict = {}
    exec(compile(kernel_texts[role][1], kernel_texts[role][0], "exec"), ns)
    coef = _root_cases()
    if role == "python":
        out = np.array([ns["_roots4"](*c) for c in coef])
    else:
        out = np.stack(ns["_roots4"](len(coef), *coef.T), axis=-1)
    _check_roots(coef, out[:, :4], out[:, 4:])
    # four known roots found, in ascending order
    known, roots = _known_roots(np.random.default_rng(31), 100)
    got = (np.array([ns["_roots4"](*c) for c in known]) if role == "python"
           else np.stack(ns["_roots4"](len(known), *known.T), axis=-1))
    assert (got[:, 4:] == 1.0).all() and np.abs(got[:, :4] - roots).max() < 1e-9


ROOTS_DRIVER = r"""#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#define DQ_NOINLINE
#define dq_atan2 atan2
static double dq_max(double a, double b) { return a > b ? a : b; }
%s

int main(void)
{
    char line[512];
    while (fgets(line, sizeof line, stdin)) {
        double c[5], t[4], ok[4];
        char *p = line;
        for (int i = 0; i < 5; ++i) {
            c[i] = strtod(p, &p);
        }
        dq_roots4(c[0], c[1], c[2], c[3], c[4], t, ok);
        printf("%%a %%a %%a %%a %%a %%a %%a %%a\n", t[0], t[1], t[2], t[3], ok[0], ok[1], ok[2], ok[3]);
    }
    return 0;
}
"""


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")
def test_c_source_compiles_as_c99_and_cxx_and_its_roots4(kernel_texts, tmp_path):
    """The emitted C with -Wall -Wextra -Wpedantic -Werror as C99 and C++17, and its dq_roots4
    (Ferrari's roots polished by the Durand-Kerner iteration) through a driver that includes its text, under the address and
    undefined-behaviour sanitizers, against numpy's companion-matrix roots."""
    for name, text in kernel_texts.values():
        (tmp_path / name).write_text(text)
    src = tmp_path / kernel_texts["c_source"][0]
    for cmd in (["gcc", "-std=c99", "-O1", "-c", "-o", "/dev/null"],
                ["g++", "-std=c++17", "-x", "c++", "-fsyntax-only"]):
        if shutil.which(cmd[0]) is None:
            continue
        res = subprocess.run([*cmd, "-Wall", "-Wextra", "-Wpedantic", "-Werror", str(src)],
                             capture_output=True, text=True)
        assert res.returncode == 0, (cmd, res.stderr[-3000:])
    # the emitted dq_roots4, cut from the source (a sanitizer build of the whole kernel takes 30 s)
    text = kernel_texts["c_source"][1]
    start, end = text.index("static void dq_quad_roots("), text.index("static DQ_NOINLINE void dq_roots4(")
    (tmp_path / "driver.c").write_text(ROOTS_DRIVER % text[start:text.index("\n}\n", end) + 3])
    res = subprocess.run(["gcc", "-std=c99", "-O1", "-Wall", "-Wextra", "-Werror", "-fsanitize=address,undefined",
                          "-fno-sanitize-recover=all", "-o", str(tmp_path / "driver"), str(tmp_path / "driver.c"),
                          "-lm"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    coef = _root_cases()
    known, roots = _known_roots(np.random.default_rng(31), 100)
    both = np.concatenate([coef, known])
    text = "".join(" ".join(float(v).hex() for v in row) + "\n" for row in both)
    run = subprocess.run([str(tmp_path / "driver")], input=text, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-3000:]
    out = np.array([[float.fromhex(v) for v in line.split()] for line in run.stdout.splitlines()])
    _check_roots(coef, out[:len(coef), :4], out[:len(coef), 4:])
    got = out[len(coef):]
    assert (got[:, 4:] == 1.0).all() and np.abs(got[:, :4] - roots).max() < 1e-9
