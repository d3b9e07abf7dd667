"""Reachability maps and base placement (derive.apps.reach, issue 34): the map against an
independent Monte-Carlo check (FK of random configurations by derive.reference) and against the
kernels' own in-limit IK on poses built another way; the local scheduler against a 2-worker
dask.distributed LocalCluster given by address; resume; placement from a known base; the CLI."""

import json
import math

import numpy as np
import pytest

import derive
from derive import reference
from derive.algebra import dualquat as dq
from derive.apps import reach as R
from derive.cli import main
from derive.errors import InputError
from derive.kinematics.pose import from_position_quaternion

VOXEL, N_OR, CHUNK = 0.1, 24, 16   # coarse: 23^3 voxels in 8 chunks, 24 orientations, 0.13 M IK calls


@pytest.fixture(scope="module")
def ur5_map(tmp_path_factory):
    out = tmp_path_factory.mktemp("reach") / "ur5.zarr"
    return R.reach("ur5", VOXEL, N_OR, out, solutions=True, chunk=CHUNK, progress=False)


def _random_q(robot, rng, n):
    lim = robot.limits
    return rng.uniform(lim[:, 0], lim[:, 1], size=(n, robot.dof))


def _angle(a, b):
    """Rotation angle between unit quaternions (..., 4)."""
    return 2.0 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0))


def test_orientations_are_unit_and_cover_so3_better_than_random():
    q = R.orientations(100)
    assert q.shape == (100, 4)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    rng = np.random.default_rng(1)
    probe = rng.normal(size=(4000, 4))
    probe /= np.linalg.norm(probe, axis=1, keepdims=True)

    def covering(points):           # the largest distance from a probe to its nearest point
        return np.max(np.min(_angle(probe[:, None, :], points[None, :, :]), axis=1))
    sf = covering(q)
    randoms = []
    for _ in range(5):
        r = rng.normal(size=(100, 4))
        randoms.append(covering(r / np.linalg.norm(r, axis=1, keepdims=True)))
    assert sf < min(randoms)
    # no two orientations the same rotation (q and -q)
    d = _angle(q[:, None, :], q[None, :, :]) + 10 * np.eye(100)
    assert d.min() > 0.2
    with pytest.raises(InputError):
        R.orientations(0)


@pytest.mark.parametrize("name", ["ur5", "irb120", "panda"])
def test_reach_bound_holds_every_position(name, rng):
    robot = derive.load_robot(name)
    tool = dq.from_rt(np.array([math.cos(0.3), math.sin(0.3), 0.0, 0.0]), np.array([0.02, 0.0, 0.1]))
    centre, radius = R.reach_bound(robot, tool)
    q = _random_q(robot, rng, 3000)
    p = dq.to_rt(dq.mul(reference.fk(robot, q), tool[None]))[1]
    assert np.max(np.linalg.norm(p - centre, axis=1)) <= radius


def test_ur5_map_attributes_and_layout(ur5_map):
    m = ur5_map
    a = m.attrs
    assert m.complete and a["complete"]
    assert a["robot"] == "ur5" and a["robot_id"] == derive.load_robot("ur5").id
    assert a["orientations"] == N_OR and a["voxel"] == VOXEL and a["tool"] is None
    # the cube centred on (0, 0, d1) with side >= 2 x the bound 1.10335 m
    assert m.reach.shape == (23, 23, 23)
    assert np.allclose(a["origin"], [-1.15, -1.15, 0.089159 - 1.15])
    assert m.reach.dtype == np.float32 and np.all((m.reach >= 0) & (m.reach <= 1))
    # fractions are multiples of 1/N, and a voxel with a solution has at least one per orientation counted
    assert np.allclose(m.reach * N_OR, np.round(m.reach * N_OR), atol=1e-5)
    assert np.all((m.solutions > 0) == (m.reach > 0))
    assert np.all(m.solutions <= 8 * N_OR)
    reopened = R.open_reach(m.path)
    assert np.array_equal(reopened.reach, m.reach)


