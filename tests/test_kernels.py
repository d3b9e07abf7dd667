"""Generated FK and IK kernels (pure Python, numpy, C99) against the numpy reference."""

import ctypes
import json
import math
import os
import platform
import re
import shutil
import subprocess
import types

import numpy as np
import pytest

import derive
from derive import InputError, dualquat, reference
from derive.codegen import loader
from derive.codegen.emit import _magnitude_bounds, render_kernels
from derive.codegen.loader import GCC_FLAGS, _compile, kernel_folder
from derive.ik.closed_form import spherical_class
from derive.ik.program import ik_program

UR = ["ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e"]


@pytest.fixture(autouse=True, scope="module")
def private_cache(run_folder):
    """A user cache of this test run, empty when the run starts: one for all the pytest-xdist
    workers, so each C extension is compiled once per run (cache writes are process-safe)."""
    old = os.environ.get("DQ_DERIVE_CACHE")
    folder = run_folder / "test_kernels-cache"
    folder.mkdir(exist_ok=True)
    os.environ["DQ_DERIVE_CACHE"] = str(folder)
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


def test_magnitude_bounds_of_the_ur_program():
    """The C kernels leave out dq_wrap where the program's bounds prove a joint value within pi.
    For the UR: theta3 = +-atan2(sqrt(.), .) and theta5 = +-2 atan2(|.|, |.|) (both arguments
    square roots) are; theta1 (a sum of two atan2), theta2, theta4 and theta6 (sums) are not."""
    b = _magnitude_bounds(ik_program(derive.load_robot("ur5")))
    assert b["theta3"] == pytest.approx(math.pi) and b["theta5"] == pytest.approx(math.pi)
    assert b["h9"] == pytest.approx(math.pi / 2)
    assert all(b[n] > math.pi + 1 for n in ("theta1", "theta2", "theta4", "theta6"))


@pytest.mark.parametrize("name", ["ur5", "irb120", "kr6-r900"])
def test_c_candidates_lie_in_minus_pi_pi(name):
    """Every joint of every C solution, wrapped or left as the bounds allow, lies in [-pi, pi]:
    batch and single calls, on random poses and on wrist-singular ones (theta5 = 0)."""
    k = derive.kernels(name, "c")
    rng = np.random.default_rng(41)
    q = rng.uniform(-math.pi, math.pi, size=(2000, 6))
    q[:200, 4] = 0.0
    sols, counts = k.ik(reference.fk(name, q))
    filled = np.arange(sols.shape[1])[None, :] < counts[:, None]
    assert counts.sum() > 8000
    assert np.all(np.abs(sols[filled]) <= math.pi)
    for i in range(0, 2000, 101):
        one, c = k.ik(reference.fk(name, q[i]))
        assert c == counts[i] and np.all(np.abs(one[:c]) <= math.pi)


@pytest.mark.parametrize("name", ["ur5", "irb120"])
def test_ik_batch_duplicate_gate_per_block(name):
    """The batch IK skips its full duplicate test in a block of 64 poses where no pose can have
    one (derive.codegen.emit._duplicate_gates). Blocks with one pose that has duplicates (wrist
    singular, theta5 = 0: the two theta5 roots meet) at a different place in each block, among
    random poses, and a block with none: the batch equals one call per pose bit for bit, and the
    counts and solution sets equal the numpy kernel's (its own merge, over the whole batch)."""
    rng = np.random.default_rng(64)
    n = 64 * 9
    q = rng.uniform(-math.pi, math.pi, size=(n, 6))
    at = [64 * b + (7 * b) % 64 for b in range(8)]   # none in the last block
    k = derive.kernels(name, "c")
    geo = spherical_class(name)           # irb120: the canonical chain's wrist angle at 0
    q[at, 4] = 0.0 if geo is None else -geo.signs[4] * geo.offsets[4]
    poses = reference.fk(name, q)
    sols, counts, branch, sing = k.ik(poses, details=True)
    assert np.all(sing[at].any(axis=1)) and not sing[64 * 8:].any()
    assert np.all(counts[at] < 8)            # duplicates merged where the theta5 roots meet
    for i in range(n):
        s1, c1, b1, g1 = k.ik(poses[i], details=True)
        assert c1 == counts[i] and np.array_equal(b1, branch[i]) and np.array_equal(g1, sing[i])
        assert np.array_equal(s1, sols[i], equal_nan=True)
    ref_s, ref_c = derive.kernels(name, "numpy").ik(poses)
    assert set_mismatches(sols, counts, ref_s, ref_c, 1e-9) == []


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


