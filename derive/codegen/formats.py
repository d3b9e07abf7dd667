"""What the loader needs to know of the emitted kernels without the emitters: the kernel
roles and file names, the calling convention, and the text of a template. It imports neither
sympy nor jinja2, so loading shipped or cached kernels does not either (docs/architecture.md,
"Light import")."""

from __future__ import annotations

import hashlib
from importlib import resources
from pathlib import Path

#: The kernels' calling convention, recorded in each kernel manifest. The loader uses a kernel
#: folder only when it records this one (2: the IK functions of 7-joint arms take the free
#: parameter; kernels of an earlier convention in the user cache are derived again).
KERNEL_FORMAT = 2

#: role: (template, file name) of every kernel file.
FILES = {
    "python": ("kinematics.py.j2", "{id}_kinematics.py"),
    "numpy": ("kinematics_numpy.py.j2", "{id}_kinematics_numpy.py"),
    "c_header": ("kinematics.h.j2", "{id}_kinematics.h"),
    "c_source": ("kinematics.c.j2", "{id}_kinematics.c"),
}

#: The project's templates/ folder (a source checkout); an installed wheel has them as
#: the package data derive.templates (as :func:`derive.codegen.templates.template_environment`).
TEMPLATE_DIR = Path(__file__).resolve().parents[2] / "templates"


def template_source(name: str) -> str:
    """The text of ``templates/<name>``, as the jinja2 environment reads it."""
    if TEMPLATE_DIR.is_dir():
        return (TEMPLATE_DIR / name).read_text(encoding="utf-8")
    return resources.files("derive").joinpath("templates", name).read_text(encoding="utf-8")


def nominal_key(nominal) -> str:
    """12 hex digits identifying a near-class arm's nominal robot and relation
    (:class:`derive.ik.nearclass.Nominal`: the nominal's identity, B, T, the signs and the offsets,
    each number to 17 significant digits): part of the cache key and of the manifest of the kernels
    polished from it (:mod:`derive.codegen.polish`)."""
    parts = [nominal.robot.id]
    for arr in (nominal.base, nominal.tool, nominal.signs, nominal.offsets):
        parts.append(",".join(f"{float(x):.17g}" for x in list(getattr(arr, "ravel", lambda: arr)())))
    return hashlib.sha256("|".join(parts).encode()).hexdigest()[:12]
