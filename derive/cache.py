"""The one cache of dq-derive: results in memory and artifacts on disk, keyed by robot identity.

Everything dq-derive computes for a robot (the symbolic derivation, the IK program, the
emitted kernel sources, compiled libraries, CasADi functions) depends only on the robot's
identity, ``Robot.id`` (:mod:`derive.model.identity`), so that is the key:

* in memory, :func:`memo` keeps one result per (kind, key) for the life of the process;
* on disk, artifacts are looked for first in the ``generated/<robot>/`` folders shipped with
  the package (each has a ``manifest.json`` that records the identity it was made from,
  :func:`shipped`), then in the user cache (:func:`user_folder`), and made only when neither
  has them.

User cache: ``$DQ_DERIVE_CACHE``, else ``$XDG_CACHE_HOME/dq-derive``, else
``~/.cache/dq-derive``. Its artifact folders sit below a folder named after the dq-derive
version and a digest of the package's code and templates, so an artifact made by other code
is never loaded; compiled libraries are named by a digest of their source, the compiler
flags and the CPU.

Integrity (docs/reliability.md, "Cache"): every file this module or the loader writes into the
user cache is written to a temporary file of the writing process and renamed into place
(``os.replace``), and recorded with its SHA-256 in the folder's manifest (``"sha256"``); it is
verified before it is loaded, imported or ``dlopen``ed, and an entry that fails the check, or
fails to load, is made again with one line on stderr saying why (:func:`notice`). One process
makes an entry while the others wait for it (:func:`build_lock`). A user cache that cannot be
written (read-only, or its path unusable) is replaced for the rest of the process by a temporary
one, with a warning (:func:`writable_root`); a finished derivation is stored there, never lost.
"""

from __future__ import annotations

import gc
import hashlib
import json
import os
import signal
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from importlib import resources
from pathlib import Path

from derive._version import __version__
from derive.errors import BudgetError, DeriveError

MANIFEST = "manifest.json"

_MEMO: dict = {}


def memo(kind: str, key, build):
    """``build()`` once per (kind, key) in this process; ``key`` is a robot identity or a
    tuple that starts with one."""
    k = (kind, key)
    if k not in _MEMO:
        _MEMO[k] = build()
    return _MEMO[k]


def peek(kind: str, key):
    """The result of (kind, key) if it was built in this process, else None."""
    return _MEMO.get((kind, key))


def clear_memory(kinds=None) -> None:
    """Forget the in-memory results of the given kinds (all when None), and the index of the
    shipped folders; tests use it to load artifacts as a fresh process would."""
    for k in [k for k in _MEMO if kinds is None or k[0] in kinds or k[0] == "shipped-index"]:
        del _MEMO[k]


# --------------------------------------------------------------------------- #
# Folders
# --------------------------------------------------------------------------- #
def user_root() -> Path:
    """The configured user cache: ``$DQ_DERIVE_CACHE``, else ``$XDG_CACHE_HOME/dq-derive``, else
    ``~/.cache/dq-derive`` (whether or not it can be written: see :func:`writable_root`)."""
    base = os.environ.get("DQ_DERIVE_CACHE")
    if base:
        return Path(base)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "dq-derive"


#: {configured root: temporary root} of the caches found unwritable in this process
_FALLBACK: dict = {}


def notice(message: str) -> None:
    """One line on stderr (a cache entry made again, a fallback, a wait), prefixed "dq-derive:"."""
    print(f"dq-derive: {' '.join(str(message).split())}", file=sys.stderr, flush=True)


def fallback_root(reason=None) -> Path:
    """The temporary cache of this process that stands in for the configured one
    (:func:`user_root`) once that cannot be written; made, with a warning naming ``reason``, on
    the first call. It is not deleted at exit (its path is in the warning)."""
    root = user_root()
    if root not in _FALLBACK:
        tmp = Path(tempfile.mkdtemp(prefix="dq-derive-cache-"))
        _FALLBACK[root] = tmp
        why = reason.strerror if isinstance(reason, OSError) and reason.strerror else reason
        notice(f"warning: the cache {root} cannot be written ({why}); this process uses the "
               f"temporary cache {tmp} instead")
    return _FALLBACK[root]


