"""The general 6R C kernel's lock-step eigen-solver (templates/general6r.c.j2:
g6_eigenvalues_lanes, up to four matrices of one size at once): bit for bit the eigenvalues and
the return value of the scalar g6_eigenvalues on each matrix, on the very matrices the kernel
makes (g6_prepare on random and axis-aligned poses) and on small, large, badly scaled and
non-finite ones, in groups of 1 to 4 of mixed sizes, built at -O0 and with the C backend's flags;
and the batch in lock step against the batch one pose at a time (the scalar solver) on the
kernels' whole answers."""

import math
import shutil
import subprocess

import numpy as np
import pytest

import derive
from derive import reference
from derive.codegen.general6r import c_ik_general
from derive.codegen.loader import c_flags

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

_HARNESS = r"""
#include <stdio.h>
static const double g6t_poses[][8] = {POSES};
#define G6T_NP ((int)(sizeof g6t_poses / sizeof g6t_poses[0]))
#define G6T_MAX (G6T_NP + 16)
static double g6t_m[G6T_MAX][576], g6t_a[G6T_MAX][576], g6t_b[G6T_MAX][576];
static double g6t_wr1[G6T_MAX][24], g6t_wi1[G6T_MAX][24], g6t_wr4[G6T_MAX][24], g6t_wi4[G6T_MAX][24];
static int g6t_n[G6T_MAX], g6t_r1[G6T_MAX], g6t_r4[G6T_MAX];
static unsigned long long g6t_seed = 12345;
static double g6t_rand(void)    /* uniform in (-1, 1), an LCG (deterministic) */
{
    g6t_seed = g6t_seed * 6364136223846793005ULL + 1442695040888963407ULL;
    return (double)(g6t_seed >> 11) / 4503599627370496.0 - 1.0;
}
int main(void)
{
    int cnt = 0;
    for (int i = 0; i < G6T_NP; ++i) {
        struct g6_work w;
        int dg = 0;
        if (g6_prepare(g6t_poses[i], &w, &dg)) {
            g6t_n[cnt] = w.n;
            memcpy(g6t_m[cnt++], w.a, sizeof w.a);
        }
    }
    const int made = cnt;
    /* dense random matrices of sizes 1, 2, 3, 5, 12, 24, rows scaled by powers of 2 up to 2^+-40
       (the balancing's work), one with a zero subdiagonal block, one with an inf, one with a NaN */
    const int sizes[16] = { 24, 24, 5, 24, 12, 12, 1, 2, 3, 24, 24, 24, 5, 5, 16, 16 };
    for (int e = 0; e < 16; ++e) {
        const int n = sizes[e];
        for (int i = 0; i < n; ++i) {
            const double sc = ldexp(1.0, (int)(40.0 * g6t_rand()));
            for (int j = 0; j < n; ++j) {
                g6t_m[cnt][i * 24 + j] = sc * g6t_rand() * (e == 4 && i >= 6 && j < 6 ? 0.0 : 1.0);
            }
        }
        if (e == 10) {
            g6t_m[cnt][3 * 24 + 7] = INFINITY;
        }
        if (e == 11) {
            g6t_m[cnt][5 * 24 + 2] = NAN;
        }
        g6t_n[cnt++] = n;
    }
    memcpy(g6t_a, g6t_m, sizeof g6t_m);
    memcpy(g6t_b, g6t_m, sizeof g6t_m);
    for (int c = 0; c < cnt; ++c) {
        g6t_r1[c] = g6_eigenvalues(g6t_n[c], g6t_a[c], 24, g6t_wr1[c], g6t_wi1[c]);
    }
    /* groups of 1, 2, 3, 4, 1, ... in a row; within one, the batch's rule: those of the first's
       size together, the rest after */
    int groups = 0, lanes = 0;
    for (int c0 = 0, gs = 1; c0 < cnt; c0 += gs, gs = gs % 4 + 1) {
        const int end = c0 + gs < cnt ? c0 + gs : cnt;
        int todo[4] = { 1, 1, 1, 1 };
        for (int v = c0; v < end; ++v) {
            if (!todo[v - c0]) {
                continue;
            }
            double *av[4], *pr[4], *pi[4];
            int ix[4], lr[4], m = 0;
            for (int u = v; u < end; ++u) {
                if (todo[u - c0] && g6t_n[u] == g6t_n[v]) {
                    todo[u - c0] = 0;
                    ix[m] = u;
                    av[m] = g6t_b[u];
                    pr[m] = g6t_wr4[u];
                    pi[m++] = g6t_wi4[u];
                }
            }
            g6_eigenvalues_lanes(g6t_n[v], m, av, pr, pi, lr);
            for (int e = 0; e < m; ++e) {
                g6t_r4[ix[e]] = lr[e];
            }
            ++groups;
            lanes += m;
        }
    }
    int bad = 0, failed = 0;
    for (int c = 0; c < cnt; ++c) {
        failed += g6t_r1[c] != 0;
        if (g6t_r1[c] != g6t_r4[c] || memcmp(g6t_wr1[c], g6t_wr4[c], sizeof(double) * (size_t)g6t_n[c])
            || memcmp(g6t_wi1[c], g6t_wi4[c], sizeof(double) * (size_t)g6t_n[c])) {
            ++bad;
            printf("differs: matrix %d (n %d)\n", c, g6t_n[c]);
        }
    }
    printf("%d %d %d %d %d\n", made, cnt, groups, lanes, bad);
    (void)failed;
    return 0;
}
"""


