"""Where the general 6R C kernel's time goes, and the eigen-solver's share (issue 31's C speed):
the per-pose time of the batch IK (``<id>_ik_batch_general``), then the eigen-solver alone
(``g6_eigenvalues`` of templates/general6r.c.j2, in the emitted source) on the very matrices the
kernel hands it for these poses: its time per call, the part before the QR iteration (balancing
and Hessenberg form, timed by a build that returns there), the QR sweeps per call and the time per
sweep, and the balancing passes; then the same matrices, in the batch's groups (up to four in a
row of one size), through ``g6_eigenvalues_lanes`` (four in lock step), timed in the same run
(scalar and lanes builds interleaved, the best of each), and its lock-step sweeps.

    .venv/bin/python benchmarks/bench_general6r_eig.py [--robots crx10ia,xarm6] [--poses N]
        [--seed S] [--repeats R]

The kernel is compiled with the C backend's flags (derive.codegen.loader.c_flags), one thread;
CPU time (CLOCK_PROCESS_CPUTIME_ID), the best of R repeats. The poses are those of
``dq-derive bench kernels`` (configurations uniform within the limits, at most one turn).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from derive import reference
from derive.codegen.emit import render_kernels
from derive.codegen.loader import c_compiler, c_flags
from derive.model.robot import load_robot

_HEAD = r"""#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
static double cpu(void)
{
    struct timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}