def roots() -> list:
    """The cache roots looked in, in order: the configured one, then this process's temporary
    one if it has one."""
    root = user_root()
    return [root] + ([_FALLBACK[root]] if root in _FALLBACK else [])


def writable_root() -> Path:
    """The root that writes go to: the configured one if its folder can be made and written,
    else (with a warning, once) a temporary one (:func:`fallback_root`)."""
    root = user_root()
    if root in _FALLBACK:
        return _FALLBACK[root]
    try:
        root.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=root, prefix=".probe-")    # the real errno, if any
        os.close(fd)
        os.unlink(probe)
        return root
    except OSError as exc:
        return fallback_root(exc)


def code_digest() -> str:
    """A digest of what made an artifact: the package's Python files and templates (their
    paths inside the package and their contents) and the versions of sympy and numpy."""
    return memo("code-digest", None, _code_digest)


def _code_digest() -> str:
    h = hashlib.sha256()
    pkg = Path(__file__).resolve().parent
    files = sorted(pkg.rglob("*.py")) + sorted(p for p in _template_files())
    for f in files:
        try:
            name = f.resolve().relative_to(pkg).as_posix()
        except ValueError:                  # a template outside the package folder
            name = "templates/" + f.name
        h.update(name.encode() + b"\0")
        h.update(f.read_bytes())
    for dist in ("sympy", "numpy"):
        h.update(f"{dist}={package_version(dist)}\0".encode())
    return h.hexdigest()[:12]


def package_version(dist: str) -> str:
    """The installed version of a distribution ("" when it is not installed)."""
    from importlib import metadata
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return ""


def _template_files():
    """The templates the emitters render: the project's ``templates/`` folder in a source tree
    (as :func:`derive.codegen.templates.template_environment` finds it), else the packaged
    ``derive.templates``."""
    source = Path(__file__).resolve().parents[1] / "templates"
    if source.is_dir():
        return sorted(source.glob("*.j2"))
    try:
        root = resources.files("derive.templates")
        return [Path(str(p)) for p in root.iterdir() if p.name.endswith(".j2")]
    except (ModuleNotFoundError, TypeError):
        return []


def user_folder(robot_id: str, root: Path | None = None) -> Path:
    """The folder of one robot's artifacts (not created) in the configured user cache, or in
    ``root``."""
    return (user_root() if root is None else root) / f"v{__version__}-{code_digest()}" / robot_id


def user_folders(robot_id: str) -> list:
    """The folders of one robot's artifacts in every root looked in (:func:`roots`)."""
    return [user_folder(robot_id, r) for r in roots()]


def build_folder(root: Path | None = None) -> Path:
    """Where compiled libraries go (named by the digest of what they are built from), in the
    configured user cache or in ``root``."""
    return (user_root() if root is None else root) / "build"


def build_folders() -> list:
    """The build folders of every root looked in (:func:`roots`)."""
    return [build_folder(r) for r in roots()]


def generated_root() -> Path | None:
    """The ``generated/`` folder shipped with the package (None when it is not there)."""
    try:
        root = Path(str(resources.files("derive.generated")))
    except (ModuleNotFoundError, TypeError):
        root = Path(__file__).resolve().parent.parent / "generated"
    return root if root.is_dir() else None


def shipped_index() -> dict:
    """{robot identity: folder} of the shipped ``generated/<robot>/`` folders (read once), and
    {"<identity>-L<limits key>": folder} for the folders whose manifest records the joint
    limits' key (kernels: two robots that differ only in their limits, the Panda and the FR3,
    share the identity but not the kernels); the first folder in name order where two share a
    key."""
    return memo("shipped-index", None, _shipped_index)


def _shipped_index() -> dict:
    root = generated_root()
    index = {}
    if root is not None:
        for m in sorted(root.glob(f"*/{MANIFEST}")):
            try:
                data = json.loads(m.read_text(encoding="utf-8"))
                keys = [data["id"]] + ([f"{data['id']}-L{data['limits']}"] if "limits" in data else [])
            except (OSError, ValueError, KeyError, TypeError):
                continue
            for key in keys:
                index.setdefault(key, m.parent)
    return index


