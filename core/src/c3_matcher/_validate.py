"""Validation helpers shared by the DTOs: each failure names the field and says why."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher.errors import InvalidInputError


def require(condition: bool, field: str, reason: str) -> None:
    if not condition:
        raise InvalidInputError(field, reason)


def whole_number(value: object) -> int | None:
    """``value`` as an int when it is a whole number: an int (not a bool) or a float with no
    fraction (``640.0``, as JSON or an untyped SQLite column may give it); None otherwise."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return value
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return None


def finite_float(
    value: object, field: str, *, low: float | None = None, high: float | None = None
) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise InvalidInputError(field, f"expected a number, got {type(value).__name__}")
    try:
        number = float(value)
    except OverflowError:  # an int beyond the float range, such as 10**400
        bits = int(value).bit_length()
        raise InvalidInputError(field, f"must be finite, got an int of {bits} bits") from None
    require(math.isfinite(number), field, f"must be finite, got {number}")
    if low is not None:
        require(number >= low, field, f"must be >= {low}, got {number}")
    if high is not None:
        require(number <= high, field, f"must be <= {high}, got {number}")
    return number


def non_negative_int(value: object, field: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InvalidInputError(field, f"expected an int, got {type(value).__name__}")
    require(int(value) >= 0, field, f"must be >= 0, got {value}")
    return int(value)


def positive_int(value: object, field: str, what: str = "") -> int:
    """A Python or numpy int > 0 as an ``int`` (a bool is refused: ``True`` is no size);
    ``what`` names the part of ``field`` it is, in the reason."""
    part = f"{what} " if what else ""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InvalidInputError(field, f"{part}must be an int, got {value!r}")
    require(int(value) > 0, field, f"{part}must be > 0, got {value}")
    return int(value)


def items(value: object, field: str, expected: str) -> tuple[Any, ...]:
    """``value``'s items as a tuple; ``InvalidInputError`` naming ``field`` when it has none
    (not iterable, or a string)."""
    if isinstance(value, (str, bytes)):
        raise InvalidInputError(field, f"expected {expected}, got {type(value).__name__}")
    try:
        return tuple(value)  # type: ignore[arg-type]
    except TypeError:
        raise InvalidInputError(field, f"expected {expected}, got {type(value).__name__}") from None


def array(
    value: object,
    field: str,
    *,
    dtype: Any,
    ndim: int | None = None,
    shape: tuple[int | None, ...] | None = None,
) -> NDArray[Any]:
    """Check an ndarray's dtype and shape (``None`` in ``shape`` means any size) exactly, and
    that a float array holds no NaN or infinite value."""
    if not isinstance(value, np.ndarray):
        raise InvalidInputError(field, f"expected numpy.ndarray, got {type(value).__name__}")
    require(
        value.dtype == np.dtype(dtype),
        field,
        f"expected dtype {np.dtype(dtype)}, got {value.dtype}",
    )
    if shape is not None:
        ok = value.ndim == len(shape) and all(
            want is None or want == got for want, got in zip(shape, value.shape, strict=True)
        )
        want_text = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        require(ok, field, f"expected shape {want_text}, got {value.shape}")
    elif ndim is not None:
        require(value.ndim == ndim, field, f"expected {ndim} dimensions, got {value.shape}")
    if value.dtype.kind == "f":
        require(bool(np.isfinite(value).all()), field, "contains NaN or infinite values")
    return value


def frozen_copy(value: NDArray[Any]) -> NDArray[Any]:
    """A read-only array: DTOs are immutable, so their arrays are too."""
    out = np.array(value, copy=True)
    out.setflags(write=False)
    return out
