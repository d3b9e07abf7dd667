"""The emitted C kernels for C++, CMake and IKFast users (issue 32): headers that compile as C99
and C++17 with warnings as errors, -ffast-math refused, optional pointers, the pose conversions
in C, the CMake package beside every C kernel and the IKFast 61 drop-in."""

import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from derive import reference
from derive.algebra import dualquat as dq
from derive.codegen.emit import render_ikfast
from derive.kinematics.pose import from_position_quaternion

ROOT = Path(__file__).resolve().parents[1]
GENERATED = sorted((ROOT / "generated").glob("*/*_kinematics.h"))
needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("g++") is None,
                               reason="gcc / g++ not installed")


def _run(cmd, **kw):
    return subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)


def _shipped(tmp_path, robot="ur5"):
    """Copy the shipped C kernels and CMake package of a robot (generated/, a fresh regeneration
    of the templates: tests/test_derivation.py) into tmp_path."""
    for path in (ROOT / "generated" / robot).iterdir():
        if path.suffix in (".c", ".h", ".txt", ".cmake"):
            shutil.copy(path, tmp_path / path.name)


@needs_gcc
def test_every_shipped_header_compiles_as_c99_and_cxx17():
    """The project check: every generated/*/*_kinematics.h with g++ -std=c++17 -Wall -Wextra
    -Werror -fsyntax-only (extern "C", DQ_RESTRICT for restrict), and as C99 (and with clang where
    present)."""
    assert len(GENERATED) >= 13
    compilers = [("g++", "-std=c++17", "c++"), ("gcc", "-std=c99", "c")]
    compilers += [(c, s, x) for c, s, x in (("clang++", "-std=c++17", "c++"), ("clang", "-std=c99", "c"))
                  if shutil.which(c)]
    for header in GENERATED:
        for cc, std, lang in compilers:
            res = _run([cc, std, "-Wall", "-Wextra", "-Werror", "-fsyntax-only", "-x", lang, header])
            assert res.returncode == 0, (cc, header.name, res.stderr)


@needs_gcc
@pytest.mark.parametrize("robot", ["ur5", "irb120", "panda", "iiwa14"])
def test_shipped_source_compiles_as_c99_and_cxx17(robot):
    """The shipped source of each robot class, as C99 with -Wpedantic and as C++17 (no unused
    variable, no C-only construct), warnings as errors."""
    source = ROOT / "generated" / robot / f"{robot}_kinematics.c"
    for cmd in (["gcc", "-std=c99", "-Wpedantic", "-O1", "-c", "-o", "/dev/null"],
                ["g++", "-std=c++17", "-x", "c++", "-fsyntax-only"]):
        res = _run([*cmd, "-Wall", "-Wextra", "-Werror", source])
        assert res.returncode == 0, (cmd, res.stderr[-3000:])


@needs_gcc
@pytest.mark.parametrize("flags", [["gcc", "-std=c99", "-Ofast"], ["gcc", "-std=c99", "-O2", "-ffast-math"],
                                   ["g++", "-std=c++17", "-x", "c++", "-Ofast"],
                                   ["gcc", "-std=c99", "-O2", "-ffinite-math-only"]])
def test_fast_math_is_refused_at_compile_time(flags):
    """-ffast-math folds dq_sincos's rounding trick away (sin and cos wrong by up to 1, all-zero
    IK solutions); the source refuses it with an #error naming the flag, and compiles without it."""
    source = ROOT / "generated" / "ur5" / "ur5_kinematics.c"
    res = _run([*flags, "-fsyntax-only", source])
    assert res.returncode != 0
    assert "#error" in res.stderr and ("-ffast-math" in res.stderr or "-ffinite-math-only" in res.stderr)
    plain = [f for f in flags if f not in ("-Ofast", "-ffast-math", "-ffinite-math-only")] + ["-O2"]
    assert _run([*plain, "-fsyntax-only", source]).returncode == 0