def read_manifest(folder: Path) -> dict:
    path = Path(folder) / MANIFEST
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def write_manifest(folder: Path, data: dict) -> Path:
    """Merge ``data`` into the folder's manifest (sorted keys, so the bytes are stable). Safe
    when several processes write the same folder: the read-merge-write holds a lock on the
    folder, and the file is replaced atomically from a temporary file of this process."""
    path = Path(folder) / MANIFEST
    with locked(folder):
        old = read_manifest(folder)
        if old.get("id") not in (None, data.get("id")):
            old = {}
        merged = {**old, **data}
        for k in ("files", "sha256"):
            if k in old and k in data:
                merged[k] = {**old[k], **data[k]}
        text = json.dumps(merged, indent=2, sort_keys=True) + "\n"
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
            tmp.write_text(text, encoding="utf-8")
            os.replace(tmp, path)
    return path


@contextmanager
def locked(path):
    """An exclusive advisory lock (flock) on an existing file or folder itself, so no lock file
    is left beside it, held for the ``with`` block; other processes locking the same path wait.
    No lock where flock is not available."""
    try:
        import fcntl
        fd = os.open(path, os.O_RDONLY)
    except (ImportError, OSError):
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:
            pass
        yield
    finally:
        os.close(fd)          # closing the descriptor releases the lock


def claim_folder(folder, robot_id: str, name: str, force: bool = False) -> None:
    """Refuse (DeriveError) to write a robot's outputs into a folder whose manifest records
    another robot's identity, for example a file named ``ur5`` with other numbers written into
    ``generated/`` over the library UR5's shipped artifacts; ``force`` allows it
    (``dq-derive generate`` regenerating the library's own folders)."""
    held = read_manifest(Path(folder)).get("id")
    if held and held != robot_id and not force:
        raise DeriveError(
            f"{folder} holds the outputs of another robot (identity {held}); {name!r} has identity "
            f"{robot_id}. Choose another --out, or give the robot another name")


def sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def verify(folder, names) -> str | None:
    """None when every file of ``names`` in ``folder`` is there with the SHA-256 its manifest
    records, else why not (one phrase)."""
    sums = read_manifest(Path(folder)).get("sha256", {})
    for name in names:
        path = Path(folder) / name
        if not path.is_file():
            return f"{path} is missing"
        if name not in sums:
            return f"{path} has no checksum in its manifest"
        try:
            actual = sha256_file(path)
        except OSError as exc:
            return f"{path} cannot be read ({exc.strerror})"
        if actual != sums[name]:
            return f"{path} does not match its checksum (changed, truncated or corrupt)"
    return None


def write_atomic(path, content) -> str:
    """Write ``content`` (text or bytes) to ``path`` through a temporary file of this process
    renamed into place, so no reader sees a partial file; returns its SHA-256."""
    path = Path(path)
    data = content if isinstance(content, bytes) else content.encode("utf-8")
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise
    return hashlib.sha256(data).hexdigest()


def record(folder, names) -> None:
    """Record the SHA-256 of files already in ``folder`` (written there atomically, for example
    a compiler's output renamed into place) in its manifest."""
    write_manifest(folder, {"sha256": {n: sha256_file(Path(folder) / n) for n in names}})


def find_artifact(robot_id: str, role: str) -> Path | None:
    """The file of ``role`` (for example "c_source", "casadi/fk") for a robot identity: first
    a shipped folder, then the user cache (verified against its manifest's checksum: an entry
    that fails is reported and skipped, :func:`verify`); None when none has it."""
    shipped_folder = shipped_index().get(robot_id)
    for folder in [shipped_folder, *user_folders(robot_id)]:
        if folder is None:
            continue
        name = read_manifest(folder).get("files", {}).get(role)
        if not name or not (folder / name).is_file():
            continue
        if folder != shipped_folder:
            why = verify(folder, [name])
            if why:
                notice(f"{why}: making it again")
                continue
        return folder / name
    return None


