"""Closed-form IK of the spherical-wrist (OPW) class: derive.ik.spherical, the IK program of the
class's equations and its kernels, against the independent IK of tests/independent_sw.py (its
own geometry from FK, Paden-Kahan subproblems) and against EAIK.

Per robot (fixed seed): 10^4 random configurations within the limits, where every solution
reproduces the pose to 1e-10 m and rad, the generating configuration is among the solutions,
and the count equals the independent IK's; 500 configurations on each singular set (wrist
theta5 = 0, wrist centre on axis 1, elbow at full stretch) with exact solutions and no NaN;
1000 poses whose exact solution sets equal EAIK's.
"""

from __future__ import annotations

import math

import independent_sw as indep
import numpy as np
import pytest

import derive
from derive import reference
from derive.cli import SW_ROBOTS, main
from derive.codegen.loader import kernels
from derive.ik import spherical
from derive.ik.closed_form import classify
from derive.model.robot import list_robots
from derive.refinement.functions import functions
from derive.symbolic.equations import derive_equations

SEED = 15
N = 10_000
N_SINGULAR = 500
N_EAIK = 1000
TOL = 1e-10

SW = [r for r in list_robots() if spherical.is_spherical(r)]
#: robots whose kernels are compared on every pose: the shipped ones, and the PUMA (lateral offset)
KERNEL_ROBOTS = list(SW_ROBOTS) + ["puma560"]


def _wrapped(a):
    return np.abs(np.mod(a + math.pi, 2 * math.pi) - math.pi)


def _check_solutions(robot, poses, q, counts, q_true=None, tol=TOL, q_tol=1e-8, joints=None):
    """Every solution (first counts[i] rows, the rest NaN) reproduces its pose; q_true (if given)
    is among them. Returns the largest position and rotation errors."""
    n, m, dof = q.shape
    slots = np.arange(m)[None, :] < counts[:, None]
    assert np.all(np.isfinite(q[slots])), "NaN inside the solution count"
    assert np.all(np.isnan(q[~slots])), "padding is not NaN"
    rows, cols = np.nonzero(slots)
    dpos, drot = reference.pose_error(reference.fk(robot, q[rows, cols]), poses[rows])
    assert dpos.max() < tol and drot.max() < tol, (robot, dpos.max(), drot.max())
    if q_true is not None:
        cols = slice(None) if joints is None else list(joints)
        d = np.nanmin(_wrapped(q - q_true[:, None, :])[..., cols].max(axis=-1), axis=1)
        assert np.all(d < q_tol), (robot, int(np.sum(d >= q_tol)), float(np.nanmax(d)))
    return dpos.max(), drot.max()


def test_the_library_has_at_least_eight_spherical_wrist_arms_with_sources():
    assert len(SW) >= 8, SW
    for name in ("irb120", "irb6700", "kr6-r900", "kr210-r2700", "lrmate200id", "gp8", "puma560"):
        assert name in SW
        r = derive.load_robot(name)
        assert r.source and len(r.source) > 20
        c = classify(name)
        assert c.closed_form and any("spherical-wrist class" in n for n in c.notes)


def test_published_opw_parameters_are_recovered():
    """The canonical parameters found from the axes equal the OPW sets published with the
    ROS-Industrial packages (opw_parameters_*.yaml; KUKA KR 6 R900-2: a1 0.025, a2 -0.025,
    b 0, c1 0.400, c2 0.455, c3 0.420, c4 0.090, sign corrections -1 1 1 -1 1 -1) and the
    ABB IRB 120 product specification (0.290, 0.270, 0.070, 0.302, 0.072)."""
    g = spherical.sw_geometry("kr6-r900")
    assert g.values == pytest.approx({"a1": 0.025, "a2": -0.025, "b": 0.0, "c1": 0.400, "c2": 0.455,
                                      "c3": 0.420, "c4": 0.090}, abs=1e-12)
    assert list(g.signs) == [-1, 1, 1, -1, 1, -1]
    g = spherical.sw_geometry("irb120")
    assert g.values == pytest.approx({"a1": 0.0, "a2": -0.070, "b": 0.0, "c1": 0.290, "c2": 0.270,
                                      "c3": 0.302, "c4": 0.072}, abs=1e-12)
    assert g.error < 1e-14


def test_other_arms_are_not_of_the_class():
    for name in ("ur5", "general-6r", "seed-arm", "kunze-2r"):
        with pytest.raises(derive.DeriveError, match="not a spherical-wrist arm"):
            spherical.sw_geometry(name)