NULL_DRIVER = r"""
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "ur5_kinematics.h"
#define N 70
int main(void)
{
    static double q[N * 6], poses[N * 8], seeds[N * 6], sols[N * 48], sols2[N * 48], qn[N * 6], qn2[N * 6];
    static double mx[N], tt[N];
    static int counts[N], counts2[N], branch[N * 8], branch2[N * 8], sing[N * 8], sing2[N * 8];
    static int nb[N], ns[N];
    for (int i = 0; i < N * 6; ++i) {
        q[i] = sin(1.7 * i + 0.3) * 3.0;
        seeds[i] = q[i] + 0.01;
    }
    for (int i = 0; i < 5; ++i) {
        q[i * 6 + 4] = 0.0;                 /* wrist-singular poses */
    }
    ur5_fk_batch(N, q, poses);
    ur5_ik_batch_ex(N, poses, sols, counts, branch, sing);
    ur5_ik_batch_ex(N, poses, sols2, counts2, branch2, NULL);   /* singular alone NULL */
    int bad = memcmp(sols, sols2, sizeof sols) != 0 || memcmp(branch, branch2, sizeof branch) != 0;
    ur5_ik_batch_ex(N, poses, sols2, counts2, NULL, sing2);     /* branch alone NULL */
    bad |= memcmp(sing, sing2, sizeof sing) != 0 || memcmp(counts, counts2, sizeof counts) != 0;
    ur5_ik_nearest_batch(N, poses, seeds, qn, mx, tt, nb, ns);
    ur5_ik_nearest_batch(N, poses, seeds, qn2, NULL, NULL, NULL, NULL);   /* only q */
    for (int i = 0; i < N * 6; ++i) {
        bad |= !(qn[i] == qn2[i] || (isnan(qn[i]) && isnan(qn2[i])));
    }
    int singular = 0;
    for (int i = 0; i < N * 8; ++i) {
        singular += sing[i];
    }
    printf("%d %d\n", bad, singular);
    return 0;
}
"""


@needs_gcc
def test_optional_pointers_may_be_null(tmp_path):
    """branch or singular alone NULL in ik_batch_ex, and every optional output of
    ik_nearest_batch NULL: nothing is written through NULL (AddressSanitizer and UBSan) and the
    other outputs are the same as with all of them."""
    _shipped(tmp_path)
    (tmp_path / "main.c").write_text(NULL_DRIVER)
    res = _run(["gcc", "-std=c99", "-O0", "-Wall", "-Wextra", "-Werror", "-fsanitize=address,undefined",
                "-fno-sanitize-recover=all", "-o", tmp_path / "t", tmp_path / "main.c",
                tmp_path / "ur5_kinematics.c", "-lm"])
    assert res.returncode == 0, res.stderr
    run = _run([tmp_path / "t"], timeout=120)
    assert run.returncode == 0, run.stderr
    bad, singular = map(int, run.stdout.split())
    assert bad == 0
    assert singular > 0            # the singular flags were really written where asked


POSE_DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "ur5_kinematics.h"
/* stdin: n, then n 4x4 matrices (16 numbers), n positions + quaternions (7 numbers);
   stdout: the poses of the 4x4 and of the 3x4 matrices, their return codes, the matrices again
   (4x4 and 3x4) and the poses of position + quaternion, and those back */