def store_artifacts(robot_id: str, files: dict, meta: dict) -> Path:
    """Write {role: (file name, text or bytes)} into the user cache, each atomically, and record
    them and their checksums in its manifest; returns the folder. Where the user cache cannot be
    written, they go to the temporary cache of this process (:func:`fallback_root`), never lost."""
    try:
        return _store(user_folder(robot_id, writable_root()), robot_id, files, meta)
    except OSError as exc:
        if user_root() in _FALLBACK:
            raise DeriveError(f"the artifacts of {robot_id} cannot be stored even in the temporary "
                              f"cache {_FALLBACK[user_root()]} ({exc})") from None
        return _store(user_folder(robot_id, fallback_root(exc)), robot_id, files, meta)


def _store(folder: Path, robot_id: str, files: dict, meta: dict) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    names, sums = {}, {}
    for role, (name, content) in files.items():
        sums[name] = write_atomic(folder / name, content)
        names[role] = name
    write_manifest(folder, {**meta, "id": robot_id, "files": names, "sha256": sums})
    return folder


@contextmanager
def build_lock(folder, what: str):
    """Hold the lock of ``folder`` (a file ``<folder>.lock`` beside it, so that the folder's own
    lock stays free for :func:`write_manifest`) while this process makes ``what``; a process
    that finds it held says so on stderr once and waits, polling, up to the time budget plus
    a grace of as long again (at most a minute), then raises DeriveError. After the ``with``, a waiter looks for the finished
    entry before it makes one itself."""
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
        fd = os.open(folder.with_name(folder.name + ".lock"), os.O_RDWR | os.O_CREAT, 0o666)
    except (ImportError, OSError):
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            notice(f"waiting for another process that is making {what}")
            wait = budget_seconds() + min(60.0, budget_seconds())
            limit = time.monotonic() + wait
            while True:
                time.sleep(0.1)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() > limit:
                        raise DeriveError(f"waited more than {wait:g} s for another "
                                          f"process making {what} (lock on {folder}); "
                                          "is one stuck?") from None
        except OSError:
            pass                  # no locks on this file system: proceed unlocked
        yield
    finally:
        os.close(fd)              # closing the descriptor releases the lock


# --------------------------------------------------------------------------- #
# Progress and the time budget of a derivation
# --------------------------------------------------------------------------- #
#: Default time budget of one derivation (s); DQ_DERIVE_BUDGET overrides it.
DEFAULT_BUDGET = 600.0

_TASKS: list = []


def budget_seconds() -> float:
    raw = os.environ.get("DQ_DERIVE_BUDGET")
    if not raw:
        return DEFAULT_BUDGET
    try:
        value = float(raw)
    except ValueError:
        raise DeriveError(f"DQ_DERIVE_BUDGET={raw!r} is not a number of seconds") from None
    if not value > 0:
        raise DeriveError(f"DQ_DERIVE_BUDGET={raw!r} must be a positive number of seconds")
    return value


@contextmanager
def task(label: str, progress: bool = True):
    """A long derivation: ``step`` lines go to stderr with the elapsed time, and
    :func:`check` raises DeriveError once the budget (:func:`budget_seconds`) is spent."""
    entry = {"label": label, "t0": time.perf_counter(), "budget": budget_seconds(), "progress": progress}
    _TASKS.append(entry)
    alarm = None
    try:
        alarm = _arm_alarm(entry)
        yield entry
        if entry.get("stopped"):
            # the timer's BudgetError was caught on the way (an ``except DeriveError`` that chose
            # another path): what was made after it is not trusted, so the task fails
            check()
    finally:
        _disarm_alarm(alarm)
        _TASKS.pop()