def _c_sources(name):
    """(source, header, prefix) of a robot's C kernels: the files derive.kernels compiles."""
    folder, manifest = kernel_folder(name)
    files = manifest["files"]
    return folder / files["c_source"], folder / files["c_header"], manifest["prefix"]


def test_c_rebuilds_when_the_source_changes(tmp_path, monkeypatch):
    """_compile builds lib<prefix>-<digest>.so in the cache's build/ folder once per (source
    text, flags, CPU): an unchanged source is not compiled again (the compiler is not even
    called, the file is untouched), an edited source gives a new library that runs the new
    code, reverting the edit finds the first library again, and other flags give another."""
    source, header, prefix = _c_sources("ur5")
    work = tmp_path / "src"
    work.mkdir()
    src = work / source.name
    shutil.copy(source, src)
    shutil.copy(header, work / header.name)
    original = src.read_text()
    cache = tmp_path / "cache"
    monkeypatch.setenv("DQ_DERIVE_CACHE", str(cache))
    monkeypatch.setenv("DQ_DERIVE_CFLAGS", "-std=c99 -O0")     # quick to build; flags are in the digest
    build = cache / "build"

    def no_compiler(*args, **kwargs):
        raise AssertionError(f"the compiler was called again: {args}")

    def symbol(lib, name, restype, argtypes):
        f = getattr(ctypes.CDLL(str(lib)), name)
        f.restype, f.argtypes = restype, argtypes
        return f

    lib1 = _compile(src, prefix)
    assert lib1.parent == build and re.fullmatch(rf"lib{prefix}-[0-9a-f]{{16}}\.so", lib1.name)
    assert sorted(p.name for p in build.iterdir()) == sorted([lib1.name, "manifest.json"])  # no temporary left
    # the library is this source compiled: its single-pose FK is the reference FK
    fk = symbol(lib1, f"{prefix}_fk", None, [ctypes.c_void_p, ctypes.c_void_p])
    q = np.array([0.3, -1.1, 1.4, -0.2, 0.9, 2.0])
    out = np.empty(8)
    fk(q.ctypes.data, out.ctypes.data)
    assert mod_sign(out, reference.fk("ur5", q)) < 1e-12
    assert not hasattr(ctypes.CDLL(str(lib1)), "probe")
    before = lib1.stat()

    # unchanged source: the same library, no compiler run, file untouched
    with monkeypatch.context() as m:
        m.setattr(loader, "subprocess", types.SimpleNamespace(run=no_compiler))
        assert _compile(src, prefix) == lib1
    assert (lib1.stat().st_mtime_ns, lib1.stat().st_ino) == (before.st_mtime_ns, before.st_ino)

    # an added function: a new library, built after the first, that has it
    src.write_text(original + "\nint probe(void) { return 7; }\n")
    lib2 = _compile(src, prefix)
    assert lib2 != lib1 and lib2.parent == build and lib1.exists()
    assert lib2.read_bytes() != lib1.read_bytes()
    assert lib2.stat().st_mtime_ns >= before.st_mtime_ns
    assert symbol(lib2, "probe", ctypes.c_int, [])() == 7
    # a changed constant: a third library with the new value
    src.write_text(original + "\nint probe(void) { return 8; }\n")
    lib3 = _compile(src, prefix)
    assert lib3 not in (lib1, lib2)
    assert symbol(lib3, "probe", ctypes.c_int, [])() == 8
    assert symbol(lib2, "probe", ctypes.c_int, [])() == 7                  # the old one is kept

    # back to the original text: the first library again, without compiling
    src.write_text(original)
    with monkeypatch.context() as m:
        m.setattr(loader, "subprocess", types.SimpleNamespace(run=no_compiler))
        assert _compile(src, prefix) == lib1
    assert lib1.stat().st_mtime_ns == before.st_mtime_ns

    # other compiler flags: another library from the same source
    monkeypatch.setenv("DQ_DERIVE_CFLAGS", "-std=c99 -O1")
    lib4 = _compile(src, prefix)
    assert lib4 not in (lib1, lib2, lib3)
    assert sorted(build.glob("*.so")) == sorted([lib1, lib2, lib3, lib4])
    assert sorted(json.loads((build / "manifest.json").read_text())["sha256"]) == sorted(p.name for p in (lib1, lib2, lib3, lib4))


