"""The three-parallel class (derive.ik.parallel3) on the Unitree Z1: its file against Unitree's URDF
and ssik's prebuilt Z1, its classification, and its closed form (numpy reference and the generated
kernels) against ssik's Z1 solver (IK-Geo's three parallel) on poses within the limits."""

import math
from pathlib import Path

import numpy as np
import pytest
import ssik.prebuilt.unitree.z1_ik as z1_ik     # ssik is in the test extra: a missing one fails

import derive
from derive import dualquat as DQ
from derive import reference
from derive.errors import DeriveError
from derive.ik import parallel3
from derive.ik.closed_form import parallel3_class
from derive.ik.subproblems import rot


HERE = Path(__file__).resolve().parent
URDF = str(HERE / "data" / "z1.urdf")
N_POSES = 300
DEG = math.pi / 180


@pytest.fixture(scope="module")
def z1():
    return derive.load_robot("z1")


@pytest.fixture(scope="module")
def within(z1):
    """N_POSES configurations drawn inside the Z1's limits and their poses."""
    rng = np.random.default_rng(20261205)
    q = rng.uniform(z1.limits[:, 0], z1.limits[:, 1], size=(N_POSES, 6))
    return q, reference.fk(z1, q)


def _wrapped(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + math.pi) % (2 * math.pi) - math.pi)


def _same_set(a, b, tol=1e-9) -> bool:
    """Two (k, 6) solution sets equal up to 2 pi windings, each row matched."""
    a, b = np.asarray(a).reshape(-1, 6), np.asarray(b).reshape(-1, 6)
    if len(a) != len(b):
        return False
    return all(len(b) and _wrapped(x, b).max(-1).min() < tol for x in a) and \
        all(len(a) and _wrapped(y, a).max(-1).min() < tol for y in b)


def _fk_errors(robot, sols, counts, poses):
    """Largest position (m) and rotation (rad) error of every returned solution."""
    rows = np.concatenate([sols[i, :counts[i]] for i in range(len(poses))])
    targets = np.repeat(poses, counts, axis=0)
    dp, dr = reference.pose_error(reference.fk(robot, rows), targets)
    return float(dp.max()), float(dr.max())


# --------------------------------------------------------------------------- #
# The file: Unitree's URDF and ssik's Z1
# --------------------------------------------------------------------------- #
def test_z1_file_is_unitrees_urdf(z1):
    urdf = derive.load_robot(URDF, base="link00", tip="link06")
    rng = np.random.default_rng(1)
    q = rng.uniform(-2 * math.pi, 2 * math.pi, size=(500, 6))
    assert np.abs(reference.fk_matrix(z1, q) - reference.fk_matrix(urdf, q)).max() < 1e-12
    # the limits in whole degrees are the URDF's radians
    assert np.abs(z1.limits - urdf.limits).max() < 1e-12
    np.testing.assert_allclose(z1.limits / DEG, [[-150, 150], [0, 170], [-165, 0], [-87, 87],
                                                  [-77, 77], [-160, 160]], atol=1e-9)
    # both descriptions are of the class, with the same numbers
    a, b = parallel3.p3_geometry(z1), parallel3.p3_geometry(urdf)
    assert np.abs(a.h - b.h).max() < 1e-12 and np.abs(a.p[2:] - b.p[2:]).max() < 1e-12
    # the point of axis 1 differs (the base origin here, the URDF's joint-1 origin 0.0585 above it)
    assert np.abs(a.p[0] + a.p[1] - b.p[0] - b.p[1]).max() < 1e-12


def test_example_robot_datas_z1_with_its_gripper_is_solved(z1):
    """example-robot-data ships the same URDF (with the gripper): link00 -> link06 is our file,
    and the chain to the gripper's stator (a tool past the flange) is of the class too."""
    import sysconfig
    found = [Path(p) / "cmeel.prefix/share/example-robot-data/robots/z1_description/urdf/z1.urdf"
             for p in {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}]
    found = [p for p in found if p.is_file()]
    assert found, "example-robot-data is not installed (a test extra)"
    path = found[0]
    flange = derive.load_robot(str(path), base="link00", tip="link06")
    q = np.random.default_rng(3).uniform(-math.pi, math.pi, size=(200, 6))
    assert np.abs(reference.fk_matrix(flange, q) - reference.fk_matrix(z1, q)).max() < 1e-12
    gripper = derive.load_robot(str(path), tip="gripperStator")
    assert derive.classify(gripper).cls == "three parallel"
    poses = reference.fk(gripper, q[:50])
    sols, counts = reference.ik_batch(gripper, poses)
    assert all(_wrapped(sols[i, :counts[i]], q[i]).max(-1).min() < 1e-9 for i in range(50))
    dp, dr = _fk_errors(gripper, sols, counts, poses)
    assert dp < 1e-10 and dr < 1e-10


