"""A standalone harness of a seven-joint arm's C with one joint given (the general elimination of
templates/free_joint.c.j2, issue 31), for A/B timing and per-function profiles: writes, into the
current folder, the kernel (``derive.codegen.free_joint.c_source(robot, K)``) with a main that
times ``<id>_ik_batch_free`` on configurations drawn within the limits with their own value of
joint K given (``whole.c``), the poses (``poses.bin``, n x 8 doubles), the values (``values.bin``,
n doubles), the C backend's flags (``flags.txt``) and the batch function's name (``batch.txt``).

    .venv/bin/python benchmarks/profile_free_joint_c.py gen3 4 [--poses N] [--seed S]
    gcc $(cat flags.txt) -w -DFJB_BATCH=$(cat batch.txt) -o whole whole.c -lm
    ./whole poses.bin values.bin 7 [OUT]   # poses, CPU us per pose and value (best of 7), rescues

With OUT the answers (solutions, counts, singular and degenerate flags, as the batch writes them)
go to that file, for a bit-for-bit comparison of two trees' builds (``cmp``).

The last figures printed: the share of poses sent to the rescue plan (fj1_run calls per pose, the
main's count by a hook on fj1_run's entry) and the solutions per pose. For a profile per function
add ``-g -fno-inline-functions -fno-inline-small-functions -fno-inline-functions-called-once``
and run ``perf record -g ./whole poses.bin values.bin 20`` (``perf report --no-children``). Build
two trees' harnesses and run them interleaved for an A/B in one session. The poses are those of
benchmarks/bench_free_joint.py (seed 1: the same draws for the same arm and number of poses).
"""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path

import numpy as np

import derive
from derive import reference
from derive.codegen.free_joint import c_source
from derive.codegen.loader import c_flags

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
static long fjb_rescues;
"""

_MAIN = r"""
static void *fjb_read(const char *path, long *bytes)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        return NULL;
    }
    fseek(f, 0, SEEK_END);
    *bytes = ftell(f);
    fseek(f, 0, SEEK_SET);
    void *buf = malloc((size_t)*bytes);
    if (fread(buf, 1, (size_t)*bytes, f) != (size_t)*bytes) {
        return NULL;
    }
    fclose(f);
    return buf;
}

int main(int argc, char **argv)
{
    /* POSES VALUES REPEATS [OUT]: the batch on the poses (8 doubles each) with the values; the
       answers written to OUT */
    long pb, vb;
    const double *poses = fjb_read(argv[1], &pb), *values = fjb_read(argv[2], &vb);
    const int reps = argc > 3 ? atoi(argv[3]) : 5;
    if (!poses || !values || pb / 64 != vb / 8) {
        return 2;
    }
    const size_t n = (size_t)vb / 8;
    double *sols = malloc(n * FJ_MAXSOL * 7 * sizeof(double));
    int *counts = malloc(n * sizeof(int)), *sing = malloc(n * FJ_MAXSOL * sizeof(int)), *deg = malloc(n * sizeof(int));
    double best = INFINITY;
    long rescues = 0;
    for (int r = 0; r < reps; ++r) {
        fjb_rescues = 0;
        const double t0 = cpu();
        FJB_BATCH(n, poses, values, sols, counts, sing, deg);
        const double t = cpu() - t0;
        best = t < best ? t : best;
        rescues = fjb_rescues;
    }
    if (argc > 4) {
        FILE *o = fopen(argv[4], "wb");
        if (!o) {
            return 2;
        }
        fwrite(sols, sizeof(double), n * FJ_MAXSOL * 7, o);
        fwrite(counts, sizeof(int), n, o);
        fwrite(sing, sizeof(int), n * FJ_MAXSOL, o);
        fwrite(deg, sizeof(int), n, o);
        fclose(o);
    }
    long total = 0, degen = 0;
    for (size_t i = 0; i < n; ++i) {
        total += counts[i];
        degen += deg[i];
    }
    printf("%zu poses: %.2f us per pose and value (best of %d); rescue plan on %.1f %% of poses; "
           "%.2f solutions per pose; %ld degenerate\n", n, best / (double)n * 1e6, reps,
           100.0 * (double)rescues / (double)n, (double)total / (double)n, degen);
    return 0;
}
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("robot")
    ap.add_argument("joint", type=int)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--poses", type=int, default=2000)
    args = ap.parse_args()
    robot = derive.load_robot(args.robot)
    lim = np.where(np.isfinite(robot.limits), robot.limits, np.array([-math.pi, math.pi]))
    rng = np.random.default_rng(args.seed)
    q = rng.uniform(np.maximum(lim[:, 0], -math.pi), np.minimum(lim[:, 1], math.pi), (args.poses, 7))
    poses = np.ascontiguousarray(reference.fk(robot, q), dtype=np.float64)
    values = np.ascontiguousarray(q[:, args.joint - 1], dtype=np.float64)
    src = c_source(robot, args.joint)
    batch = re.search(r"void (\w+_ik_batch_free)\(", src)
    if batch is None:
        raise SystemExit(f"{args.robot} q{args.joint}: not the general elimination (no _ik_batch_free)")
    # the rescue plan's count: a hook at fj1_run's entry
    src, hooked = re.subn(r"(static int fj1_run\([^{]*\{\n)", r"\1    ++fjb_rescues;\n", src, count=1)
    if not hooked:
        print("(no rescue plan's fj1_run found: the rescue share is not counted)")
    Path("poses.bin").write_bytes(poses.tobytes())
    Path("values.bin").write_bytes(values.tobytes())
    Path("whole.c").write_text(_HEAD + src + _MAIN)
    Path("batch.txt").write_text(batch.group(1))
    Path("flags.txt").write_text(" ".join(c_flags()))
    print(f"wrote whole.c, poses.bin, values.bin ({len(poses)} poses), flags.txt, batch.txt")


if __name__ == "__main__":
    main()
