"""The generated kernels of the 7-joint arms (Franka Panda / FR3 with q7 given, KUKA iiwa 7 / 14
with the arm angle psi given): every backend against the reference FK and the numpy closed
forms of derive.ik.panda / derive.ik.srs (written separately, with rotation matrices), the C
batch against its single-pose function, the singular sets, ik_sweep, nearest along a path, the
input contract and the CasADi ik function."""

import math

import numpy as np
import pytest

import derive
from derive import reference
from derive.errors import InputError
from derive.ik import redundant, srs
from derive.refinement.functions import functions
from paths7 import assert_continuous, follow, trajectory

ROBOTS = ["panda", "fr3", "iiwa7", "iiwa14"]
N = 10_000


def _wrapped(a):
    return np.abs((np.asarray(a) + np.pi) % (2 * np.pi) - np.pi)


def _own_free(robot, q):
    """q7 for the Panda class, the arm angle (derive.ik.srs.arm_angle) for SRS."""
    name, _ = redundant.free_parameter(robot)
    return q[:, 6].copy() if name == "q7" else np.atleast_1d(srs.arm_angle(robot, q))


def _configurations(robot, n, seed):
    lim = derive.load_robot(robot).limits
    return np.random.default_rng(seed).uniform(lim[:, 0], lim[:, 1], size=(n, 7))


def _residual(robot, sols, counts, poses):
    """The largest position (m) / rotation (rad) error of every returned solution against its pose,
    by the reference FK (a dual-quaternion product, no code shared with the kernels)."""
    rows = np.nonzero(np.arange(sols.shape[1])[None, :] < counts[:, None])
    dp, dr = reference.pose_error(reference.fk(robot, sols[rows]), poses[rows[0]])
    return max(float(dp.max(initial=0.0)), float(dr.max(initial=0.0)))


@pytest.mark.parametrize("robot", ROBOTS)
@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_kernels_at_the_generating_value_find_the_generating_configuration(robot, backend):
    """10^4 configurations inside the limits, each at its own free value: every solution
    reproduces the pose (< 1e-10), the generating configuration is among them, the counts equal
    the numpy closed form's (its candidates checked by the reference FK), and so do the solutions
    themselves, in the same (branch) order."""
    q = _configurations(robot, N, seed=11)
    poses = reference.fk(robot, q)
    free = _own_free(robot, q)
    k = derive.kernels(robot, backend)
    assert k.free == redundant.free_parameter(robot)[0]
    sols, counts = k.ik(poses, free=free)
    assert sols.shape == (N, 8, 7) and not np.isnan(sols[np.arange(8)[None] < counts[:, None]]).any()
    assert np.isnan(sols[np.arange(8)[None] >= counts[:, None]]).all()
    assert _residual(robot, sols, counts, poses) < 1e-10
    assert np.all(np.nanmin(_wrapped(sols - q[:, None]).max(axis=-1), axis=1) < 1e-9)
    ref = redundant.solve(robot, poses, free)
    np.testing.assert_array_equal(counts, ref.counts)
    assert np.nanmax(_wrapped(sols - ref.q)) < 1e-8
    assert np.array_equal(np.isnan(sols), np.isnan(ref.q))


@pytest.mark.parametrize("robot", ["panda", "iiwa14"])
def test_pure_python_kernel_equals_numpy_kernel(robot):
    q = _configurations(robot, 300, seed=12)
    poses, free = reference.fk(robot, q), _own_free(robot, q)
    a, ca = derive.kernels(robot, "python").ik(poses, free=free)
    b, cb = derive.kernels(robot, "numpy").ik(poses, free=free)
    np.testing.assert_array_equal(ca, cb)
    assert np.nanmax(np.abs(a - b)) < 1e-12


@pytest.mark.parametrize("robot", ["panda", "iiwa14"])
def test_c_details_single_calls_and_ctypes_agree(robot):
    """Branch ids and singular flags equal the numpy closed form's; one pose per call gives the
    batch's bits; the ctypes path (the library without the extension) too."""
    q = _configurations(robot, 500, seed=13)
    poses, free = reference.fk(robot, q), _own_free(robot, q)
    k = derive.kernels(robot, "c")
    sols, counts, branch, sing = k.ik(poses, free=free, details=True)
    ref = redundant.solve(robot, poses, free)
    np.testing.assert_array_equal(branch, ref.branch)
    np.testing.assert_array_equal(sing, ref.singular)
    for i in range(0, 500, 25):
        s1, c1 = k.ik(poses[i], free=free[i])
        assert c1 == counts[i]
        assert np.array_equal(s1, sols[i], equal_nan=True)
    k._load_ctypes()
    out = np.empty((500, 8, 7))
    c = np.empty(500, dtype=np.intc)
    pz, fz = np.ascontiguousarray(poses), np.ascontiguousarray(free)
    k._ik_batch(500, pz.ctypes.data, fz.ctypes.data, out.ctypes.data, c.ctypes.data)
    np.testing.assert_array_equal(c, counts)
    # the extension normalises the poses first, so the last bits differ (amplified near the
    # singular sets): the same solutions to 1e-9, each exact
    assert np.array_equal(np.isnan(out), np.isnan(sols)) and np.nanmax(np.abs(out - sols)) < 1e-9
    assert _residual(robot, out, c.astype(int), poses) < 1e-10


