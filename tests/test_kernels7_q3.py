"""The SRS arms' alternative free parameter: kernels that solve with joint 3 given
(``derive.kernels(robot, backend, free="q3")``, program ``derive.ik.program7.srs_joint3_program``),
checked against the numpy closed form ``derive.ik.srs.ik_joint`` and the reference FK."""

import math

import numpy as np
import pytest

import derive
from derive import reference
from derive.errors import InputError
from derive.ik import srs

ROBOTS = ["iiwa7", "iiwa14"]


def _wrapped(d):
    return np.abs((np.asarray(d) + math.pi) % (2 * math.pi) - math.pi)


def _inside(name, n, rng):
    lo, hi = derive.load_robot(name).limits.T
    return rng.uniform(lo, hi, (n, 7))


@pytest.mark.parametrize("name", ROBOTS)
def test_q3_kernels_solve_10k_configurations_as_the_numpy_closed_form(name):
    """10^4 configurations inside the limits, q3 given as the generating value: every solution
    reproduces the pose (1e-10), the generating configuration is among them, and the counts, the
    branch ids and the values equal srs.ik_joint's (1e-8); numpy and pure Python kernels agree."""
    rng = np.random.default_rng(31)
    robot = derive.load_robot(name)
    q = _inside(name, 10_000, rng)
    poses = reference.fk(robot, q)
    k = derive.kernels(name, "c", free="q3")
    assert k.free == "q3"
    sols, counts, branch, sing = k.ik(poses, free=q[:, 2], details=True)
    ref = srs.ik_joint(robot, poses, 3, q[:, 2])
    np.testing.assert_array_equal(counts, ref.count)
    assert counts.min() >= 1
    valid = np.arange(sols.shape[1])[None] < counts[:, None]
    assert np.all(np.isfinite(sols[valid])) and np.all(np.isnan(sols[~valid]))
    rows = np.nonzero(valid)[0]
    dp, dr = reference.pose_error(reference.fk(robot, sols[valid]), poses[rows])
    assert max(dp.max(), dr.max()) < 1e-10
    # joint 3 is returned as given (wrapped)
    assert _wrapped(sols[valid][:, 2] - q[rows, 2]).max() < 1e-12
    gen = np.nanmin(_wrapped(sols - q[:, None]).max(-1), axis=1)
    assert np.all(gen < 1e-9), int(np.argmax(gen))
    # the same branch ids with the same values: sort both by branch id
    kb = np.where(valid, branch, 99)
    order_k = np.argsort(kb, axis=1, kind="stable")
    rb = np.where(ref.branch >= 0, ref.branch, 99)
    order_r = np.argsort(rb, axis=1, kind="stable")
    np.testing.assert_array_equal(np.take_along_axis(kb, order_k, 1), np.take_along_axis(rb, order_r, 1))
    a = np.take_along_axis(sols, order_k[..., None], 1)
    b = np.take_along_axis(ref.q, order_r[..., None], 1)
    assert np.nanmax(_wrapped(a - b)) < 1e-8
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    # the other backends (generated from the same program) on the first 500 poses
    s_np, c_np = derive.kernels(name, "numpy", free="q3").ik(poses[:500], free=q[:500, 2])
    np.testing.assert_array_equal(c_np, counts[:500])
    assert np.nanmax(np.abs(s_np - sols[:500])) < 1e-10
    s_py, c_py = derive.kernels(name, "python", free="q3").ik(poses[:20], free=q[:20, 2])
    np.testing.assert_array_equal(c_py, counts[:20])
    assert np.nanmax(np.abs(s_py - s_np[:20])) < 1e-12
    # one pose per call equals the batch bit for bit
    for i in range(5):
        one, c1 = k.ik(poses[i], free=float(q[i, 2]))
        assert c1 == counts[i]
        np.testing.assert_array_equal(one, sols[i])


@pytest.mark.parametrize("name", ROBOTS)
def test_q3_kernels_at_the_singular_sets_are_exact_or_empty_never_nan(name):
    """Wrist centre on axis 1 (q2 = 0, elbow stretched: q1 is free and set to 0), wrist aligned
    (q6 = 0), elbow stretched (q4 = 0): at least one solution, all exact, flagged singular where
    a joint was free; q3 out of reach for the pose: no solution, no NaN in the count."""
    rng = np.random.default_rng(32)
    robot = derive.load_robot(name)
    q = _inside(name, 300, rng)
    q[:100, 1] = 0.0
    q[:100, 3] = 0.0
    q[100:200, 5] = 0.0
    q[200:, 3] = 0.0
    poses = reference.fk(robot, q)
    k = derive.kernels(name, "c", free="q3")
    sols, counts, branch, sing = k.ik(poses, free=q[:, 2], details=True)
    assert counts.min() >= 1
    valid = np.arange(sols.shape[1])[None] < counts[:, None]
    assert np.all(np.isfinite(sols[valid]))
    rows = np.nonzero(valid)[0]
    dp, dr = reference.pose_error(reference.fk(robot, sols[valid]), poses[rows])
    assert max(dp.max(), dr.max()) < 1e-10
    # the solution that is the generating configuration (up to the free joint) is flagged
    # singular on the first two sets; the other roots need not lie on the set
    near = np.nanargmin(np.where(valid, _wrapped(sols[..., [1, 3, 5]] - q[:, None, [1, 3, 5]]).max(-1), np.inf), axis=1)
    assert np.all(sing[np.arange(200), near[:200]])
    # a pose of the arm folded near the base with q3 turned so that the forearm leaves every
    # plane through axis 1 (as in tests/test_srs.py): no solution with that q3
    qq = np.array([0.0, 0.5, 0.0, 0.5 + math.asin(math.sin(0.5)), 0.0, 0.3, 0.0])
    pose = reference.fk(robot, qq)
    ref = srs.ik_joint(robot, pose, 3, math.pi / 2)
    s1, c1 = k.ik(pose, free=math.pi / 2)
    assert c1 == ref.count == 0 and np.all(np.isnan(s1))


