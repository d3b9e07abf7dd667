"""Tests of tests/independent_sw.py, the independent OPW (spherical wrist) IK used to count and
check the project's closed-form IK: round trips from random configurations, the pose accuracy
of every solution, the solution counts, agreement with EAIK, and the singular sets.

Robots: every library robot of class OPW (derive.model.classify, as ``derive.classify``
reports it), found when the tests run; irb120 and irb1600 at least.
"""

from __future__ import annotations

import ast
import time
from collections import Counter
from pathlib import Path

import independent_sw as sw
import numpy as np
import pytest

import derive
from derive.model.classify import classify
from derive.model.robot import list_robots

SEED = 20261202
N_ROUNDTRIP = 2000
N_EAIK = 500
N_SINGULAR = 50


def _opw_robots() -> list[str]:
    out = []
    for name in list_robots():
        try:
            if classify(name).cls == "OPW":
                out.append(name)
        except derive.DeriveError:
            continue
    return out


OPW = _opw_robots()


def _same_class(a, b, tol):
    """Rows of a (k, 6) each matched by a row of b (m, 6) within tol modulo 2 pi."""
    if len(a) == 0:
        return True
    if len(b) == 0:
        return False
    d = np.max(np.abs(sw.wrap(a[:, None, :] - b[None, :, :])), axis=-1)
    return bool(np.all(d.min(axis=1) < tol))


def _contains(sols, q, tol):
    return len(sols) > 0 and bool(np.any(np.all(np.abs(sw.wrap(sols - q)) < tol, axis=1)))


def _stack(sols):
    allq = np.vstack([s for s in sols] + [np.zeros((0, 6))])
    idx = np.repeat(np.arange(len(sols)), [len(s) for s in sols])
    return allq, idx


def test_library_has_the_opw_robots():
    assert {"irb120", "irb1600"} <= set(OPW)


