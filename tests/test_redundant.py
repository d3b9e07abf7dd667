"""Seven-joint arms through one interface (derive.reference.ik / ik_batch with free=, ik_sweep,
nearest; derive.ik.redundant): the Franka Panda class with q7 given and the SRS class (iiwa)
with the arm angle psi given, checked against the reference FK, and the CLI's --free / --sweep /
--seed for them."""

import json
import math

import numpy as np
import pytest

import derive
from derive import reference
from derive.cli import main
from derive.errors import InputError
from derive.ik import redundant, srs
from paths7 import assert_continuous, follow, trajectory

SEED = 17
ROBOTS = ["panda", "fr3", "iiwa7", "iiwa14"]


def _wrapped(a):
    return np.abs((np.asarray(a) + np.pi) % (2 * np.pi) - np.pi)


def _inside(robot, n, rng):
    lim = derive.load_robot(robot).limits
    return rng.uniform(lim[:, 0], lim[:, 1], size=(n, 7))


def _own_free(robot, q):
    """The free value of configurations q: q7 for the Panda class, the arm angle for SRS (its
    definition in derive.ik.srs, tested there against the elbow's rotation about the
    shoulder-wrist line)."""
    name, _ = redundant.free_parameter(robot)
    return q[:, 6].copy() if name == "q7" else srs.arm_angle(robot, q)


def _errors(robot, q, poses):
    dp, dr = reference.pose_error(reference.fk(robot, q), poses)
    return float(dp.max(initial=0.0)), float(dr.max(initial=0.0))


# --------------------------------------------------------------------------- #
# The free parameter and the dispatch
# --------------------------------------------------------------------------- #
def test_free_parameter_names_the_value_and_its_range():
    for name in ("panda", "fr3"):
        lim = derive.load_robot(name).limits[6]
        assert reference.free_parameter(name) == ("q7", (lim[0], lim[1]))
    for name in ("iiwa7", "iiwa14"):
        assert reference.free_parameter(name) == ("psi", (-math.pi, math.pi))
    with pytest.raises(InputError, match="neither of the Franka Panda class .* nor of the SRS class"):
        reference.free_parameter("ur5")
    assert redundant.redundant_kind("ur5") is None


@pytest.mark.parametrize("name", ROBOTS)
def test_free_per_pose_finds_the_generating_configuration(name):
    """300 configurations inside the limits: at each one's own free value every returned
    solution reproduces the pose (reference FK, < 1e-10) and the configuration is among them."""
    rng = np.random.default_rng(SEED)
    q = _inside(name, 300, rng)
    poses = reference.fk(name, q)
    free = _own_free(name, q)
    sols, counts, branch, singular = reference.ik_batch(name, poses, free=free, details=True)
    assert sols.shape == (300, 8, 7) and counts.shape == (300,) and branch.shape == (300, 8)
    assert np.all(counts >= 1) and np.all(counts <= 8)
    valid = np.arange(8)[None, :] < counts[:, None]
    assert np.all(np.isfinite(sols[valid])) and np.all(np.isnan(sols[~valid]))
    assert np.all(branch[~valid] == -1) and np.all((branch[valid] >= 0) & (branch[valid] < 8))
    assert not np.any(singular[~valid])
    for i in range(300):                              # branch ids distinct per pose
        assert len(set(branch[i, :counts[i]])) == counts[i]
    rows = np.nonzero(valid)[0]
    assert max(_errors(name, sols[valid], poses[rows])) < 1e-10
    gap = np.nanmin(_wrapped(sols - q[:, None]).max(axis=-1), axis=1)
    assert gap.max() < 1e-9
    # q7 is returned as given; the arm angle of every solution is the psi asked for
    if name in ("panda", "fr3"):
        assert np.all(sols[valid][:, 6] == np.repeat(free, counts))
    else:
        assert _wrapped(srs.arm_angle(name, sols[valid]) - np.repeat(free, counts)).max() < 1e-9


