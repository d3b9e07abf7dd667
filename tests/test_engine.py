"""The engine the closed-form classes share (issue 30, item 2): the one ZYZ decomposition
(derive.ik.euler), the one finish step and result type (derive.ik.finish), the one
nearest-winding rule (derive.ik.select), the class registry (derive.ik.classes) and the one
tolerance module (derive.ik.tolerances)."""

import math

import numpy as np
import pytest

from derive import reference
from derive.algebra.rotations import rot_y, rot_z
from derive.ik import classes, closed_form, euler, finish, panda, redundant, select, srs, tolerances
from derive.kinematics.fk import fk_matrix
from derive.model.robot import load_robot


def test_zyz_matrix_is_the_product_of_the_three_rotations():
    rng = np.random.default_rng(1)
    a, b, c = rng.uniform(-math.pi, math.pi, (3, 50))
    np.testing.assert_allclose(euler.zyz_matrix(a, b, c), rot_z(a) @ rot_y(b) @ rot_z(c), atol=1e-15)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_zyz_recovers_the_rotation_on_both_branches(sign):
    rng = np.random.default_rng(2)
    a, c = rng.uniform(-math.pi, math.pi, (2, 200))
    b = rng.uniform(0.01, math.pi - 0.01, 200)
    m = rot_z(a) @ rot_y(b) @ rot_z(c)
    ra, rb, rc, sing = euler.zyz(m, sign, 0.0)
    assert not sing.any() and np.all(np.sign(np.sin(rb)) == sign)
    np.testing.assert_allclose(rot_z(ra) @ rot_y(rb) @ rot_z(rc), m, atol=1e-14)
    if sign > 0:                      # the + branch is the generating angles themselves
        np.testing.assert_allclose(rb, b, atol=1e-13)
        np.testing.assert_allclose(np.cos(ra - a), 1.0, atol=1e-13)


@pytest.mark.parametrize("b", [0.0, math.pi])
def test_zyz_takes_the_free_angle_at_its_singularity(b):
    """sin b = 0: only a + c (b = 0) or a - c (b = pi) is fixed; a is the given free value and the
    product still reproduces m exactly, the row is flagged."""
    a, c, free = 0.7, -1.2, np.array([0.3, -2.0])
    m = np.broadcast_to(rot_z(np.array(a)) @ rot_y(np.array(b)) @ rot_z(np.array(c)), (2, 3, 3))
    ra, rb, rc, sing = euler.zyz(m, 1.0, free)
    assert sing.all() and np.array_equal(ra, free) and np.allclose(rb, b)
    np.testing.assert_allclose(rot_z(ra) @ rot_y(rb) @ rot_z(rc), m, atol=1e-14)


def test_duplicates_keeps_the_first_of_a_group_and_wraps():
    cand = np.array([[[0.1, 0.2], [0.1 + 1e-7, 0.2], [math.pi - 1e-8, 0.0], [-math.pi + 1e-8, 0.0],
                      [1.0, 1.0], [1.0, 1.0 + 2e-6]]])
    ok = np.ones((1, 6), dtype=bool)
    assert finish.duplicates(cand, ok).tolist() == [[False, True, False, True, False, False]]
    # a candidate next to one that failed the check is not a duplicate of it
    ok[0, 0] = False
    assert finish.duplicates(cand, ok)[0, 1] == np.False_


def test_check_accepts_the_generating_configuration_and_measures_the_residual():
    """The residual is the larger of the position error (m) and the rotation angle (rad), here
    computed again from 4x4 matrices."""
    rng = np.random.default_rng(3)
    q = rng.uniform(-3, 3, (20, 6))
    poses = reference.fk("ur5", q)
    off = q + np.array([0, 0, 0, 0, 0, 3e-8])                     # joint 6: a pure rotation
    far = q + np.array([2e-6, 0, 0, 0, 0, 0])
    ok, res = finish.check(load_robot("ur5"), poses, np.stack([q, off, far], 1))
    assert ok[:, 0].all() and res[:, 0].max() < 1e-12
    a, b = fk_matrix("ur5", off), fk_matrix("ur5", q)
    rel = np.swapaxes(a[:, :3, :3], 1, 2) @ b[:, :3, :3]       # angle = atan2(|vee(R - R^T)| / 2, (tr R - 1) / 2)
    vee = np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], 1)
    ang = np.arctan2(0.5 * np.linalg.norm(vee, axis=1), 0.5 * (np.trace(rel, axis1=1, axis2=2) - 1))
    np.testing.assert_allclose(res[:, 1], np.maximum(ang, np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1)),
                               rtol=1e-5)
    assert not ok[:, 1].any() and not ok[:, 2].any()              # 3e-8 rad > ACCEPT_ANGLE


def test_finish_compacts_in_branch_order():
    robot = load_robot("ur5")
    q = np.array([[0.1, -1.0, 1.2, 0.3, 0.8, -0.4]])
    pose = reference.fk("ur5", q)
    cand = np.full((1, 4, 6), np.nan)
    cand[0, 1], cand[0, 3] = q[0], q[0] + 1e-9                    # a duplicate
    cand[0, 2] = q[0] + 0.5                                         # does not reproduce the pose
    qq, counts, branch, sing, res = finish.finish(robot, pose, cand, np.array([[0, 1, 0, 0]], bool))
    assert counts.tolist() == [1] and branch.tolist() == [[1, -1, -1, -1]]
    assert sing.tolist() == [[True, False, False, False]] and np.isnan(qq[0, 1:]).all()
    np.testing.assert_array_equal(qq[0, 0], q[0])
    assert res[0, 0] < 1e-12 and np.isnan(res[0, 1:]).all()


