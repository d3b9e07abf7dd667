"""The UR and spherical-wrist (OPW) classes as compositions of subproblems (issue 30, item 1):
their numpy solvers (:func:`derive.ik.closed_form.solve_batch`,
:func:`derive.ik.spherical.solve_batch`, now sp4, sp2, sp1, sp3, sp1 and sp4, sp3, sp1, sp2, sp1
of :mod:`derive.ik.subproblems`) checked against an outside solver, ssik 8.2.0 (IK-Geo's
subproblems in C++, ``Manipulator.from_axes`` on our chain's axes and axis points at zero), and
against the meaning of the registry's labels, on the poses the rewrite had to keep:

* regular poses (random configurations): the same solution sets as ssik (equal counts, each
  solution within 1e-9 rad modulo 2 pi of one of the other side's), the generating configuration
  among them, no singular flag, reason "";
* branch ids: each bit means what ``branch_labels`` says (the root of theta1 on the side of the
  wrist point, the sign of sin t5, the sign of sin t3 / sin(t3 + psi3)), read off the solutions'
  angles and the pose, not off the solver;
* the wrist singular set (sin t5 = 0, generated so): the solutions on it (and only they) flagged
  singular, the free joint taken from ``q_ref`` (so the generating configuration is found), FK
  within 1e-9;
* unreachable poses (the wrist pushed three times as far out; for the UR, a flange pose whose
  wrist point lies nearer axis 1 than d4 allows): no solution on either side, and the class's
  reason.
"""

from __future__ import annotations

import numpy as np
import pytest

import ssik

from derive import reference
from derive.algebra import dualquat as dq
from derive.ik import classes, closed_form
from derive.ik.finish import finish
from derive.model.geometry import numeric_chain
from derive.model.robot import load_robot

SAME = 1e-9
ARMS = ["ur5", "ur10e", "puma560", "kr6-r900", "rx160"]


def _wrap(d):
    return (np.asarray(d) + np.pi) % (2 * np.pi) - np.pi


def _ssik_arm(name):
    """ssik's product-of-exponentials arm of our chain and our end rotation at zero (4x4)."""
    ch = numeric_chain(name)
    pts = ch.start + np.vstack([np.zeros(3), np.cumsum(ch.links, axis=0)])
    t0 = reference.fk_matrix(name, np.zeros(6))
    P = np.vstack([pts[0], np.diff(pts[:6], axis=0), t0[:3, 3] - pts[5]])
    r0 = np.eye(4)
    r0[:3, :3] = t0[:3, :3]
    return ssik.Manipulator.from_axes(np.array(ch.axes, dtype=float), P), r0


def _ssik_set(man, target):
    out: list = []
    for s in man.solve(target, respect_limits=False):
        x = np.asarray(s.q, dtype=float)
        if not any(np.abs(_wrap(x - u)).max() < SAME for u in out):
            out.append(x)
    return np.array(out).reshape(-1, 6)


def _solve(name, poses, q_ref=None):
    """The class's candidates through the finish step: (q, counts, branch, singular, reasons)."""
    robot = load_robot(name)
    cls, geo = classes.detect(robot, dof=6)
    free = None if q_ref is None else q_ref[:, cls.free_joint]
    cand, sing, code = cls.candidates(geo, poses, free)
    q, counts, branch, singular, _ = finish(robot, poses, cand, sing)
    _, _, _, reasons = closed_form.solve(robot, geo, poses, free)
    return cls, geo, q, counts, branch, singular, reasons


def _canonical(cls, geo, q):
    """The class's own angles of robot configurations q (..., 6)."""
    return q if cls.name == "ur" else geo.to_canonical(q)


def _branch_bits(cls, geo, poses, theta):
    """The three branch bits (most significant first) that the registry's labels give to
    solutions ``theta`` (n, 6) in the class's angles, from their angles and the pose alone."""
    if cls.name == "ur":
        chain = dq._mul(poses, dq.conj_quaternion(geo.g)[None])
        r = np.stack([dq.to_matrix(c)[:3, :3] for c in chain])
        p5 = dq._translation(chain) + geo.d6 * r[:, :, 1]       # the frame-5 point
        t1, t3, t5 = theta[:, 0], theta[:, 2], theta[:, 4]
        # theta1 root "+": p5 on the + side across the arm plane's normal (x5 c1 + y5 s1 > 0)
        front = p5[:, 0] * np.cos(t1) + p5[:, 1] * np.sin(t1)
        return front < 0, np.sin(t5) < 0, np.sin(t3) < 0
    chain = geo.into_canonical(poses)
    r = np.stack([dq.to_matrix(c)[:3, :3] for c in chain])
    w = dq._translation(chain) - geo.c4 * r[:, :, 2]              # the wrist centre
    t1, t3, t5 = theta[:, 0], theta[:, 2], theta[:, 4]
    front = w[:, 0] * np.cos(t1) + w[:, 1] * np.sin(t1)            # W ahead of axis 1 or behind
    psi3 = np.arctan2(geo.a2, geo.c3)
    return front < 0, np.sin(t3 + psi3) < 0, np.sin(t5) < 0