@pytest.mark.parametrize("name", ["panda", "iiwa14"])
def test_a_scalar_free_is_the_same_value_for_every_pose_and_ik_is_one_row(name):
    rng = np.random.default_rng(SEED + 1)
    q = _inside(name, 20, rng)
    poses = reference.fk(name, q)
    a, ca = reference.ik_batch(name, poses, free=0.3)
    b, cb = reference.ik_batch(name, poses, free=np.full(20, 0.3))
    np.testing.assert_array_equal(ca, cb)
    np.testing.assert_array_equal(a, b)
    one = reference.ik(name, poses[4], free=0.3)
    assert isinstance(one, reference.RedundantIKSolutions) and one.free == 0.3
    assert one.shape == (ca[4], 7) and one.branch.shape == (ca[4],) and one.singular.shape == (ca[4],)
    np.testing.assert_array_equal(np.asarray(one), a[4, :ca[4]])
    # a 4x4 matrix works as the pose too
    m, cm = reference.ik_batch(name, reference.fk_matrix(name, q[4])[None], free=0.3)
    np.testing.assert_allclose(m[0, :cm[0]], a[4, :ca[4]], atol=1e-12)
    inside = reference.ik(name, poses[4], free=float(_own_free(name, q[4:5])[0]), within_limits=True)
    lim = derive.load_robot(name).limits
    assert len(inside) >= 1 and np.all((inside >= lim[:, 0] - 1e-12) & (inside <= lim[:, 1] + 1e-12))


def test_without_free_a_seven_joint_robot_says_which_parameter_it_needs():
    pose = reference.fk("panda", [0.1, -0.5, 0.2, -2.0, 0.3, 1.5, 0.4])
    with pytest.raises(InputError, match=r"panda has 7 joints.*needs free= \(q7"):
        reference.ik("panda", pose)
    with pytest.raises(InputError, match=r"needs free= \(q7"):
        reference.ik_batch("panda", pose[None])
    pose = reference.fk("iiwa14", np.full(7, 0.3))
    with pytest.raises(InputError, match=r"iiwa14 has 7 joints.*needs free= \(psi, the arm angle"):
        reference.ik("iiwa14", pose)
    with pytest.raises(InputError, match=r"free: expected a number or shape \(2,\)"):
        reference.ik_batch("iiwa14", np.stack([pose, pose]), free=[0.1, 0.2, 0.3])
    with pytest.raises(InputError, match="free: ur5 has 6 joint variables and no free parameter"):
        reference.ik("ur5", reference.fk("ur5", np.zeros(6)), free=0.2)
    with pytest.raises(InputError, match="free: contains NaN"):
        reference.ik_batch("iiwa14", pose[None], free=float("nan"))


def test_an_unreachable_pose_has_no_solutions_and_a_reason():
    far = derive.dualquat.from_rt(np.array([1.0, 0, 0, 0]), np.array([3.0, 0, 0]))
    for name in ("panda", "iiwa14"):
        sols = reference.ik(name, far, free=0.0)
        assert sols.shape == (0, 7) and sols.reason.startswith("unreachable")
        res = reference.nearest(name, far, np.zeros(7))
        assert not res.found and np.all(np.isnan(res.q)) and res.branch == -1


# --------------------------------------------------------------------------- #
# Sweep
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("name", ["panda", "iiwa14"])
def test_sweep_covers_the_feasible_range_with_solutions_inside_the_limits(name):
    rng = np.random.default_rng(SEED + 2)
    robot = derive.load_robot(name)
    q = _inside(name, 6, rng)
    poses = reference.fk(name, q)
    sw = reference.ik_sweep(name, poses, 8)
    assert sw.free.shape == (6, 8) and sw.q.shape == (6, 8, 8, 7) and sw.counts.shape == (6, 8)
    lim = robot.limits
    if name == "panda":
        lo, hi = lim[6]
        np.testing.assert_allclose(sw.free, np.broadcast_to(lo + (hi - lo) * (np.arange(8) + 0.5) / 8, (6, 8)))
    else:
        for i in range(6):
            iv = np.concatenate(srs.psi_intervals(name, poses[i]))
            assert all(np.any((iv[:, 0] <= p) & (p <= iv[:, 1])) for p in sw.free[i])
        assert np.all(sw.counts >= 1)           # a feasible psi has an in-limit solution
    valid = np.arange(sw.q.shape[2])[None, None, :] < sw.counts[..., None]
    sols = sw.q[valid]
    assert np.all(np.isfinite(sols)) and np.all(np.isnan(sw.q[~valid]))
    assert np.all((sols >= lim[:, 0] - 1e-12) & (sols <= lim[:, 1] + 1e-12))
    assert np.all(sw.branch[valid] >= 0) and np.all(sw.branch[~valid] == -1)
    rows = np.nonzero(valid)[0]
    assert max(_errors(name, sols, poses[rows])) < 1e-10
    free_rows = np.broadcast_to(sw.free[..., None], valid.shape)[valid]
    own = sols[:, 6] if name == "panda" else srs.arm_angle(name, sols)
    assert _wrapped(own - free_rows).max() < 1e-9
    one = reference.ik_sweep(name, poses[0], 3)
    assert one.free.shape == (3,) and one.q.shape == (3, 8, 7)
    with pytest.raises(InputError, match="positive integer"):
        reference.ik_sweep(name, poses, 0)
    with pytest.raises(InputError, match="no closed form with a free parameter"):
        reference.ik_sweep("ur5", reference.fk("ur5", np.zeros(6)), 4)