def _singular_configurations(robot, rng, n=400):
    """Configurations on the classes' singular sets (limits ignored: the closed form does not
    use them): SRS shoulder aligned (q2 = 0), elbow stretched (q4 = 0), wrist aligned (q6 = 0)
    and pairs of them; Panda sin q2 = 0, the shoulder on axis 5 (q4 = 0, where X = 0 since
    a4 = -a3), q5 = +-pi/2 (the q6 double root) and pairs."""
    q = rng.uniform(-math.pi, math.pi, size=(n, 7))
    groups = ([[1], [3], [5], [1, 3], [3, 5], [1, 5], [1, 3, 5]] if robot.startswith("iiwa")
              else [[1], [3], [1, 3]])
    for i in range(n):
        for j in groups[i % len(groups)]:
            # the iiwa 7's elbow folded (q4 = pi, d_se = d_ew) puts the wrist centre at the
            # shoulder, where no arm angle exists: its elbow is stretched only
            folded_ok = j != 3 or not robot.startswith("iiwa")
            q[i, j] = math.pi if folded_ok and rng.random() >= 0.7 else 0.0
    if robot == "panda":
        q[2::7, 4] = rng.choice([-1, 1], len(q[2::7])) * math.pi / 2
    return q


@pytest.mark.parametrize("robot", ROBOTS)
def test_singular_sets_give_exact_solutions_never_nan(robot):
    """On the singular sets the kernels return exact solutions (< 1e-10), flagged singular where a
    joint was free, never NaN, and at least one per pose: the generating configuration's pose is
    reached even where the free joint was set to 0."""
    q = _singular_configurations(robot, np.random.default_rng(14))
    poses, free = reference.fk(robot, q), _own_free(robot, q)
    k = derive.kernels(robot, "c")
    sols, counts, branch, sing = k.ik(poses, free=free, details=True)
    assert np.all(counts >= 1)
    assert not np.isnan(sols[np.arange(8)[None] < counts[:, None]]).any()
    assert _residual(robot, sols, counts, poses) < 1e-10
    assert sing.any(axis=1).mean() > 0.5
    s2, c2 = derive.kernels(robot, "numpy").ik(poses, free=free)
    np.testing.assert_array_equal(c2, counts)


def test_a_free_value_out_of_reach_gives_no_solution_and_no_nan():
    """The Panda at q7 far from a pose's own value: some poses have no solution there (the point
    O6 beyond the elbow's range); their rows are empty, the others exact."""
    q = _configurations("panda", 2000, seed=15)
    poses = reference.fk("panda", q)
    free = q[:, 6] + np.random.default_rng(16).choice([-1.5, 1.5], 2000)
    sols, counts = derive.kernels("panda", "c").ik(poses, free=free)
    ref = redundant.solve("panda", poses, free)
    np.testing.assert_array_equal(counts, ref.counts)
    assert 0 < np.count_nonzero(counts == 0) < 2000
    assert np.isnan(sols[counts == 0]).all()
    assert _residual("panda", sols, counts, poses) < 1e-10


@pytest.mark.parametrize("robot", ["panda", "iiwa14"])
def test_ik_sweep_on_the_kernels_equals_the_reference_sweep(robot):
    q = _configurations(robot, 40, seed=18)
    poses = reference.fk(robot, q)
    got = derive.kernels(robot, "c").ik_sweep(poses, 16)
    ref = redundant.ik_sweep(robot, poses, 16)
    assert np.array_equal(np.isnan(got.free), np.isnan(ref.free))
    assert np.nanmax(np.abs(got.free - ref.free)) < 1e-12
    np.testing.assert_array_equal(got.counts, ref.counts)
    assert got.q.shape == ref.q.shape
    assert np.nanmax(np.abs(got.q - ref.q)) < 1e-8
    assert np.all(got.counts.sum(axis=1) > 0)
    lim = derive.load_robot(robot).limits
    ok = ~np.isnan(got.q[..., 0])
    assert np.all((got.q[ok] >= lim[:, 0] - 1e-12) & (got.q[ok] <= lim[:, 1] + 1e-12))


