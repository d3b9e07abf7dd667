"""The general 6R solver (derive.ik.general6r): Raghavan-Roth elimination + Manocha-Canny
eigenproblem, checked on the library's general-6r against the plain 4x4-matrix FK, the
generating configuration, a dense multi-start of derive.refine and (opt-in) ssik's general
solver; and its report on an arm whose elimination degenerates (the Fanuc CRX-10iA geometry of
ssik.prebuilt)."""

import importlib
import math
import os

import numpy as np
import pytest

import derive
from derive import reference
from derive.algebra.angles import wrap_angle
from derive.errors import DeriveError
from derive.ik import general6r
from derive.model.classify import classify
from derive.model.geometry import numeric_chain

ROBOT = "general-6r"


def _contains(sols, q, tol=1e-6):
    """Whether q is among the rows of sols, joint by joint modulo 2 pi."""
    return len(sols) > 0 and bool(np.any(np.all(np.abs(wrap_angle(sols - q)) < tol, axis=1)))


def test_general_6r_file_is_a_6r_without_special_structure():
    chain = numeric_chain(ROBOT)
    assert chain.n == 6 and all(t == "revolute" for t in chain.types)
    points = chain.start + np.concatenate([np.zeros((1, 3)), np.cumsum(chain.links, axis=0)])
    for i in range(5):
        w1, w2 = chain.axes[i], chain.axes[i + 1]
        cross = np.cross(w1, w2)
        assert np.linalg.norm(cross) > 0.1                       # not parallel
        dist = abs(np.dot(points[i + 1] - points[i], cross)) / np.linalg.norm(cross)
        assert dist > 1e-3                                       # not intersecting
    assert classify(ROBOT).cls == "general"


def test_chain_form_reproduces_the_matrix_fk():
    c, scale = general6r.chain_form(ROBOT)
    q = np.random.default_rng(3).uniform(-math.pi, math.pi, (50, 6))
    _, end = general6r._chain_frames(c, q)
    end[:, :3, 3] *= scale
    assert np.abs(end - reference.fk_matrix(ROBOT, q)).max() < 1e-12


@pytest.mark.parametrize("robot", ["general-6r", "crx10ia", "xarm6"])
def test_column_layout_chain_and_folded_fk_agree_with_the_matrix_and_quaternion_fk(robot):
    """The solver's hot path against the independent ones: the column-layout chain (every joint's
    z axis and origin, the end; stopped before any joint and continued, as the back-substitution
    does) against plain 4x4 matrices (reference.fk_matrix, scaled), and the FK check's folded
    dual-quaternion product against derive.kinematics.fk.fk."""
    from derive.kinematics.fk import _pose_error, fk
    c, scale = general6r.chain_form(robot)
    q = np.random.default_rng(4).uniform(-math.pi, math.pi, (40, 6))
    mats = reference.fk_matrix(robot, q)
    zs, ps, x = general6r._frames_x(c, q)
    end = np.stack([x[0], x[1], x[2], x[3]], 2)                  # (n, 3, 4)
    assert np.abs(end[:, :, :3] - mats[:, :3, :3]).max() < 1e-12
    assert np.abs(end[:, :, 3] * scale - mats[:, :3, 3]).max() < 1e-12
    frames, _ = general6r._chain_frames(c, q)
    assert np.abs(zs - frames[:, :, :3, 2]).max() < 1e-13 and np.abs(ps - frames[:, :, :3, 3]).max() < 1e-13
    cq, sq = np.cos(q), np.sin(q)
    for stop in range(6):
        z2, p2 = np.empty((40, 6, 3)), np.empty((40, 6, 3))
        a = general6r._chain_x(c, cq, sq, z2, p2, stop=stop)      # A before joint stop's rotation
        assert np.abs(np.stack(list(a), 2) - frames[:, stop, :3, :]).max() < 1e-13
        general6r._x_rot(a, cq[:, stop, None], sq[:, stop, None])
        rest = general6r._chain_x(c, cq, sq, z2, p2, x=a, start=stop + 1)
        assert np.abs(np.stack(list(rest), 2) - end).max() < 1e-13
        assert np.abs(z2 - zs).max() < 1e-13
    dpos, drot = _pose_error(general6r._fk_exact(derive.load_robot(robot), q), fk(robot, q))
    assert dpos.max() < 1e-13 and drot.max() < 1e-13


