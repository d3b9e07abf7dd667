"""Generated FK kernels (pure Python, numpy, C99) against the numpy reference."""

import math
import os
import shutil
import subprocess

import numpy as np
import pytest

import derive
from derive import InputError, reference
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


def test_kernel_input_errors():
    k = derive.kernels("ur5", "numpy")
    with pytest.raises(InputError, match=r"expected shape \(6,\)"):
        k.fk(np.zeros((3, 5)))
    with pytest.raises(InputError, match="NaN"):
        k.fk([0, 0, float("nan"), 0, 0, 0])
    with pytest.raises(InputError, match="unknown backend"):
        derive.kernels("ur5", "fortran")


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
    files = render_kernels("ur10e")
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    q = np.random.default_rng(3).uniform(-3, 3, size=(50, 6))
    rows = ",\n".join("{" + ", ".join(repr(float(v)) for v in row) + "}" for row in q)
    (tmp_path / "main.c").write_text(
        '#include <stdio.h>\n#include "ur10e_kinematics.h"\n'
        f"static const double Q[50][6] = {{{rows}}};\n"
        "int main(void) { double out[50 * 8]; ur10e_fk_batch(50, &Q[0][0], out);\n"
        "  for (int i = 0; i < 400; ++i) {\n    printf(\"%.17g\\n\", out[i]);\n  }\n  return 0;\n}\n")
    flags = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror", *extra]
    res = subprocess.run(["gcc", *flags, "-o", str(tmp_path / "t"), str(tmp_path / "main.c"),
                          str(tmp_path / "ur10e_kinematics.c"), "-lm"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    run = subprocess.run([str(tmp_path / "t")], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    out = np.array([float(v) for v in run.stdout.split()]).reshape(50, 8)
    assert mod_sign(out, reference.fk("ur10e", q)) < 1e-12


@pytest.mark.skipif(shutil.which("clang") is None, reason="clang not installed")
def test_c_compiles_with_clang(tmp_path):
    for name, text in render_kernels("ur5").items():
        (tmp_path / name).write_text(text)
    res = subprocess.run(["clang", "-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-c",
                          str(tmp_path / "ur5_kinematics.c"), "-o", str(tmp_path / "k.o")],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