def test_z1_file_matches_ssiks_z1(z1):
    rng = np.random.default_rng(2)
    q = rng.uniform(-math.pi, math.pi, size=(100, 6))
    ours = reference.fk_matrix(z1, q)
    theirs = np.array([z1_ik.fk(x) for x in q])
    assert np.abs(ours - theirs).max() < 1e-12
    assert np.abs(np.array(z1_ik._JOINT_LIMITS) - z1.limits).max() < 1e-12


# --------------------------------------------------------------------------- #
# Classification
# --------------------------------------------------------------------------- #
def test_z1_is_three_parallel_and_ur_stays_ur():
    c = derive.classify("z1")
    assert (c.cls, c.nominal_cls, c.closed_form, c.near_misses) == ("three parallel", "three parallel", True, [])
    assert c.pieper == [((2, 3, 4), "parallel")]
    pair = {p.i: p for p in c.pairs}
    assert pair[4].perpendicular.holds and not pair[4].intersecting.holds     # axes 4, 5: not the UR
    assert pair[4].distance == pytest.approx(0.07, abs=1e-12)
    assert pair[5].intersecting.holds
    assert any("derive.ik.parallel3" in n for n in c.notes)
    assert not any("derive.refine solves" in n for n in c.notes)
    for name in ("ur5", "ur10e"):
        assert derive.classify(name).cls == "UR"
        assert parallel3_class(name) is None
    with pytest.raises(DeriveError, match="UR layout"):
        parallel3.p3_geometry("ur5")


def _edited(tmp_path, old, new):
    text = (HERE.parent / "derive" / "robots" / "z1.yaml").read_text(encoding="utf-8")
    assert old in text
    path = tmp_path / "z1-edited.yaml"
    path.write_text(text.replace(old, new).replace("name: z1", "name: z1-edited"), encoding="utf-8")
    return derive.load_robot(str(path))


def test_an_offset_between_axes_5_and_6_moves_it_to_the_sp6_layout(tmp_path):
    r = _edited(tmp_path, "link: [0.0492, 0, 0]", "link: [0.0492, 0.02, 0]")
    c = derive.classify(r)
    assert c.cls == "three parallel" and c.closed_form and "neither intersecting" in c.test
    with pytest.raises(DeriveError, match="axes 5 and 6 do not intersect"):
        parallel3.p3_geometry(r)
    assert parallel3.p3_sp6_geometry(r).layout == "sp6"
    # IK-Geo's three parallel (subproblem 6) solves it; the general 6R elimination agrees
    from derive.ik import general6r
    q0 = np.array([0.3, -0.4, 0.5, 0.2, -0.6, 0.7])
    pose = reference.fk(r, q0)
    sols = np.asarray(reference.ik(r, pose))
    assert len(sols) >= 1 and _wrapped(sols, q0).max(-1).min() < 1e-9
    assert np.abs(reference.fk_matrix(r, sols) - reference.fk_matrix(r, q0)).max() < 1e-10
    g = general6r.solve(r, pose[None])
    assert _same_set(sols, g.q[0, :g.counts[0]], 1e-6)


# --------------------------------------------------------------------------- #
# Numpy reference against ssik's Z1
# --------------------------------------------------------------------------- #
def test_reference_is_ssiks_solution_set_within_the_limits(z1, within):
    q, poses = within
    sols, counts = reference.ik_batch(z1, poses)
    assert set(np.unique(counts)) <= {4, 8} and counts.min() >= 1
    for i in range(N_POSES):
        theirs = [s.q for s in z1_ik.solve(DQ.to_matrix(poses[i]), respect_limits=False)]
        assert _same_set(sols[i, :counts[i]], theirs), i
        assert _wrapped(sols[i, :counts[i]], q[i]).max(-1).min() < 1e-9, i       # the generating one
    dp, dr = _fk_errors(z1, sols, counts, poses)
    assert dp < 1e-10 and dr < 1e-10
    # within the limits: ssik's own limit filter gives the same in-limit set
    for i in range(0, N_POSES, 10):
        ours = reference.ik(z1, poses[i], within_limits=True)
        theirs = [s.q for s in z1_ik.solve(DQ.to_matrix(poses[i]), respect_limits=True)]
        assert _same_set(ours, theirs), i


def test_the_urdf_is_solved_the_same(z1, within):
    urdf = derive.load_robot(URDF, base="link00", tip="link06")
    _, poses = within
    a, ca = reference.ik_batch(z1, poses[:50])
    b, cb = reference.ik_batch(urdf, poses[:50])
    assert np.array_equal(ca, cb)
    assert all(_same_set(a[i, :ca[i]], b[i, :cb[i]]) for i in range(50))