# --------------------------------------------------------------------------- #
# Nearest along a path
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("name", ["panda", "iiwa14"])
def test_nearest_along_a_trajectory_stays_continuous_and_on_the_generating_branch(name):
    """1000 poses of a smooth trajectory, each step seeded with the previous answer (the first
    with the generating configuration): every answer reproduces its pose (< 1e-10), lies inside
    the limits, no step is larger than 3 x the trajectory's own step, and the branch is the
    generating configuration's at every step."""
    rng = np.random.default_rng(0)
    q = trajectory(name, 1000, rng)
    poses = reference.fk(name, q)
    gen = redundant.solve(name, poses, _own_free(name, q))
    d = _wrapped(gen.q - q[:, None]).max(axis=-1)
    gen_branch = gen.branch[np.arange(1000), np.nanargmin(d, axis=1)]
    out, branch = follow(lambda pose, seed: reference.nearest(name, pose, seed), poses, q[0])
    assert max(_errors(name, out, poses)) < 1e-10
    assert_continuous(q, out, derive.load_robot(name).limits)
    np.testing.assert_array_equal(branch, gen_branch)


def test_nearest_of_batches_with_a_tolerance_and_the_6r_path(monkeypatch):
    rng = np.random.default_rng(SEED + 3)
    q = _inside("iiwa7", 30, rng)
    poses = reference.fk("iiwa7", q)
    lim = derive.load_robot("iiwa7").limits
    seeds = np.clip(q + 0.01, lim[:, 0], lim[:, 1])
    res = reference.nearest("iiwa7", poses, seeds)
    # without the slack the answer is the least largest move M: the generating configuration
    # moves at most 0.01 from the seed, so M is no more
    with monkeypatch.context() as m:
        m.setattr(redundant, "SLACK", 0.0)
        least = reference.nearest("iiwa7", poses, seeds)
    assert least.found.all() and least.max_move.max() <= 0.01 + 1e-9
    # (here every joint moves 0.01 and the self-motion moves some joint more: q itself)
    unclipped = np.all(seeds == q + 0.01, axis=1)
    assert unclipped.sum() >= 20 and _wrapped(least.q[unclipped] - q[unclipped]).max() < 1e-9
    # with it: a largest move of at most 1.5 M, and no larger summed squared move than the
    # generating configuration's wherever that is within the bound
    assert redundant.SLACK == 0.5
    assert res.found.all() and np.all(res.max_move <= 1.5 * least.max_move + 1e-9)
    assert np.all(res.max_move >= least.max_move - 1e-9) and res.max_move.max() > 0.01
    sq = ((res.q - seeds) ** 2).sum(axis=1)
    gen_max, gen_sq = np.abs(q - seeds).max(axis=1), ((q - seeds) ** 2).sum(axis=1)
    within = gen_max <= 1.5 * least.max_move
    assert within.sum() >= 20 and np.all(sq[within] <= gen_sq[within] + 1e-12)
    assert max(_errors("iiwa7", res.q, poses)) < 1e-10
    assert np.all(res.total_move >= res.max_move)
    tight = reference.nearest("iiwa7", poses, seeds, tol=1e-4)
    assert not tight.found.any() and np.all(tight.branch == -1)
    with pytest.raises(InputError, match="tol"):
        reference.nearest("iiwa7", poses, seeds, tol=-1.0)
    with pytest.raises(InputError, match="q_seed"):
        reference.nearest("iiwa7", poses, np.zeros((3, 7)))
    # a 6R arm: every solution and derive.ik.select.nearest
    q6 = np.array([0.3, -1.2, 1.1, -0.4, 1.3, 0.2])
    r6 = reference.nearest("ur5", reference.fk("ur5", q6), q6 + 0.01)
    assert r6.found and abs(r6.max_move - 0.01) < 1e-9 and _wrapped(r6.q - q6).max() < 1e-9