int main(void)
{
    size_t n;
    if (scanf("%zu", &n) != 1) {
        return 1;
    }
    double *m = (double *)malloc(sizeof(double) * 16 * n), *m3 = (double *)malloc(sizeof(double) * 12 * n);
    double *pq = (double *)malloc(sizeof(double) * 7 * n), *t = (double *)malloc(sizeof(double) * 3 * n);
    double *qu = (double *)malloc(sizeof(double) * 4 * n);
    double *p4 = (double *)malloc(sizeof(double) * 8 * n), *p3 = (double *)malloc(sizeof(double) * 8 * n);
    double *pp = (double *)malloc(sizeof(double) * 8 * n), *back4 = (double *)malloc(sizeof(double) * 16 * n);
    double *back3 = (double *)malloc(sizeof(double) * 12 * n), *tb = (double *)malloc(sizeof(double) * 3 * n);
    double *qb = (double *)malloc(sizeof(double) * 4 * n);
    for (size_t i = 0; i < 16 * n; ++i) {
        if (scanf("%lf", &m[i]) != 1) {
            return 1;
        }
    }
    for (size_t i = 0; i < 7 * n; ++i) {
        if (scanf("%lf", &pq[i]) != 1) {
            return 1;
        }
    }
    for (size_t i = 0; i < n; ++i) {
        for (int k = 0; k < 12; ++k) {
            m3[12 * i + k] = m[16 * i + k];
        }
        for (int k = 0; k < 3; ++k) {
            t[3 * i + k] = pq[7 * i + k];
        }
        for (int k = 0; k < 4; ++k) {
            qu[4 * i + k] = pq[7 * i + 3 + k];
        }
    }
    const size_t r4 = ur5_poses_from_matrices(n, 4, m, p4);
    const size_t r3 = ur5_poses_from_matrices(n, 3, m3, p3);
    const size_t rq = ur5_poses_from_position_quaternion(n, t, qu, pp);
    ur5_poses_to_matrices(n, 4, p4, back4);
    ur5_poses_to_matrices(n, 3, p4, back3);
    ur5_poses_to_position_quaternion(n, pp, tb, qb);
    printf("%zu %zu %zu\n", r4, r3, rq);
    for (size_t i = 0; i < n; ++i) {
        for (int k = 0; k < 8; ++k) {
            printf("%.17g %.17g %.17g\n", p4[8 * i + k], p3[8 * i + k], pp[8 * i + k]);
        }
        for (int k = 0; k < 16; ++k) {
            printf("%.17g %.17g\n", back4[16 * i + k], k < 12 ? back3[12 * i + k] : 0.0);
        }
        for (int k = 0; k < 3; ++k) {
            printf("%.17g\n", tb[3 * i + k]);
        }
        for (int k = 0; k < 4; ++k) {
            printf("%.17g\n", qb[4 * i + k]);
        }
    }
    return 0;
}
"""


def _pose_program(tmp_path, compiler):
    _shipped(tmp_path)
    (tmp_path / "main.c").write_text(POSE_DRIVER)
    cmd = (["gcc", "-std=c99", "-Wpedantic"] if compiler == "gcc" else ["g++", "-std=c++17", "-x", "c++"])
    res = _run([*cmd, "-O2", "-Wall", "-Wextra", "-Werror", "-o", tmp_path / "t", tmp_path / "main.c",
                tmp_path / "ur5_kinematics.c", "-lm"])
    assert res.returncode == 0, res.stderr
    return tmp_path / "t"


def _convert(program, mats, pq):
    text = f"{len(mats)}\n" + "\n".join(" ".join(repr(float(v)) for v in row)
                                        for row in [*mats.reshape(len(mats), 16), *pq])
    run = _run([program], input=text, timeout=60)
    assert run.returncode == 0, run.stderr
    lines = run.stdout.split("\n")
    codes = [int(v) for v in lines[0].split()]
    n = len(mats)
    p4, p3, pp = np.zeros((n, 8)), np.zeros((n, 8)), np.zeros((n, 8))
    back4, back3 = np.zeros((n, 16)), np.zeros((n, 12))
    tb, qb = np.zeros((n, 3)), np.zeros((n, 4))
    at = 1
    for i in range(n):
        for k in range(8):
            p4[i, k], p3[i, k], pp[i, k] = map(float, lines[at].split())
            at += 1
        for k in range(16):
            a, b = map(float, lines[at].split())
            back4[i, k] = a
            if k < 12:
                back3[i, k] = b
            at += 1
        tb[i] = [float(lines[at + k]) for k in range(3)]
        qb[i] = [float(lines[at + 3 + k]) for k in range(4)]
        at += 7
    return codes, p4, p3, pp, back4.reshape(n, 4, 4), back3.reshape(n, 3, 4), tb, qb


@needs_gcc
@pytest.mark.parametrize("compiler", ["gcc", "g++"])
def test_pose_conversions_in_c_match_the_python_ones(tmp_path, compiler):
    """<robot>_poses_from_matrices (4x4 and 3x4), _from_position_quaternion and the inverse
    conversions in C (and compiled as C++) against derive.algebra.dualquat.from_matrix /
    derive.pose.from_position_quaternion, on random poses and on 180-degree turns (every pivot of
    Shepperd's method); bad matrices give 1 + the index of the first."""
    rng = np.random.default_rng(11)
    q = rng.uniform(-np.pi, np.pi, size=(300, 6))
    mats = reference.fk_matrix("ur5", q)
    turns = np.tile(np.eye(4), (4, 1, 1))
    turns[1, :3, :3] = np.diag([1.0, -1.0, -1.0])
    turns[2, :3, :3] = np.diag([-1.0, 1.0, -1.0])
    turns[3, :3, :3] = np.diag([-1.0, -1.0, 1.0])
    turns[:, :3, 3] = rng.normal(size=(4, 3))
    mats = np.concatenate([mats, turns])
    ref = dq.from_matrix(mats)
    position, quat = ref_t, ref_q = dq.to_rt(ref)[1], dq.to_rt(ref)[0]
    pq = np.concatenate([position, quat * 1.0000003], axis=1)          # not quite unit: normalised
    program = _pose_program(tmp_path, compiler)
    codes, p4, p3, pp, back4, back3, tb, qb = _convert(program, mats, pq)
    assert codes == [0, 0, 0]
    assert np.max(np.abs(p4 - ref)) < 1e-15 * 8 and np.max(np.abs(p3 - ref)) < 1e-15 * 8
    assert np.all(p4[:, 0] >= 0.0)
    assert np.max(np.abs(pp - from_position_quaternion(position, quat, "wxyz"))) < 1e-15 * 8
    assert np.max(np.abs(back4 - mats)) < 1e-14 and np.max(np.abs(back3 - mats[:, :3])) < 1e-14
    assert np.max(np.abs(tb - ref_t)) < 1e-14 and np.max(np.abs(qb - ref_q)) < 1e-15 * 8
    # rigid-transform checks: the first bad matrix / quaternion, 1-based
    bad = mats[:6].copy()
    bad[4, :3, :3] *= 1.001                                              # |R^T R - I| = 0.002
    bad[5, 3, 0] = 0.1                                                   # last row
    bpq = pq[:6].copy()
    bpq[3, 3:] *= 1.01
    codes = _convert(program, bad, bpq)[0]
    assert codes == [5, 5, 4]                 # the 3x4 form has no last row: matrix 4 first too
    refl = mats[:3].copy()
    refl[2, :3, 2] *= -1.0                                               # det = -1
    refl[0, 1, 1] = math.nan
    assert _convert(program, refl, pq[:3])[0][:2] == [1, 1]


@pytest.mark.skipif(shutil.which("cmake") is None, reason="cmake not installed")
@needs_gcc
def test_cmake_package_builds_installs_and_is_found(tmp_path):
    """The CMake package written beside the C kernels: configure, build, install into a
    temporary prefix, then a consumer project (C and C++) finds it with find_package and links
    the target; the consumer's FK and IK agree with the reference."""
    src = tmp_path / "ur5"
    src.mkdir()
    _shipped(src)
    assert (src / "CMakeLists.txt").is_file() and (src / "ur5_kinematicsConfig.cmake").is_file()
    build, prefix = tmp_path / "build", tmp_path / "prefix"
    for cmd in (["cmake", "-S", src, "-B", build, "-DCMAKE_C_FLAGS=-Wall -Wextra -Werror"],
                ["cmake", "--build", build], ["cmake", "--install", build, "--prefix", prefix]):
        res = _run(cmd, timeout=300)
        assert res.returncode == 0, (cmd, res.stdout[-2000:], res.stderr[-2000:])
    assert (prefix / "include" / "ur5_kinematics.h").is_file()
    assert list(prefix.glob("lib*/cmake/ur5_kinematics/ur5_kinematicsConfig.cmake"))
    consumer = tmp_path / "consumer"
    consumer.mkdir()
    (consumer / "CMakeLists.txt").write_text(
        "cmake_minimum_required(VERSION 3.14)\nproject(consumer C CXX)\n"
        "find_package(ur5_kinematics REQUIRED)\n"
        "add_executable(use_c main.c)\ntarget_link_libraries(use_c PRIVATE ur5_kinematics::ur5_kinematics)\n"
        "add_executable(use_cpp main.cpp)\ntarget_link_libraries(use_cpp PRIVATE ur5_kinematics::ur5_kinematics)\n")
    main = ('#include <stdio.h>\n#include "ur5_kinematics.h"\n'
            "int main(void) {\n  const double q[6] = {0.1, -0.7, 1.1, 0.4, 0.9, -2.0};\n"
            "  double p[8], s[48];\n  ur5_fk(q, p);\n  const int c = ur5_ik(p, s);\n"
            '  printf("%d", c);\n  for (int k = 0; k < 8; ++k) printf(" %.17g", p[k]);\n'
            '  for (int k = 0; k < 48; ++k) printf(" %.17g", s[k]);\n  printf("\\n");\n  return 0;\n}\n')
    (consumer / "main.c").write_text(main)
    (consumer / "main.cpp").write_text(main)
    cbuild = tmp_path / "cbuild"
    for cmd in (["cmake", "-S", consumer, "-B", cbuild, f"-DCMAKE_PREFIX_PATH={prefix}",
                 "-DCMAKE_CXX_FLAGS=-Wall -Wextra -Werror"], ["cmake", "--build", cbuild]):
        res = _run(cmd, timeout=300)
        assert res.returncode == 0, (cmd, res.stdout[-2000:], res.stderr[-2000:])
    q = np.array([0.1, -0.7, 1.1, 0.4, 0.9, -2.0])
    for exe in ("use_c", "use_cpp"):
        out = _run([cbuild / exe], timeout=60).stdout.split()
        count, pose = int(out[0]), np.array([float(v) for v in out[1:9]])
        sols = np.array([float(v) for v in out[9:]]).reshape(8, 6)
        ref = reference.fk("ur5", q)
        assert min(np.abs(pose - ref).max(), np.abs(pose + ref).max()) < 1e-12
        assert count == 8
        d = np.abs(np.remainder(sols[:count] - q + np.pi, 2 * np.pi) - np.pi).max(axis=1)
        assert d.min() < 1e-9


def test_generated_kernels_ship_a_cmake_package():
    """Every kernel folder of generated/ has the CMake package of its C kernels, naming its files."""
    for header in GENERATED:
        folder, ident = header.parent, header.name[: -len("_kinematics.h")]
        lists = (folder / "CMakeLists.txt").read_text()
        assert f"add_library({ident}_kinematics {ident}_kinematics.c)" in lists
        assert (folder / f"{ident}_kinematicsConfig.cmake").is_file()


IKFAST_H = r"""// Minimal declarations of IKFast's ikfast.h API (IKFast 61: the classes the solvers and MoveIt's
// plugin use, and the library functions under IKFAST_HAS_LIBRARY), written for dq-derive's tests.
#ifndef DQ_TEST_IKFAST_H
#define DQ_TEST_IKFAST_H
#include <cstddef>
#include <list>
#include <stdexcept>
#include <vector>

#define IKFAST_VERSION 0x1000004b

namespace ikfast {

template <typename T>
class IkSingleDOFSolutionBase {
public:
    IkSingleDOFSolutionBase() : fmul(0), foffset(0), freeind(-1), jointtype(0x01), maxsolutions(1)
    {
        for (int i = 0; i < 5; ++i) {
            indices[i] = (unsigned char)-1;
        }
    }
    T fmul, foffset;              // value = fmul * free[freeind] + foffset
    signed char freeind;          // < 0: no free parameter
    unsigned char jointtype;      // 0x01 revolute, 0x11 prismatic
    unsigned char maxsolutions;
    unsigned char indices[5];
};

template <typename T>
class IkSolutionBase {
public:
    virtual ~IkSolutionBase() {}
    virtual void GetSolution(T* solution, const T* freevalues) const = 0;
    virtual const std::vector<int>& GetFree() const = 0;
    virtual int GetDOF() const = 0;
};

template <typename T>
class IkSolutionListBase {
public:
    virtual ~IkSolutionListBase() {}
    virtual std::size_t AddSolution(const std::vector<IkSingleDOFSolutionBase<T> >& vinfos, const std::vector<int>& vfree) = 0;
    virtual const IkSolutionBase<T>& GetSolution(std::size_t index) const = 0;
    virtual std::size_t GetNumSolutions() const = 0;
    virtual void Clear() = 0;
};

template <typename T>
class IkSolution : public IkSolutionBase<T> {
public:
    IkSolution(const std::vector<IkSingleDOFSolutionBase<T> >& vinfos, const std::vector<int>& vfree)
        : info(vinfos), free(vfree) {}
    void GetSolution(T* solution, const T* freevalues) const override
    {
        for (std::size_t i = 0; i < info.size(); ++i) {
            solution[i] = info[i].freeind < 0 ? info[i].foffset : freevalues[info[i].freeind] * info[i].fmul + info[i].foffset;
        }
    }
    const std::vector<int>& GetFree() const override { return free; }
    int GetDOF() const override { return (int)info.size(); }
    std::vector<IkSingleDOFSolutionBase<T> > info;
    std::vector<int> free;
};

template <typename T>
class IkSolutionList : public IkSolutionListBase<T> {
public:
    std::size_t AddSolution(const std::vector<IkSingleDOFSolutionBase<T> >& vinfos, const std::vector<int>& vfree) override
    {
        items.push_back(IkSolution<T>(vinfos, vfree));
        return items.size() - 1;
    }
    const IkSolutionBase<T>& GetSolution(std::size_t index) const override
    {
        if (index >= items.size()) {
            throw std::runtime_error("GetSolution: no such index");
        }
        typename std::list<IkSolution<T> >::const_iterator it = items.begin();
        for (std::size_t i = 0; i < index; ++i) {
            ++it;
        }
        return *it;
    }
    std::size_t GetNumSolutions() const override { return items.size(); }
    void Clear() override { items.clear(); }

private:
    std::list<IkSolution<T> > items;
};

}  // namespace ikfast

#endif

#ifdef IKFAST_HAS_LIBRARY
#ifdef IKFAST_CLIBRARY
#define IKFAST_API extern "C"
#else
#define IKFAST_API
#endif
#ifdef IKFAST_NAMESPACE
namespace IKFAST_NAMESPACE {
#endif
typedef double IkReal;
IKFAST_API bool ComputeIk(const IkReal* eetrans, const IkReal* eerot, const IkReal* pfree, ikfast::IkSolutionListBase<IkReal>& solutions);
IKFAST_API bool ComputeIk2(const IkReal* eetrans, const IkReal* eerot, const IkReal* pfree, ikfast::IkSolutionListBase<IkReal>& solutions, void* pOpenRAVEManip);
IKFAST_API void ComputeFk(const IkReal* joints, IkReal* eetrans, IkReal* eerot);
IKFAST_API int GetNumFreeParameters();
IKFAST_API int* GetFreeParameters();
IKFAST_API int GetNumJoints();
IKFAST_API int GetIkRealSize();
IKFAST_API const char* GetIkFastVersion();
IKFAST_API int GetIkType();
IKFAST_API const char* GetKinematicsHash();
#ifdef IKFAST_NAMESPACE
}
#endif
#endif
"""

IKFAST_DRIVER = r"""
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <list>
#include <stdexcept>
#include <vector>
/* as MoveIt's IKFast plugin: the solver included inside the plugin's namespace */
namespace plugin_ns {
#define IKFAST_NO_MAIN
#include "SOLVER"
}
/* stdin: n, then per pose 12 numbers [R | t] row-major and the free value; stdout per pose the
   count, each solution, then ComputeFk of each solution (eetrans, eerot) */
int main()
{
    using namespace plugin_ns;
    if (GetIkType() != 0x67000001 || GetIkRealSize() != (int)sizeof(double) || std::strlen(GetKinematicsHash()) == 0
        || std::strcmp(GetIkFastVersion(), "0x1000004b") != 0) {
        return 2;
    }
    std::printf("%d %d", GetNumJoints(), GetNumFreeParameters());
    for (int i = 0; i < GetNumFreeParameters(); ++i) {
        std::printf(" %d", GetFreeParameters()[i]);
    }
    std::printf("\n");
    int n;
    if (std::scanf("%d", &n) != 1) {
        return 1;
    }
    const int dof = GetNumJoints();
    for (int i = 0; i < n; ++i) {
        double m[12], fv[1];
        for (int k = 0; k < 12; ++k) {
            if (std::scanf("%lf", &m[k]) != 1) {
                return 1;
            }
        }
        if (std::scanf("%lf", &fv[0]) != 1) {
            return 1;
        }
        IkReal eerot[9] = {m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]};
        IkReal eetrans[3] = {m[3], m[7], m[11]};
        ikfast::IkSolutionList<IkReal> solutions;
        const bool ok = ComputeIk(eetrans, eerot, GetNumFreeParameters() ? fv : NULL, solutions);
        std::printf("%d %d\n", (int)ok, (int)solutions.GetNumSolutions());
        std::vector<IkReal> q(dof);
        for (std::size_t s = 0; s < solutions.GetNumSolutions(); ++s) {
            const ikfast::IkSolutionBase<IkReal>& sol = solutions.GetSolution(s);
            sol.GetSolution(&q[0], NULL);
            IkReal t[3], r[9];
            ComputeFk(&q[0], t, r);
            for (int k = 0; k < dof; ++k) {
                std::printf("%.17g ", q[k]);
            }
            for (int k = 0; k < 3; ++k) {
                std::printf("%.17g ", t[k]);
            }
            for (int k = 0; k < 9; ++k) {
                std::printf("%.17g ", r[k]);
            }
            std::printf("\n");
        }
    }
    return 0;
}
"""


@needs_gcc
@pytest.mark.parametrize("robot, n", [("ur5", 10_000), ("irb120", 2000), ("panda", 2000), ("iiwa14", 500)])
def test_ikfast_drop_in(tmp_path, robot, n):
    """The IKFast 61 drop-in, compiled with g++ -Werror against ikfast.h's documented API (the
    declarations above) the way MoveIt's plugin includes it (inside a namespace, IKFAST_NO_MAIN):
    on random poses ([R | t] from the independent 4x4 reference) ComputeIk finds the generating
    configuration among its solutions (up to 2 pi), every solution's ComputeFk reproduces the
    pose within 1e-10, and a seven-joint arm's free joint is IKFast's free parameter (joint 7 of
    the Panda, joint 3 of the iiwa)."""
    name, text = render_ikfast(robot)
    assert name == f"{robot}_ikfast_solver.cpp"
    assert "#define IKFAST_HAS_LIBRARY" in text and '#include "ikfast.h"' in text
    (tmp_path / name).write_text(text)
    (tmp_path / "ikfast.h").write_text(IKFAST_H)
    (tmp_path / "driver.cpp").write_text(IKFAST_DRIVER.replace("SOLVER", name))
    res = _run(["g++", "-std=c++17", "-O1", "-Wall", "-Wextra", "-Werror", "-o", tmp_path / "drv",
                tmp_path / "driver.cpp"], timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    standalone = _run(["g++", "-std=c++17", "-O0", "-Wall", "-Wextra", "-Werror", "-o", tmp_path / "ik",
                       tmp_path / name], timeout=600)       # with IKFast's own kind of main
    assert standalone.returncode == 0, standalone.stderr[-3000:]
    robot_ = __import__("derive").load_robot(robot)
    dof = robot_.dof
    rng = np.random.default_rng(5)
    lo, hi = np.maximum(robot_.limits[:, 0], -np.pi), np.minimum(robot_.limits[:, 1], np.pi)
    q = rng.uniform(lo, hi, size=(n, dof))
    mats = reference.fk_matrix(robot, q)
    free_index = {"panda": 6, "iiwa14": 2}.get(robot)       # q7 (Panda class), q3 (SRS class)
    fv = q[:, free_index] if free_index is not None else np.zeros(n)
    text_in = f"{n}\n" + "\n".join(" ".join(repr(float(v)) for v in [*m[:3].reshape(12), f])
                                   for m, f in zip(mats, fv))
    run = _run([tmp_path / "drv"], input=text_in, timeout=600)
    assert run.returncode == 0, run.stderr
    lines = run.stdout.split("\n")
    head = [int(v) for v in lines[0].split()]
    assert head[:2] == [dof, 1 if dof == 7 else 0]
    if dof == 7:
        assert head[2] == free_index
    at, missed, worst = 1, 0, 0.0
    for i in range(n):
        ok, count = map(int, lines[at].split())
        at += 1
        assert ok == (count > 0)
        vals = np.array([[float(v) for v in lines[at + s].split()] for s in range(count)]).reshape(count, dof + 12)
        at += count
        sols, t, r = vals[:, :dof], vals[:, dof:dof + 3], vals[:, dof + 3:].reshape(count, 3, 3)
        if count:
            worst = max(worst, np.abs(t - mats[i, :3, 3]).max(), np.abs(r - mats[i, :3, :3]).max())
            if free_index is not None:
                assert np.all(sols[:, free_index] == fv[i])
        d = np.abs(np.remainder(sols - q[i] + np.pi, 2 * np.pi) - np.pi).max(axis=1) if count else [np.inf]
        missed += np.min(d) > 1e-6
    assert missed == 0
    assert worst <= 1e-10
    # a matrix that is not a rotation: no solutions
    bad = mats[0, :3].copy()
    bad[:, :3] *= 1.01
    out = _run([tmp_path / "ik", *[repr(float(v)) for v in bad.reshape(12)], *(["0.3"] if dof == 7 else [])])
    assert out.returncode != 0 and "Failed" in out.stderr
    good = _run([tmp_path / "ik", *[repr(float(v)) for v in mats[0, :3].reshape(12)],
                 *([repr(float(fv[0]))] if dof == 7 else [])])
    assert good.returncode == 0 and good.stdout.startswith("Found ")
