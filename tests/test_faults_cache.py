"""The cache's fault suite (issue 33, docs/reliability.md "Cache"): damaged, deleted and
write-protected cache entries of every kind (the pure-Python and numpy kernel sources, the C
kernel source, the C shared library loaded by ctypes, the CPython extension), and concurrent
builds. Each case runs in a fresh subprocess, so that a crash shows as a negative return code (a
bus error is SIGBUS) and a hang as a timeout; the outcome must be the right answer (FK compared
with the numpy reference of derive.reference, computed here in the test process) or a one-line
DeriveError, never a crash, a hang or a traceback. Every process uses a cache of its own under
tmp_path (DQ_DERIVE_CACHE), never the user's.

The robot is a two-joint variant of the library's kunze-2r (other lengths, so it is not the
library robot and has no shipped kernels): its derivation takes well under a second, and its C
kernels compile in about a second (DQ_DERIVE_CFLAGS=-O0)."""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from derive import reference
from derive.model.robot import LIBRARY_DIR

TIMEOUT = 180          # s per subprocess: a hang fails the test instead of the run
Q = [0.3, -0.7]

#: The child: loads the kernels of one backend and prints FK at Q as JSON; a DeriveError is
#: printed as the CLI would (one line) with exit code 2. ctypes: the shared library through the
#: C API of the generated header (<prefix>_fk_batch(n, q, out)), without the extension.
CHILD = r"""
import ctypes, json, sys
import numpy as np
import derive
from derive.errors import DeriveError
robot, backend = sys.argv[1], sys.argv[2]
q = np.array(json.loads(sys.argv[3]))
try:
    k = derive.kernels(robot, "c" if backend == "ctypes" else backend)
    if backend == "ctypes":
        lib = ctypes.CDLL(str(k.library))
        f = getattr(lib, k._manifest["prefix"] + "_fk_batch")
        f.restype, f.argtypes = None, [ctypes.c_size_t, ctypes.c_void_p, ctypes.c_void_p]
        qq = np.ascontiguousarray(q[None, :]); out = np.empty((1, 8))
        f(1, qq.ctypes.data, out.ctypes.data)
        out = out[0]
    else:
        out = k.fk(q)
    print(json.dumps({"fk": list(map(float, out)), "folder": str(k.folder),
                      "ext": backend == "c" and k._ext is not None,
                      "ext_file": getattr(k._ext, "__file__", None) if backend == "c" else None}))
except DeriveError as exc:
    print(f"error: {exc}", file=sys.stderr)
    sys.exit(2)
"""


def _env(cache, **extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("DQ_DERIVE_CACHE", "XDG_CACHE_HOME")}
    env.update(DQ_DERIVE_CACHE=str(cache), DQ_DERIVE_CFLAGS="-std=c99 -O0", **extra)
    return env