# --------------------------------------------------------------------------- #
# Classification and the command line
# --------------------------------------------------------------------------- #
def test_classify_and_robots_say_the_closed_form_has_a_free_parameter(capsys):
    for name, word in (("panda", "q7"), ("fr3", "q7"), ("iiwa7", "psi"), ("iiwa14", "psi")):
        c = derive.classify(name)
        assert c.closed_form and any(word in n and "free parameter" in n for n in c.notes), c.notes
    assert main(["robots", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)["robots"]}
    assert rows["panda"]["ik"] == "Panda, q7 free" and rows["fr3"]["free_parameter"] == "q7"
    assert rows["iiwa14"]["ik"] == "SRS, psi free" and rows["iiwa7"]["closed_form_ik"] == "SRS"
    assert rows["ur5"]["free_parameter"] is None and rows["seed-arm"]["ik"] == "no: refine"


def test_cli_ik_free_lists_the_solutions_with_the_generating_configuration(capsys):
    q = [0.1, -0.5, 0.2, -2.0, 0.3, 1.5, 0.4]
    argv = ["ik", "panda", "--q", *map(str, q), "--free", "0.4"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "closed form at q7 = 0.4 rad" in out and "panda_joint7" in out and "branch" in out
    assert main(argv + ["--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["free_parameter"]["name"] == "q7" and data["free_parameter"]["unit"] == "rad"
    assert [j["name"] for j in data["joints"]][6] == "panda_joint7"
    sols = np.array([s["q"] for s in data["solutions"]])
    assert data["count"] == len(sols) == 8
    assert _wrapped(sols - q).max(axis=1).min() < 1e-9
    assert all(s["free"] == 0.4 and 0 <= s["branch"] < 8 for s in data["solutions"])
    assert max(_errors("panda", sols, np.repeat(reference.fk("panda", q)[None], 8, 0))) < 1e-10
    # degrees in and out
    qd = [10, 20, 30, -40, 50, 60, 70]
    assert main(["ik", "iiwa14", "--q", *map(str, qd), "--deg", "--free", "15", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["free_parameter"]["name"] == "psi" and data["free_parameter"]["unit"] == "deg"
    sols = np.radians([s["q"] for s in data["solutions"]])
    assert _wrapped(srs.arm_angle("iiwa14", sols) - math.radians(15)).max() < 1e-9


def test_cli_ik_sweep_and_seed(capsys):
    q = np.radians([10, 20, 30, -40, 50, 60, 70])
    args = ["ik", "iiwa14", "--q", *map(str, q)]
    assert main(args + ["--sweep", "4", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    free = sorted({s["free"] for s in data["solutions"]})
    assert len(free) == 4 and data["count"] == len(data["solutions"]) >= 4
    sols = np.array([s["q"] for s in data["solutions"]])
    lim = derive.load_robot("iiwa14").limits
    assert np.all((sols >= lim[:, 0] - 1e-12) & (sols <= lim[:, 1] + 1e-12))
    assert main(args + ["--sweep", "2"]) == 0
    out = capsys.readouterr().out
    assert "2 values of psi over its feasible range" in out and "(rad)" in out
    assert main(args + ["--seed", *map(str, q + 0.01), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    # q moves 0.01 in every joint: the least largest move is at most that, the answer's at most
    # 1.5 x the least (derive.ik.redundant.SLACK)
    assert data["count"] == 1 and data["largest_move"] <= 1.5 * 0.01
    assert _wrapped(np.array(data["solutions"][0]["q"]) - q).max() < 0.02


@pytest.mark.parametrize("argv, message", [
    (["ik", "panda", "--q", "0", "0", "0", "-1", "0", "1", "0"], "give exactly one of --free V (q7"),
    (["ik", "iiwa7", "--q", "0", "0.3", "0", "1", "0", "1", "0", "--free", "1", "--sweep", "3"],
     "got --free and --sweep"),
    (["ik", "ur5", "--q", "0", "0", "0", "0", "0", "0", "--free", "1"], "ur5 has none"),
    (["ik", "panda", "--free", "1"], "need a target"),
    (["ik", "iiwa7", "--q", "0", "0.3", "0", "1", "0", "1", "0", "--sweep", "0"], "integer >= 1"),
])
def test_cli_ik_seven_joint_errors_exit_2(argv, message, capsys):
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_cli_ik_free_unreachable_exits_1_with_the_reason(capsys):
    assert main(["ik", "panda", "--dq", "1", "0", "0", "0", "0", "1.5", "0", "0", "--free", "0", "--json"]) == 1
    data = json.loads(capsys.readouterr().out)
    assert data["count"] == 0 and data["reason"].startswith("unreachable")
