"""Near-class kernels (issue 30, item 3, emitted side): the nominal robot's closed form, every
candidate polished by damped Newton steps on the arm's own FK (derive.codegen.polish), in C,
numpy and pure Python. Checked against the reference FK (dual-quaternion products, a path that
shares no code with the kernels' FK or with the polish), the generating configurations, and the
nominal robot's solution counts from the reference IK (derive.ik.closed_form)."""

import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import derive
from derive import reference
from derive.codegen.emit import render_kernels
from derive.codegen.formats import nominal_key
from derive.codegen.polish import POLISH_ACCEPT, nominal_program, poe_chain
from derive.errors import DeriveError
from derive.ik.closed_form import ik_batch, nominal_relation
from derive.ik.nearclass import Nominal
from derive.kinematics.fk import fk_matrix, pose_error

ROOT = Path(__file__).resolve().parents[1]
IDENTITY = np.array([1.0, 0, 0, 0, 0, 0, 0, 0])
needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("g++") is None,
                               reason="gcc / g++ not installed")


@pytest.fixture(scope="module")
def decimal(tmp_path_factory):
    """The UR5 with its twists written 1.5708 (not exact; it is of the three-parallel class, but
    here it is given the UR5 as its nominal by hand, to test the polish) and its
    nominal, the library UR5, related by identities (the relation written by hand)."""
    text = (ROOT / "derive" / "robots" / "ur5.yaml").read_text()
    text = text.replace("name: ur5", "name: ur5-decimal").replace("-pi/2", "-1.5708").replace("pi/2", "1.5708")
    path = tmp_path_factory.mktemp("near") / "ur5-decimal.yaml"
    path.write_text(text)
    robot = derive.load_robot(path)
    assert not robot.exact
    nominal = Nominal(derive.load_robot("ur5"), IDENTITY, IDENTITY, np.ones(6), np.zeros(6),
                      abs(1.5708 - math.pi / 2), "by hand: the twists 1.5708 are pi/2")
    return robot, nominal


@pytest.fixture(scope="module")
def calibrated():
    """ur5-calibrated (millimetres and tenths of a degree off the UR5) with the UR5 as nominal,
    B, T and the signs from derive.ik.closed_form.nominal_relation."""
    robot = derive.load_robot("ur5-calibrated")
    rel = nominal_relation(robot)
    assert rel is not None and rel.other == "ur5"
    return robot, Nominal(derive.load_robot("ur5"), rel.base, rel.tool, rel.signs, np.zeros(6), rel.error,
                          "derive.ik.closed_form.nominal_relation")


@pytest.fixture(scope="module")
def fast_c():
    """The C backend built at -O0 for these tests (quicker to compile; the results do not depend on the flags)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("DQ_DERIVE_CFLAGS", "-std=c99 -O0")
        yield


def _poses(robot, n, seed, well_conditioned=False):
    """Configurations within the limits and their poses by the reference FK; ``well_conditioned``:
    away from the elbow's fold and stretch and the wrist singularity (|sin q3|, |sin q5| > 0.25)
    and from the shoulder's boundary (the wrist point d6 behind the flange at least 5 cm outside
    the cylinder of radius d4 about axis 1, where the two roots of theta1 meet), where a 1.6 cm
    mismatch moves the nominal's roots by tenths of a radian."""
    rng = np.random.default_rng(seed)
    lo, hi = np.maximum(robot.limits[:, 0], -math.pi), np.minimum(robot.limits[:, 1], math.pi)
    Q = rng.uniform(lo, hi, size=(4 * n, robot.dof))
    if well_conditioned:
        T = fk_matrix(robot, Q)
        wrist = T[:, :3, 3] - 0.0823 * T[:, :3, 2]           # the UR5's d6 along the flange's z
        Q = Q[(np.abs(np.sin(Q[:, 2])) > 0.25) & (np.abs(np.sin(Q[:, 4])) > 0.25)
              & (np.hypot(wrist[:, 0], wrist[:, 1]) > 0.10915 + 0.05)]
    Q = Q[:n]
    return Q, reference.fk(robot, Q)


