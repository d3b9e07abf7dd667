"""Fast first use (issue 30, item 4): a new robot of a known class gets its kernels from the
class's shipped symbolic IK (derive/data/ik_classes.json) by substitution, never by a symbolic
derivation on its own chain; the identity leaves the joint limits out, so a limit edit derives
nothing. tests/test_derivation.py derives ik_classes.json again and compares it byte for byte.
The timings are in benchmarks/bench_first_use.py, not here."""

from __future__ import annotations

import re

import numpy as np
import pytest

import derive
from derive.cache import clear_memory
from derive.kinematics.fk import _pose_error

from derive.model.robot import LIBRARY_DIR as ROBOTS  # noqa: E402

#: (library file, text replaced, replacement): a length changed, so a robot of no known identity
VARIANTS = {
    "ur": ("ur5.yaml", "d1: 0.089159", "d1: 0.5"),
    "sw": ("irb120.yaml", "link: [0, 0, 0.270]", "link: [0, 0, 0.280]"),
    "srs": ("iiwa14.yaml", "d_se: 0.420", "d_se: 0.430"),
    "panda": ("panda.yaml", "d5: 0.384", "d5: 0.390"),
}


def _variant(tmp_path, cls: str, limits=None):
    src, old, new = VARIANTS[cls]
    text = (ROBOTS / src).read_text(encoding="utf-8").replace(old, new, 1)
    assert new in text
    text = re.sub(r"^name: .*$", f"name: new-{cls}", text, count=1, flags=re.M)
    if limits is not None:
        text, n = re.subn(r"limits: \[[^\]]*\]", f"limits: [{limits[0]}, {limits[1]}]", text, count=1)
        assert n == 1
    path = tmp_path / f"new-{cls}{'-lim' if limits else ''}.yaml"
    path.write_text(text, encoding="utf-8")
    return derive.load_robot(str(path))


def _no_symbolic_derivation(monkeypatch):
    """Every entry of the symbolic derivation on a robot's own chain raises."""
    def refuse(*args, **kwargs):
        raise AssertionError("a symbolic derivation ran for a robot of a known class")

    import derive.codegen.fk
    import derive.ik.extract
    import derive.ik.program
    import derive.symbolic.equations
    import derive.symbolic.trig
    for mod, name in [(derive.ik.program, "extract"), (derive.ik.program, "derive_equations"),
                      (derive.ik.extract, "extract"), (derive.codegen.fk, "derive_equations"),
                      (derive.codegen.fk, "_fk_symbolic"), (derive.symbolic.equations, "derive_equations"),
                      (derive.symbolic.trig, "compact")]:
        monkeypatch.setattr(mod, name, refuse)


@pytest.fixture
def empty_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DQ_DERIVE_CACHE", str(tmp_path / "cache"))
    clear_memory()
    yield tmp_path
    clear_memory()


def _check_6r(robot, k, n=300, seed=3):
    """The kernels' IK of n poses agrees with the numpy reference (derive.reference.ik_batch, a
    hand-written closed form): the same number of solutions per pose, each kernel solution
    within 1e-9 (wrapped) of a reference one, and each reproducing the pose by the reference FK."""
    rng = np.random.default_rng(seed)
    lo, hi = np.clip(robot.limits[:, 0], -np.pi, np.pi), np.clip(robot.limits[:, 1], -np.pi, np.pi)
    q = rng.uniform(lo, hi, size=(n, robot.dof))
    poses = derive.reference.fk(robot, q)
    sols, counts = k.ik(poses)
    ref, ref_counts = derive.reference.ik_batch(robot, poses)
    assert np.array_equal(np.asarray(counts), ref_counts)
    assert ref_counts.min() >= 1
    for i in range(n):
        mine, theirs = sols[i, :counts[i]], ref[i, :ref_counts[i]]
        d = np.abs(np.angle(np.exp(1j * (mine[:, None, :] - theirs[None, :, :])))).max(axis=-1)
        assert d.min(axis=1).max() < 1e-9, (i, d.min(axis=1))
        dp, dr = _pose_error(derive.reference.fk(robot, mine), np.repeat(poses[i:i + 1], len(mine), 0))
        assert max(dp.max(), dr.max()) < 1e-9
        # the configuration the pose came from is among the solutions
        back = np.abs(np.angle(np.exp(1j * (mine - q[i])))).max(axis=-1)
        assert back.min() < 1e-7