def test_derived_equations_hold_on_configurations():
    """P(q3) X1 = Q(l, p) X2, the 14 derived equations, at random configurations (their
    coefficients come from sympy; the configurations' poses from the dual-quaternion FK)."""
    pl = general6r.plan(ROBOT)
    el = pl.elim
    q = np.random.default_rng(4).uniform(-math.pi, math.pi, (40, 6))
    c = general6r._reverse(pl.c) if pl.reverse else pl.c
    qq = -q[:, ::-1] if pl.reverse else q
    _, end = general6r._chain_frames(c, qq)
    t7 = end @ general6r._inv(c[6])
    lp = np.concatenate([t7[:, :3, 2], t7[:, :3, 3]], axis=1)
    pm = general6r._pose_monomials(lp, el.monomials)
    trig = [np.stack([np.sin(qq[:, k]), np.cos(qq[:, k]), np.ones(len(q))], 1) for k in range(5)]
    x1 = np.einsum("na,nb->nab", trig[3], trig[4]).reshape(-1, 9)
    x2 = np.einsum("na,nb->nab", trig[0], trig[1]).reshape(-1, 9)[:, :8]
    lhs = np.einsum("eaj,na,nj->ne", el.pl, trig[2], x1) - pm @ el.r0.T
    rhs = np.einsum("ekm,nm,nk->ne", el.q, pm, x2)
    assert np.abs(lhs - rhs).max() < 1e-10
    assert pl.rank_q == 8


@pytest.fixture(scope="module")
def solved():
    rng = np.random.default_rng(20261205)
    q = rng.uniform(-math.pi, math.pi, (300, 6))
    P = reference.fk(ROBOT, q)
    return q, P, general6r.solve(ROBOT, P)


def test_every_solution_reproduces_the_pose_and_the_generating_one_is_found(solved):
    q, P, res = solved
    counts = res.counts
    assert counts.min() >= 1 and counts.max() <= 16
    for i in range(len(q)):
        sols = res.q[i, :counts[i]]
        assert np.all(np.isfinite(sols)) and np.all(np.isnan(res.q[i, counts[i]:]))
        # FK by plain 4x4 matrices (fk_matrix shares no code with the dual-quaternion FK the
        # solver checks with)
        err = np.abs(reference.fk_matrix(ROBOT, sols) - reference.fk_matrix(ROBOT, q[i])).max()
        assert err < 1e-10
        assert _contains(sols, q[i]), i
    # a general 6R has an even number of real solutions off its singular set
    regular = ~np.any(res.singular, axis=1) & ~res.degenerate
    assert np.all(counts[regular] % 2 == 0)
    dist = np.bincount(counts, minlength=17)
    print("general-6r solution counts (number of poses with 0..16 solutions):", dist.tolist())
    assert dist[8:].sum() > 0                                    # 8 or more occur


def test_contains_every_solution_of_a_dense_multistart_refine(solved):
    """derive.refine from 64 random starts per pose (an independent numeric path): every
    solution it converges to is among ours."""
    q, P, res = solved
    for i in range(8):
        ref = derive.refine(ROBOT, P[i], starts=64, seed=i + 1)
        found = np.array([s for s in np.atleast_2d(ref.solutions) if np.all(np.isfinite(s))])
        dpos, drot = reference.pose_error(reference.fk(ROBOT, found), np.tile(P[i], (len(found), 1)))
        for s in found[(dpos < 1e-9) & (drot < 1e-9)]:
            assert _contains(res.q[i, :res.counts[i]], s, 1e-5), (i, s)


@pytest.mark.skipif(not os.environ.get("DQ_DERIVE_TEST_SSIK_6R"),
                    reason="ssik's first solve of a new DH arm derives for minutes; set "
                           "DQ_DERIVE_TEST_SSIK_6R=1 (its cache keeps it afterwards)")