def test_unreachable_pose_says_why(z1):
    pose = DQ.from_rt([1.0, 0.0, 0.0, 0.0], [1.5, 0.0, 0.2])
    sols = reference.ik(z1, pose)
    assert len(sols) == 0 and sols.reason == parallel3.REASON_REACH


def _shoulder_singular_q():
    """A configuration whose wrist point (axes 5 and 6 meet) lies on axis 1: x of the wrist point
    in the arm plane, -0.35 c2' ... solved for q3 by bisection with q2, q4 fixed."""
    def wrist_x(q3, q2=1.2, q4=0.3):
        h = np.array([0.0, 1.0, 0.0])
        v = np.array([-0.35, 0, 0]) + rot(h, q3, np.array([0.218, 0, 0.057])) \
            + rot(h, q3 + q4, np.array([0.07, 0, 0]))
        return rot(h, q2, v)[0]
    lo, hi = -2.8, -0.1
    assert wrist_x(lo) * wrist_x(hi) < 0
    for _ in range(200):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if wrist_x(lo) * wrist_x(mid) > 0 else (lo, mid)
    return np.array([0.7, 1.2, (lo + hi) / 2, 0.3, 0.4, -0.5])


def test_singular_sets_take_the_free_joint_from_the_reference(z1):
    for q in (_shoulder_singular_q(), np.array([0.3, 1.0, -1.2, 0.4, math.pi / 2, 0.8])):
        pose = reference.fk(z1, q)
        sols = reference.ik(z1, pose, q_ref=q)
        k = int(np.argmin(_wrapped(sols, q).max(-1)))
        assert _wrapped(sols[k], q).max() < 1e-9
        assert sols.singular[k]
        dp, dr = reference.pose_error(reference.fk(z1, np.asarray(sols)), np.repeat(pose[None], len(sols), 0))
        assert dp.max() < 1e-10 and dr.max() < 1e-10
        # without a reference the free joint is 0: still solutions of the pose
        free = reference.ik(z1, pose)
        assert len(free) and free.singular.all()
        dp, dr = reference.pose_error(reference.fk(z1, np.asarray(free)), np.repeat(pose[None], len(free), 0))
        assert dp.max() < 1e-10 and dr.max() < 1e-10


# --------------------------------------------------------------------------- #
# Generated kernels
# --------------------------------------------------------------------------- #
@pytest.fixture(scope="module")
def ref_sets(z1, within):
    _, poses = within
    return reference.ik_batch(z1, poses)


@pytest.mark.parametrize("backend", ["c", "numpy", "python"])
def test_kernels_give_the_reference_solutions(z1, within, ref_sets, backend):
    _, poses = within
    k = derive.kernels("z1", backend)
    assert k.has_ik
    sols, counts = ref_sets
    if backend == "python":
        out = [k.ik(p) for p in poses[:60]]
        ks = np.full((60, 8, 6), np.nan)
        kc = np.array([c for _, c in out])
        for i, (s, c) in enumerate(out):
            ks[i, :c] = np.asarray(s).reshape(-1, 6)[:c]
        n = 60
    else:
        ks, kc = k.ik(poses)
        n = N_POSES
    assert np.array_equal(kc[:n], counts[:n])
    assert all(_same_set(ks[i, :kc[i]], sols[i, :counts[i]]) for i in range(n))
    dp, dr = _fk_errors(z1, ks[:n], kc[:n], poses[:n])
    assert dp < 1e-10 and dr < 1e-10


def test_c_kernels_branches_and_singular_flags(z1, within):
    """The C batch's branch ids are the reference's k = 4 i1 + 2 i5 + i3 (each solution is the
    reference's candidate of its branch), and on the singular sets the solutions are flagged,
    with the free joint at 0 as the reference without a q_ref."""
    k = derive.kernels("z1", "c")
    _, poses = within
    sols, counts, branch, _ = k.ik(poses[:100], details=True)
    cand, _, _ = parallel3.solve_batch(parallel3.p3_geometry(z1), poses[:100])
    for i in range(100):
        for j in range(counts[i]):
            assert _wrapped(sols[i, j], cand[i, branch[i, j]]).max() < 1e-9, (i, j)
    for qs in (_shoulder_singular_q(), np.array([0.3, 1.0, -1.2, 0.4, math.pi / 2, 0.8])):
        pose = reference.fk(z1, qs)
        s, cnt, _, sing = k.ik(pose[None], details=True)
        assert cnt[0] >= 1 and sing[0, :cnt[0]].all()
        assert _same_set(s[0, :cnt[0]], reference.ik(z1, pose), tol=1e-7)
