"""The project's exceptions and the input checks that raise them.

Every bad input (wrong shape, NaN or inf, unknown robot, malformed robot file,
non-unit pose) raises :class:`DeriveError` or one of its subclasses, with a
message that names the problem. Nothing returns NaN silently.
"""

from __future__ import annotations

import numpy as np


class DeriveError(Exception):
    """Base class of every error raised by dq-derive."""


class InputError(DeriveError, ValueError):
    """An argument has the wrong shape, is not finite, or is out of range."""


class UnknownRobotError(DeriveError, LookupError):
    """A robot name is neither in the library nor a path to a description file."""


class RobotFileError(DeriveError):
    """A robot description file is malformed or inconsistent."""


class BudgetError(DeriveError):
    """A derivation spent its time budget (``DQ_DERIVE_BUDGET``) and was stopped
    (:func:`derive.cache.check`)."""


#: numpy dtype kinds read as real numbers: float, signed and unsigned integer.
_REAL_KINDS = "fiu"


def _plain_numbers(value, name: str) -> None:
    """Refuse booleans, complex numbers and strings (numeric strings such as "1.0" too) before
    numpy casts them to floats, as the C extension's input check does (``plain_numbers`` in
    templates/pyext.c.j2): a ``True`` joint value or a complex pose is a mistake, not a 1.0."""
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in _REAL_KINDS:
            raise InputError(f"{name}: expected real numbers, got an array of dtype {value.dtype}")
        return
    if isinstance(value, (bool, np.bool_, complex, np.complexfloating, str, bytes, np.str_, np.bytes_)):
        raise InputError(f"{name}: expected a real number, got {type(value).__name__} {value!r}")
    if isinstance(value, (list, tuple)):
        for item in value:
            _plain_numbers(item, name)


def as_finite_array(value, name: str, last_dim: int | None = None,
                    ndim_min: int = 1) -> np.ndarray:
    """Return ``value`` as a float64 array after checking its type, shape and values.

    ``value`` holds real numbers (int or float, Python or numpy); booleans, complex numbers and
    strings raise :class:`InputError` naming ``name``. ``last_dim`` is the required size of the
    last axis (4 for a quaternion, 8 for a dual quaternion, 3 for a vector); ``None`` accepts
    any size.
    """
    _plain_numbers(value, name)
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot be read as an array of numbers ({exc})") from None
    if arr.ndim < ndim_min:
        raise InputError(f"{name}: expected at least {ndim_min} dimension(s), got shape {arr.shape}")
    if last_dim is not None and arr.shape[-1] != last_dim:
        raise InputError(f"{name}: expected last dimension {last_dim}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        bad = np.argwhere(~np.isfinite(arr))[0]
        kind = "NaN" if np.isnan(arr[tuple(bad)]) else "inf"
        raise InputError(f"{name}: contains {kind} at index {tuple(int(i) for i in bad)}")
    return arr


def finite_number(value, name: str, minimum: float | None = None, strict: bool = False) -> float:
    """One real, finite number (int or float, not bool), optionally ``>= minimum`` (``>`` with
    ``strict``), as a float; otherwise :class:`InputError` naming ``name``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{name}: expected a real number, got {type(value).__name__} {value!r}")
    x = float(value)
    if not np.isfinite(x):
        raise InputError(f"{name}: must be finite, got {x}")
    if minimum is not None and (x <= minimum if strict else x < minimum):
        raise InputError(f"{name}: must be {'>' if strict else '>='} {minimum:g}, got {x:g}")
    return x


def whole_number(value, name: str, minimum: int | None = None) -> int:
    """One integer (Python or numpy, not bool, not a float), optionally ``>= minimum``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise InputError(f"{name}: expected an integer, got {type(value).__name__} {value!r}")
    if minimum is not None and value < minimum:
        raise InputError(f"{name}: must be an integer >= {minimum}, got {int(value)}")
    return int(value)