def test_monte_carlo_configurations_land_in_reachable_voxels(ur5_map):
    """FK (derive.reference, the numpy dual-quaternion product) of random configurations within the
    limits: >= 99 % of those whose voxel is away from the map's boundary (all 26 neighbours
    reachable) land in a voxel marked reachable."""
    m, robot = ur5_map, derive.load_robot("ur5")
    rng = np.random.default_rng(7)
    q = _random_q(robot, rng, 20000)
    p = dq.to_rt(reference.fk(robot, q))[1]
    idx = m.index(p)
    shape = np.array(m.reach.shape)
    assert np.all((idx >= 1) & (idx < shape - 1))     # the grid holds the reach with a margin
    r = m.reach > 0
    neigh = np.ones(len(idx), dtype=bool)
    for d in np.ndindex(3, 3, 3):
        off = np.array(d) - 1
        if not off.any():
            continue
        j = idx + off
        neigh &= r[j[:, 0], j[:, 1], j[:, 2]]
    hit = r[idx[:, 0], idx[:, 1], idx[:, 2]]
    assert neigh.sum() > 10000                         # most samples are away from the boundary
    assert hit[neigh].mean() >= 0.99
    assert hit.mean() >= 0.95                          # and nearly all of them overall


def test_no_reachable_voxel_beyond_the_arms_length(ur5_map):
    """The largest distance of the flange from the base over all configurations, by numeric
    maximisation of |p(q)| (scipy, many starts, the C FK kernel: FK, not the IK the map uses):
    every voxel centre the map marks reachable is within it."""
    from scipy.optimize import minimize
    robot = derive.load_robot("ur5")
    fk = derive.kernels(robot, "c").fk

    def neg(q):
        return -np.linalg.norm(dq.to_rt(fk(q))[1])
    rng = np.random.default_rng(3)
    best = max(-minimize(neg, q0, method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-12,
                                                                   "maxiter": 4000}).fun
               for q0 in _random_q(robot, rng, 10))
    assert 1.0 < best < R.reach_bound(robot)[1] + 0.089159   # UR5: 1.04 m from the base origin
    m = ur5_map
    centres = m.centres(np.argwhere(m.reach > 0))
    assert np.max(np.linalg.norm(centres, axis=1)) <= best + 1e-6
    # and the map does reach out to within two voxels of it
    assert np.max(np.linalg.norm(centres, axis=1)) >= best - 2 * VOXEL


def test_map_equals_the_kernels_in_limit_ik_on_poses_built_independently(ur5_map):
    """At sampled voxels, the fraction recomputed with derive.kernels(...).ik(within_limits=True)
    on poses from derive.pose.from_position_quaternion."""
    m = ur5_map
    k = derive.kernels("ur5", "c")
    quats = R.orientations(N_OR)
    rng = np.random.default_rng(11)
    cand = np.argwhere(np.isfinite(m.reach))
    picks = cand[rng.choice(len(cand), 60, replace=False)]
    picks = np.vstack([picks, np.argwhere((m.reach > 0) & (m.reach < 1))[:40]])
    diffs = []
    for ijk in picks:
        c = m.centres(ijk)
        poses = from_position_quaternion(np.broadcast_to(c, (N_OR, 3)), quats, order="wxyz")
        if np.linalg.norm(c - m.centre) > m.radius:
            frac = 0.0                                  # outside the bound: not computed, 0
        else:
            _, counts = k.ik(poses, within_limits=True)
            frac = np.count_nonzero(counts) / N_OR
        diffs.append(abs(frac - float(m.reach[tuple(ijk)])))
    diffs = np.array(diffs)
    assert np.max(diffs) <= 1.0 / N_OR + 1e-6
    assert np.count_nonzero(diffs > 1e-6) <= 2


