"""IK extraction from the derived equations: order, patterns, numeric checks, and the extracted
closed forms against the reference IK."""

import itertools
import math

import numpy as np
import pytest
import sympy as sp

from derive import dualquat as DQ
from derive import reference
from derive.algebra.angles import wrap_angle
from derive.ik.extract import R_SYMS, _rot, check_numerically, extract
from derive.kinematics import fk as kin
from derive.symbolic.equations import POSES

#: one pytest-xdist worker runs the tests of group "ur-derivation" (make test: --dist loadgroup),
#: so the symbolic work they share (the UR family's equations, memoised in the process) is done once
pytestmark = pytest.mark.xdist_group("ur-derivation")


@pytest.fixture(scope="module")
def ext():
    e = extract("ur3")
    check_numerically(e, samples=100)
    return e


def test_order_and_patterns(ext):
    thetas = [f"theta{k}" for k in range(1, 7)]
    individual = [s.unknown for s in ext.steps if s.unknown in thetas]
    assert individual == ["theta1", "theta5", "theta6", "theta3", "theta2", "theta4"]   # the thesis's
    by = {s.unknown: s for s in ext.steps}
    assert by["theta1"].pattern == "S1" and by["theta1"].equations == ["W.6"] and by["theta1"].branches == 2
    assert by["theta5"].pattern == "S1" and by["theta5"].equations == ["B.13"]
    assert by["theta3"].pattern == "S3" and by["theta3"].equations == ["C.19", "C.21"]
    assert by["theta6"].pattern == "span" and by["theta4"].pattern == "span"
    compounds = [s for s in ext.steps if s.unknown not in thetas]
    assert {tuple(s.equations) for s in compounds} >= {("B.30", "B.32"), ("B.29", "B.31")}


def test_every_closed_form_contains_the_true_angle(ext):
    assert all(s.check == 1.0 for s in ext.steps)


def test_frame5_point_is_free_of_theta6(ext):
    x5 = ext.definitions[POSES["W"][4]]
    assert not x5.has(sp.Symbol("theta6", real=True))
    d6, x, r12 = sp.Symbol("d6", real=True), POSES["B"][4], R_SYMS[0, 1]
    assert sp.expand(x5 - (x + d6 * r12)) == 0


def _solve_with_forms(ext, pose):
    """All solutions from the extracted closed forms, every branch combination."""
    chain = ext.chain
    thetas = [j.theta for j in chain.joints]
    env0 = {**chain.parameters, **dict(zip(POSES["B"], list(pose[:4]) + list(DQ.to_rt(pose)[1])))}
    env0.update(zip(list(R_SYMS), [float(v) for v in _rot(pose[:4]).reshape(9, 1)]))
    sols = []
    for choice in itertools.product(*[range(len(s.forms)) for s in ext.steps]):
        env = dict(env0)
        ok = True
        for s, k in zip(ext.steps, choice):
            for sym, definition in ext.definitions.items():
                if sym not in env and definition.free_symbols <= set(env):
                    env[sym] = float(definition.subs(env))
            v = complex(sp.N(s.forms[k].subs(env)))
            if abs(v.imag) > 1e-9 or math.isnan(v.real):
                ok = False
                break
            env[s.symbol] = v.real
        if ok:
            sols.append(wrap_angle(np.array([env[t] for t in thetas])))
    return sols


def test_extracted_forms_give_the_reference_solution_set(ext, rng):
    from derive.ik.closed_form import ur_geometry
    geo = ur_geometry("ur3")
    for q in rng.uniform(-math.pi, math.pi, size=(4, 6)):
        if abs(math.sin(q[4])) < 0.1:
            continue
        pose = DQ.mul(reference.fk("ur3", q), DQ.conj_quaternion(geo.g))   # chain end frame
        # the quaternion equations need the product's sign
        frames = kin._frames_dq(__import__("derive").load_robot("ur3-thesis"), q[None])
        if np.dot(frames[-1][0][:4], pose[:4]) < 0:
            pose = -pose
        ours = _solve_with_forms(ext, pose)
        ref = reference.ik("ur3", reference.fk("ur3", q))
        valid = [s for s in ours if reference.pose_error(reference.fk("ur3", s), reference.fk("ur3", q))[0] < 1e-9]
        assert len(ref) > 0
        for s in ref:
            assert any(np.max(np.abs(wrap_angle(s - o))) < 1e-7 for o in valid)
        for o in valid:
            assert any(np.max(np.abs(wrap_angle(s - o))) < 1e-7 for s in ref)