def _check(robot, nominal, Q, P, sols, counts, same_count=1.0):
    """Every solution's reference FK within 1e-10 of its pose, the generating configuration among
    the solutions, and (on at least the fraction ``same_count`` of the poses) the count the nominal
    robot's reference IK gives at the corresponding pose FK_nominal(s q + o). That pose is not the
    arm's pose moved into the nominal's frames: 1.6 cm off, another of its roots may lie beyond a
    boundary of the nominal's (ssik's general 6R solver, on ur5-calibrated's own chain, gave our
    counts on the five poses of test_calibrated_... where the two differ; 11 s a pose, too slow
    for the suite)."""
    n = len(Q)
    filled = np.arange(sols.shape[1])[None, :] < counts[:, None]
    assert not np.isnan(sols[filled]).any() and np.isnan(sols[~filled]).all()
    dp, da = pose_error(reference.fk(robot, sols[filled]), np.repeat(P, counts, axis=0))
    assert dp.max() <= 1e-10 and da.max() <= 1e-10, (dp.max(), da.max())
    gap = np.abs((sols - Q[:, None, :] + math.pi) % (2 * math.pi) - math.pi).max(axis=2)
    nearest = np.where(filled, gap, np.inf).min(axis=1)
    assert np.all(nearest < 1e-8), (np.nonzero(nearest >= 1e-8)[0], nearest[nearest >= 1e-8])
    _, nominal_counts = ik_batch(nominal.robot, reference.fk(nominal.robot, nominal.signs * Q + nominal.offsets))
    same = counts == nominal_counts
    assert same.mean() >= same_count, np.nonzero(~same)[0]
    assert counts.sum() >= 4 * n           # most poses of a UR have 8, some 4 or 6


def test_decimal_ur5_c_kernels_keep_the_closed_form(decimal, fast_c):
    robot, nominal = decimal
    k = derive.kernels(robot, "c", nominal=nominal)
    assert k.has_ik and k.nominal is nominal
    Q, P = _poses(robot, 300, 1)
    sols, counts = k.ik(P)
    _check(robot, nominal, Q, P, sols, counts)
    s2, c2, res, its = k.ik_polish(P)
    filled = np.arange(sols.shape[1])[None, :] < counts[:, None]
    # the extension's ik and the library's ik_polish: one source, two builds
    assert np.array_equal(c2, counts) and np.abs(s2[filled] - sols[filled]).max() < 1e-12
    assert np.nanmax(res[filled]) <= POLISH_ACCEPT and np.isnan(res[~filled]).all()
    # 1.5708 is 3.7e-6 off pi/2: from there Newton's quadratic convergence takes two steps to
    # rounding (a few more near a singular set)
    assert np.median(its[filled]) == 2 and its[filled].max() <= 10 and (its[~filled] == -1).all()
    # the nearest solution to the generating configuration is that configuration
    near = k.nearest(P, Q)
    assert near.found.all() and np.abs(near.q - Q).max() < 1e-8


def test_calibrated_ur5_c_kernels_polish_a_centimetre(calibrated, fast_c):
    """ur5-calibrated is 0.016 (m, rad) from the UR5: the polish takes a few more steps."""
    robot, nominal = calibrated
    assert nominal.deviation > 0.01
    k = derive.kernels(robot, "c", nominal=nominal)
    Q, P = _poses(robot, 300, 2, well_conditioned=True)
    assert len(Q) == 300
    sols, counts, res, its = k.ik_polish(P)
    _check(robot, nominal, Q, P, sols, counts, same_count=0.97)
    filled = np.arange(sols.shape[1])[None, :] < counts[:, None]
    assert np.median(its[filled]) >= 3 and its[filled].max() <= 30


def test_numpy_and_python_kernels_agree_with_c(decimal, calibrated, fast_c):
    for (robot, nominal), seed in ((decimal, 3), (calibrated, 4)):
        Q, P = _poses(robot, 60, seed, well_conditioned=True)
        c_sols, c_counts, c_res, c_its = derive.kernels(robot, "c", nominal=nominal).ik_polish(P)
        for backend in ("numpy", "python"):
            sols, counts, res, its = derive.kernels(robot, backend, nominal=nominal).ik_polish(P)
            assert np.array_equal(counts, c_counts), backend
            filled = np.arange(sols.shape[1])[None, :] < counts[:, None]
            assert np.abs(sols[filled] - c_sols[filled]).max() < 1e-9, backend
            assert np.isnan(sols[~filled]).all()
            assert np.nanmax(res) <= POLISH_ACCEPT and np.array_equal(np.isnan(res), ~filled)
            # the same Newton steps (one step more or less where the last one lands on rounding)
            assert np.abs(its[filled] - c_its[filled]).max() <= 1, backend
        _check(robot, nominal, Q, P, sols, counts, same_count=0.9)