def test_joint_limit_test_matches_the_windings_of_within_limits():
    """The solver's vectorised in-limit test against derive.ik.select.within_limits (through
    k.ik(within_limits=True)) on a robot with limits narrower than a turn (irb120)."""
    robot = derive.load_robot("irb120")
    k = derive.kernels(robot, "c")
    s = R._solver(robot.name, robot.id, None, 8)
    rng = np.random.default_rng(5)
    pts = rng.uniform(-0.7, 0.7, size=(300, 3))
    poses = R._poses(pts, R.orientations(10))
    mine = s.count(poses)
    sols, counts = k.ik(poses)
    assert np.array_equal(mine > 0, np.asarray(k.ik(poses, within_limits=True)[1]) > 0)
    assert np.all(mine <= counts)
    assert 0 < np.count_nonzero(mine) < len(poses) and np.any((mine < counts) & (mine > 0))


def test_local_scheduler_and_a_two_worker_cluster_give_the_same_maps(ur5_map, tmp_path, rng):
    distributed = pytest.importorskip("distributed")
    robot = derive.load_robot("ur5")
    targets = reference.fk(robot, _random_q(robot, rng, 10))
    local_place = R.place("ur5", targets, (-0.2, 0.2, -0.2, 0.2), 0.2, yaw_steps=2, progress=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        m = R.reach("ur5", VOXEL, N_OR, tmp_path / "cluster.zarr", solutions=True, chunk=CHUNK,
                    scheduler=cluster.scheduler_address, progress=False)
        p = R.place("ur5", targets, (-0.2, 0.2, -0.2, 0.2), 0.2, yaw_steps=2, progress=False,
                    scheduler=cluster.scheduler_address)
    assert m.complete and m.stats.computed == m.stats.chunks == 8
    assert np.array_equal(m.reach, ur5_map.reach)                 # bit for bit, no NaN when complete
    assert np.array_equal(m.solutions, ur5_map.solutions)
    assert np.array_equal(p.placement, local_place.placement)
    assert local_place.placement[1, 1, 0] == 1.0                 # the targets came from the origin


def test_resume_computes_only_the_missing_chunks(ur5_map, tmp_path):
    out = tmp_path / "resume.zarr"
    first = R.reach("ur5", VOXEL, N_OR, out, solutions=True, chunk=CHUNK, max_chunks=3, progress=False)
    assert not first.complete and first.stats.computed == 3
    assert np.isnan(first.reach).any()                            # the chunks not yet computed
    chunk_files = sorted((out / "reach" / "c").rglob("*"))
    chunk_files = [f for f in chunk_files if f.is_file()]
    assert len(chunk_files) == 3
    stamps = {f: f.stat().st_mtime_ns for f in chunk_files}
    second = R.reach("ur5", VOXEL, N_OR, out, solutions=True, chunk=CHUNK, progress=False)
    assert second.complete and second.stats.computed == 8 - 3
    assert np.array_equal(second.reach, ur5_map.reach)
    assert np.array_equal(second.solutions, ur5_map.solutions)
    assert all(f.stat().st_mtime_ns == t for f, t in stamps.items())   # not rewritten
    third = R.reach("ur5", VOXEL, N_OR, out, solutions=True, chunk=CHUNK, progress=False)
    assert third.stats.computed == 0
    with pytest.raises(InputError, match="other parameters"):
        R.reach("ur5", VOXEL, N_OR + 1, out, chunk=CHUNK, progress=False)


def test_placement_finds_the_base_the_targets_came_from(tmp_path):
    """Targets made by a UR5 with a tool mounted at base Trans(0.3, -0.2, 0.1) Rz(pi/2): the
    placement map gives 1 there (one of 3 x 3 positions x 4 yaws), less elsewhere."""
    robot = derive.load_robot("ur5")
    tool = [0.0, 0.05, 0.12, 0.0, math.sin(0.2), 0.0, math.cos(0.2)]
    tool_dq = from_position_quaternion(tool[:3], tool[3:], order="xyzw")
    base = dq.from_rt(np.array([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)]), np.array([0.3, -0.2, 0.1]))
    rng = np.random.default_rng(21)
    world = dq.mul(base[None], dq.mul(reference.fk(robot, _random_q(robot, rng, 60)), tool_dq[None]))
    r, t = dq.to_rt(world)
    rows = np.column_stack([t, r[:, 1:], r[:, :1]])
    csv = tmp_path / "targets.csv"
    csv.write_text("x,y,z,qx,qy,qz,qw\n" + "\n".join(",".join(f"{v:.17g}" for v in row) for row in rows) + "\n")
    p = R.place("ur5", csv, (0.1, 0.5, -0.4, 0.0), 0.2, z=0.1, yaw_steps=4, tool=tool, chunk=2,
                out=tmp_path / "place.zarr", progress=False)
    assert p.placement.shape == (3, 3, 4) and p.complete
    assert np.allclose(p.xs, [0.1, 0.3, 0.5]) and np.allclose(p.ys, [-0.4, -0.2, 0.0])
    assert p.placement[1, 1, 1] == 1.0
    assert np.count_nonzero(p.placement == 1.0) < p.placement.size
    best = p.best(3)
    assert best[0][4] == 1.0 and len(best) == 3
    assert p.attrs["targets"] == 60 and p.attrs["z"] == 0.1