@pytest.mark.parametrize("backend", ["python", "numpy", "c"])
def test_kernels_reject_non_finite_joints_and_non_unit_poses(backend):
    """NaN / inf joint values and poses that are not unit dual quaternions or rigid transforms
    raise InputError naming the problem, before any kernel runs; the kernel still works after."""
    k = derive.kernels("ur5", backend)
    q = np.array([0.3, -1.1, 1.4, -0.2, 0.9, 2.0])
    for index, value, kind in ((2, math.nan, "NaN"), (0, math.inf, "inf"), (5, -math.inf, "inf")):
        bad = q.copy()
        bad[index] = value
        with pytest.raises(InputError, match=rf"^Q: contains {kind} at index \({index},\)$"):
            k.fk(bad)
    batch = np.tile(q, (4, 1))
    batch[3, 4] = math.nan
    with pytest.raises(InputError, match=r"^Q: contains NaN at index \(3, 4\)$"):
        k.fk(batch)

    pose = reference.fk("ur5", q)
    T = reference.fk_matrix("ur5", q)
    nan_pose = pose.copy()
    nan_pose[5] = math.nan
    inf_matrix = T.copy()
    inf_matrix[1, 3] = math.inf
    skew_dual = pose + np.r_[np.zeros(4), 0.01 * pose[:4]]      # <real, dual> = 0.01 |real|^2
    scaled = T.copy()
    scaled[:3, :3] *= 1.1                                         # R^T R - I = 0.21 I
    sheared = T.copy()
    sheared[0, 1] += 0.01
    bottom = T.copy()
    bottom[3, 0] = 0.5
    bad_poses = [
        (0.9 * pose, r"^pose: not a unit dual quaternion \(\| \|real\| - 1 \| = 0\.1 > 1e-06\)$"),
        (np.stack([pose, pose, 1.5 * pose]), r"^pose: not a unit dual quaternion \(\| \|real\| - 1 \| = 0\.5 "),
        (skew_dual, r"^pose: not a unit dual quaternion \(<real, dual> = 0\.01, must be 0 within 1e-06\)$"),
        (nan_pose, r"^pose: contains NaN at index \(5,\)$"),
        (pose + np.r_[np.zeros(4), 1e200, 0.0, 0.0, 0.0],          # finite, but |dual|^2 overflows
         r"^pose: not a unit dual quaternion \(the squares of its dual part overflow\)$"),
        (np.stack([pose, pose + np.r_[np.zeros(5), 1e200, 0.0, 0.0]]),
         r"^pose: not a unit dual quaternion \(the squares of its dual part overflow"),
        (inf_matrix, r"^pose: contains inf at index \(1, 3\)$"),
        (scaled, r"^pose: the 3x3 block is not a rotation matrix \(max \|R\^T R - I\| = 0\.21\)$"),
        (T @ np.diag([1.0, 1.0, -1.0, 1.0]), r"^pose: the 3x3 block is not a rotation matrix"),  # reflection
        (sheared, r"^pose: the 3x3 block is not a rotation matrix"),
        (np.stack([T, scaled]), r"^pose: the 3x3 block is not a rotation matrix \(max \|R\^T R - I\| = 0\.21\)$"),
        (bottom, r"the last row of a homogeneous matrix must be \(0, 0, 0, 1\)"),
    ]
    for bad, message in bad_poses:
        with pytest.raises(InputError, match=message):
            k.ik(bad)
    # nothing was left in a bad state
    assert mod_sign(k.fk(q), pose) < 1e-12
    sols, count = k.ik(pose)
    assert count == 8 and np.min(np.abs(np.remainder(sols - q + np.pi, 2 * np.pi) - np.pi).max(-1)) < 1e-12