def test_unreachable_and_singular_poses_give_no_nan(decimal, fast_c):
    """Out of reach: no solution; a singular configuration (q5 = 0, the wrist axes 4 and 6 in
    line) and the zero configuration: finite solutions whose FK is the pose, or none."""
    robot, nominal = decimal
    k = derive.kernels(robot, "c", nominal=nominal)
    far = derive.dualquat.from_rt(np.array([1.0, 0, 0, 0]), np.array([3.0, 0.2, 0.1]))
    sols, count = k.ik(far)
    assert count == 0 and np.isnan(sols).all()
    Q = np.array([[0.3, -1.2, 1.4, -0.5, 0.0, 0.7], [0.0] * 6, [0.5, -1.0, 0.0, 0.3, 1.0, 0.2]])
    P = reference.fk(robot, Q)
    sols, counts, res, its = k.ik_polish(P)
    filled = np.arange(sols.shape[1])[None, :] < counts[:, None]
    assert np.isfinite(sols[filled]).all() and np.isfinite(res[filled]).all()
    dp, da = pose_error(reference.fk(robot, sols[filled]), np.repeat(P, counts, axis=0))
    assert max(dp.max(), da.max()) <= 1e-10


def test_product_of_exponentials_matches_the_matrix_fk(calibrated):
    """The polish's FK (product of exponentials from the joint screws at q = 0) against the
    4x4 matrix chain, and its geometric Jacobian against central differences."""
    robot, _ = calibrated
    w, c, prismatic, variables, M = poe_chain(robot)
    assert not prismatic.any() and list(variables) == list(range(6))
    rng = np.random.default_rng(5)
    for q in rng.uniform(-math.pi, math.pi, size=(5, 6)):
        T = fk_matrix(robot, q)
        # the Jacobian from the screws: columns [z x (p - c); z]
        frame, cols = np.eye(4), []
        for i in range(6):
            z, ci = frame[:3, :3] @ w[i], frame[:3, :3] @ c[i] + frame[:3, 3]
            cols.append((z, ci))
            K = np.array([[0, -w[i][2], w[i][1]], [w[i][2], 0, -w[i][0]], [-w[i][1], w[i][0], 0]])
            E = np.eye(4)
            E[:3, :3] = np.eye(3) + math.sin(q[i]) * K + (1 - math.cos(q[i])) * K @ K
            E[:3, 3] = c[i] - E[:3, :3] @ c[i]
            frame = frame @ E
        assert np.abs(frame @ M - T).max() < 1e-12
        J = np.array([np.concatenate([np.cross(z, T[:3, 3] - ci), z]) for z, ci in cols]).T
        h = 1e-6
        for i in range(6):
            dq_ = np.zeros(6)
            dq_[i] = h
            Tp, Tm = fk_matrix(robot, q + dq_), fk_matrix(robot, q - dq_)
            dt = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
            dR = (Tp[:3, :3] - Tm[:3, :3]) / (2 * h) @ T[:3, :3].T
            omega = np.array([dR[2, 1], dR[0, 2], dR[1, 0]])
            assert np.abs(dt - J[:3, i]).max() < 1e-8 and np.abs(omega - J[3:, i]).max() < 1e-8


@needs_gcc
def test_near_class_c_source_compiles_as_c99_and_cxx17_and_refuses_fast_math(decimal, tmp_path):
    robot, nominal = decimal
    files = render_kernels(robot, nominal=nominal)
    for name, text in files.values():
        (tmp_path / name).write_text(text)
    source = tmp_path / files["c_source"][0]
    header = tmp_path / files["c_header"][0]
    assert "_ik_batch_polish(" in header.read_text()
    for cmd in (["gcc", "-std=c99", "-Wpedantic", "-O1", "-c", "-o", "/dev/null"],
                ["g++", "-std=c++17", "-x", "c++", "-fsyntax-only"]):
        res = subprocess.run([*cmd, "-Wall", "-Wextra", "-Werror", str(source)], capture_output=True, text=True)
        assert res.returncode == 0, (cmd, res.stderr[-3000:])
    for cmd in (["g++", "-std=c++17", "-x", "c++"], ["gcc", "-std=c99"]):
        res = subprocess.run([*cmd, "-Wall", "-Wextra", "-Werror", "-fsyntax-only", str(header)],
                             capture_output=True, text=True)
        assert res.returncode == 0, (cmd, res.stderr)
    res = subprocess.run(["gcc", "-std=c99", "-O2", "-ffast-math", "-fsyntax-only", str(source)],
                         capture_output=True, text=True)
    assert res.returncode != 0 and "#error" in res.stderr