def test_nearest_windings_and_inside_limits():
    lo, hi = np.array([-math.pi, -1.0]), np.array([2 * math.pi, 1.0])
    best = select.nearest_windings(np.array([[-3.1, 0.5]]), np.array([[3.1, 0.4]]), lo, hi)
    np.testing.assert_allclose(best, [[-3.1 + 2 * math.pi, 0.5]])
    best = select.nearest_windings(np.array([[0.0, 2.0]]), np.array([[0.0, 0.0]]), lo, hi)
    assert best[0, 0] == 0.0 and np.isnan(best[0, 1])             # 2.0 and its windings are outside
    lim = np.stack([lo, hi], 1)
    assert select.inside_limits(np.array([[-3.1 + 4 * math.pi, 0.9], [0.0, 1.5], [np.nan, 0.0]]),
                                lim).tolist() == [True, False, False]


@pytest.mark.parametrize("name, want", [("ur5", "ur"), ("puma560", "spherical"), ("irb120", "spherical"),
                                        ("iiwa7", "srs"), ("panda", "panda"), ("fr3", "panda"),
                                        ("general-6r", None), ("kunze-2r", None)])
def test_registry_detects_each_class(name, want):
    hit = classes.detect(name)
    assert (hit and hit[0].name) == want
    if hit:
        cls, geo = hit
        assert len(cls.branch_labels) == 3 and cls.steps and cls.singular_sets and len(cls.reasons) == 2
        assert cls.dof == load_robot(name).dof and cls is classes.find(cls.name)


@pytest.mark.parametrize("name", ["ur10", "kr6-r900", "iiwa14", "panda"])
def test_registry_candidates_through_the_finish_step_are_the_solvers_solutions(name):
    """The registry's candidates, finished, equal the public solvers' solutions (to rounding):
    the 6R ik_batch and the 7R redundant.solve."""
    cls, geo = classes.detect(name)
    rng = np.random.default_rng(4)
    q = rng.uniform(-2.5, 2.5, (40, cls.dof))
    poses = reference.fk(name, q)
    if cls.dof == 6:
        cand, sing, _ = cls.candidates(geo, poses)
        want, counts = reference.ik_batch(name, poses)
    else:
        free = q[:, 6] if cls.free == "q7" else srs.arm_angle(name, q)
        cand, sing, _ = cls.candidates(geo, poses, free)
        r = redundant.solve(name, poses, free)
        want, counts = r.q, r.counts
    got, cnt, _, _, _ = finish.finish(load_robot(name), poses, cand, sing)
    assert np.array_equal(cnt, counts) and (cnt >= 1).all()
    assert np.array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_one_result_type_with_the_former_field_names():
    q = np.radians([10, 20, 30, -40, 50, 60, 70])
    r = panda.ik_q7("panda", reference.fk("panda", q), q[6])
    s = srs.ik_psi("iiwa7", reference.fk("iiwa7", q), 0.3)
    assert type(r) is type(s) is finish.Solutions is panda.PandaSolutions is srs.SRSSolutions is redundant.Solutions
    assert r.branches is r.branch and r.reasons is r.reason and s.count is s.counts
    assert r.residual[0, :r.counts[0]].max() < 1e-12 and np.isnan(r.residual[0, r.counts[0]:]).all()
    one = r.rows(0)
    assert one.q.shape == (8, 7) and one.reason == "" and one.free == q[6]


def test_tolerances_are_defined_once():
    """No IK module redefines a tolerance of derive.ik.tolerances (they import it)."""
    import inspect
    names = {n for n in dir(tolerances) if n.isupper()}
    for mod in (closed_form, srs, panda, redundant, select, euler, finish):
        src = inspect.getsource(mod)
        for n in names:
            assert f"\n{n} = " not in src, f"{mod.__name__} redefines {n}"
    assert tolerances.ACCEPT_POSITION == tolerances.ACCEPT_ANGLE == 1e-8


@pytest.mark.parametrize("name, module", [("iiwa14", "srs"), ("panda", "panda"), ("fr3", "panda"),
                                          ("z1", "parallel3")])
def test_registry_steps_name_the_subproblems_the_candidates_call(name, module, monkeypatch):
    """The 7R classes (and the three-parallel class) are compositions of derive.ik.subproblems:
    the subproblems named in the registry's steps ("sp3: ...") are exactly the ones the class's
    candidates call, and each call returns exact solutions on most poses."""
    import importlib
    import re

    mod = importlib.import_module(f"derive.ik.{module}")
    called: dict = {}
    for k in range(1, 7):
        fn = getattr(mod, f"sp{k}", None)
        if fn is not None:
            def spy(*args, _fn=fn, _k=k):
                out = _fn(*args)
                called.setdefault(_k, []).append(float(np.mean(out.exact)))
                return out
            monkeypatch.setattr(mod, f"sp{k}", spy)
    cls, geo = classes.detect(name)
    rng = np.random.default_rng(9)
    lo, hi = np.asarray(load_robot(name).limits, dtype=float).T
    q = rng.uniform(np.maximum(lo, -3.0), np.minimum(hi, 3.0), (30, cls.dof))
    poses = reference.fk(name, q)
    if cls.dof == 7:
        free = srs.arm_angle(name, q) if cls.free == "psi" else q[:, 6]
        cand = cls.candidates(geo, poses, free)[0]
    else:
        cand = cls.candidates(geo, poses)[0]
    named = {int(m) for _, text in cls.steps for m in re.findall(r"\bsp(\d)\b", text)}
    assert named and set(called) == named, (sorted(called), sorted(named))
    assert all(max(rates) > 0.5 for rates in called.values()), called
    assert np.isfinite(cand).any(axis=-1).all(axis=-1).any()