def _x86_has(flag: str) -> bool:
    """The x86 CPU lists this feature flag in /proc/cpuinfo (False elsewhere)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            return platform.machine() in ("x86_64", "AMD64") and f" {flag} " in f.read()
    except OSError:
        return False


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")
@pytest.mark.parametrize("extra", [[], ["-fsanitize=address,undefined", "-fno-omit-frame-pointer"],
                                   pytest.param(["-O3", "-mavx2", "-mfma"], marks=pytest.mark.skipif(
                                       not _x86_has("avx2"), reason="no AVX2 to run it"))])
def test_c_compiles_cleanly_and_runs_standalone(tmp_path, extra):
    """FK batch, IK single and IK batch from a plain C program (also under the sanitizers, and
    vectorised with AVX2, where the batch functions carry DQ_SCHED's attribute)."""
    for name, text in render_kernels("ur10e").values():         # {role: (file name, text)}
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
        "    for (int k = 0; k < 48; ++k) {\n      printf(\"%.17g %.17g\\n\", sols[i * 48 + k], one[k]);\n    }\n  }\n"
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
    for name, text in render_kernels("ur5").values():
        (tmp_path / name).write_text(text)
    res = subprocess.run(["clang", "-std=c99", "-O3", "-march=native", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-c",
                          str(tmp_path / "ur5_kinematics.c"), "-o", str(tmp_path / "k.o")],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr


# --- the C helpers dq_sincos and dq_atan2, called directly ----------------------------------
# A driver that #includes the generated source (the helpers are static inline there) and
# evaluates them on hex-float arguments read from stdin: "s x" -> "sin cos", "a y x" -> "atan2".
HELPERS_DRIVER = r"""#include <stdio.h>
#include <stdlib.h>
#include "%s"

int main(void)
{
    char line[256];
    while (fgets(line, sizeof line, stdin)) {
        char *end;
        const double a = strtod(line + 2, &end);
        if (line[0] == 's') {
            double s, c;
            dq_sincos(a, &s, &c);
            printf("%%a %%a\n", s, c);
        } else {
            printf("%%a\n", dq_atan2(a, strtod(end, NULL)));
        }
    }
    return 0;
}
"""


@pytest.fixture(scope="module", params=["portable", "fma"])
def c_helpers(request, tmp_path_factory):
    """run(kind, args) -> the helpers' results (floats, bit exact) for a list of arguments; once
    as a portable build (two operations where the source says DQ_FMA) and once with x86 FMA
    (-mfma: one fused instruction), the two polynomial paths of the helpers."""
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler (gcc or cc) on PATH")
    extra = []
    if request.param == "fma":
        if not _x86_has("fma"):
            pytest.skip("this CPU has no x86 FMA")
        extra = ["-mfma", "-mavx2"]
    source, header, _ = _c_sources("ur5")
    d = tmp_path_factory.mktemp("c_helpers")
    shutil.copy(source, d / source.name)
    shutil.copy(header, d / header.name)
    (d / "driver.c").write_text(HELPERS_DRIVER % source.name)
    res = subprocess.run([cc, "-std=c99", "-O2", *extra, "-Wall", "-o", str(d / "driver"), str(d / "driver.c"), "-lm"],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr

    def run(kind, args):
        text = "".join(f"{kind} {' '.join(float(v).hex() for v in row)}\n" for row in args)
        out = subprocess.run([str(d / "driver")], input=text, capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        rows = [[float.fromhex(v) for v in line.split()] for line in out.stdout.splitlines()]
        assert len(rows) == len(args)
        return np.array(rows)

    return run


def _ulp(v):
    return np.array([math.ulp(abs(x)) for x in v])


def test_dq_sincos_against_the_c_library(c_helpers):
    """dq_sincos is documented "accurate to a few ulp for |x| up to about 1e6" with x - k pi/2
    formed with pi/2 in two parts (fdlibm's 33-bit pio2_1 plus its tail). Tolerance: 4 ulp of
    the result, plus the reduction's own absolute error, which grows with k: the rounding of
    k * tail and the tail's truncation are each below |x| 2^-77.5, so |x| 2^-76 in all. The
    second term matters only next to the zeros of sin and cos (at |x| = 1e6 it is 1.3e-17);
    e.g. without the tail the error there would be |x| 6e-11. Measured: 2 ulp."""
    rng = np.random.default_rng(12)
    half_pi = [k * (math.pi / 2) for k in range(-2000, 2001)]
    near_1e6 = [s * k * (math.pi / 2) for k in range(636000, 636620) for s in (1, -1)]   # |x| <= 1e6
    quarter = [k * (math.pi / 4) for k in range(-400, 401, 2)] + [k * (math.pi / 4) for k in range(-399, 400, 2)]
    xs = np.concatenate([
        np.linspace(-1e6, 1e6, 20001),
        rng.uniform(-1e6, 1e6, 10000), rng.uniform(-10, 10, 10000),
        half_pi, near_1e6, quarter,                                 # zeros of sin / cos; octant edges
        [math.nextafter(x, math.inf) for x in half_pi + quarter],
        [math.nextafter(x, -math.inf) for x in half_pi + quarter],
        [1e6, -1e6, math.nextafter(1e6, 0), 3.0, -3.0],
    ])
    got = c_helpers("s", xs[:, None])
    sin_ref = np.array([math.sin(x) for x in xs])
    cos_ref = np.array([math.cos(x) for x in xs])
    for name, col, ref in (("sin", 0, sin_ref), ("cos", 1, cos_ref)):
        err = np.abs(got[:, col] - ref)
        tol = 4 * _ulp(ref) + np.abs(xs) * 2.0 ** -76
        worst = int(np.argmax(err / tol))
        assert np.all(err <= tol), (f"dq_sincos {name}({xs[worst]!r}) = {got[worst, col]!r}, "
                                    f"libm {ref[worst]!r}: {err[worst] / _ulp([ref[worst]])[0]:.3g} ulp")
        assert np.all(np.abs(got[:, col]) <= 1.0)

    # tiny arguments (subnormal ones too) and signed zeros: sin x = x and cos x = 1 exactly
    # (|x| < 2^-27: x^3/6 is below half an ulp of x), the sign of a zero kept
    tiny = np.array([0.0, -0.0, 5e-324, -5e-324, 1e-310, -1e-310, 2.2250738585072014e-308, 1e-300,
                     -1e-300, 1e-160, -1e-160, 1e-20, -1e-20, 1e-9, -1e-9])
    got = c_helpers("s", tiny[:, None])
    for x, (s, c) in zip(tiny, got):
        assert s == x and math.copysign(1.0, s) == math.copysign(1.0, x), (x, s)
        assert c == 1.0, (x, c)


def test_dq_atan2_against_the_c_library(c_helpers):
    """dq_atan2 is documented "max error 4.4e-16 against the C library": tolerance 4.45e-16
    (the bound to its printed precision; it is 2 ulp of pi), and 4 ulp of the result for the
    small angles, where an absolute bound says nothing. On every axis and at signed zeros the
    result is the exact value of C99 atan2 (0, pi/2, pi with their signs). Measured: 4.44e-16,
    2 ulp."""
    rng = np.random.default_rng(13)
    angles = np.linspace(-math.pi, math.pi, 721)                          # every half degree
    rays = [(m * math.sin(a), m * math.cos(a)) for m in (1e-300, 1e-150, 1e-20, 1e-3, 1.0, 1e3, 1e20, 1e150, 1e300)
            for a in angles]
    t = 0.26794919243112270                                               # tan(pi/12): the reduction's edge
    edges = []
    for lo in (t, math.nextafter(t, 0), math.nextafter(t, 1), 1.0, math.nextafter(1.0, 0), 1e-17):
        for sy in (1, -1):
            for sx in (1, -1):
                edges += [(sy * lo, sx * 1.0), (sy * 1.0, sx * lo)]
    mixed = [(sy * a, sx * b) for a in (1e-300, 1e300, 1.0) for b in (1e-300, 1e300, 1.0)
             for sy in (1, -1) for sx in (1, -1)]
    scattered = rng.uniform(-1, 1, size=(5000, 2)) * 10.0 ** rng.uniform(-6, 6, size=(5000, 2))
    pairs = np.concatenate([np.array(rays + edges + mixed), rng.normal(size=(10000, 2)), scattered])
    got = c_helpers("a", pairs)[:, 0]
    ref = np.array([math.atan2(y, x) for y, x in pairs])
    err = np.abs(got - ref)
    worst = int(np.argmax(err))
    assert err.max() <= 4.45e-16, (pairs[worst], got[worst], ref[worst])
    ulps = err / _ulp(ref)
    worst = int(np.argmax(ulps))
    assert ulps.max() <= 4, (pairs[worst], got[worst], ref[worst], ulps[worst])
    assert np.all(np.sign(got) == np.sign(ref))
    assert np.all(np.abs(got) <= math.pi)

    # axis points and signed zeros: exactly the values C99 (Annex F) defines
    specials = [(sy * y, sx * x) for y, x in ((0.0, 1.0), (0.0, 1e-300), (0.0, 1e300), (0.0, 5e-324),
                                              (1.0, 0.0), (1e-300, 0.0), (1e300, 0.0), (5e-324, 0.0))
                for sy in (1, -1) for sx in (1, -1)]
    specials += [(0.0, 0.0), (-0.0, 0.0)]
    got = c_helpers("a", specials)[:, 0]
    for (y, x), g in zip(specials, got):
        r = math.atan2(y, x)
        assert g == r and math.copysign(1.0, g) == math.copysign(1.0, r), ((y, x), g, r)


def test_dq_atan2_of_zero_over_negative_zero(c_helpers):
    got = c_helpers("a", [(0.0, -0.0), (-0.0, -0.0)])[:, 0]
    assert got[0] == math.atan2(0.0, -0.0) == math.pi
    assert got[1] == math.atan2(-0.0, -0.0) == -math.pi


def test_dq_atan2_at_the_edges_of_its_domain(c_helpers):
    """dq_atan2's documented domain: |x|, |y| <= 1e307 and max(|x|, |y|) >= 1e-300 unless it is 0
    (the IK programs' arguments lie far inside it; it spends no scaling on the rest). At its
    edges, on both sides of the reduction (|y|/|x| = 1 and 0.3 are reduced, 0.1 is not), and with
    the smaller magnitude deep in the subnormal range."""
    pairs = [(sy * y, sx * x) for y, x in ((1e307, 1e307), (3e306, 1e307), (1e306, 1e307), (1e307, 1e306),
                                           (1e-300, 1e-300), (3e-301, 1e-300), (1e-301, 1e-300),
                                           (5e-324, 1e-300), (1e-300, 5e-324))
             for sy in (1, -1) for sx in (1, -1)]
    got = c_helpers("a", pairs)[:, 0]
    ref = np.array([math.atan2(y, x) for y, x in pairs])
    assert np.all(np.abs(got - ref) <= 4.45e-16), list(zip(pairs, got, ref))


def _assert_marked_loops_vectorise(source, markers, tmp_path, extra=()):
    """Each loop of ``source`` marked /* vectorised: <marker> */ (exactly one per marker, on a
    for line) has a "loop vectorized" line in gcc's -mavx2 report. The backend's gcc flag is
    used (no narrower remainder copies of the loops: a third less compile time)."""
    lines = source.read_text(encoding="utf-8").splitlines()
    marked = {}
    for marker in markers:
        at = [i + 1 for i, line in enumerate(lines) if f"/* vectorised: {marker} */" in line]
        assert len(at) == 1, (marker, at)
        assert re.match(r"\s*for \(", lines[at[0] - 1]), lines[at[0] - 1]
        marked[marker] = at[0]
    res = subprocess.run(["gcc", "-std=c99", "-O3", "-mavx2", "-mfma", "-fno-math-errno", *GCC_FLAGS, *extra,
                          "-fopt-info-vec-optimized", "-c", str(source), "-o", str(tmp_path / "k.o")],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    report = res.stdout + res.stderr
    vectorised = {int(m.group(1)) for m in
                  re.finditer(rf"{re.escape(source.name)}:(\d+):\d+: optimized: loop vectorized", report)}
    for marker, line in marked.items():
        assert line in vectorised, (marker, line, report)


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")
@pytest.mark.parametrize("robot", ["ur5", "irb120", "iiwa14", "panda"])
def test_batch_loops_vectorise_with_avx2(tmp_path, robot):
    """The batch FK loop, the main batch IK loop, the duplicate gates and marking after it and the
    nearest-solution pass of the shipped sources are branch-free (selects through dq_sel, the
    singular poses and the packing in scalar passes after them), so gcc vectorises them without
    masked stores: with AVX2, no AVX-512. The loops carry marker comments; the report must have
    a "loop vectorized" line at each of their line numbers."""
    from pathlib import Path

    source = Path(__file__).resolve().parents[1] / "generated" / robot / f"{robot}_kinematics.c"
    _assert_marked_loops_vectorise(
        source, ("fk batch", "ik batch", "ik duplicate gates", "ik duplicates", "ik nearest"), tmp_path)


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")
def test_extension_input_checks_vectorise_with_avx2(tmp_path):
    """The extension's checks of joint values and poses (finite, in range, unit) are loops
    without exits, so a batch is checked at vector speed: the -mavx2 report has a "loop
    vectorized" line at each marked loop of the extension's source (the one the loader built)."""
    import sysconfig
    from pathlib import Path

    k = derive.kernels("ur5", "c")
    if k._ext is None:
        pytest.skip("no CPython extension (Python headers missing)")
    lib = Path(k._ext.__file__)
    # the source beside the module: <module>.<abi>.c; extensions built before that name: <module>.c
    source = next(p for p in (lib.with_suffix(".c"), lib.with_name(f"{k._ext.__name__}.c")) if p.exists())
    _assert_marked_loops_vectorise(source, ("q check", "pose check"), tmp_path,
                                   ("-fPIC", f"-I{sysconfig.get_paths()['include']}", f"-I{np.get_include()}"))

def test_fk_angle_sums_come_from_two_called_angles():
    """derive.codegen.fk._sums: an angle that is x + y, x - y or y - x of two other called
    angles is taken by the addition theorem, never from another such angle, the longest angles
    first; the UR5's FK then calls dq_sincos 6 times instead of 7 and the Panda's 10 times
    instead of 27 (the FK values themselves are checked against the reference in
    test_fk_matches_reference)."""
    import sympy as sp

    from derive.codegen.fk import _sums, fk_kernel

    a, b, c = sp.symbols("a b c", real=True)
    assert _sums([a, b, a + b, c, b - c, c - a]) == {a + b: (a, b, 1), b - c: (b, c, -1), c - a: (c, a, -1)}
    # x + 2y = (x + y) + y, but x + y is itself a sum: x + 2y stays a call
    assert _sums([a, b, a + b, a + 2 * b]) == {a + b: (a, b, 1)}
    assert _sums([a, b, c]) == {}
    for robot, calls, sums in (("ur5", 6, 1), ("panda", 10, 17)):
        k = fk_kernel(robot)
        assert k.n_sincos == calls
        assert sum(isinstance(t[2], tuple) and t[2][0] == "sum" for t in k.trig) == sums


def _c_batches(lib, ident, poses, fv, seeds):
    """ik_batch_ex, nearest_batch and the single-pose ik of a compiled kernel library (ctypes):
    every array they write, for a bit-for-bit comparison."""
    n, dof = seeds.shape
    nmax = 8
    pz, sz = np.ascontiguousarray(poses), np.ascontiguousarray(seeds)
    fz = None if fv is None else np.ascontiguousarray(fv)      # kept alive while C reads it
    lead = [pz.ctypes.data] + ([fz.ctypes.data] if fz is not None else [])
    sols, counts = np.empty((n, nmax, dof)), np.empty(n, dtype=np.intc)
    branch, sing = np.empty((n, nmax), dtype=np.intc), np.empty((n, nmax), dtype=np.intc)
    f = getattr(lib, f"{ident}_ik_batch_ex")
    f.restype = None
    f(ctypes.c_size_t(n), *map(ctypes.c_void_p, lead + [sols.ctypes.data, counts.ctypes.data,
                                                        branch.ctypes.data, sing.ctypes.data]))
    q, mx, tt = np.empty((n, dof)), np.empty(n), np.empty(n)
    nb, ns = np.empty(n, dtype=np.intc), np.empty(n, dtype=np.intc)
    g = getattr(lib, f"{ident}_ik_nearest_batch")
    g.restype = None
    g(ctypes.c_size_t(n), *map(ctypes.c_void_p, lead + [sz.ctypes.data, q.ctypes.data, mx.ctypes.data,
                                                        tt.ctypes.data, nb.ctypes.data, ns.ctypes.data]))
    one = np.full((n, nmax, dof), 7.0)
    h = getattr(lib, f"{ident}_ik")
    h.restype = ctypes.c_int
    c1 = np.array([h(ctypes.c_void_p(pz[i].ctypes.data),
                     *([ctypes.c_double(fv[i])] if fv is not None else []),
                     ctypes.c_void_p(one[i].ctypes.data)) for i in range(n)])
    return [sols, counts, branch, sing, q, mx, tt, nb, ns, one, c1]


@pytest.mark.skipif(loader.c_compiler() is None, reason="no C compiler")
@pytest.mark.parametrize("robot, block", [("ur5", 8), ("ur5", 1), ("panda", 8)])
def test_block_size_changes_no_bit(robot, block, monkeypatch):
    """DQ_BLOCK (the poses per block of the batch loops, on the stack) is a build option for small
    stacks: with -DDQ_BLOCK=8 or 1 the IK batch with details, the nearest batch and the
    single-pose IK (a batch of one, NaN past its count) write the same bits as the default build
    of 64, on random and singular poses that straddle the blocks. -Werror: a DQ_BLOCK that the
    source redefined instead of taking would be a warning, and so a failure here."""
    rng = np.random.default_rng(8)
    lim = derive.load_robot(robot).limits
    dof = len(lim)
    q = rng.uniform(np.maximum(lim[:, 0], -math.pi), np.minimum(lim[:, 1], math.pi), size=(150, dof))
    on_set = np.zeros(len(q), dtype=bool)
    on_set[5::11] = True
    q[on_set, 4 if dof == 6 else 1] = 0.0          # wrist (UR) or shoulder (Panda, q2) singular
    poses = reference.fk(robot, q)
    fv = q[:, 6].copy() if dof == 7 else None      # the Panda's free parameter is q7
    seeds = q + rng.normal(0, 0.05, size=q.shape)
    k = derive.kernels(robot, "c")
    default = _c_batches(ctypes.CDLL(str(k.library)), k._ident, poses, fv, seeds)
    monkeypatch.setenv("DQ_DERIVE_CFLAGS", " ".join(loader.c_flags() + [f"-DDQ_BLOCK={block}", "-Werror"]))
    small = _c_batches(ctypes.CDLL(str(_compile(k._c_source, k._ident))), k._ident, poses, fv, seeds)
    for a, b in zip(default, small):
        np.testing.assert_array_equal(a, b)
    sols, counts, branch, sing, q_near, *_, one, c1 = default
    np.testing.assert_array_equal(c1, counts)
    np.testing.assert_array_equal(one, sols)                  # the batch of one, NaN padding included
    assert np.all(np.isnan(sols) == (np.arange(8)[None, :, None] >= counts[:, None, None]))
    assert sing[on_set].any() and counts.min() >= 1 and not np.isnan(q_near[~on_set]).any()
    # the solutions are real ones: each reproduces its pose (the reference FK, plain products)
    rows = np.nonzero(np.arange(8)[None, :] < counts[:, None])
    assert mod_sign(reference.fk(robot, sols[rows]), poses[rows[0]]) < 1e-9


def test_extension_converts_matrices_and_rt_pairs_in_c():
    """k.ik with (n, 4, 4), (n, 3, 4), (4, 4) and (3, 4) matrices (converted and checked in the C
    extension) and with (R, t) pairs, single and batched, gives the solutions of the same poses
    as dual quaternions (within rounding of the two conversions), for the C, numpy and python
    backends alike; nearest takes matrices too."""
    rng = np.random.default_rng(21)
    q = rng.uniform(-np.pi, np.pi, size=(300, 6))
    T = reference.fk_matrix("ur5", q)
    P = reference.fk("ur5", q)
    k = derive.kernels("ur5", "c")
    ref_s, ref_c = k.ik(P)
    for form in (T, T[:, :3, :], (T[:, :3, :3], T[:, :3, 3])):
        s, c = k.ik(form)
        assert np.array_equal(c, ref_c)
        assert np.nanmax(np.abs(s - ref_s)) < 1e-9
    for form in (T[7], T[7, :3], (T[7, :3, :3], T[7, :3, 3]), (T[7, :3, :3].tolist(), list(T[7, :3, 3]))):
        s, c = k.ik(form)
        assert c == ref_c[7] and np.nanmax(np.abs(s - ref_s[7])) < 1e-9
    for backend in ("numpy", "python"):
        kb = derive.kernels("ur5", backend)
        s, c = kb.ik((T[:20, :3, :3], T[:20, :3, 3]))
        assert np.array_equal(c, ref_c[:20]) and np.nanmax(np.abs(s - ref_s[:20])) < 1e-9
        s, c = kb.ik(T[:20, :3])
        assert np.array_equal(c, ref_c[:20])
    near = k.nearest(T[:50], q[:50] + 0.01)
    assert np.all(near.found) and np.abs(near.q - q[:50]).max() < 1e-9
    # the tool: the same poses of the tool frame
    tool = dualquat.from_rt(np.array([np.cos(0.2), 0.0, np.sin(0.2), 0.0]), np.array([0.0, 0.01, 0.1]))
    kt = k.with_tool(tool)
    s, c = kt.ik(dualquat.to_matrix(dualquat.mul(P[:30], tool[None])))
    assert np.array_equal(c, ref_c[:30]) and np.nanmax(np.abs(s - ref_s[:30])) < 1e-9


def test_extension_matrix_checks_in_c():
    """The C extension checks matrices as the numpy path does (tests above: the same messages),
    also for the (3, 4) form and in a batch (the first bad matrix's number, the largest error)."""
    k = derive.kernels("ur5", "c")
    T = reference.fk_matrix("ur5", np.random.default_rng(2).uniform(-3, 3, size=(5, 6)))
    bad = T.copy()
    bad[3, :3, :3] *= 1.1
    with pytest.raises(InputError, match=r"^pose: the 3x3 block is not a rotation matrix \(max \|R\^T R - I\| = 0\.21\)$"):
        k.ik(bad[:, :3])
    nan = T.copy()
    nan[2, 1, 2] = math.nan
    with pytest.raises(InputError, match=r"^pose: contains NaN at index \(2, 1, 2\)$"):
        k.ik(nan)
    bottom = T.copy()
    bottom[4, 3, 3] = 2.0
    with pytest.raises(InputError, match=r"the last row of a homogeneous matrix must be \(0, 0, 0, 1\)"):
        k.ik(bottom)
    with pytest.raises(InputError, match=r"\(R, t\) needs R"):
        k.ik((T[0, :3, :3], T[:2, :3, 3]))


def test_extension_batches_release_the_gil():
    """Two threads calling k.ik / k.fk / k.nearest on large batches at once (the GIL released
    around the C batch work) give the same results as one thread, bit for bit."""
    import threading

    k = derive.kernels("ur5", "c")
    rng = np.random.default_rng(8)
    q = rng.uniform(-np.pi, np.pi, size=(2, 20_000, 6))
    P = [reference.fk("ur5", qi) for qi in q]
    alone = [k.ik(p) for p in P]
    fk_alone = [k.fk(qi) for qi in q]
    near_alone = [k.nearest(p, qi).q for p, qi in zip(P, q)]
    out: dict = {}

    def work(i):
        out[i] = [(k.ik(P[i]), k.fk(q[i]), k.nearest(P[i], q[i]).q) for _ in range(3)]

    threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for i in range(2):
        for (s, c), f, nq in out[i]:
            assert np.array_equal(s, alone[i][0], equal_nan=True) and np.array_equal(c, alone[i][1])
            assert np.array_equal(f, fk_alone[i])
            assert np.array_equal(nq, near_alone[i], equal_nan=True)