def test_q3_kernels_input_contract():
    pose = reference.fk("iiwa14", np.full(7, 0.3))
    k = derive.kernels("iiwa14", "c", free="q3")
    cases = [
        (lambda: k.ik(pose), "free= \\(q3"),
        (lambda: k.ik(pose, free=[0.1, 0.2]), "free"),
        (lambda: k.ik(pose, free=math.nan), "free"),
        (lambda: k.ik_sweep(pose, 4), "ik_sweep: these kernels take q3"),
        (lambda: k.nearest(pose, np.zeros(7)), "nearest: these kernels take q3"),
        (lambda: derive.kernels("iiwa14", "c", free="q4"), "joint 4 alone sets the shoulder-wrist distance"),
        (lambda: derive.kernels("iiwa14", "c", free="q8"), "its choices: psi, q3"),
        (lambda: derive.kernels("panda", "c", free="psi"), "its choices: q7"),
        (lambda: derive.kernels("ur5", "c", free="q3"), "none"),
    ]
    for call, text in cases:
        with pytest.raises(InputError, match=text):
            call()
    # any other joint of a 7R arm: the free-joint kernels (in C the class's program on the SRS
    # class's routes: tests/test_free_joint_srs_c.py), not the class's generated kernels
    assert derive.kernels("iiwa14", "c", free="q2").free == "q2"      # built by test_free_joint_srs_c too
    from derive.codegen.loader import _any_joint
    assert _any_joint(derive.load_robot("panda"), "q3") and not _any_joint(derive.load_robot("iiwa14"), "q3")
    # the class's default parameter by name is the default kernels
    assert derive.kernels("iiwa14", "c", free="psi") is derive.kernels("iiwa14", "c")


def test_cli_ik_with_joint_3_given(capsys):
    """dq-derive ik iiwa14 --q Q --free V --free-joint 3: the closed form of srs.ik_joint, the
    generating configuration among the solutions when V is its q3."""
    import json

    from derive.cli import main

    q = [0.3, 0.5, -0.4, 1.1, 0.2, -0.7, 0.4]
    assert main(["ik", "iiwa14", "--q", *map(str, q), "--free", "-0.4", "--free-joint", "3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["free_parameter"]["name"] == "q3" and out["count"] == 8
    sols = np.array([s["q"] for s in out["solutions"]])
    assert np.all(np.abs(sols[:, 2] + 0.4) < 1e-12)
    assert _wrapped(sols - np.array(q)).max(-1).min() < 1e-9
    pose = reference.fk("iiwa14", q)
    dp, dr = reference.pose_error(reference.fk("iiwa14", sols), np.repeat(pose[None], 8, 0))
    assert max(dp.max(), dr.max()) < 1e-10
    # any other arm and joint: derive.ik.free_joint (tests/test_free_joint.py)
    assert main(["ik", "panda", "--q", *map(str, q), "--free", "-0.4", "--free-joint", "3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    sols = np.array([s["q"] for s in out["solutions"]])
    assert out["free_parameter"]["name"] == "q3" and _wrapped(sols - np.array(q)).max(-1).min() < 1e-8
    assert main(["ik", "iiwa14", "--q", *map(str, q), "--sweep", "3", "--free-joint", "3"]) == 2
    assert "give --free V" in capsys.readouterr().err


def test_casadi_ik_q3_equals_the_q3_kernels():
    """The CasADi function ik_q3(pose, free) of the SRS arms (the same program, in SX): on 30
    configurations every kernel solution is its column of the branch id, within 1e-10."""
    from derive.refinement.functions import functions

    fns = functions("iiwa14")
    ik = fns["ik_q3"]
    assert ik.name() == "ik_q3" and ik.name_in() == ["pose", "free"]
    assert "ik_q3" not in functions("panda")
    rng = np.random.default_rng(33)
    q = _inside("iiwa14", 30, rng)
    poses = reference.fk("iiwa14", q)
    sols, counts, branch, _ = derive.kernels("iiwa14", "c", free="q3").ik(poses, free=q[:, 2], details=True)
    for i in range(30):
        Q, valid = (np.array(x) for x in ik(poses[i], q[i, 2]))
        for j in range(counts[i]):
            assert valid[0, branch[i, j]]
            assert _wrapped(Q[:, branch[i, j]] - sols[i, j]).max() < 1e-10