def _axis_aligned_and_random(robot, n_random, seed):
    r = derive.load_robot(robot)
    grid = np.array(np.meshgrid(*[[0.0, math.pi / 2, -math.pi / 2, math.pi]] * 2, indexing="ij")).reshape(2, -1).T
    q = np.zeros((len(grid), 6))
    q[:, 1:3] = grid
    q[:, 4] = math.pi / 2
    lo = np.maximum(r.limits[:, 0], -math.pi)
    hi = np.minimum(r.limits[:, 1], math.pi)
    q = np.concatenate([q, np.random.default_rng(seed).uniform(lo, hi, (n_random, 6))])
    return reference.fk(r, q)


@needs_gcc
@pytest.mark.parametrize("robot", ["crx10ia", "xarm6"])
def test_lock_step_eigenvalues_are_the_scalar_solvers_bit_for_bit(robot, tmp_path):
    from derive.codegen import emit
    files = emit.render_kernels(robot)
    for name, text in files.values():
        (tmp_path / name).write_text(text)
    P = _axis_aligned_and_random(robot, 40, 7)
    rows = ",\n".join("{" + ", ".join(repr(float(v)) for v in p) + "}" for p in P)
    (tmp_path / "t.c").write_text(f'#include "{files["c_source"][0]}"\n' + _HARNESS.replace("{POSES}", "{" + rows + "}"))
    for tag, flags in (("O0", ["-std=c99", "-O0"]), ("backend", c_flags())):
        exe = tmp_path / f"t_{tag}"
        res = subprocess.run(["gcc", *flags, "-w", "-o", str(exe), str(tmp_path / "t.c"), "-lm"],
                             capture_output=True, text=True)
        assert res.returncode == 0, res.stderr[-3000:]
        out = subprocess.run([str(exe)], capture_output=True, text=True, timeout=120).stdout.split()
        made, cnt, groups, lanes, bad = map(int, out[-5:])
        assert made >= len(P) - 4 and cnt == made + 16 and lanes == cnt and groups >= cnt // 3, (tag, out[-5:])
        assert bad == 0, (tag, out)


@needs_gcc
def test_batch_in_lock_step_gives_the_scalar_answers_bit_for_bit(monkeypatch):
    """The batch (<id>_ik_batch_general) in groups of four poses, their eigenvalues in lock step
    (G6_LOCKSTEP=2: every group with two or more matrices of one size), and the same function on
    one pose at a time (the scalar solver) give the same whole answers bit for bit (solutions,
    counts, singular and degenerate flags), on random and axis-aligned poses of the CRX (the
    axis-aligned ones take the nearby-pose fallback)."""
    monkeypatch.setenv("DQ_DERIVE_CFLAGS", "-std=c99 -O1 -DG6_LOCKSTEP=2")
    k = derive.kernels("crx10ia", "c")
    P = _axis_aligned_and_random("crx10ia", 22, 3)
    sols, counts, sing, degen = c_ik_general(k, P)
    assert counts.sum() > 4 * len(P) and degen.any() and not degen.all()
    for i in range(len(P)):
        s1, c1, g1, d1 = c_ik_general(k, P[i:i + 1])
        assert c1[0] == counts[i] and d1[0] == degen[i] and np.array_equal(g1[0], sing[i]), i
        assert np.array_equal(s1[0].view(np.uint64), sols[i].view(np.uint64)), i
