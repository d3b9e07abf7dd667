"""Where a general 6R arm's C kernels spend their time on axis-aligned poses (joints in multiples
of pi/2 within the limits) against random ones: a counting build of the emitted C (the arm's
kernel source with counters added: g6_candidates calls, Newton runs and iterations, patient or
not, clusters, near-chain candidates, Newton runs that reach the step limit), a main that times
each pose (best of 5, CLOCK_MONOTONIC, one pose per call of <id>_ik_batch_general), and the
time per category with a least-squares split over the counters.

    .venv/bin/python benchmarks/profile_general6r_fallback.py [crx10ia] [--random 1000]

The counters are added by text substitution on the rendered source; the script stops with an
error when a pattern is not found (the template changed).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import derive
from derive import reference
from derive.codegen import emit
from derive.codegen.loader import c_flags

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_general6r_axis_aligned import configurations  # noqa: E402

COUNTERS = ["cand", "runs", "iters", "patient_runs", "patient_iters", "own_degen", "clusters", "extra",
            "capped"]


def _sub(src, old, new):
    if old not in src:
        raise SystemExit(f"pattern not found in the emitted C: {old[:60]!r}")
    return src.replace(old, new, 1)


def counting_source(robot):
    files = emit.render_kernels(robot)
    name, src = files["c_source"]
    ident = name[:-len("_kinematics.c")]
    newton_max = int(re.search(r"    for \(int it = 0; it < (\d+); \+\+it\) \{\n        double err\[6\], jac\[36\]",
                               src).group(1))
    head = ("#define _POSIX_C_SOURCE 199309L\nstatic long st[%d];\n" % len(COUNTERS))
    sig = "static double g6_newton(const double c[7][16], double *q, const double (*sc0)[2], const double *t, int patient)\n{\n"
    src = _sub(src, sig, sig +
               "    st[patient ? 3 : 1]++;\n    int itc = 0;\n")
    src = _sub(src, "{\n        double err[6], jac[36]", "{\n        st[patient ? 4 : 2]++;\n        itc++;\n"
               "        double err[6], jac[36]")
    src = _sub(src, "    return last_step <= 1e-6 ? bound : 0.0;\n}",
               f"    st[8] += patient && itc >= {newton_max};\n    return last_step <= 1e-6 ? bound : 0.0;\n}}")
    src = _sub(src, "static int g6_candidates(const double *DQ_RESTRICT pose, double (*DQ_RESTRICT cq)[7], "
               "int *DQ_RESTRICT degenerate)\n{\n",
               "static int g6_candidates(const double *DQ_RESTRICT pose, double (*DQ_RESTRICT cq)[7], "
               "int *DQ_RESTRICT degenerate)\n{\n    st[0]++;\n")
    src = _sub(src, "    int nc = g6_candidates(pose, cq, &degen);\n",
               "    int nc = g6_candidates(pose, cq, &degen);\n    st[5] = degen & 1;\n")
    src = _sub(src, "        if (size >= 2) {\n            double m[144], basis[144], vv[144];",
               "        if (size >= 2) {\n            st[6]++;\n            double m[144], basis[144], vv[144];")
    src = _sub(src, "        a = e + 1;\n    }\n    return n;\n}", "        a = e + 1;\n    }\n    st[7] += n - nx;\n"
               "    return n;\n}")
    main = f"""
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
static double now(void) {{ struct timespec ts; clock_gettime(CLOCK_MONOTONIC, &ts); return ts.tv_sec + 1e-9 * ts.tv_nsec; }}
int main(int argc, char **argv) {{
    (void)argc;
    FILE *f = fopen(argv[1], "rb"); size_t n; if (fread(&n, sizeof n, 1, f) != 1) return 1;
    double *P = malloc(n * 8 * sizeof(double)); if (fread(P, sizeof(double), 8 * n, f) != 8 * n) return 1; fclose(f);
    double sols[16 * 6]; int counts, sing[16], degen;
    for (size_t i = 0; i < n; ++i) {{
        double best = 1e9;
        for (int r = 0; r < 5; ++r) {{
            memset(st, 0, sizeof st);
            double t0 = now();
            {ident}_ik_batch_general(1, P + 8 * i, sols, &counts, sing, &degen);
            double t1 = now() - t0; if (t1 < best) best = t1;
        }}
        printf("%.3f %d %d", best * 1e6, degen, counts);
        for (int k = 0; k < {len(COUNTERS)}; ++k) printf(" %ld", st[k]);
        printf("\\n");
    }}
    return 0;
}}
"""
    return files, head + src + main


def run(binary, poses, folder, tag):
    path = Path(folder) / f"{tag}.bin"
    with open(path, "wb") as f:
        f.write(np.array([len(poses)], dtype=np.uint64).tobytes())
        f.write(np.ascontiguousarray(poses, dtype=np.float64).tobytes())
    out = subprocess.run([binary, str(path)], capture_output=True, text=True, check=True).stdout
    a = np.array([[float(x) for x in line.split()] for line in out.splitlines()])
    return {"t": a[:, 0], "degen": a[:, 1] > 0, **{k: a[:, 3 + i] for i, k in enumerate(COUNTERS)}}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("robot", nargs="?", default="crx10ia")
    ap.add_argument("--random", type=int, default=1000)
    args = ap.parse_args(argv)
    robot = derive.load_robot(args.robot)
    lim = robot.limits
    qr = np.random.default_rng(1).uniform(np.maximum(lim[:, 0], -np.pi), np.minimum(lim[:, 1], np.pi),
                                          (args.random, 6))
    with tempfile.TemporaryDirectory() as d:
        files, src = counting_source(robot)
        for name, text in files.values():
            (Path(d) / name).write_text(text)
        (Path(d) / "counting.c").write_text(src)
        subprocess.run(["gcc", *c_flags(), "-o", str(Path(d) / "counting"), str(Path(d) / "counting.c"), "-lm"],
                       check=True)
        r = run(str(Path(d) / "counting"), reference.fk(robot, qr), d, "random")
        a = run(str(Path(d) / "counting"), reference.fk(robot, configurations(robot)), d, "axis")
    print(f"{robot.name}: random poses {len(r['t'])}, mean {r['t'].mean():.1f} us; axis-aligned {len(a['t'])}, "
          f"mean {a['t'].mean():.1f} us")
    near = a["cand"] > 1

    def row(name, m):
        if not m.any():
            print(f"  {name:44s}     0")
            return
        print(f"  {name:44s} {m.sum():5d}  mean {a['t'][m].mean():6.1f} us  share {a['t'][m].sum() / a['t'].sum():6.1%}"
              f"  Newton runs {a['runs'][m].mean():5.1f} ({a['iters'][m].mean():6.1f} iterations), carried back "
              f"{a['patient_runs'][m].mean():5.1f} ({a['patient_iters'][m].mean():6.1f}; {a['capped'][m].mean():.1f} at "
              f"the limit), clusters {a['clusters'][m].mean():.1f}, near-chain candidates {a['extra'][m].mean():.1f}")

    row("all axis-aligned", np.ones(len(a["t"]), dtype=bool))
    row("solved directly", ~near)
    row("through the nearby poses", near)
    row("  own elimination degenerate", near & (a["own_degen"] > 0))
    row("  only a (near-)singular solution", near & ~(a["own_degen"] > 0))
    row("flagged degenerate", a["degen"])
    cols = ["cand", "iters", "patient_iters"]
    x = np.concatenate([np.stack([a[c] for c in cols] + [a["runs"] + a["patient_runs"]], 1),
                        np.stack([r[c] for c in cols] + [r["runs"] + r["patient_runs"]], 1)])
    coef = np.linalg.lstsq(x, np.concatenate([a["t"], r["t"]]), rcond=None)[0]
    print("  least squares, us: per g6_candidates call %.1f, per Newton iteration %.3f, per carried-back iteration "
          "%.3f, per Newton run %.3f" % tuple(coef))
    if near.any():
        parts = (x[:len(a["t"])][near] * coef).mean(0)
        print("  through the nearby poses, mean us: eliminations %.1f, own Newton %.1f, carried back %.1f, "
              "runs' checks %.1f" % tuple(parts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