def _run_cli(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_reach_and_place_end_to_end(tmp_path, capsys, rng):
    out = tmp_path / "m.zarr"
    png = tmp_path / "m.png"
    code, text, _ = _run_cli(["reach", "ur5", "--voxel", "0.2", "--orientations", "8", "--out", str(out),
                              "--plot", str(png), "--json", "--quiet"], capsys)
    assert code == 0
    summary = json.loads(text)
    assert summary["complete"] and summary["shape"] == [12, 12, 12] and summary["reachable_voxels"] > 100
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert R.open_reach(out).orientations == 8
    robot = derive.load_robot("ur5")
    world = reference.fk(robot, _random_q(robot, rng, 12))
    r, t = dq.to_rt(world)
    csv = tmp_path / "t.csv"
    csv.write_text("\n".join(",".join(repr(float(v)) for v in (*t[i], *r[i, 1:], r[i, 0])) for i in range(12)))
    code, text, _ = _run_cli(["place", "ur5", "--targets", str(csv), "--region", "-0.2", "0.2", "-0.2", "0.2",
                              "--step", "0.2", "--yaw-steps", "2", "--out", str(tmp_path / "p.zarr"),
                              "--plot", str(tmp_path / "p.png"), "--quiet"], capsys)
    assert code == 0
    assert "best placements" in text and "x=+0.0000 y=+0.0000 z=+0.0000 yaw=   0.00  1.0000" in text
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("argv, word", [
    (["reach", "no-such-robot", "--voxel", "0.2", "--out", "{tmp}/a.zarr"], "no-such-robot"),
    (["reach", "ur5", "--voxel", "nan", "--out", "{tmp}/a.zarr"], "voxel"),
    (["reach", "ur5", "--voxel", "0.2", "--orientations", "0", "--out", "{tmp}/a.zarr"], "orientations"),
    (["reach", "ur5", "--voxel", "0.2", "--out", "{tmp}/file.txt"], "not a Zarr group"),
    (["reach", "ur5", "--voxel", "0.2", "--tool", "0", "0", "0", "0", "0", "0", "2", "--out", "{tmp}/a.zarr"],
     "norm"),
    (["reach", "kunze-2r", "--voxel", "0.5", "--out", "{tmp}/a.zarr"], "IK"),
    (["place", "ur5", "--targets", "{tmp}/bad.csv", "--region", "0", "1", "0", "1", "--step", "0.5",
      "--out", "{tmp}/p.zarr"], "line 2"),
    (["place", "ur5", "--targets", "{tmp}/missing.csv", "--region", "0", "1", "0", "1", "--step", "0.5",
      "--out", "{tmp}/p.zarr"], "cannot read"),
    (["place", "ur5", "--targets", "{tmp}/good.csv", "--region", "1", "0", "0", "1", "--step", "0.5",
      "--out", "{tmp}/p.zarr"], "region"),
])
def test_cli_bad_input_one_line_exit_2(argv, word, tmp_path, capsys):
    (tmp_path / "file.txt").write_text("x")
    (tmp_path / "bad.csv").write_text("0.1,0.2,0.3,0,0,0,1\n0.1,0.2,oops,0,0,0,1\n")
    (tmp_path / "good.csv").write_text("0.1,0.2,0.3,0,0,0,1\n")
    code, _, err = _run_cli([a.replace("{tmp}", str(tmp_path)) for a in argv], capsys)
    assert code == 2
    # one line, the last (a robot derived on first use prints its progress lines before it)
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("[")]
    assert len(lines) == 1 and lines[0].startswith("dq-derive: error:") and word in lines[0]
    assert "Traceback" not in err and err.strip().splitlines()[-1] == lines[0]