static FILE *g6b_dump;
static long g6b_sweeps, g6b_passes;
static void g6b_record(int n, const double *a, int ld)
{
    if (g6b_dump) {
        fwrite(&n, sizeof n, 1, g6b_dump);
        for (int i = 0; i < n; ++i) {
            fwrite(a + i * ld, sizeof(double), (size_t)n, g6b_dump);
        }
    }
}
"""

_MAIN = r"""
int main(int argc, char **argv)
{
    /* POSES|MATRICES REPEATS [DUMP]: the batch IK on poses (8 doubles each) where G6B_BATCH is
       defined, else g6_eigenvalues on recorded matrices (n, then n x n row by row) */
    const int reps = atoi(argv[2]);
    FILE *f = fopen(argv[1], "rb");
    if (!f) {
        return 2;
    }
    fseek(f, 0, SEEK_END);
    const long bytes = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *buf = malloc((size_t)bytes);
    if (fread(buf, 1, (size_t)bytes, f) != (size_t)bytes) {
        return 2;
    }
    fclose(f);
    double best = INFINITY;
    long count = 0;
#ifdef G6B_BATCH
    const size_t n = (size_t)bytes / 64;
    double *sols = malloc(n * 16 * 6 * sizeof(double));
    int *counts = malloc(n * sizeof(int));
    count = (long)n;
    if (argc > 3) {
        g6b_dump = fopen(argv[3], "wb");
        G6B_BATCH(n, (const double *)buf, sols, counts, NULL, NULL);
        fclose(g6b_dump);
        g6b_dump = NULL;
    }
    for (int r = 0; r < reps; ++r) {
        const double t0 = cpu();
        G6B_BATCH(n, (const double *)buf, sols, counts, NULL, NULL);
        const double t = cpu() - t0;
        best = t < best ? t : best;
    }
#else
    /* the matrices in groups as the batch makes them (up to 4 in a row of one size), solved
       by g6_eigenvalues one by one, or with G6B_LANES by g6_eigenvalues_lanes (one alone by
       g6_eigenvalues, as in the batch); the copies of the input are timed too (2 KB each) */
    static double wr[4][24], wi[4][24], a[4][24 * 24];
    double *av[4], *pr[4], *pi[4];
    int ret[4];
    for (int v = 0; v < 4; ++v) {
        av[v] = a[v];
        pr[v] = wr[v];
        pi[v] = wi[v];
    }
    for (int r = 0; r < reps; ++r) {
        long off = 0;
        count = 0;
        g6b_sweeps = g6b_passes = 0;
        const double t0 = cpu();
        while (off < bytes) {
            int n0 = -1, ng = 0;
            while (ng < 4 && off < bytes) {
                int n;
                memcpy(&n, buf + off, sizeof n);
                if (ng > 0 && n != n0) {
                    break;
                }
                n0 = n;
                off += (long)sizeof n;
                for (int i = 0; i < n; ++i) {
                    memcpy(a[ng] + i * 24, buf + off + (long)i * n * 8, (size_t)n * 8);
                }
                off += (long)n * n * 8;
                ++ng;
            }
#ifdef G6B_LANES
            if (ng >= G6_LOCKSTEP) {
                g6_eigenvalues_lanes(n0, ng, av, pr, pi, ret);
            } else {
                for (int v = 0; v < ng; ++v) {
                    ret[v] = g6_eigenvalues(n0, a[v], 24, wr[v], wi[v]);
                }
            }
#else
            for (int v = 0; v < ng; ++v) {
                ret[v] = g6_eigenvalues(n0, a[v], 24, wr[v], wi[v]);
            }
#endif
            count += ng;
        }
        const double t = cpu() - t0;
        best = t < best ? t : best;
    }
    (void)ret;
#endif
    printf("%ld %.6e %ld %ld\n", count, best / (double)count, g6b_sweeps, g6b_passes);
    return 0;
}
"""


def _hooked(src: str, record: bool, stop_before_qr: bool, count: bool) -> str:
    """The emitted source with the benchmark's hooks in its eigen-solver (g6_balance_hessenberg,
    g6_hqr, g6_eigenvalues and g6_eigenvalues_lanes): recording each input matrix, counting the QR
    sweeps, the lock-step sweeps and the balancing passes, or returning before the QR iteration."""
    out = src

    def hook(marker, add, after=True):
        nonlocal out
        if marker not in out:
            raise SystemExit(f"bench_general6r_eig: the marker {marker.strip()!r} is not in the eigen-solver")
        out = out.replace(marker, marker + add if after else add + marker, 1)

    if record:
        hook("static int g6_eigenvalues(int n, double *a, int ld, double *wr, double *wi)\n{\n",
             "    g6b_record(n, a, ld);\n")
        hook("double *const *wi, int *ret)\n{\n", "    for (int g6b_v = 0; g6b_v < cnt; ++g6b_v) {\n"
             "        g6b_record(n, a[g6b_v], 24);\n    }\n")
    if count:
        hook("        done = 1;\n", "        ++g6b_passes;\n")
        hook("++its;", " ++g6b_sweeps;")
        hook("        if (k1 < 0) {\n            break;\n        }\n", "        ++g6b_sweeps;\n")
    if stop_before_qr:
        marker = "    g6_balance_hessenberg(n, a, ld);\n    return g6_hqr(n, a, ld, wr, wi);\n"
        if marker not in out:
            raise SystemExit("bench_general6r_eig: g6_eigenvalues is not g6_balance_hessenberg + g6_hqr")
        out = out.replace(marker, "    g6_balance_hessenberg(n, a, ld);\n    (void)wr;\n    (void)wi;\n    return 0;\n", 1)
    return out


def _build(folder: Path, name: str, text: str, extra=()) -> Path:
    c = folder / f"{name}.c"
    c.write_text(text)
    exe = folder / name
    cc = c_compiler()
    if cc is None:
        raise SystemExit("bench_general6r_eig: no C compiler")
    subprocess.run([cc, *c_flags(), *extra, "-w", "-o", str(exe), str(c), "-lm"], check=True)
    return exe


def _run(exe: Path, *args) -> list:
    out = subprocess.run([str(exe), *map(str, args)], check=True, capture_output=True, text=True).stdout.split()
    return [int(out[0]), float(out[1]), int(out[2]), int(out[3])]


def profile(robot: str, n: int, seed: int, repeats: int) -> dict:
    r = load_robot(robot)
    rng = np.random.default_rng(seed)
    lo = np.maximum(r.limits[:, 0], -np.pi)
    hi = np.minimum(r.limits[:, 1], np.pi)
    poses = np.ascontiguousarray(reference.fk(r, rng.uniform(lo, hi, (n, 6))), dtype=np.float64)
    files = render_kernels(r)
    _, src = files["c_source"]
    _, hdr = files["c_header"]
    batch = re.search(r"void (\w+_ik_batch_general)\(", src).group(1)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / files["c_header"][0]).write_text(hdr)
        (d / "poses.bin").write_bytes(poses.tobytes())
        whole = _build(d, "whole", _HEAD + _hooked(src, True, False, False) + _MAIN, [f"-DG6B_BATCH={batch}"])
        cnt, t_pose, _, _ = _run(whole, d / "poses.bin", repeats, d / "mats.bin")
        full = _build(d, "eig", _HEAD + _hooked(src, False, False, True) + _MAIN)
        lanes = _build(d, "lanes", _HEAD + _hooked(src, False, False, True) + _MAIN, ["-DG6B_LANES"])
        pre = _build(d, "pre", _HEAD + _hooked(src, False, True, False) + _MAIN)
        # scalar and lanes interleaved, the best of each
        t_eig = t_lanes = np.inf
        for _ in range(2):
            calls, t, sweeps, passes = _run(full, d / "mats.bin", repeats)
            t_eig = min(t_eig, t)
            _, t, lsweeps, _ = _run(lanes, d / "mats.bin", repeats)
            t_lanes = min(t_lanes, t)
        _, t_pre, _, _ = _run(pre, d / "mats.bin", repeats)
    return {"robot": robot, "poses": cnt, "pose_us": t_pose * 1e6, "calls": calls, "eig_us": t_eig * 1e6,
            "pre_us": t_pre * 1e6, "sweeps": sweeps / calls, "passes": passes / calls,
            "lanes_us": t_lanes * 1e6, "lock_sweeps": lsweeps}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default="crx10ia,xarm6")
    ap.add_argument("--poses", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args(argv)
    print(f"C flags: {' '.join(c_flags())}; CPU time, best of {a.repeats}")
    for robot in a.robots.split(","):
        p = profile(robot, a.poses, a.seed, a.repeats)
        per_pose = p["eig_us"] * p["calls"] / p["poses"]
        qr = p["eig_us"] - p["pre_us"]
        print(f"{robot}: batch IK {p['pose_us']:.1f} us per pose ({p['poses']} poses); "
              f"g6_eigenvalues {per_pose:.1f} us per pose ({100 * per_pose / p['pose_us']:.0f} %, "
              f"{p['calls']} calls, {p['eig_us']:.2f} us per call)")
        print(f"  balancing + Hessenberg {p['pre_us']:.2f} us per call ({p['passes']:.2f} balancing passes); "
              f"QR {qr:.2f} us per call: {p['sweeps']:.2f} sweeps, {1e3 * qr / p['sweeps']:.0f} ns per sweep")
        print(f"  in the batch's groups, four in lock step (g6_eigenvalues_lanes, alone where a group has one "
              f"or two matrices of its size, as the batch): {p['lanes_us']:.2f} us per call ({p['lanes_us'] / p['eig_us']:.3f} of "
              f"g6_eigenvalues', balancing and Hessenberg form included); {p['lock_sweeps'] / p['calls']:.2f} "
              f"sweeps per call (a lock-step sweep counted once for its group)")


if __name__ == "__main__":
    main()