def test_exact_kernels_are_unchanged_and_keys_name_the_relation(decimal, calibrated):
    """The exact classes' emitted files do not change (the shipped generated/ur5 C source is what
    render_kernels writes without a nominal); the cache key and the manifest name the nominal
    robot and the relation."""
    ur5 = render_kernels("ur5")
    shipped = ROOT / "generated" / "ur5"
    for role in ("c_source", "c_header", "numpy", "python"):
        name, text = ur5[role]
        assert (shipped / name).read_text() == text, role
    robot, nominal = decimal
    other = Nominal(nominal.robot, nominal.base, nominal.tool, nominal.signs, np.full(6, 1e-3),
                    nominal.deviation, nominal.how)
    assert nominal_key(nominal) != nominal_key(other) != nominal_key(calibrated[1])
    assert nominal_key(nominal) == nominal_key(Nominal(*[getattr(nominal, f) for f in
                                                         ("robot", "base", "tool", "signs", "offsets",
                                                          "deviation")], how="other words"))
    manifest = derive.codegen.emit.kernel_manifest(robot, nominal=nominal)
    assert manifest["nominal"]["robot"] == "ur5" and manifest["nominal"]["key"] == nominal_key(nominal)
    # the program: the nominal's after the pose moved, its solutions mapped by s (q - o)
    prog = nominal_program(robot, other)
    assert prog.branches == 8 and prog.steps[-1][1] == "Newton polish"
    with pytest.raises(DeriveError, match="joints"):
        nominal_program(robot, Nominal(derive.load_robot("iiwa14"), IDENTITY, IDENTITY, np.ones(7),
                                       np.zeros(7), 0.0, "wrong"))


def test_seven_joint_arm_with_joint_3_given(tmp_path, fast_c):
    """An iiwa14 whose elbow axis misses the shoulder-wrist plane by 0.4 mm (no SRS closed form of
    its own), nominal iiwa14, joint 3 given (``free="q3"``): the nominal's q3 kernels' program,
    the polish holding joint 3; every solution's FK within 1e-10, q3 as given, the generating
    configuration among them and the nominal's count at the corresponding pose; the numpy and
    Python kernels agree with C."""
    text = (ROOT / "derive" / "robots" / "iiwa14.yaml").read_text().replace("name: iiwa14", "name: iiwa14-near")
    text = text.replace("{name: A4, axis: [0, -1, 0], link: [0, 0, 0],", "{name: A4, axis: [0, -1, 0], link: [0.0004, 0, 0],")
    assert "0.0004" in text
    (tmp_path / "iiwa14-near.yaml").write_text(text)
    robot = derive.load_robot(tmp_path / "iiwa14-near.yaml")
    one = np.array([1.0, 0, 0, 0, 0, 0, 0, 0])
    nominal = Nominal(derive.load_robot("iiwa14"), one, one, np.ones(7), np.zeros(7), 4e-4, "by hand")
    with pytest.raises(DeriveError, match="not a joint"):
        nominal_program(robot, nominal)                  # the arm angle psi: no joint to hold
    rng = np.random.default_rng(6)
    Q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], size=(100, 7))
    P = reference.fk(robot, Q)
    k = derive.kernels(robot, "c", free="q3", nominal=nominal)
    assert k.free == "q3"
    sols, counts, res, its = k.ik_polish(P, free=Q[:, 2])
    filled = np.arange(sols.shape[1])[None, :] < counts[:, None]
    dp, da = pose_error(reference.fk(robot, sols[filled]), np.repeat(P, counts, axis=0))
    assert max(dp.max(), da.max()) <= 1e-10
    assert np.abs(sols[filled][:, 2] - np.repeat(Q[:, 2], counts)).max() < 1e-12
    gap = np.abs((sols - Q[:, None, :] + math.pi) % (2 * math.pi) - math.pi).max(axis=2)
    assert np.all(np.where(filled, gap, np.inf).min(axis=1) < 1e-8)
    _, nominal_counts = derive.kernels("iiwa14", "c", free="q3").ik(reference.fk("iiwa14", Q), free=Q[:, 2])
    assert np.array_equal(counts, nominal_counts)
    plain, plain_counts = k.ik(P, free=Q[:, 2])
    assert np.array_equal(plain_counts, counts)
    for backend, m in (("numpy", 100), ("python", 10)):
        s2, c2, r2, i2 = derive.kernels(robot, backend, free="q3", nominal=nominal).ik_polish(P[:m], free=Q[:m, 2])
        assert np.array_equal(c2, counts[:m])
        f2 = filled[:m]
        assert np.abs(s2[f2] - sols[:m][f2]).max() < 1e-9 and np.abs(i2[f2] - its[:m][f2]).max() <= 1