def test_a_new_ur_robot_gets_kernels_without_a_symbolic_derivation(empty_cache, monkeypatch):
    robot = _variant(empty_cache, "ur")
    assert robot.exact and robot.id not in {derive.load_robot(n).id for n in derive.list_robots()}
    _no_symbolic_derivation(monkeypatch)
    k = derive.kernels(robot, "c")
    assert k.has_ik
    _check_6r(robot, k)


def test_a_new_spherical_wrist_robot_gets_kernels_without_a_symbolic_derivation(empty_cache, monkeypatch):
    robot = _variant(empty_cache, "sw")
    _no_symbolic_derivation(monkeypatch)
    k = derive.kernels(robot, "numpy")
    _check_6r(robot, k, n=200)


@pytest.mark.parametrize("cls", ["srs", "panda"])
def test_a_new_seven_joint_robot_gets_kernels_without_a_symbolic_derivation(empty_cache, monkeypatch, cls):
    robot = _variant(empty_cache, cls)
    _no_symbolic_derivation(monkeypatch)
    k = derive.kernels(robot, "numpy")
    rng = np.random.default_rng(5)
    q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], size=(100, 7))
    poses = derive.reference.fk(robot, q)
    from derive.ik.srs import arm_angle
    for i in range(len(q)):
        fv = float(np.ravel(arm_angle(robot, q[i]))[0]) if cls == "srs" else q[i, 6]
        sols, count = k.ik(poses[i], free=fv)
        sols = np.asarray(sols)[:int(np.ravel(count)[0])]
        ref = derive.reference.ik(robot, poses[i], free=fv)
        assert len(sols) == len(ref) >= 1
        d = np.abs(np.angle(np.exp(1j * (np.asarray(sols)[:, None, :] - np.asarray(ref)[None])))).max(axis=-1)
        assert d.min(axis=1).max() < 1e-8
        assert np.abs(np.angle(np.exp(1j * (np.asarray(sols) - q[i])))).max(axis=-1).min() < 1e-7


def test_a_limit_edit_keeps_the_identity_and_derives_nothing(empty_cache, monkeypatch):
    ur5 = derive.load_robot("ur5")
    edited = _variant(empty_cache, "ur", limits=("-pi", "pi"))
    plain = _variant(empty_cache, "ur")
    assert edited.id == plain.id and edited.limits_id != plain.limits_id
    # the library's UR5 with a limit edited: not the shipped kernels (those compile the UR5's
    # limits in), rendered again from the class program, no derivation
    path = empty_cache / "ur5-lim.yaml"
    text = (ROBOTS / "ur5.yaml").read_text(encoding="utf-8")
    path.write_text(text.replace("limits: [-2*pi, 2*pi]", "limits: [-pi, pi]", 1), encoding="utf-8")
    ur5_lim = derive.load_robot(str(path))
    assert ur5_lim.id == ur5.id and ur5_lim.limits_id != ur5.limits_id
    _no_symbolic_derivation(monkeypatch)
    k = derive.kernels(ur5_lim, "numpy")
    assert k.folder != derive.kernels(ur5, "numpy").folder
    rng = np.random.default_rng(11)
    q = rng.uniform(-np.pi, np.pi, size=(50, 6))
    poses = derive.reference.fk(ur5, q)
    sols, counts = k.ik(poses, within_limits=True)
    kept = np.concatenate([sols[i, :counts[i]] for i in range(len(q))])
    assert len(kept) and np.all(np.abs(kept[:, 0]) <= np.pi + 1e-9)
    wide, wide_counts = derive.kernels(ur5, "numpy").ik(poses, within_limits=True)
    assert wide_counts.sum() > counts.sum()         # the UR5's +-2 pi keeps more windings
    # in one process, the edited copy of a new robot reuses the derivation of the first
    monkeypatch.undo()
    clear_memory()
    derive.kernels(plain, "numpy")
    _no_symbolic_derivation(monkeypatch)
    import derive.ik.program as program
    calls = []
    real = program._ur_program
    monkeypatch.setattr(program, "_ur_program", lambda *a: calls.append(a) or real(*a))
    derive.kernels(edited, "numpy")
    assert calls == []                              # the IK program is kept under the identity