def test_best_placements_one_per_position_inside_the_plateau():
    """A plateau of 1 over positions 1..3 x 1..3 (of 5 x 5) with lower values around it: the
    centre (2, 2) is first (its neighbourhood is all 1), each position appears once, at its best yaw."""
    val = np.full((5, 5, 2), 0.25)
    val[1:4, 1:4, 1] = 1.0
    val[4, 4, 0] = 0.5
    p = R.Placement(placement=val, xs=np.arange(5) * 0.1, ys=np.arange(5) * 0.1, z=0.0,
                    yaws=np.array([0.0, math.pi]), targets=np.zeros((1, 8)), complete=True, path=None,
                    attrs={}, stats=None)
    best = p.best(10)
    assert best[0][:2] == pytest.approx((0.2, 0.2)) and best[0][3] == math.pi and best[0][4] == 1.0
    assert [b[4] for b in best[:9]] == [1.0] * 9 and best[9][4] == 0.5
    assert len({(b[0], b[1]) for b in best}) == 10


@pytest.mark.parametrize("name", ["panda", "iiwa7"])
def test_seven_joint_maps_from_free_samples_pass_the_monte_carlo_check(name):
    """7-joint arms: reachable where one of 4 values of the free parameter over its feasible range
    (Kernels.ik_sweep) gives an in-limit solution, a lower bound; still >= 99 % of random
    configurations away from the boundary land in voxels marked reachable (15 cm, 12 orientations)."""
    m = R.reach(name, 0.15, 12, free_samples=4, chunk=16, progress=False)
    robot = derive.load_robot(name)
    assert m.attrs["free_parameter"] == {"panda": "q7", "iiwa7": "psi"}[name] and m.attrs["free_samples"] == 4
    rng = np.random.default_rng(7)
    p = dq.to_rt(reference.fk(robot, _random_q(robot, rng, 5000)))[1]
    idx = m.index(p) + 1
    r = np.pad(m.reach > 0, 1)                        # outside the grid: not reachable
    neigh = np.ones(len(idx), dtype=bool)
    for d in np.ndindex(3, 3, 3):
        off = np.array(d) - 1
        if off.any():
            j = idx + off
            neigh &= r[j[:, 0], j[:, 1], j[:, 2]]
    hit = r[idx[:, 0], idx[:, 1], idx[:, 2]]
    assert neigh.sum() > 1000
    assert hit[neigh].mean() >= 0.99


@pytest.mark.parametrize("kwargs, word", [
    (dict(tool="a tool"), "tool"),
    (dict(tool=[0, 0, 0, 0, 0, 0, float("nan")]), "NaN"),
    (dict(chunk=0), "chunk"),
    (dict(max_chunks=-1), "max_chunks"),
    (dict(scheduler=""), "scheduler"),
])
def test_reach_refuses_bad_arguments(kwargs, word):
    with pytest.raises(InputError, match=word):
        R.reach("ur5", 0.2, 4, progress=False, **kwargs)
