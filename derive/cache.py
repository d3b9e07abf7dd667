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
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import sys
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
    base = os.environ.get("DQ_DERIVE_CACHE")
    if base:
        return Path(base)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "dq-derive"


def code_digest() -> str:
    """A digest of the package's Python files and templates (what made an artifact)."""
    return memo("code-digest", None, _code_digest)


def _code_digest() -> str:
    h = hashlib.sha256()
    pkg = Path(__file__).resolve().parent
    files = sorted(pkg.rglob("*.py")) + sorted(p for p in _template_files())
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def _template_files():
    try:
        root = resources.files("derive.templates")
        return [Path(str(p)) for p in root.iterdir() if p.name.endswith(".j2")]
    except (ModuleNotFoundError, TypeError):
        return []


def user_folder(robot_id: str) -> Path:
    """The user-cache folder of one robot's artifacts (not created)."""
    return user_root() / f"v{__version__}-{code_digest()}" / robot_id


def build_folder() -> Path:
    """Where compiled libraries go (named by the digest of what they are built from)."""
    return user_root() / "build"


def generated_root() -> Path | None:
    """The ``generated/`` folder shipped with the package (None when it is not there)."""
    try:
        root = Path(str(resources.files("derive.generated")))
    except (ModuleNotFoundError, TypeError):
        root = Path(__file__).resolve().parent.parent / "generated"
    return root if root.is_dir() else None


def shipped_index() -> dict:
    """{robot identity: folder} of the shipped ``generated/<robot>/`` folders (read once)."""
    return memo("shipped-index", None, _shipped_index)


def _shipped_index() -> dict:
    root = generated_root()
    index = {}
    if root is not None:
        for m in sorted(root.glob(f"*/{MANIFEST}")):
            try:
                index[json.loads(m.read_text(encoding="utf-8"))["id"]] = m.parent
            except (OSError, ValueError, KeyError):
                continue
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
        for k in ("files",):
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


def find_artifact(robot_id: str, role: str) -> Path | None:
    """The file of ``role`` (for example "c_source", "casadi/fk") for a robot identity: first
    a shipped folder, then the user cache; None when neither has it."""
    for folder in (shipped_index().get(robot_id), user_folder(robot_id)):
        if folder is None:
            continue
        name = read_manifest(folder).get("files", {}).get(role)
        if name and (folder / name).is_file():
            return folder / name
    return None


def store_artifacts(robot_id: str, files: dict, meta: dict) -> Path:
    """Write {role: (file name, text or bytes)} into the user cache and record them in its
    manifest; returns the folder."""
    folder = user_folder(robot_id)
    folder.mkdir(parents=True, exist_ok=True)
    names = {}
    for role, (name, content) in files.items():
        path = folder / name
        tmp = path.with_name(path.name + f".{os.getpid()}.tmp")
        if isinstance(content, bytes):
            tmp.write_bytes(content)
        else:
            tmp.write_text(content, encoding="utf-8")
        os.replace(tmp, path)
        names[role] = name
    write_manifest(folder, {**meta, "id": robot_id, "files": names})
    return folder


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
    alarm = _arm_alarm(entry)
    try:
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
_ALARM_GRACE = 0.05


def _on_alarm(signum, frame):
    try:
        check()
    except BudgetError:
        for t in _TASKS:
            t["stopped"] = True
        # fire again if a caller swallows the error and goes on deriving
        signal.setitimer(signal.ITIMER_REAL, 10 * _ALARM_GRACE)
        raise
    # not yet over budget by the perf_counter clock (timer granularity): look again shortly
    signal.setitimer(signal.ITIMER_REAL, _ALARM_GRACE)


def _arm_alarm(entry):
    """Arm the budget timer for the outermost task in the main thread; returns what
    :func:`_disarm_alarm` restores (None when no timer was armed)."""
    if len(_TASKS) != 1 or not hasattr(signal, "setitimer") \
            or threading.current_thread() is not threading.main_thread():
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