def test_contains_every_solution_of_ssik_general_solver(solved):
    import ssik
    import yaml
    d = yaml.safe_load(open(derive.load_robot(ROBOT).path))
    arm = ssik.Manipulator.from_dh([j["alpha"] for j in d["joints"]], [j["a"] for j in d["joints"]],
                                   [j["d"] for j in d["joints"]])
    q, P, res = solved
    total = 0
    for i in range(60):
        T = reference.fk_matrix(ROBOT, q[i])
        for s in arm.solve(T):
            total += 1
            assert _contains(res.q[i, :res.counts[i]], np.asarray(s.q), 1e-6), (i, s.q)
    assert total > 0


def test_reference_ik_routes_arms_without_a_special_class():
    q = np.array([0.3, -1.2, 1.4, -0.5, 1.1, 0.7])
    sols = reference.ik(ROBOT, reference.fk(ROBOT, q))
    assert _contains(np.asarray(sols), q) and not np.any(sols.singular)
    Q, counts = reference.ik_batch(ROBOT, reference.fk(ROBOT, np.stack([q, -q])))
    assert Q.shape == (2, 16, 6) and np.all(counts >= 2)
    assert _contains(Q[1, :counts[1]], -q)


def test_unreachable_pose_has_no_solution_and_says_why():
    far = derive.pose.from_position_quaternion([5.0, 0.0, 0.0], [1, 0, 0, 0], order="wxyz")
    res = general6r.solve(ROBOT, far[None])
    assert res.counts[0] == 0 and "unreachable" in res.reason[0]
    assert np.all(np.isnan(res.q))
    sols = reference.ik(ROBOT, far)
    assert len(sols) == 0 and "unreachable" in sols.reason


def test_derivation_is_stored_and_reloaded():
    from derive.cache import clear_memory, find_artifact
    general6r.plan(ROBOT)
    robot = derive.load_robot(ROBOT)
    assert find_artifact(robot.id, "general6r") is not None
    clear_memory(["general6r-plan"])
    again = general6r.plan(ROBOT, progress=False)
    assert again.rank_q == 8 and again.elim.q.shape[:2] == (14, 8)


# --------------------------------------------------------------------------- #
# An arm whose elimination degenerates: the Fanuc CRX-10iA geometry of ssik.prebuilt
# --------------------------------------------------------------------------- #
def crx_description():
    """The CRX-10iA as ssik bakes it (ssik.prebuilt.fanuc.crx10ia_ik: joint origins, axes, limits
    and the tool offset), in our urdf convention."""
    m = importlib.import_module("ssik.prebuilt.fanuc.crx10ia_ik")
    joints = []
    for i in range(6):
        left, right = m._JOINT_T_LEFTS[i], m._JOINT_T_RIGHTS[i]
        assert np.allclose(left[:3, :3], np.eye(3)) and np.allclose(right[:3, :3], np.eye(3))
        assert i == 5 or np.allclose(right[:3, 3], 0)
        joints.append({"name": f"j{i + 1}", "origin": {"translation": left[:3, 3].tolist()},
                       "axis": np.asarray(m._JOINT_AXES[i], float).tolist(),
                       "limits": [float(v) for v in m._JOINT_LIMITS[i]]})
    return m, {"name": "ssik-crx-geometry", "convention": "urdf", "joints": joints,
               "tool": {"translation": m._JOINT_T_RIGHTS[5][:3, 3].tolist()}}


@pytest.fixture(scope="module")
def crx(tmp_path_factory):
    import yaml
    m, desc = crx_description()
    path = tmp_path_factory.mktemp("crx") / "ssik-crx-geometry.yaml"
    path.write_text(yaml.safe_dump(desc))
    return m, derive.load_robot(str(path))


def test_crx_geometry_is_ssik_arm_and_needs_the_cut(crx):
    m, robot = crx
    q = np.random.default_rng(5).uniform(-1.5, 1.5, (5, 6))
    for qq in q:        # the transcription is ssik's arm
        assert np.abs(reference.fk_matrix(robot, qq) - m.fk(qq)).max() < 1e-12
    assert classify(robot).cls == "general"
    # CRX: axes 2 and 3 parallel, 1-2, 4-5 and 5-6 intersecting: the standard cut's 12 x 12
    # pencil has rank 10 for every q3 in both directions; the cut at joint 2 is regular
    notes = " ".join(general6r.plan(robot, progress=False).notes)
    assert "singular for every q3" in notes and "cut at joint 2: triple (3, 4, 5)" in notes


