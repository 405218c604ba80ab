"""A value given for a named quantity, checked against its accepted range: one check for fault and plant parameters
alike, so a command line, a scenario file and a message all say the same of a bad value."""
import math
from dataclasses import dataclass


def shortest(x: float) -> str:
    """Shortest text that reads back exactly: 300000 rather than 300000.0."""
    short = f"{x:g}"
    return short if float(short) == x else repr(x)


def check_in_range(name: str, value: float | str, low: float, high: float, unit: str) -> float:
    """Return value as a float if it is a finite number within [low, high]; else ValueError naming it and the range.

    Strings are parsed, so a command line can pass the text after NAME= unchanged.
    """
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}={value!r} is not a number") from None
    if not math.isfinite(x):
        raise ValueError(f"{name}={value} is not a finite number")
    if not low <= x <= high:
        raise ValueError(f"{name}={shortest(x)} is outside the accepted range {shortest(low)} … {shortest(high)} {unit}")
    return x


@dataclass(frozen=True)
class Ranged:
    """A named quantity's SI unit, nominal value and accepted range (a fault's or a plant's parameter)."""

    name: str
    unit: str
    nominal: float
    low: float
    high: float

    def check(self, value: float | str) -> float:
        """`value` as a float within the range, or ValueError naming it and the range (check_in_range)."""
        return check_in_range(self.name, value, self.low, self.high, self.unit)
