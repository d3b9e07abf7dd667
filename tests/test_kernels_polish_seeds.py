"""Near-class kernels near the singular sets (issue 30, item 3): the emitted C kernels (and the numpy
and pure-Python ones) seed candidates near a singular set along its singular direction, as the
numpy reference does (derive.ik.nearclass._singular_seeds), so that both roots of a fold are found.
Checked against the numpy reference (derive.ik.nearclass.ik_batch: another implementation, with
its own candidates, homotopy and two-pass polish) on poses drawn uniformly and on poses at a few
hundredths of a radian from the arms' singular sets, and against the reference FK."""

import math
import shutil

import numpy as np
import pytest

import derive
from derive import reference
from derive.codegen.polish import POLISH_ACCEPT
from derive.ik import nearclass
from derive.kinematics.fk import pose_error

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")
DATA = "tests/data"


@pytest.fixture(scope="module", autouse=True)
def fast_c():
    """The C backend at -O1 for these tests (quicker to compile; the results do not depend on it)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("DQ_DERIVE_CFLAGS", "-std=c99 -O1")
        yield


def _configurations(robot, n_uniform, near, seed):
    """n_uniform configurations uniform within the limits (clipped to +-pi) and, for each
    (joint, centre) of ``near``, 40 with that joint at centre +- 0.002..0.04 rad (the others
    uniform): a nearly stretched elbow, a nearly aligned wrist or shoulder."""
    rng = np.random.default_rng(seed)
    lo, hi = np.maximum(robot.limits[:, 0], -math.pi), np.minimum(robot.limits[:, 1], math.pi)
    parts = [rng.uniform(lo, hi, (n_uniform, robot.dof))]
    for joint, centre in near:
        q = rng.uniform(lo, hi, (40, robot.dof))
        q[:, joint] = centre + rng.choice([-1.0, 1.0], 40) * rng.uniform(0.002, 0.04, 40)
        parts.append(q)
    return np.concatenate(parts)


def _same_sets(a, ca, b, cb, tol=1e-6, subset=False):
    """Per pose: whether the solution sets a[:ca] and b[:cb] are equal (each solution of one within
    tol rad of one of the other in every joint, modulo 2 pi, and the same count); ``subset``: only
    whether each of a's is among b's."""
    out = []
    for i in range(len(a)):
        x, y = a[i, :ca[i]], b[i, :cb[i]]
        if not subset and len(x) != len(y):
            out.append(False)
            continue
        d = np.abs((x[:, None] - y[None] + math.pi) % (2 * math.pi) - math.pi).max(-1) < tol
        out.append(bool(d.any(1).all() and (subset or d.any(0).all())))
    return np.array(out)


def _check(robot, Q, P, free, kern):
    """The kernels' solutions against the numpy reference: the same sets on every pose (where the
    reference has more solutions than the kernels hold, 9 or 10 of ur5-calibrated near its wrist
    singular set, the kernels' slots all filled with some of them), every solution's reference FK
    within 1e-10, the generating configuration among them."""
    ref = (nearclass.ik_batch(robot, P) if free is None
           else nearclass.ik_batch(robot, P, free=free, free_name="q3"))
    sols, counts, res, its = kern.ik_polish(P) if free is None else kern.ik_polish(P, free)
    width = sols.shape[1]
    fits = ref.counts <= width
    same = _same_sets(sols, counts, ref.q, ref.counts)
    assert same[fits].all(), (np.nonzero(~same & fits)[0], counts[~same & fits], ref.counts[~same & fits])
    over = np.nonzero(~fits)[0]
    assert (counts[over] == width).all() and _same_sets(sols[over], counts[over], ref.q[over], ref.counts[over],
                                                        subset=True).all()
    filled = np.arange(width)[None, :] < counts[:, None]
    dp, da = pose_error(reference.fk(robot, sols[filled]), np.repeat(P, counts, axis=0))
    assert max(dp.max(), da.max()) <= 1e-10
    assert np.nanmax(res[filled]) <= POLISH_ACCEPT
    gap = np.abs((sols - Q[:, None, :] + math.pi) % (2 * math.pi) - math.pi).max(axis=2)
    assert np.all(np.where(filled, gap, np.inf).min(axis=1)[fits] < 1e-6)
    return sols, counts, ref


def test_calibrated_ur5_c_kernels_equal_the_reference_near_singular_sets():
    """ur5-calibrated (0.016 from the UR5): near the wrist (q5 = 0, pi), the elbow (q3 = 0) and at
    random; the poses near the wrist have 4 or 6 solutions where both roots of a fold count."""
    robot = derive.load_robot("ur5-calibrated")
    Q = _configurations(robot, 100, [(4, 0.0), (4, math.pi), (2, 0.0)], seed=21)
    P = reference.fk(robot, Q)
    k = derive.kernels(robot, "c")
    assert k.nominal is not None and k.nominal.robot.name == "ur5"
    sols, counts, ref = _check(robot, Q, P, None, k)
    # the near-singular poses are where the counts differ from the nominal's 8; a few have 10
    assert (counts[100:] < 8).sum() >= 20 and set(np.unique(counts)) >= {4, 6, 8}
    assert 1 <= (ref.counts > 8).sum() <= 10
    # the numpy kernels: the same sets
    s2, c2, _, _ = derive.kernels(robot, "numpy").ik_polish(P)
    assert _same_sets(s2, c2, sols, counts).all()


def test_iiwa14_off_c_kernels_equal_the_reference_near_singular_sets():
    """iiwa14 with axes 0.44 mm off, joint 3 given: near the stretched elbow (q4 = 0), the shoulder
    (q2 = 0) and the wrist (q6 = 0). At the stretched elbow the nominal's two elbow roots are one
    candidate; the seeds along its singular direction find both of the arm's."""
    robot = derive.load_robot(f"{DATA}/iiwa14-off.urdf")
    Q = _configurations(robot, 100, [(3, 0.0), (1, 0.0), (5, 0.0)], seed=22)
    P = reference.fk(robot, Q)
    k = derive.kernels(robot, "c", free="q3")
    assert k.nominal is not None
    sols, counts, ref = _check(robot, Q, P, Q[:, 2], k)
    assert (counts == 8).mean() > 0.9
    s2, c2, _, _ = derive.kernels(robot, "numpy", free="q3").ik_polish(P, Q[:, 2])
    assert _same_sets(s2, c2, sols, counts).all()
    # pure Python on the stretched-elbow poses
    sl = slice(100, 130)
    s3, c3, _, _ = derive.kernels(robot, "python", free="q3").ik_polish(P[sl], Q[sl, 2])
    assert _same_sets(s3, c3, sols[sl], counts[sl]).all()
