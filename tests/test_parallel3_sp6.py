"""The three-parallel class with axes 5 and 6 not meeting (IK-Geo's "three parallel" with
subproblem 6, derive.ik.parallel3.solve_batch_sp6) on a test arm of that layout
(tests/data/ur5-wrist-offset.yaml: the UR5 with a5 = 0.05 m): its file against EAIK's DH model,
its classification, and the numpy reference's solution sets against EAIK's solver (family
6R-THREE_INNER_PARALLEL)."""

import math
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


def test_no_kernel_program_yet_says_so(arm):
    with pytest.raises(DeriveError, match="subproblem 6"):
        ik_program(arm)


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
