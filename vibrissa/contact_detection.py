"""Contact detection on noisy wrenches: a threshold with hysteresis, set from the free-rod noise.

A free rod's clamp wrench w = (f0, m0) is the sensor's noise, with covariance Sigma (6 x 6, SI,
in C). Its Mahalanobis norm d = sqrt(w^T Sigma^-1 w) then follows the chi distribution with
6 degrees of freedom (mean 2.35), whatever the sensor's units and axes. A whisker enters contact
when d reaches ``on_sigmas`` and leaves it when d falls below ``off_sigmas``: with the defaults a
free sample starts a contact with probability P(chi^2_6 >= 49) = 1.5e-8, and a contact whose
wrench dips into the band between the two (near a touch or a detachment, or in stick-slip) is
not split. Samples are taken per whisker in arrival order; the state survives between calls.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from vibrissa.compiled import compiled

FloatArray = NDArray[np.float64]

ON_SIGMAS = 7.0
"""Default Mahalanobis norm of the wrench at which a free whisker enters contact."""
OFF_SIGMAS = 5.0
"""Default Mahalanobis norm below which a whisker in contact leaves it."""
MAX_WHISKERS = 4096
"""Whiskers whose state is kept; rows of any further name (a sender inventing names) are
judged alone, in contact only at ``on_sigmas``."""


def wrench_covariance(force_std_n: float, moment_std_nm: float) -> FloatArray:
    """Covariance (6, 6) of independent noise on each force axis (N) and moment axis (N m)."""
    for name, value in (("force_std_n", force_std_n), ("moment_std_nm", moment_std_nm)):
        if not (value > 0.0 and math.isfinite(value)):
            raise ValueError(f"{name} must be a finite number > 0, got {value}")
    return np.diag([force_std_n**2] * 3 + [moment_std_nm**2] * 3)


class ContactDetector:
    """Whether each whisker touches something, from its wrenches and its free-rod noise.

    Parameters
    ----------
    covariance : ndarray, shape (6, 6)
        The free-rod noise of (f0, m0), N^2, N^2 m, N^2 m^2, positive definite.
    on_sigmas, off_sigmas
        Enter contact at d >= ``on_sigmas``, leave it at d < ``off_sigmas`` (see the module).
    """

    def __init__(self, covariance: FloatArray, on_sigmas: float = ON_SIGMAS,
                 off_sigmas: float = OFF_SIGMAS) -> None:
        covariance = np.asarray(covariance, dtype=float)
        if covariance.shape != (6, 6) or not np.isfinite(covariance).all():
            raise ValueError(f"covariance must be a finite (6, 6) matrix, got shape "
                             f"{covariance.shape}")
        try:
            root = np.linalg.cholesky(covariance)
        except np.linalg.LinAlgError:
            raise ValueError("covariance must be symmetric positive definite") from None
        if not (0.0 < off_sigmas <= on_sigmas < math.inf):
            raise ValueError(f"need 0 < off_sigmas <= on_sigmas < inf, got off_sigmas "
                             f"{off_sigmas}, on_sigmas {on_sigmas}")
        self.covariance = covariance
        self.on_sigmas, self.off_sigmas = float(on_sigmas), float(off_sigmas)
        self._whitening = np.ascontiguousarray(np.linalg.inv(root))  # d = |L^-1 w|
        self._index: dict[str, int] = {}
        self._state = np.zeros(0, dtype=np.bool_)

    def in_contact(self, whiskers: Sequence[str]) -> list[bool]:
        """The current state of each of ``whiskers`` (False for one not seen yet)."""
        return [bool(self._state[self._index[w]]) if w in self._index else False
                for w in whiskers]

    def update(self, whiskers: Sequence[str], f0_C_n: FloatArray, m0_C_nm: FloatArray
               ) -> tuple[NDArray[np.bool_], FloatArray]:
        """Take the samples (rows, in arrival order; a whisker may come more than once) and
        return whether each row is in contact and its Mahalanobis norm d. A row with NaN in its
        wrench leaves its whisker's state as it was and is not in contact."""
        rows = np.empty(len(whiskers), dtype=np.int64)
        for i, name in enumerate(whiskers):
            index = self._index.get(name)
            if index is None:
                if len(self._index) >= MAX_WHISKERS:
                    index = -1
                else:
                    index = self._index[name] = len(self._index)
            rows[i] = index
        if len(self._index) > len(self._state):
            self._state = np.concatenate(
                [self._state, np.zeros(len(self._index) - len(self._state), dtype=np.bool_)])
        wrench = np.ascontiguousarray(np.hstack([np.reshape(f0_C_n, (-1, 3)),
                                                 np.reshape(m0_C_nm, (-1, 3))]), dtype=float)
        return _hysteresis(rows, wrench, self._whitening, self.on_sigmas, self.off_sigmas,
                           self._state)


@compiled
def _hysteresis(rows: NDArray[np.int64], wrench: FloatArray, whitening: FloatArray,
                on: float, off: float, state: NDArray[np.bool_]
                ) -> tuple[NDArray[np.bool_], FloatArray]:
    """:meth:`ContactDetector.update` of every row, updating ``state`` (per whisker)."""
    n = rows.shape[0]
    touching = np.zeros(n, dtype=np.bool_)
    norm = np.empty(n)
    for i in range(n):
        d2 = 0.0
        for r in range(6):
            z = 0.0
            for c in range(r + 1):
                z += whitening[r, c] * wrench[i, c]
            d2 += z * z
        d = math.sqrt(d2)
        norm[i] = d
        if math.isnan(d):  # NaN in the wrench; one too large for d^2 is inf: in contact
            continue
        k = rows[i]
        if k < 0:  # a whisker past MAX_WHISKERS: no state
            touching[i] = d >= on
            continue
        state[k] = d >= on or (state[k] and d >= off)
        touching[i] = state[k]
    return touching, norm