# The budget also holds inside one long sympy call (expand, factor, simplify of a long chain),
# where no step() or check() runs: the outermost task arms an interval timer (SIGALRM) for its
# budget, and the handler runs check(), which raises DeriveError in the interrupted frame. sympy
# is pure Python, so the signal is handled between two bytecodes of the call. Only the main
# thread receives signals; in another thread (or without SIGALRM) the checks in the loops remain.
# The signal can land in code where the interpreter drops an exception (a gc callback such as
# hypothesis's, a __del__, a weakref finalizer: "Exception ignored"); there the handler only
# marks the tasks stopped and looks again every _ALARM_RETRY s, so the error is raised in the
# derivation's own code as soon as it runs again.
_ALARM_GRACE = 0.05
#: A budget this long (s, about 30 years; inf included) arms no timer: setitimer cannot hold it
_ALARM_MAX = 1e9


#: While the interrupted code is one whose exceptions the interpreter drops (:func:`_dropping`),
#: the handler looks again this often (s) until the derivation's own code runs
_ALARM_RETRY = 0.001


def _on_alarm(signum, frame):
    try:
        check()
    except BudgetError:
        for t in _TASKS:
            t["stopped"] = True
        if _dropping(frame):
            # raised here, the error would be printed and dropped ("Exception ignored in ...")
            # and the derivation would go on: raise it once that code has returned
            signal.setitimer(signal.ITIMER_REAL, _ALARM_RETRY)
            return
        # fire again if a caller swallows the error and goes on deriving
        signal.setitimer(signal.ITIMER_REAL, 10 * _ALARM_GRACE)
        raise
    # not yet over budget by the perf_counter clock (timer granularity): look again shortly
    signal.setitimer(signal.ITIMER_REAL, _ALARM_GRACE)


def _dropping(frame) -> bool:
    """Whether the interrupted code (``frame`` and its callers) runs where the interpreter
    reports an exception and drops it: a gc callback (``gc.callbacks``, as hypothesis's), a
    ``__del__``, a ``weakref.finalize`` callback."""
    codes = set()
    for cb in gc.callbacks:
        code = getattr(getattr(cb, "__func__", cb), "__code__", None)
        if code is not None:
            codes.add(code)
    while frame is not None:
        if frame.f_code in codes or frame.f_code.co_name == "__del__" \
                or frame.f_globals.get("__name__") == "weakref":
            return True
        frame = frame.f_back
    return False


def _arm_alarm(entry):
    """Arm the budget timer for the outermost task in the main thread; returns what
    :func:`_disarm_alarm` restores (None when no timer was armed)."""
    if len(_TASKS) != 1 or not hasattr(signal, "setitimer") \
            or threading.current_thread() is not threading.main_thread() or not entry["budget"] < _ALARM_MAX:
        return None
    try:
        old_handler = signal.signal(signal.SIGALRM, _on_alarm)
    except (ValueError, OSError):
        return None
    old_timer = signal.setitimer(signal.ITIMER_REAL, entry["budget"] + _ALARM_GRACE)
    return old_handler, old_timer, time.monotonic()


def _disarm_alarm(alarm) -> None:
    if alarm is None:
        return
    old_handler, (delay, interval), t_armed = alarm
    signal.setitimer(signal.ITIMER_REAL, 0)
    # None: the handler was not set from Python; the default is the closest we can restore
    signal.signal(signal.SIGALRM, signal.SIG_DFL if old_handler is None else old_handler)
    if delay > 0:        # someone else's timer was running: give it back what is left of it
        signal.setitimer(signal.ITIMER_REAL, max(1e-3, delay - (time.monotonic() - t_armed)), interval)


def step(message: str) -> None:
    """Report one step of the running task on stderr (nothing outside a task)."""
    if _TASKS and _TASKS[-1]["progress"]:
        t = _TASKS[-1]
        print(f"[{t['label']}] {message} ({time.perf_counter() - t['t0']:.1f} s)",
              file=sys.stderr, flush=True)
    check()


def check() -> None:
    """Raise DeriveError when the running task has spent its time budget."""
    for t in _TASKS:
        elapsed = time.perf_counter() - t["t0"]
        if elapsed > t["budget"]:
            raise BudgetError(
                f"{t['label']}: the derivation took more than its time budget of {t['budget']:g} s "
                f"({elapsed:.0f} s so far) and was stopped; raise DQ_DERIVE_BUDGET to give it "
                "longer, or use derive.refine, which needs no derivation")