@pytest.mark.parametrize("robot, seed", [
    ("panda", 0), ("panda", 1), ("panda", 2), ("panda", 3), ("panda", 9),
    ("iiwa14", 0), ("iiwa14", 2), ("iiwa14", 4), ("iiwa14", 6),
])
def test_kernel_nearest_along_a_trajectory_is_continuous_and_on_the_generating_branch(robot, seed):
    """k.nearest (the 1-D search on the C batch IK), 1000 poses seeded with the previous answer:
    exact, inside the limits, no step above 3 x the trajectory's own step, on the generating
    configuration's branch throughout; the same answers as the numpy search to 1e-9."""
    rng = np.random.default_rng(seed)
    q = trajectory(robot, 1000, rng)
    poses = reference.fk(robot, q)
    gen = redundant.solve(robot, poses, _own_free(robot, q))
    d = _wrapped(gen.q - q[:, None]).max(axis=-1)
    gen_branch = gen.branch[np.arange(1000), np.nanargmin(d, axis=1)]
    k = derive.kernels(robot, "c")
    out, branch = follow(k.nearest, poses, q[0])
    dp, dr = reference.pose_error(reference.fk(robot, out), poses)
    assert max(dp.max(), dr.max()) < 1e-10
    assert_continuous(q, out, derive.load_robot(robot).limits)
    np.testing.assert_array_equal(branch, gen_branch)
    # batch form, every pose seeded with the generating configuration: the numpy search agrees
    a = k.nearest(poses[::10], q[::10])
    b = redundant.nearest(robot, poses[::10], q[::10])
    np.testing.assert_array_equal(a.branch, b.branch)
    assert np.nanmax(np.abs(a.q - b.q)) < 1e-9


@pytest.mark.parametrize("backend", ["c", "numpy", "python"])
def test_the_free_parameter_is_required_checked_and_refused_for_six_joints(backend):
    k = derive.kernels("iiwa14", backend)
    pose = reference.fk("iiwa14", np.full(7, 0.3))
    with pytest.raises(InputError, match="free= .psi, the arm angle"):
        k.ik(pose)
    with pytest.raises(InputError, match="free"):
        k.ik(np.stack([pose, pose]), free=[0.1, 0.2, 0.3])
    with pytest.raises(InputError, match="free"):
        k.ik(pose, free=float("nan"))
    with pytest.raises(InputError, match="free"):
        derive.kernels("ur5", backend).ik(reference.fk("ur5", np.full(6, 0.3)), free=0.1)
    with pytest.raises(InputError, match="no free parameter"):
        derive.kernels("ur5", backend).ik_sweep(reference.fk("ur5", np.full(6, 0.3)), 4)


def test_with_tool_solves_tool_frame_poses():
    q = _configurations("iiwa14", 50, seed=19)
    tool = derive.dualquat.from_rt(np.array([0.9238795325112867, 0.0, 0.3826834323650898, 0.0]),
                                   np.array([0.0, 0.02, 0.15]))
    k = derive.kernels("iiwa14", "c").with_tool(tool)
    poses = k.fk(q)
    sols, counts = k.ik(poses, free=_own_free("iiwa14", q))
    assert np.all(np.nanmin(_wrapped(sols - q[:, None]).max(axis=-1), axis=1) < 1e-9)


@pytest.mark.parametrize("robot", ["panda", "iiwa14"])
def test_casadi_ik_takes_the_free_parameter_and_equals_the_kernels(robot):
    ik = functions(robot)["ik"]
    assert ik.name_in() == ["pose", "free"]
    q = _configurations(robot, 30, seed=20)
    poses, free = reference.fk(robot, q), _own_free(robot, q)
    _, _, branch, _ = derive.kernels(robot, "c").ik(poses, free=free, details=True)
    sols, counts = derive.kernels(robot, "c").ik(poses, free=free)
    for i in range(30):
        Q, valid = (np.array(x) for x in ik(poses[i], free[i]))
        for j in range(counts[i]):
            assert valid[0, branch[i, j]]
            assert np.abs(_wrapped(Q[:, branch[i, j]] - sols[i, j])).max() < 1e-10


def test_c_header_documents_the_branch_ids_the_kernels_return():
    """The header's branch index formula has the weights of the ids the kernels return (0-7):
    4 x the first label, 2 x the second, 1 x the third, labels as derive.ik.redundant's."""
    header = derive.kernels("iiwa14", "c").folder / "iiwa14_kinematics.h"
    text = " ".join(header.read_text().split())
    labels = redundant.branch_labels("iiwa14")
    assert f"index = 4 x ({labels[0]}: 1 for the second root) + 2 x ({labels[1]}: 1 for the second root) " \
           f"+ 1 x ({labels[2]}: 1 for the second root)" in text
    assert "double fv" in text and "const double *DQ_RESTRICT fv" in text
