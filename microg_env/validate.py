"""The one validator: every number a user can pass is checked here, with an error naming it.

Each function returns the value as a plain ``float`` (or ``int``) and raises :class:`FieldError`
(a ``ValueError``) with one line that names the argument, the bound it broke and the value it got,
and with the argument's name in ``fields``. Booleans are not numbers here, NaN and infinities are
never accepted, and NumPy scalars are.
"""

from __future__ import annotations

import math
import numbers
import reprlib

#: How values are echoed in errors: bounded, so a huge or deeply shared value (a YAML alias bomb)
#: cannot make a huge message.
_SHOWN = reprlib.Repr()  # (keyword arguments only from Python 3.12)
for _name, _limit in {"maxlevel": 3, "maxlist": 6, "maxtuple": 6, "maxdict": 6, "maxset": 6, "maxstring": 200}.items():
    setattr(_SHOWN, _name, _limit)
_SHOWN.maxother, _SHOWN.maxlong = 200, 60


class FieldError(ValueError):
    """A ValueError about the values of named fields: ``fields`` are their names (keyword
    arguments, dataclass fields such as ``PadParams.stiffness_n_per_m``, or dotted parameter paths),
    first the one to change, so that a caller can say what set them (the CLI: its option) without
    reading the message."""

    def __init__(self, message: str, *fields: str) -> None:
        super().__init__(message)
        self.fields = fields

    def __reduce__(self):  # crosses process pools and Ray with its fields
        return type(self), (str(self), *self.fields)


def shown(value: object) -> str:
    """``repr(value)``, bounded (long strings and collections are cut with "...")."""
    return _SHOWN.repr(value)


def fault(error: BaseException) -> str:
    """The first line of an error's message, or its type's name if it has none."""
    lines = str(error).strip().splitlines()
    return lines[0] if lines else type(error).__name__


def _real(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise FieldError(f"{name} must be a number, got {shown(value)}", name)
    number = float(value)
    if not math.isfinite(number):
        raise FieldError(f"{name} must be a finite number, got {shown(value)}", name)
    return number


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def finite(name: str, value: object) -> float:
    """Any finite number."""
    return _real(name, value)


def positive(name: str, value: object, unit: str = "", upper: float = math.inf, why: str = "") -> float:
    """A number in (0, upper]; ``why`` names the reason for the upper bound."""
    number = _real(name, value)
    if not number > 0:
        raise FieldError(f"{name} must be positive, got {shown(value)}", name)
    if number > upper:
        reason = f" ({why})" if why else ""
        raise FieldError(f"{name} must be at most {upper:g}{_unit(unit)}{reason}, got {shown(value)}", name)
    return number


def non_negative(name: str, value: object, unit: str = "", upper: float = math.inf, why: str = "") -> float:
    """A number in [0, upper]."""
    number = _real(name, value)
    if number < 0:
        raise FieldError(f"{name} must be >= 0, got {shown(value)}", name)
    if number > upper:
        reason = f" ({why})" if why else ""
        raise FieldError(f"{name} must be at most {upper:g}{_unit(unit)}{reason}, got {shown(value)}", name)
    return number


def at_least(name: str, value: object, lower: float, unit: str = "", why: str = "") -> float:
    """A number >= lower."""
    number = _real(name, value)
    if number < lower:
        reason = f" ({why})" if why else ""
        raise FieldError(f"{name} must be at least {lower:g}{_unit(unit)}{reason}, got {shown(value)}", name)
    return number


def between(name: str, value: object, low: float, high: float, unit: str = "", high_open: bool = False) -> float:
    """A number in [low, high] (or [low, high) with ``high_open``)."""
    number = _real(name, value)
    above = number >= high if high_open else number > high
    if number < low or above:
        bracket = ")" if high_open else "]"
        raise FieldError(f"{name} must be in [{low:g}, {high:g}{bracket}{_unit(unit)}, got {shown(value)}", name)
    return number


def integer(name: str, value: object, low: int | None = None, high: int | None = None) -> int:
    """An integer in [low, high] (either bound optional)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise FieldError(f"{name} must be an integer, got {shown(value)}", name)
    number = int(value)
    if (low is not None and number < low) or (high is not None and number > high):
        low_text = "-inf" if low is None else str(low)
        high_text = "inf" if high is None else str(high)
        raise FieldError(f"{name} must be an integer in [{low_text}, {high_text}], got {shown(value)}", name)
    return number


def choice(name: str, value: object, options: tuple) -> object:
    """One of ``options``."""
    if value not in options:
        raise FieldError(f"{name} must be one of {', '.join(map(repr, options))}, got {shown(value)}", name)
    return value


def instance(name: str, value: object, kind: type) -> object:
    """An instance of ``kind``."""
    if not isinstance(value, kind):
        raise FieldError(f"{name} must be a {kind.__name__}, got {type(value).__name__}", name)
    return value