def test_class_equations_are_verified_once_for_every_arm():
    """One derivation serves the class: the canonical chains of two arms give the same
    equations (lengths as symbols), each verified symbolically and numerically."""
    c1, sets1 = derive_equations(spherical.canonical_robot(spherical.sw_geometry("irb120")))
    c2, sets2 = derive_equations(spherical.canonical_robot(spherical.sw_geometry("kr210-r2700")))
    assert [s.key for s in sets1] == ["P", "O"]
    for a, b in zip(sets1, sets2):
        assert [(e.id, str(e.lhs), str(e.rhs)) for e in a.equations] == \
               [(e.id, str(e.lhs), str(e.rhs)) for e in b.equations]
    for s in sets1 + sets2:
        assert all(e.symbolic and e.numeric_error < 1e-12 for e in s.equations)


@pytest.mark.parametrize("name", SW)
def test_reference_ik_round_trips_and_counts(name):
    rng = np.random.default_rng(SEED)
    q_true = indep.random_configs(name, N, rng)
    poses = reference.fk(name, q_true)
    q, counts = reference.ik_batch(name, poses)
    _check_solutions(name, poses, q, counts, q_true)
    T = reference.fk_matrix(name, q_true)
    independent = np.array([len(s) for s in indep.ik_all_batch(name, T)])
    assert np.array_equal(counts, independent), np.nonzero(counts != independent)[0][:5]


@pytest.mark.parametrize("name", KERNEL_ROBOTS)
@pytest.mark.parametrize("lang", ["numpy", "c"])
def test_kernels_equal_the_reference(name, lang):
    rng = np.random.default_rng(SEED + 1)
    q_true = indep.random_configs(name, N, rng)
    poses = reference.fk(name, q_true)
    q, counts = kernels(name, lang).ik(poses)
    _check_solutions(name, poses, q, counts, q_true)
    q_ref, c_ref = reference.ik_batch(name, poses)
    assert np.array_equal(counts, c_ref)
    both = ~np.isnan(q_ref)
    assert np.array_equal(both, ~np.isnan(q))
    assert _wrapped(q[both] - q_ref[both]).max() < 1e-9


@pytest.mark.parametrize("name", KERNEL_ROBOTS)
def test_python_kernel_and_single_c_call_agree_with_the_batch(name):
    rng = np.random.default_rng(SEED + 2)
    poses = reference.fk(name, indep.random_configs(name, 50, rng))
    q_b, c_b = kernels(name, "c").ik(poses)
    py = kernels(name, "python")
    c = kernels(name, "c")
    for i, p in enumerate(poses):
        for k in (py, c):
            q1, c1 = k.ik(p)
            q1 = np.asarray(q1, dtype=float)
            assert int(c1) == c_b[i]
            assert np.allclose(q1[:c1], q_b[i, :c1], atol=1e-12, rtol=0)


def _offset_shoulder_configs(name, n, rng):
    """Configurations of an arm with a lateral offset b != 0 on its shoulder singular set: the
    wrist centre at distance |b| from axis 1 (in the canonical chain the arm-plane coordinate
    a1 + c2 sin t2 + k sin(t2 + t3 + psi3) is 0), the two theta1 roots one. Made from the
    canonical parameters; tests/independent_sw.py confirms the rank loss of the Jacobian."""
    g = spherical.sw_geometry(name)
    k, psi = math.hypot(g.a2, g.c3), math.atan2(g.a2, g.c3)
    lo, hi = (np.array(v) for v in zip(*derive.load_robot(name).limits))
    found = []
    while len(found) < n:
        th = rng.uniform(-math.pi, math.pi, size=(4 * n, 6))
        v = -(g.a1 + g.c2 * np.sin(th[:, 1])) / k
        ok = np.abs(v) <= 1
        root = np.where(rng.integers(0, 2, 4 * n) == 1, np.arcsin(np.clip(v, -1, 1)),
                        math.pi - np.arcsin(np.clip(v, -1, 1)))
        th[:, 2] = root - psi - th[:, 1]
        q = g.from_canonical(th)
        ok &= np.all((q >= lo) & (q <= hi), axis=1)
        found += list(q[ok])
    return np.array(found[:n])


@pytest.mark.parametrize("kind", ["wrist", "shoulder", "elbow"])
@pytest.mark.parametrize("name", SW)
def test_singular_sets_give_exact_solutions_without_nan(name, kind):
    rng = np.random.default_rng(SEED + 3)
    if kind == "shoulder" and spherical.sw_geometry(name).b != 0:
        q_true = _offset_shoulder_configs(name, N_SINGULAR, rng)
        assert np.all(indep.sigma_min(name, q_true[:20]) < 1e-7)
    else:
        q_true = indep.singular_configs(name, kind, N_SINGULAR, rng)
    poses = reference.fk(name, q_true)
    runs = [reference.ik_batch(name, poses)]
    if name in KERNEL_ROBOTS:
        runs += [kernels(name, lang).ik(poses) for lang in ("numpy", "c")]
    for q, counts in runs:
        assert np.all(counts >= 1)
        # at full stretch the generating arm joints are found: a double root, whose rounding
        # (the conditioning there is sqrt(eps)) moves theta3 by up to ~1e-8 rad, and q4 - q6 by
        # that over sin q5 (so q4, q6 are left to the pose check); on the wrist and shoulder
        # sets one joint is free, so the pose (not the configuration) is checked
        _check_solutions(name, poses, q, counts, q_true if kind == "elbow" else None, q_tol=1e-6,
                         joints=(0, 1, 2, 4))
    if kind == "wrist":
        q, counts = runs[0]
        assert np.all(np.nanmin(_wrapped(q[:, :, 4] - q_true[:, None, 4]), axis=1) < 1e-9)