def test_module_is_independent():
    """tests/independent_sw.py imports nothing from derive.ik, derive.codegen, derive.symbolic."""
    tree = ast.parse(Path(sw.__file__).read_text())
    banned = ("derive.ik", "derive.codegen", "derive.symbolic")
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            names = [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
        else:
            continue
        for n in names:
            assert not n.startswith(banned), n
            assert n.split(".")[0] in ("__future__", "math", "dataclasses", "numpy", "derive",
                                       "eaik"), n


@pytest.mark.parametrize("name", list_robots())
def test_geometry_agrees_with_classify(name):
    """The FK-extracted structure test accepts exactly the robots classify calls OPW."""
    try:
        cls = classify(name).cls
    except derive.DeriveError:
        pytest.skip(f"{name}: not classifiable")
    try:
        sw.geometry(name)
        ok = True
    except sw.NotOPW:
        ok = False
    assert ok == (cls == "OPW")


@pytest.mark.parametrize("name", OPW)
def test_geometry_product_of_exponentials(name):
    """exp(xi_1 q1) ... exp(xi_6 q6) T0 from the extracted axes reproduces fk_matrix."""
    g = sw.geometry(name)
    assert sw.geometry(name) is g                       # cached
    assert np.allclose(np.linalg.norm(g.H, axis=1), 1.0, atol=1e-15)
    q = sw.random_configs(name, 200, np.random.default_rng(SEED))
    assert np.max(np.abs(g.fk(q) - derive.reference.fk_matrix(name, q))) < 1e-12
    assert g.spread < 1e-12


@pytest.mark.parametrize("name", OPW)
def test_roundtrip_random(name):
    """2000 random configurations within the limits: the generating configuration is among the
    solutions, every solution reproduces the pose to 1e-10 (fk_matrix and the dual-quaternion
    fk), and the counts are 8, or 4 where the q1 + pi branch is out of reach (shoulder offset)."""
    rng = np.random.default_rng(SEED)
    q = sw.random_configs(name, N_ROUNDTRIP, rng)
    T = derive.reference.fk_matrix(name, q)
    sols = sw.ik_all_batch(name, T)
    assert all(s.shape[1] == 6 and np.all(np.isfinite(s)) for s in sols)
    assert all(np.all((s > -np.pi) & (s <= np.pi)) for s in sols)
    missing = [i for i, (s, qq) in enumerate(zip(sols, q)) if not _contains(s, sw.wrap(qq), 1e-8)]
    assert not missing, f"generating configuration not found for {len(missing)} poses"
    allq, idx = _stack(sols)
    dp, dr = sw.pose_errors(derive.reference.fk_matrix(name, allq), T[idx])
    assert dp.max() < 1e-10 and dr.max() < 1e-10
    dpq, drq = derive.reference.pose_error(derive.reference.fk(name, allq),
                                           derive.reference.fk(name, q[idx]))
    assert dpq.max() < 1e-10 and drq.max() < 1e-10
    # distinct: no two solutions of a pose within 1e-6 in every joint
    for s in sols:
        if len(s) < 2:
            continue
        d = np.max(np.abs(sw.wrap(s[:, None] - s[None])), axis=-1) + np.eye(len(s))
        assert d.min() > 1e-6
    hist = Counter(len(s) for s in sols)
    print(f"\n{name}: count histogram over {N_ROUNDTRIP} random poses: {dict(sorted(hist.items()))}")
    assert set(hist) <= {4, 8}
    g = sw.geometry(name)
    # no shoulder offset (axes 1 and 2 intersect): the q1 branches mirror each other, both
    # reach, 8 everywhere; with an offset the q1 + pi branch is often out of reach: 4
    n12 = np.cross(g.H[0], g.H[1])
    if abs(np.dot(g.P[1] - g.P[0], n12)) / np.linalg.norm(n12) < 1e-12:
        assert set(hist) == {8}
    assert hist[8] > 0
    assert len(sw.ik_all(name, T[0])) == sw.count(name, T[0]) == len(sols[0])
    assert np.array_equal(sw.ik_all(name, T[0]), sols[0])


@pytest.mark.parametrize("name", OPW)
def test_unreachable(name):
    T = np.eye(4)
    T[:3, 3] = (10.0, 0.0, 0.0)
    assert sw.ik_all(name, T).shape == (0, 6)
    assert sw.count(name, T) == 0
    assert sw.eaik_solutions(name, T).shape[1] == 6


@pytest.mark.parametrize("name", OPW)
def test_against_eaik(name):
    """500 random poses: EAIK's exact (not least-squares) solutions equal ours as sets, modulo
    2 pi, within 1e-8."""
    pytest.importorskip("eaik")
    rng = np.random.default_rng(SEED + 1)
    q = sw.random_configs(name, N_EAIK, rng)
    T = derive.reference.fk_matrix(name, q)
    mine = sw.ik_all_batch(name, T)
    theirs = [sw.eaik_solutions(name, t) for t in T]
    bad = [i for i, (a, b) in enumerate(zip(mine, theirs))
           if len(a) != len(b) or not _same_class(a, b, 1e-8) or not _same_class(b, a, 1e-8)]
    worst = 0.0
    for a, b in zip(mine, theirs):
        if len(a) and len(a) == len(b):
            d = np.max(np.abs(sw.wrap(a[:, None] - b[None])), axis=-1)
            worst = max(worst, float(d.min(axis=1).max()))
    print(f"\n{name}: EAIK agrees on {N_EAIK - len(bad)}/{N_EAIK} poses, largest joint difference "
          f"{worst:.2e} rad; EAIK counts {dict(sorted(Counter(len(b) for b in theirs).items()))}")
    assert not bad, f"{len(bad)} poses differ, first {bad[:5]}"


def _perturbed(name, q, joint, step=0.1):
    """q with one joint moved by +-step, staying within the limits."""
    lo, hi = sw.geometry(name).limits[joint]
    out = q.copy()
    up = q[:, joint] + step
    out[:, joint] = np.where(up <= hi, up, q[:, joint] - step)
    assert np.all(out[:, joint] >= lo)
    return out


KINDS = {"wrist": 4, "shoulder": 1, "elbow": 2}     # the joint that leaves the set


@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("name", OPW)
def test_singular_configs(name, kind):
    g = sw.geometry(name)
    rng = np.random.default_rng(SEED + 2)
    try:
        q = sw.singular_configs(name, kind, N_SINGULAR, rng)
    except sw.SingularSetUnreachable as e:
        pytest.skip(str(e))
    assert q.shape == (N_SINGULAR, 6)
    assert np.all((q >= g.limits[:, 0]) & (q <= g.limits[:, 1]))
    # the defining property, exactly
    h1, h2, h3, h4, h5, h6 = g.H
    W = g.wrist_centre(q)
    if kind == "wrist":
        w = np.einsum("nij,j->ni", sw.rot(h5, q[:, 4]), h6)
        assert np.linalg.norm(np.cross(w, h4), axis=1).max() < 1e-14
    elif kind == "shoulder":
        assert np.linalg.norm(np.cross(W - g.P[0], h1), axis=1).max() < 1e-13
    else:
        a, b = g.W0 - g.P[2], g.P[1] - g.P[2]
        reach = (np.linalg.norm(a - a.dot(h3) * h3) + np.linalg.norm(b - b.dot(h3) * h3))
        # the wrist centre in the arm's own frame, before axis 1: distance from axis 2
        W1 = np.einsum("nji,nj->ni", sw.rot(h1, q[:, 0]), W - g.P[0]) + g.P[0]
        dist = np.linalg.norm(np.cross(W1 - g.P[1], h2), axis=1)
        assert np.abs(dist - reach).max() < 1e-13
    # singular: the finite-difference Jacobian has rank 5; one step off the set it has rank 6
    smin = sw.sigma_min(name, q)
    ctrl = sw.sigma_min(name, _perturbed(name, q, KINDS[kind]))
    print(f"\n{name} {kind}: sigma_min on the set <= {smin.max():.1e}, "
          f"one joint 0.1 rad off >= {ctrl.min():.1e}")
    assert smin.max() < 1e-7
    assert ctrl.min() > 1e-5
    # the IK there: finite, every solution reproduces the pose, the generating class is found
    T = derive.reference.fk_matrix(name, q)
    sols = sw.ik_all_batch(name, T)
    assert all(np.all(np.isfinite(s)) for s in sols)
    allq, idx = _stack(sols)
    dp, dr = sw.pose_errors(derive.reference.fk_matrix(name, allq), T[idx])
    assert dp.max() < 1e-10 and dr.max() < 1e-10
    qw = sw.wrap(q)
    for s, qq in zip(sols, qw):
        if kind == "elbow":
            # the two q3 roots are one; joint precision at a stretch is sqrt(eps) intrinsically
            assert _contains(s, qq, 1e-6)
        elif kind == "wrist":
            # the family q4 + sign * q6 = const is represented by q4 = 0
            sign = float(h4 @ sw.rot(h5, qq[4]) @ h6)
            ks, kq = (np.column_stack([x[:, :3], x[:, 4], x[:, 3] + sign * x[:, 5]])
                      for x in (s, qq[None]))
            m = np.all(np.abs(sw.wrap(ks - kq)) < 1e-8, axis=1)
            assert m.sum() == 1 and np.abs(s[m, 3]).max() == 0.0
        else:
            # every q1 works: the representatives q1 = 0 and q1 = pi
            assert np.all(np.isclose(np.abs(s[:, 0]), 0.0) | np.isclose(s[:, 0], np.pi))
            m = np.all(np.abs(sw.wrap(s[:, :3] - np.r_[0.0, qq[1:3]])) < 1e-8, axis=1)
            assert m.any()
    hist = Counter(len(s) for s in sols)
    print(f"{name} {kind}: count histogram {dict(sorted(hist.items()))}")


@pytest.mark.parametrize("name", OPW)
def test_singular_against_eaik(name):
    """What EAIK does on the singular sets (reported, and checked where it is a plain subset):
    its exact solutions reproduce the pose and, off the degenerate families, are ours."""
    pytest.importorskip("eaik")
    rng = np.random.default_rng(SEED + 3)
    lines = []
    for kind in KINDS:
        try:
            q = sw.singular_configs(name, kind, N_SINGULAR, rng)
        except sw.SingularSetUnreachable:
            continue
        T = derive.reference.fk_matrix(name, q)
        mine = sw.ik_all_batch(name, T)
        theirs = [sw.eaik_solutions(name, t) for t in T]
        allq, idx = _stack(theirs)
        if len(allq):
            dp, dr = sw.pose_errors(derive.reference.fk_matrix(name, allq), T[idx])
            assert dp.max() < 1e-9 and dr.max() < 1e-9
        if kind != "shoulder":          # EAIK picks its own q1 in the shoulder family
            assert all(_same_class(b, a, 1e-6) for a, b in zip(mine, theirs))
        lines.append(f"{kind}: ours {dict(sorted(Counter(len(a) for a in mine).items()))}, "
                     f"EAIK exact {dict(sorted(Counter(len(b) for b in theirs).items()))}")
    print(f"\n{name} singular sets: " + "; ".join(lines))


def test_timing_batch():
    """10^4 poses in well under ~10 s."""
    name = "irb120"
    q = sw.random_configs(name, 10_000, np.random.default_rng(SEED + 4))
    T = derive.reference.fk_matrix(name, q)
    sw.geometry(name)
    t = time.perf_counter()
    sols = sw.ik_all_batch(name, T)
    dt = time.perf_counter() - t
    print(f"\nik_all_batch: 10^4 poses in {dt:.2f} s")
    assert len(sols) == 10_000
    assert dt < 10.0