def _start(robot, backend, env, q=Q, **kw):
    return subprocess.Popen([sys.executable, "-c", CHILD, str(robot), backend, json.dumps(q)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def _finish(proc):
    try:
        out, err = proc.communicate(timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail(f"the child hung (more than {TIMEOUT} s)")
    assert proc.returncode >= 0, f"the child crashed (signal {-proc.returncode}):\n{err}"
    assert "Traceback" not in err, err
    return proc.returncode, out, err


def _run(robot, backend, env, q=Q, **kw):
    return _finish(_start(robot, backend, env, q, **kw))


def _right(out, robot, q=Q) -> dict:
    res = json.loads(out)
    want = reference.fk(str(robot), np.array(q))
    got = np.array(res["fk"])
    assert min(np.abs(got - want).max(), np.abs(got + want).max()) < 1e-12
    return res


@pytest.fixture(scope="module")
def robot(tmp_path_factory) -> Path:
    text = (LIBRARY_DIR / "kunze-2r.yaml").read_text().replace("s: 3, a: 1,", "s: 2, a: 1.5,")
    text = text.replace("name: kunze-2r", "name: fault-2r")
    assert "s: 2, a: 1.5," in text
    path = tmp_path_factory.mktemp("robot") / "fault-2r.yaml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def primed(robot, tmp_path_factory) -> tuple:
    """A cache holding every artifact kind of the robot (kernel sources, extension, library),
    made at a fixed path and saved: (that path, the saved copy). The extension includes the
    kernel source by its path, so a copy is put back at the same path (:func:`cache`)."""
    top = tmp_path_factory.mktemp("primed")
    cache = top / "cache"
    for backend in ("numpy", "python", "c", "ctypes"):
        rc, out, err = _run(robot, backend, _env(cache))
        assert rc == 0, err
        _right(out, robot)
    shutil.copytree(cache, top / "saved")
    return cache, top / "saved"


@pytest.fixture
def cache(primed) -> Path:
    """The primed cache, put back as it was made (the tests of one worker run one at a time)."""
    path, saved = primed
    if path.exists():
        shutil.rmtree(path)
    shutil.copytree(saved, path)
    return path


def _entries(cache: Path) -> dict:
    """{kind: path} of the artifacts in a cache."""
    kernels = next(p for p in cache.glob("v*/*") if p.is_dir())
    build = cache / "build"
    return {"python": next(kernels.glob("*_kinematics.py")),
            "numpy": next(kernels.glob("*_kinematics_numpy.py")),
            "c_source": next(kernels.glob("*_kinematics.c")),
            "extension": next(build.glob("_dqk_*.so")),
            "library": next(build.glob("lib*.so"))}


#: which backend loads each artifact kind
LOADED_BY = {"python": "python", "numpy": "numpy", "c_source": "c", "extension": "c", "library": "ctypes"}


def _damage(path: Path, fault: str) -> None:
    data = path.read_bytes()
    if fault == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif fault == "empty":
        path.write_bytes(b"")
    elif fault in ("garbage", "garbage-with-checksum"):
        path.write_bytes(np.random.default_rng(33).integers(0, 256, len(data), dtype=np.uint8).tobytes())
        if fault == "garbage-with-checksum":   # the manifest agrees: only loading can tell
            import hashlib
            manifest = path.parent / "manifest.json"
            m = json.loads(manifest.read_text())
            m["sha256"][path.name] = hashlib.sha256(path.read_bytes()).hexdigest()
            manifest.write_text(json.dumps(m))
    elif fault == "deleted":
        path.unlink()
    else:
        raise AssertionError(fault)


#: (kind, fault): every kind truncated, loaded despite a matching checksum, and (but for the
#: two kernel modules, whose loss is the C source's) deleted; the extension also empty, the two
#: shared libraries also overwritten with random bytes (the cases of issue 33)
CASES = ([(k, "truncated") for k in LOADED_BY] + [(k, "garbage-with-checksum") for k in LOADED_BY]
         + [(k, "deleted") for k in ("c_source", "extension", "library")]
         + [("extension", "empty"), ("extension", "garbage"), ("library", "garbage")])


@pytest.mark.parametrize("kind, fault", CASES)
def test_damaged_entry_is_made_again(robot, cache, kind, fault):
    """A damaged or missing entry: the right answer, and (but for a deleted one) one line on
    stderr naming the file and why it is made again; after a truncation, the next process loads
    the new entry without a word. "garbage-with-checksum" passes the checksum and fails to load
    (import, dlopen): it is made again all the same."""
    backend = LOADED_BY[kind]
    path = _entries(cache)[kind]
    _damage(path, fault)
    rc, out, err = _run(robot, backend, _env(cache))
    assert rc == 0, err
    res = _right(out, robot)
    if backend == "c":
        assert res["ext"], err          # the extension again, not a silent fallback to ctypes
    if fault != "deleted":
        said = [line for line in err.splitlines() if line.startswith("dq-derive:")]
        assert said and path.name in said[0], err
        assert ("checksum" if fault != "garbage-with-checksum" else "did not") in said[0], err
    if fault == "truncated" and kind in ("numpy", "extension", "library"):
        rc, out, err = _run(robot, backend, _env(cache))
        assert rc == 0 and not err.strip(), err
        _right(out, robot)


def test_damaged_manifest(robot, cache):
    """A manifest that is not JSON: the kernels are derived again, the right answer."""
    manifest = _entries(cache)["numpy"].parent / "manifest.json"
    manifest.write_text('{"id": "trunc')
    rc, out, err = _run(robot, "numpy", _env(cache))
    assert rc == 0, err
    _right(out, robot)
    assert "deriving them" in err


def test_concurrent_fresh_builds(robot, tmp_path):
    """Four processes on an empty cache: one derives the kernels (and one compiles each
    library), the others wait for it; all four give the right answer."""
    cache = tmp_path / "cache"
    for backend in ("numpy", "c"):
        procs = [_start(robot, backend, _env(cache)) for _ in range(4)]
        results = [_finish(p) for p in procs]
        for rc, out, err in results:
            assert rc == 0, err
            _right(out, robot)
        errs = [err for _, _, err in results]
        if backend == "numpy":
            assert sum("deriving them" in e for e in errs) == 1, errs
    build = json.loads((cache / "build" / "manifest.json").read_text())["sha256"]
    assert len(build) == 1 and sorted(p.name for p in (cache / "build").glob("*.so")) == sorted(build)
    assert not list(cache.rglob("*.tmp")) and not list(cache.rglob("*.tmp.c"))


def test_cache_path_unusable(robot, tmp_path):
    """The cache's path cannot be a folder (a file is in the way: every write is an OSError):
    one warning, the derivation and the build go to a temporary cache, the right answer; the
    kernels are there, in the folder the child loaded them from."""
    blocker = tmp_path / "blocker"
    blocker.write_text("not a folder")
    for backend in ("numpy", "c"):
        rc, out, err = _run(robot, backend, _env(blocker / "cache", TMPDIR=str(tmp_path)))
        assert rc == 0, err
        res = _right(out, robot)
        warnings = [line for line in err.splitlines() if "cannot be written" in line]
        assert len(warnings) == 1, err
        folder = Path(res["folder"])
        assert folder.is_relative_to(tmp_path) and not folder.is_relative_to(blocker)
        assert (folder / "manifest.json").is_file()


def _read_only_runner(cache: Path):
    """How to run a child that sees ``cache`` write-protected: for a user, the folder's write
    permissions removed (undone by the returned cleanup); for root, whom permissions do not
    stop, a read-only bind mount of it in a mount namespace of the child's own (``unshare``),
    which gives the EROFS of a read-only file system. None where neither can be had."""
    if os.geteuid() != 0:
        paths = [cache, *cache.rglob("*")]
        for p in paths:
            p.chmod(stat.S_IMODE(p.stat().st_mode) & ~0o222)

        def undo():
            for p in paths:
                p.chmod(stat.S_IMODE(p.stat().st_mode) | 0o200)
        return [], undo
    unshare = shutil.which("unshare")
    if unshare is None:
        return None
    wrap = [unshare, "-m", "sh", "-c", 'mount --bind -o ro "$0" "$0" && exec "$@"', str(cache)]
    probe = subprocess.run([*wrap, "sh", "-c", 'touch "$0"/probe', str(cache)],
                           capture_output=True, text=True, timeout=60)
    if probe.returncode == 0 or "Read-only" not in probe.stderr:
        (cache / "probe").unlink(missing_ok=True)
        return None
    return wrap, lambda: None


@pytest.mark.parametrize("populated", [False, True, "ur5"])
def test_read_only_cache(robot, primed, tmp_path, populated, request):
    """A write-protected cache: populated, it is read, and nothing is written and nothing said;
    empty, the derivation goes to a temporary cache with one warning, never an OSError; "ur5":
    the library UR5's C backend (shipped sources, its extension compiled into the temporary
    cache; the case of issue 33, an OSError before)."""
    q = Q
    if populated == "ur5":
        robot, q = "ur5", [0.3, -1.1, 1.4, -0.2, 0.9, 2.0]
        populated = False
    if populated:
        cache = request.getfixturevalue("cache")
    else:
        cache = tmp_path / "cache"
        cache.mkdir()
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    before = {str(p): p.stat().st_mtime_ns for p in cache.rglob("*")}
    runner = _read_only_runner(cache)
    if runner is None:
        pytest.skip("no way to write-protect a folder for root here (no unshare with mount rights)")
    wrap, undo = runner
    try:
        for backend in ("numpy", "c") if robot != "ur5" else ("c",):
            env = _env(cache, TMPDIR=str(tmp))
            proc = subprocess.Popen([*wrap, sys.executable, "-c", CHILD, str(robot), backend, json.dumps(q)],
                                    env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            rc, out, err = _finish(proc)
            assert rc == 0, err
            res = _right(out, robot, q)
            if populated:
                assert not err.strip(), err
                assert Path(res["folder"]).is_relative_to(cache)
            else:
                assert err.count("cannot be written") == 1, err
                made = res["ext_file"] if robot == "ur5" else res["folder"]
                assert Path(made).is_relative_to(tmp), err
                if backend == "c":
                    assert res["ext"], err
    finally:
        undo()
    assert {str(p): p.stat().st_mtime_ns for p in cache.rglob("*")} == before


def test_wait_is_bounded(tmp_path, monkeypatch, capsys):
    """A process that waits for a lock held by a stuck one gives up after the budget plus its
    grace (here 0.5 + 0.5 s) with a DeriveError, and says once that it waits."""
    import fcntl
    import time

    from derive.cache import build_lock
    from derive.errors import DeriveError
    monkeypatch.setenv("DQ_DERIVE_BUDGET", "0.5")
    folder = tmp_path / "robot"
    (tmp_path / "robot.lock").touch()
    with open(tmp_path / "robot.lock") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        t0 = time.monotonic()
        with pytest.raises(DeriveError, match="waited more than 1 s"):
            with build_lock(folder, "the kernels of a test"):
                pytest.fail("the lock was taken twice")
        assert 0.9 < time.monotonic() - t0 < 30
    assert capsys.readouterr().err.count("waiting for another process") == 1
    with build_lock(folder, "the kernels of a test"):      # released: taken at once
        pass


def test_keys_cover_versions_and_compiler(tmp_path, monkeypatch):
    """The kernel folders' code digest changes with sympy's and numpy's versions; the C
    library's name with the compiler (path and version), besides the source and the flags."""
    from derive import cache
    from derive.codegen import loader

    def digest_with(versions):
        monkeypatch.setattr(cache, "package_version", lambda dist: versions.get(dist, ""))
        cache.clear_memory(["code-digest"])
        return cache.code_digest()

    try:
        base = digest_with({"sympy": "1.13", "numpy": "2.1"})
        assert digest_with({"sympy": "1.13", "numpy": "2.1"}) == base
        assert digest_with({"sympy": "1.14", "numpy": "2.1"}) != base
        assert digest_with({"sympy": "1.13", "numpy": "2.2"}) != base
        # a template's contents, under the same file name
        edited = tmp_path / "templates" / "kinematics.c.j2"
        edited.parent.mkdir()
        edited.write_text("// another template\n")
        real = cache._template_files()
        assert real and "kinematics.c.j2" in [p.name for p in real]
        monkeypatch.setattr(cache, "_template_files", lambda: [p for p in real if p.name != edited.name] + [edited])
        assert digest_with({"sympy": "1.13", "numpy": "2.1"}) != base
    finally:
        monkeypatch.undo()
        cache.clear_memory(["code-digest"])

    monkeypatch.setenv("DQ_DERIVE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("DQ_DERIVE_CFLAGS", "-std=c99 -O0")
    src = tmp_path / "tiny.c"
    src.write_text("int tiny_answer(void) { return 42; }\n")
    lib1 = loader._compile(src, "tiny")
    monkeypatch.setattr(loader, "_compiler_key", lambda: "another compiler 99.1")
    lib2 = loader._compile(src, "tiny")
    assert lib1 != lib2 and lib1.is_file() and lib2.is_file()
    sums = json.loads((lib1.parent / "manifest.json").read_text())["sha256"]
    import hashlib
    assert sums == {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in (lib1, lib2)}