@pytest.mark.parametrize("name", SW)
def test_solution_sets_equal_eaik(name):
    pytest.importorskip("eaik")
    rng = np.random.default_rng(SEED + 4)
    q_true = indep.random_configs(name, N_EAIK, rng)
    poses = reference.fk(name, q_true)
    q, counts = reference.ik_batch(name, poses)
    theirs = indep.eaik_solutions_batch(name, reference.fk_matrix(name, q_true))
    worst = 0.0
    for i, sols in enumerate(theirs):
        ours = q[i, :counts[i]]
        assert len(sols) == counts[i], (name, i, len(sols), counts[i])
        for s in sols:
            d = _wrapped(ours - s).max(axis=1).min()
            worst = max(worst, d)
    assert worst < 1e-8, worst


def test_unreachable_pose_gives_no_solution_and_a_reason():
    far = reference.fk("irb120", np.zeros(6)).copy()
    far[4:] = derive.dualquat.from_rt(far[:4], np.array([2.0, 0.0, 0.5]))[4:]
    sols = reference.ik("irb120", far)
    assert len(sols) == 0 and "unreachable" in sols.reason
    q, c = kernels("irb120", "c").ik(far[None])
    assert c[0] == 0 and np.all(np.isnan(q))
    # the PUMA's lateral offset b: the wrist centre cannot come nearer axis 1 than |b|
    g = spherical.sw_geometry("puma560")
    near = derive.dualquat.from_rt(np.array([1.0, 0, 0, 0]), np.array([0.0, 0.0, 0.3]))
    pose = derive.dualquat.mul(derive.dualquat.mul(g.base, near), g.tool)
    sols = reference.ik("puma560", pose)
    assert len(sols) == 0 and "lateral offset" in sols.reason


def test_reference_takes_the_free_wrist_joint_from_q_ref():
    q = np.array([0.3, -0.2, 0.4, 1.1, 0.0, -0.5])
    pose = reference.fk("irb120", q)
    sols = reference.ik("irb120", pose, q_ref=q)
    assert sols.singular.any()
    hit = sols[sols.singular]
    assert np.min(_wrapped(hit - q).max(axis=1)) < 1e-9
    # without q_ref the kernels and the reference take q4 = 0, joint 6 the rest
    q_k, c_k = kernels("irb120", "c").ik(pose[None])
    assert np.any(np.abs(q_k[0, :c_k[0], 3]) < 1e-12)


def test_casadi_ik_of_a_spherical_wrist_arm():
    ik = functions("irb120")["ik"]
    rng = np.random.default_rng(SEED + 5)
    poses = reference.fk("irb120", indep.random_configs("irb120", 100, rng))
    q_ref, c_ref = reference.ik_batch("irb120", poses)
    for i, p in enumerate(poses):
        Q, valid = (np.array(x) for x in ik(p))
        cand = Q.T[valid.ravel() > 0.5]
        dpos, drot = reference.pose_error(reference.fk("irb120", cand), np.tile(p, (len(cand), 1)))
        assert dpos.max() < TOL and drot.max() < TOL
        for s in q_ref[i, :c_ref[i]]:
            assert _wrapped(cand - s).max(axis=1).min() < 1e-9


def test_cli_ik_kernels_and_appendix_of_a_spherical_wrist_arm(tmp_path, capsys):
    assert main(["ik", "puma560", "--q", "0.1", "0.2", "-0.3", "0.4", "0.5", "0.6"]) == 0
    out = capsys.readouterr().out
    assert "8 solution(s)" in out
    assert main(["kernels", "puma560", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "puma560" / "puma560_kinematics.c").exists()
    assert main(["appendix", "tx2-60", "--out", str(tmp_path), "--quiet"]) == 0
    text = (tmp_path / "tx2-60" / "appendix.md").read_text()
    assert "spherical wrist with an ortho-parallel base" in text and "(P.13)" in text
    assert main(["ik", "tx2-60", "--out", str(tmp_path), "--quiet"]) == 0
    text = (tmp_path / "tx2-60" / "ik.md").read_text()
    assert "check 100 %" in text and "(O.16)" in text