def test_crx_all_solutions_contain_the_generating_one_and_ssik(crx):
    m, robot = crx
    rng = np.random.default_rng(20261206)
    q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (300, 6))
    res = general6r.solve(robot, reference.fk(robot, q))
    assert res.counts.max() <= 16
    for i in range(len(q)):
        sols = res.q[i, :res.counts[i]]
        assert np.all(np.isfinite(sols))
        assert np.abs(reference.fk_matrix(robot, sols) - reference.fk_matrix(robot, q[i])).max() < 1e-10
        assert _contains(sols, q[i]), i
    total = 0
    for i in range(100):        # ssik's general solver (Raghavan-Roth + Manocha-Canny, its C++ path)
        for s in m.solve(reference.fk_matrix(robot, q[i]), native=True):
            total += 1
            assert _contains(res.q[i, :res.counts[i]], np.asarray(s.q, float)), (i, s.q)
    assert total >= 400
    dist = np.bincount(res.counts, minlength=17)
    print("CRX-10iA solution counts (number of poses with 0..16 solutions):", dist.tolist())
    assert dist[12:].sum() > 0                                   # more than a Pieper arm's 8


def test_crx_root_shared_by_several_solutions(crx):
    """At this symmetric pose four solutions share q3 (a 4-fold eigenvalue with a 4-dimensional
    eigenspace): each gets its own monomial vector (the shift structure), so the generating
    configuration is found; the single null vector of the simple-root path mixed them."""
    _, robot = crx
    q = np.array([0.0, math.pi / 2, math.pi / 2, -math.pi / 2, math.pi / 2, -math.pi / 2])
    res = general6r.solve(robot, reference.fk(robot, q[None]))
    sols = res.q[0, :res.counts[0]]
    assert _contains(sols, q)
    assert np.sum(np.abs(wrap_angle(sols[:, 2] - q[2])) < 1e-6) >= 4
    assert np.abs(reference.fk_matrix(robot, sols) - reference.fk_matrix(robot, q)).max() < 1e-10


@pytest.mark.parametrize("robot", ["crx10ia", "xarm6"])
def test_newton_giving_up_on_far_candidates_keeps_every_answer(robot, monkeypatch):
    """The first solve's Newton stops a far candidate (error above 1e-6, not halving) from step
    general6r.NEWTON_FAR on: on random poses within the limits the solutions, counts and flags are
    those of Newton taking every step (NEWTON_FAR past G6_NEWTON_MAX: the rule never applies),
    with fewer Newton evaluations (the spurious candidates of near chains and clusters no longer
    take all G6_NEWTON_MAX steps)."""
    r = derive.load_robot(robot)
    rng = np.random.default_rng(31)
    lo, hi = np.maximum(r.limits[:, 0], -np.pi), np.minimum(r.limits[:, 1], np.pi)
    poses = reference.fk(r, rng.uniform(lo, hi, (300, 6)))
    steps = []
    err_jt = general6r._err_jt
    monkeypatch.setattr(general6r, "_err_jt", lambda t, *a: steps.append(len(t)) or err_jt(t, *a))
    fast = general6r.solve(r, poses)
    n_fast = len(steps)
    steps.clear()
    monkeypatch.setattr(general6r, "NEWTON_FAR", general6r.G6_NEWTON_MAX + 1)
    every = general6r.solve(r, poses)
    assert n_fast < len(steps)
    assert np.array_equal(fast.counts, every.counts) and fast.counts.sum() > 6 * len(poses)
    assert np.array_equal(fast.singular, every.singular)
    assert np.array_equal(fast.degenerate, every.degenerate)
    ok = np.isfinite(every.q)
    assert np.array_equal(ok, np.isfinite(fast.q))
    assert np.abs(wrap_angle(fast.q[ok] - every.q[ok])).max() < 1e-12
