"""First use of a new robot of a known class (issue 30, item 4 "fast first use").

Each measurement runs in a fresh Python process with an empty user cache ($DQ_DERIVE_CACHE set
to a new temporary folder), so it includes the import, the IK program (the class's shipped
program with the robot's numbers substituted), the kernels' rendering and the C compile:

* ``kernels``: ``derive.kernels(robot, "c")`` for a copy of a library robot with one length
  changed, one per class: UR (ur5 with d1 = 0.5), spherical wrist / OPW (irb120 with the upper
  arm 0.280 m), SRS (iiwa14 with d_se = 0.430), Panda (panda with d5 = 0.390); target <= 10 s;
* ``limit edit``: the same robot with one joint limit edited, in a process whose user cache
  already holds the first one's kernels: the kernels are rendered and compiled again, nothing is
  derived (the identity leaves the limits out);
* ``classify fresh``: ``import derive`` + ``derive.classify`` of a URDF (tests/data/iiwa14.urdf,
  and the UR5 exported as a URDF, whose closed form is found by relating it to the library's UR
  robots; target <= 2 s) and the same through the command line (``dq-derive classify FILE``);
* ``classify warm``: ``derive.classify`` in one process of five copies of the URDF, each with
  its first joint moved (another robot each time, the parse included; target <= 0.3 s).

Run: python benchmarks/bench_first_use.py [--only ur,sw,srs,panda,classify]
Prints one line per measurement: wall time and CPU time (user + system, compiler included) of
the child process; on a shared machine the CPU time is the steadier figure.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ROBOTS = ROOT / "derive" / "robots"
URDF = ROOT / "tests" / "data" / "iiwa14.urdf"

#: (class, library file, text replaced, replacement): one length changed, the name changed
VARIANTS = [
    ("ur", "ur5.yaml", "d1: 0.089159", "d1: 0.5"),
    ("sw", "irb120.yaml", "link: [0, 0, 0.270]", "link: [0, 0, 0.280]"),
    ("srs", "iiwa14.yaml", "d_se: 0.420", "d_se: 0.430"),
    ("panda", "panda.yaml", "d5: 0.384", "d5: 0.390"),
]


def variant(folder: Path, cls: str, src: str, old: str, new: str, limit: bool = False) -> Path:
    text = (ROBOTS / src).read_text(encoding="utf-8")
    assert old in text, (src, old)
    text = text.replace(old, new, 1)
    text = re.sub(r"^name: .*$", f"name: new-{cls}", text, count=1, flags=re.M)
    if limit:       # the first joint's limits edited (their second number written otherwise)
        text = re.sub(r"limits: \[([^,\]]+), ([^\]]+)\]", lambda m: f"limits: [{m.group(1)}, ({m.group(2)})*0.9]",
                      text, count=1)
    path = folder / f"new-{cls}{'-limit' if limit else ''}.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run(code: str, cache: Path, argv=None) -> str:
    """Wall and CPU time (user + system, the compiler's included) of one child process."""
    env = dict(os.environ, DQ_DERIVE_CACHE=str(cache))
    cmd = argv or [sys.executable, "-c", code]
    t, c = time.perf_counter(), _cpu()
    res = subprocess.run(cmd, env=env, capture_output=True, text=True)
    dt, dc = time.perf_counter() - t, _cpu() - c
    if res.returncode != 0:
        raise SystemExit(f"failed: {' '.join(cmd)}\n{res.stderr[-2000:]}")
    return f"{dt:7.2f} s wall, {dc:6.2f} s CPU"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", default="ur,sw,srs,panda,classify")
    args = ap.parse_args(argv)
    only = set(args.only.split(","))
    tmp = Path(tempfile.mkdtemp(prefix="dq-first-use-"))
    try:
        for cls, src, old, new in VARIANTS:
            if cls not in only:
                continue
            cache = tmp / f"cache-{cls}"
            path = variant(tmp, cls, src, old, new)
            dt = run(f"import derive; derive.kernels({str(path)!r}, 'c')", cache)
            print(f"kernels c, new {cls:5s} robot, empty cache: {dt}")
            edited = variant(tmp, cls, src, old, new, limit=True)
            dt = run(f"import derive; derive.kernels({str(edited)!r}, 'c')", cache)
            print(f"kernels c, new {cls:5s} robot, one limit edited: {dt}")
        if "classify" in only:
            cache = tmp / "cache-classify"
            # a 6R URDF too: the UR5 exported (its closed form found through the library's UR5)
            ur5 = tmp / "ur5-export.urdf"
            run("", cache, [sys.executable, "-m", "derive", "export", "ur5", "--urdf", str(ur5)])
            for urdf in (URDF, ur5):
                dt = run(f"import derive; derive.classify({str(urdf)!r})", cache)
                print(f"import derive + classify {urdf.name} (fresh process): {dt}")
                dt = run("", cache, [sys.executable, "-m", "derive", "classify", str(urdf)])
                print(f"dq-derive classify {urdf.name} (fresh process): {dt}")
            # each copy another robot (its first joint 0.1 mm higher per copy), so nothing of
            # the previous ones is reused but what does not depend on the robot
            code = (f"import time, derive\n"
                    f"from pathlib import Path\n"
                    f"text = Path({str(URDF)!r}).read_text()\n"
                    f"assert 'xyz=\"0.0 0 0.1475\"' in text\n"
                    f"derive.classify({str(URDF)!r})\n"
                    f"ts = []\n"
                    f"for i in range(5):\n"
                    f"    p = Path({str(tmp)!r}) / f'copy{{i}}.urdf'\n"
                    f"    p.write_text(text.replace('xyz=\"0.0 0 0.1475\"', f'xyz=\"0.0 0 {{0.1476 + i * 1e-4}}\"'))\n"
                    f"    t = time.perf_counter(); derive.classify(str(p)); ts.append(time.perf_counter() - t)\n"
                    f"print(min(ts), sorted(ts)[2])\n")
            env = dict(os.environ, DQ_DERIVE_CACHE=str(cache))
            out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
            if out.returncode != 0:
                raise SystemExit(out.stderr[-2000:])
            best, median = (float(x) for x in out.stdout.split())
            print(f"classify {URDF.name} in a warm process (another robot each time): "
                  f"median {median:.3f} s, fastest {best:.3f} s")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
