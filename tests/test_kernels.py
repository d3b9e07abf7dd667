"""Generated FK and IK kernels (pure Python, numpy, C99) against the numpy reference."""

import math
import os
import shutil
import subprocess

import numpy as np
import pytest

import derive
from derive import InputError, dualquat, reference
from derive.emit import render_kernels

UR = ["ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e"]


@pytest.fixture(autouse=True, scope="module")
def private_cache(tmp_path_factory):
    old = os.environ.get("DQ_DERIVE_CACHE")
    os.environ["DQ_DERIVE_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    yield
    if old is None:
        os.environ.pop("DQ_DERIVE_CACHE", None)
    else:
        os.environ["DQ_DERIVE_CACHE"] = old


def mod_sign(a, b):
    return np.max(np.minimum(np.abs(a - b), np.abs(a + b)).max(axis=-1))


@pytest.mark.parametrize("name", UR)
@pytest.mark.parametrize("backend", ["python", "numpy", "c"])
def test_fk_matches_reference(name, backend):
    q = np.random.default_rng(7).uniform(-2 * math.pi, 2 * math.pi, size=(10_000, 6))
    k = derive.kernels(name, backend)
    out = k.fk(q)
    assert out.shape == (10_000, 8)
    assert mod_sign(out, reference.fk(name, q)) < 1e-12
    single = k.fk(q[0])
    assert single.shape == (8,) and mod_sign(single, reference.fk(name, q[0])) < 1e-12


def set_mismatches(a, ca, b, cb, tol):
    """Indices where the solution sets differ: other counts, or a solution of one side with no
    partner on the other within tol in every joint (mod 2 pi)."""
    bad = []
    for i in range(len(ca)):
        x, y = a[i, :ca[i]], b[i, :cb[i]]
        if ca[i] != cb[i]:
            bad.append(i)
            continue
        if ca[i] == 0:
            continue
        d = np.abs(np.remainder(x[:, None] - y[None] + np.pi, 2 * np.pi) - np.pi).max(-1)
        if d.min(1).max() >= tol or d.min(0).max() >= tol:
            bad.append(i)
    return bad


def ik_cases(name, n=10_000):
    """Random configurations (fixed seed) plus the singular sets theta5 = 0, theta5 = pi, and
    poses out of reach; the sign of half the poses is flipped (-P is the same pose)."""
    rng = np.random.default_rng(2026)
    q = rng.uniform(-math.pi, math.pi, size=(n, 6))
    q[:300, 4] = 0.0
    q[300:600, 4] = math.pi
    poses = reference.fk(name, q)
    poses[::2] *= -1
    rot = reference.fk(name, rng.uniform(-math.pi, math.pi, size=(200, 6)))[:, :4]
    far = dualquat.from_rt(rot, np.tile([3.0, 0.5, 0.2], (200, 1)))         # 3 m away
    return q, np.concatenate([poses, far])


@pytest.mark.parametrize("name", UR)
@pytest.mark.parametrize("backend", ["python", "numpy", "c"])
def test_ik_matches_reference(name, backend):
    q, poses = ik_cases(name)
    ref_q, ref_c = reference.ik_batch(name, poses)
    sols, counts = derive.kernels(name, backend).ik(poses)
    assert sols.shape == (len(poses), 8, 6) and counts.shape == (len(poses),)
    assert set_mismatches(sols, counts, ref_q, ref_c, 1e-9) == []
    assert np.all(counts[-200:] == 0) and np.all(np.isnan(sols[-200:]))
    # the singular sets are exercised: theta6 is chosen for reach, so every one of these poses
    # (reachable by construction) gets a singular solution
    wrist = np.abs(np.sin(np.nan_to_num(sols[:600, :, 4], nan=1.0)))
    assert np.all(np.any(wrist < 1e-12, axis=1))
    # NaN padding past the count, and every returned solution reproduces the pose
    filled = np.arange(8)[None, :] < counts[:, None]
    assert not np.any(np.isnan(sols[filled])) and np.all(np.isnan(sols[~filled]))
    rows = np.repeat(np.arange(len(poses)), counts)
    dpos, drot = reference.pose_error(reference.fk(name, sols[filled]), poses[rows])
    assert dpos.max() < 1e-10 and drot.max() < 1e-10


@pytest.mark.parametrize("backend", ["python", "numpy", "c"])
def test_ik_elbow_singular(backend):
    """theta3 = 0: the double root is split by rounding (theta3 ~ +-1e-8, the square root of the
    pose's rounding error), so the sets are compared within 2e-6, and each solution must still
    reproduce the pose."""
    rng = np.random.default_rng(5)
    q = rng.uniform(-math.pi, math.pi, size=(300, 6))
    q[:, 2] = 0.0
    poses = reference.fk("ur5", q)
    sols, counts = derive.kernels("ur5", backend).ik(poses)
    ref_q, ref_c = reference.ik_batch("ur5", poses)
    for i in range(len(poses)):
        x, y = sols[i, :counts[i]], ref_q[i, :ref_c[i]]
        d = np.abs(np.remainder(x[:, None] - y[None] + np.pi, 2 * np.pi) - np.pi).max(-1)
        assert d.min(0).max() < 2e-6 and d.min(1).max() < 2e-6
        assert np.any(np.abs(np.remainder(x - q[i] + np.pi, 2 * np.pi) - np.pi).max(-1) < 2e-6)
    rows = np.repeat(np.arange(len(poses)), counts)
    filled = np.arange(8)[None, :] < counts[:, None]
    dpos, drot = reference.pose_error(reference.fk("ur5", sols[filled]), poses[rows])
    assert dpos.max() < 1e-8 and drot.max() < 1e-8


def test_ik_single_pose_and_matrix_input():
    q = np.array([0.3, -1.1, 1.4, -0.2, 0.9, 2.0])
    pose = reference.fk("ur5", q)
    for backend in ("python", "numpy", "c"):
        k = derive.kernels("ur5", backend)
        sols, count = k.ik(pose)
        assert sols.shape == (8, 6) and count == 8
        assert np.min(np.abs(np.remainder(sols - q + np.pi, 2 * np.pi) - np.pi).max(-1)) < 1e-12
        sols_m, count_m = k.ik(reference.fk_matrix("ur5", q))
        assert count_m == 8 and np.allclose(sols_m, sols, atol=1e-12)


def test_kernel_input_errors():
    k = derive.kernels("ur5", "numpy")
    with pytest.raises(InputError, match=r"expected shape \(6,\)"):
        k.fk(np.zeros((3, 5)))
    with pytest.raises(InputError, match="NaN"):
        k.fk([0, 0, float("nan"), 0, 0, 0])
    with pytest.raises(InputError, match="unknown backend"):
        derive.kernels("ur5", "fortran")
    with pytest.raises(InputError, match="not a unit dual quaternion"):
        k.ik(np.ones(8))
    with pytest.raises(InputError, match="pose"):
        k.ik(np.zeros((2, 7)))


def test_c_rebuilds_when_the_source_changes(tmp_path):
    k = derive.kernels("ur3", "c")
    libs = list(k.folder.glob("*.so"))
    assert len(libs) == 1
    # the cache folder is named by the source hash: other sources give another folder
    other = derive.kernels("ur5", "c")
    assert other.folder != k.folder


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")
@pytest.mark.parametrize("extra", [[], ["-fsanitize=address,undefined", "-fno-omit-frame-pointer"]])
def test_c_compiles_cleanly_and_runs_standalone(tmp_path, extra):
    """FK batch, IK single and IK batch from a plain C program (also under the sanitizers)."""
    files = render_kernels("ur10e")
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    rng = np.random.default_rng(3)
    q = rng.uniform(-3, 3, size=(50, 6))
    q[:5, 4] = 0.0
    poses = reference.fk("ur10e", q)

    def table(a):
        return ",\n".join("{" + ", ".join(repr(float(v)) for v in row) + "}" for row in a)

    (tmp_path / "main.c").write_text(
        '#include <stdio.h>\n#include "ur10e_kinematics.h"\n'
        f"static const double Q[50][6] = {{{table(q)}}};\n"
        f"static const double P[50][8] = {{{table(poses)}}};\n"
        "int main(void) {\n  double out[50 * 8], sols[50 * 48], one[48]; int counts[50];\n"
        "  ur10e_fk_batch(50, &Q[0][0], out);\n"
        "  for (int i = 0; i < 400; ++i) {\n    printf(\"%.17g\\n\", out[i]);\n  }\n"
        "  ur10e_ik_batch(50, &P[0][0], sols, counts);\n"
        "  for (int i = 0; i < 50; ++i) {\n    const int c = ur10e_ik(P[i], one);\n"
        "    printf(\"%d %d\\n\", counts[i], c);\n"
        "    for (int k = 0; k < 48; ++k) {\n      printf(\"%.17g %.17g\\n\", sols[i * 48 + k], k < 6 * c ? one[k] : 0.0 / 0.0);\n    }\n  }\n"
        "  return 0;\n}\n")
    flags = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror", *extra]
    res = subprocess.run(["gcc", *flags, "-o", str(tmp_path / "t"), str(tmp_path / "main.c"),
                          str(tmp_path / "ur10e_kinematics.c"), "-lm"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    run = subprocess.run([str(tmp_path / "t")], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    lines = run.stdout.split("\n")
    out = np.array([float(v) for v in lines[:400]]).reshape(50, 8)
    assert mod_sign(out, reference.fk("ur10e", q)) < 1e-12
    counts, batch, single = np.zeros(50, dtype=int), np.zeros((50, 8, 6)), np.zeros((50, 8, 6))
    pos = 400
    for i in range(50):
        c_batch, c_single = map(int, lines[pos].split())
        assert c_batch == c_single
        counts[i] = c_batch
        vals = np.array([[float(v) for v in lines[pos + 1 + k].split()] for k in range(48)])
        batch[i], single[i] = vals[:, 0].reshape(8, 6), vals[:, 1].reshape(8, 6)
        pos += 49
    np.testing.assert_array_equal(batch, single)          # the two code paths agree bit for bit
    ref_q, ref_c = reference.ik_batch("ur10e", poses)
    assert set_mismatches(batch, counts, ref_q, ref_c, 1e-9) == []


@pytest.mark.skipif(shutil.which("clang") is None, reason="clang not installed")
def test_c_compiles_with_clang(tmp_path):
    for name, text in render_kernels("ur5").items():
        (tmp_path / name).write_text(text)
    res = subprocess.run(["clang", "-std=c99", "-O3", "-march=native", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-c",
                          str(tmp_path / "ur5_kinematics.c"), "-o", str(tmp_path / "k.o")],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
