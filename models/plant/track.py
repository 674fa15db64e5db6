"""Track data: the grade profile i(X) and the reference speed profile V_zad(X).

Profiles are parsed from CSV *text* (the caller reads the file), so that this module stays
free of I/O and every error can name the source and the line.
"""
from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass


GRADE_COLUMNS = ("distance_m", "grade_permille")
SPEED_COLUMNS = ("distance_m", "speed_mps")


class ProfileError(ValueError):
    """A malformed profile; the message names the source (file) and the line."""


MAX_GRADE = 200.0   # [permille] |grade| accepted in a profile: rack-free railways stay below ~120
MAX_SPEED = 200.0   # [m/s] accepted in a speed profile (720 km/h)


def csv_number_rows(text: str, source: str, columns: tuple[str, ...]):
    """(1-based line, floats) of each data row of a CSV whose header is exactly ``columns``:
    blank lines and lines starting with ``#`` skipped, a UTF-8 byte-order mark before the header
    too; every row as many cells as ``columns``, each a finite number. Raises
    :class:`ProfileError` naming ``source`` and the line (the words models/core/profile.c
    repeats for the two-column profiles)."""
    if text.startswith("\ufeff"):
        text = text[1:]
    header_seen = False
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        cells = [c.strip().strip('"') for c in line.split(",")]
        if not header_seen:
            if tuple(cells) != columns:
                raise ProfileError(f"{source}: line {lineno}: header must be "
                                   f"'{','.join(columns)}', got '{line}'")
            header_seen = True
            continue
        if len(cells) != len(columns):
            raise ProfileError(f"{source}: line {lineno}: expected {len(columns)} values, "
                               f"got {len(cells)}: '{line}'")
        try:
            numbers = [float(c) for c in cells]
        except ValueError:
            raise ProfileError(f"{source}: line {lineno}: not a number: '{line}'") from None
        if not all(math.isfinite(x) for x in numbers):
            raise ProfileError(f"{source}: line {lineno}: non-finite value: '{line}'")
        yield lineno, numbers
    if not header_seen:
        raise ProfileError(f"{source}: line 1: empty file, expected header '{','.join(columns)}'")


def parse_profile_csv(text: str, source: str, columns: tuple[str, str], *,
                      nonnegative_values: bool = False,
                      max_abs_value: float = math.inf) -> tuple[list[float], list[float]]:
    """Parse a two-column profile CSV.

    The header must be exactly ``columns`` (e.g. ``distance_m,grade_permille``); distances [m]
    must be finite, >= 0 and strictly increasing; values within +-``max_abs_value``. A UTF-8
    byte-order mark before the header is skipped. Blank lines and lines starting with ``#``
    are skipped. Raises :class:`ProfileError` naming ``source`` and the 1-based line number.
    """
    distances: list[float] = []
    values: list[float] = []
    for lineno, (d, v) in csv_number_rows(text, source, columns):
        if d < 0:
            raise ProfileError(f"{source}: line {lineno}: {columns[0]} must be >= 0, got {d}")
        if distances and d <= distances[-1]:
            raise ProfileError(f"{source}: line {lineno}: {columns[0]} must increase "
                               f"({d} after {distances[-1]})")
        if nonnegative_values and v < 0:
            raise ProfileError(f"{source}: line {lineno}: {columns[1]} must be >= 0, got {v}")
        if abs(v) > max_abs_value:
            raise ProfileError(f"{source}: line {lineno}: {columns[1]} must be within "
                               f"+-{max_abs_value:g}, got {v}")
        distances.append(d)
        values.append(v)
    if not distances:
        raise ProfileError(f"{source}: no data rows after the header")
    return distances, values


@dataclass(frozen=True)
class GradeProfile:
    """Grade i(X) [permille, +uphill], piecewise constant from each distance [m] on.

    Before the first distance the first grade applies. ``average(x, length)`` is the grade
    averaged over a car/train of ``length`` [m] whose front is at ``x`` (Meleshin's (2011)
    "inextensible string" model); ``length = 0`` gives the point-mass grade.
    """
    distances: tuple[float, ...] = (0.0,)
    grades: tuple[float, ...] = (0.0,)

    def __post_init__(self):
        if len(self.distances) != len(self.grades) or not self.distances:
            raise ValueError("GradeProfile: distances and grades must be non-empty and of equal length")
        # cumulative integral of the grade [permille*m] at each breakpoint, for exact averaging
        cum = [0.0]
        for k in range(1, len(self.distances)):
            cum.append(cum[-1] + self.grades[k - 1] * (self.distances[k] - self.distances[k - 1]))
        object.__setattr__(self, "_cum", tuple(cum))

    @classmethod
    def level(cls) -> "GradeProfile":
        return cls()

    @classmethod
    def from_csv_text(cls, text: str, source: str) -> "GradeProfile":
        d, g = parse_profile_csv(text, source, GRADE_COLUMNS, max_abs_value=MAX_GRADE)
        return cls(tuple(d), tuple(g))

    def at(self, x: float) -> float:
        """Point-mass grade [permille] at distance ``x`` [m]."""
        k = bisect_right(self.distances, x) - 1
        return self.grades[k if k >= 0 else 0]

    def _integral(self, x: float) -> float:
        """Integral of the grade from distances[0] to x [permille*m] (negative below it)."""
        k = bisect_right(self.distances, x) - 1
        if k < 0:
            return self.grades[0] * (x - self.distances[0])
        return self._cum[k] + self.grades[k] * (x - self.distances[k])

    def average(self, x: float, length: float) -> float:
        """Grade [permille] averaged over [x - length, x]; ``length`` [m] >= 0."""
        if length <= 0.0:
            return self.at(x)
        return (self._integral(x) - self._integral(x - length)) / length


@dataclass(frozen=True)
class SpeedProfile:
    """Reference speed V_zad(X) [m/s], piecewise linear in distance [m], held beyond the ends."""
    distances: tuple[float, ...]
    speeds: tuple[float, ...]

    def __post_init__(self):
        if len(self.distances) != len(self.speeds) or not self.distances:
            raise ValueError("SpeedProfile: distances and speeds must be non-empty and of equal length")

    @classmethod
    def from_csv_text(cls, text: str, source: str) -> "SpeedProfile":
        d, v = parse_profile_csv(text, source, SPEED_COLUMNS, nonnegative_values=True,
                                 max_abs_value=MAX_SPEED)
        return cls(tuple(d), tuple(v))

    def at(self, x: float) -> float:
        """V_zad [m/s] at distance ``x`` [m]."""
        d = self.distances
        k = bisect_right(d, x)
        if k == 0:
            return self.speeds[0]
        if k == len(d):
            return self.speeds[-1]
        x0, x1 = d[k - 1], d[k]
        v0, v1 = self.speeds[k - 1], self.speeds[k]
        return v0 + (v1 - v0) * (x - x0) / (x1 - x0)