@pytest.mark.parametrize("name", ARMS)
def test_regular_poses_equal_ssik_and_branch_labels_hold(name):
    rng = np.random.default_rng(3030)
    q = rng.uniform(-np.pi, np.pi, (120, 6))
    poses = reference.fk(name, q)
    mats = reference.fk_matrix(name, q)
    man, r0 = _ssik_arm(name)
    assert max(np.abs(man.fk(q[i]) @ r0 - mats[i]).max() for i in range(len(q))) < 1e-12
    cls, geo, sols, counts, branch, singular, reasons = _solve(name, poses)
    assert not singular.any() and all(r == "" for r in reasons)
    for i in range(len(q)):
        ours, theirs = sols[i, :counts[i]], _ssik_set(man, mats[i] @ np.linalg.inv(r0))
        assert len(ours) == len(theirs), (name, i, len(ours), len(theirs))
        d = np.abs(_wrap(ours[:, None] - theirs[None])).max(-1)
        assert d.min(1).max() < SAME and d.min(0).max() < SAME, (name, i)
        assert np.abs(_wrap(ours - q[i])).max(1).min() < SAME
    ok = counts[:, None] > np.arange(8)
    theta = _canonical(cls, geo, sols[ok])
    bits = _branch_bits(cls, geo, np.repeat(poses, 8, axis=0)[ok.ravel()], theta)
    b = branch[ok]
    for k, bit in enumerate(bits):
        assert np.array_equal((b >> (2 - k)) & 1, bit.astype(int)), (name, cls.branch_labels[k])
    assert len(np.unique(b)) == 8                      # every branch occurs


@pytest.mark.parametrize("name", ARMS)
def test_wrist_singular_poses_take_the_free_joint_from_q_ref(name):
    robot = load_robot(name)
    cls, geo = classes.detect(robot, dof=6)
    rng = np.random.default_rng(3031)
    theta = rng.uniform(-np.pi, np.pi, (40, 6))
    theta[:, 4] = rng.choice([0.0, np.pi], 40) if cls.name == "ur" else 0.0
    q = theta if cls.name == "ur" else geo.from_canonical(theta)
    poses = reference.fk(name, q)
    _, _, sols, counts, _, singular, reasons = _solve(name, poses, q_ref=q)
    assert np.all(counts > 0) and all(r == "" for r in reasons)
    ok = counts[:, None] > np.arange(8)
    # flagged exactly where the solution lies on the set (another theta1 root may not)
    t5 = _canonical(cls, geo, sols[ok])[:, 4]
    assert np.array_equal(singular[ok], np.abs(np.sin(t5)) < 1e-9)
    assert np.all(singular.any(axis=1))
    got = reference.fk_matrix(name, sols[ok])
    want = np.repeat(reference.fk_matrix(name, q), 8, axis=0)[ok.ravel()]
    assert np.abs(got - want).max() < 1e-9
    for i in range(len(q)):
        assert np.abs(_wrap(sols[i, :counts[i]] - q[i])).max(1).min() < 1e-9


@pytest.mark.parametrize("name", ARMS)
def test_unreachable_poses_have_no_solution_and_the_class_reason(name):
    robot = load_robot(name)
    cls, geo = classes.detect(robot, dof=6)
    man, r0 = _ssik_arm(name)
    rng = np.random.default_rng(3032)
    poses = reference.fk(name, rng.uniform(-np.pi, np.pi, (20, 6)))
    t = dq._translation(poses)
    far = dq.from_rt(poses[:, :4], 3.0 * t + 0.5 * np.sign(t))
    _, _, _, counts, _, _, reasons = _solve(name, far)
    assert np.all(counts == 0) and all(r == cls.reasons[1] for r in reasons)
    for p in far[:5]:
        assert len(_ssik_set(man, dq.to_matrix(p) @ np.linalg.inv(r0))) == 0
    if cls.name == "ur":
        # the flange where the wrist point p5 = p + d6 R e_y lands on axis 1: nearer than d4
        rot = poses[:, :4]                                   # the chain end's rotations
        r = np.stack([dq.to_matrix(dq.from_rt(x, np.zeros(3)))[:3, :3] for x in rot])
        near = dq._mul(dq.from_rt(rot, -geo.d6 * r[:, :, 1] + [0.0, 0.0, 0.3]), geo.g[None])
        _, _, _, counts, _, _, reasons = _solve(name, near)
        assert np.all(counts == 0) and all(r == cls.reasons[0] for r in reasons)
        for p in near[:5]:
            assert len(_ssik_set(man, dq.to_matrix(p) @ np.linalg.inv(r0))) == 0
