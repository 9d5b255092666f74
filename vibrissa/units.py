"""The one conversion between the paper's units (eq. 1) and SI.

Lengths are measured in the rod length L, forces in EI/L^2 and moments in EI/L, so a rod of
any length and stiffness has the same dimensionless mechanics.
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


def finite_number(value: object) -> bool:
    """Whether ``value`` is an int or float (not a bool) with a finite float value: NaN, inf
    and an int of 400 digits are not."""
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and abs(value) <= sys.float_info.max)


def number_text(text: str) -> float:
    """A number written as text: decimal or exponent notation, ``nan``, ``inf`` (as ``float``
    reads them), but ASCII only and without Python's ``1_000``; ValueError otherwise."""
    if "_" in text or not text.isascii():
        raise ValueError(f"{text!r} is not a number")
    return float(text)


@dataclass(frozen=True)
class RodScale:
    """A rod of length ``length_m`` (m) and bending stiffness ``ei_nm2`` (N m^2)."""

    length_m: float = 1.0
    ei_nm2: float = 1.0

    def __post_init__(self) -> None:
        if not (self.length_m > 0 and self.ei_nm2 > 0):
            raise ValueError(f"length_m and ei_nm2 must be > 0, got {self.length_m}, {self.ei_nm2}")

    @functools.cached_property
    def units(self) -> NDArray[np.float64]:
        """`rod_units` of this rod (1, 3), read-only: made once (a stream passes the same rod
        tick after tick)."""
        units = rod_units([self])
        units.flags.writeable = False
        return units

    @property
    def force_n(self) -> float:
        """The unit of force, EI / L^2, in N."""
        return self.ei_nm2 / self.length_m**2

    @property
    def moment_nm(self) -> float:
        """The unit of moment, EI / L, in N m."""
        return self.ei_nm2 / self.length_m

    def wrench_to_si(self, f0: ArrayLike, m0: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Dimensionless (f0, m0) to N and N m."""
        return np.asarray(f0, dtype=float) * self.force_n, np.asarray(m0, dtype=float) * self.moment_nm

    def wrench_from_si(self, f0_n: ArrayLike, m0_nm: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(f0, m0) in N and N m to the paper's units."""
        return np.asarray(f0_n, dtype=float) / self.force_n, np.asarray(m0_nm, dtype=float) / self.moment_nm


def rod_units(rods: Sequence[RodScale]) -> NDArray[np.float64]:
    """The units of each rod (N, 3): L (m), EI/L^2 (N) and EI/L (N m), one row per rod."""
    return np.array([(r.length_m, r.force_n, r.moment_nm) for r in rods],
                    dtype=float).reshape(-1, 3)
