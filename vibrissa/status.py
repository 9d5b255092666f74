"""Per-sample contact phase and status flags: the one definition, used by the core, the messages
and the nodes."""

from __future__ import annotations

import enum


class ContactPhase(enum.IntEnum):
    """Where the rod touches the surface: nowhere, at its tip, or tangentially along it."""

    NONE = 0
    TIP = 1
    TANGENTIAL = 2


class ContactStatus(enum.IntFlag):
    """Why a wrench has, or has no, consistent single contact.

    ``OK`` and ``AXIAL_LOAD`` carry a usable contact point; every other flag means none.
    """

    OK = 0
    NO_FORCE = 1  # |f0| == 0: nothing touches the rod
    CURVATURE_NEVER_VANISHES = 2  # kappa has no zero at finite arc length (k >= 1)
    CONTACT_BEYOND_ROD = 4  # first zero of kappa lies past the rod's tip (s1 > 1)
    NON_FINITE_INPUT = 8  # NaN or inf in p0, f0 or m0
    AXIAL_LOAD = 16  # force along the straight rod: taken as tip contact of the straight rod


#: Flags that leave no usable contact point.
NO_CONTACT = (
    ContactStatus.NO_FORCE
    | ContactStatus.CURVATURE_NEVER_VANISHES
    | ContactStatus.CONTACT_BEYOND_ROD
    | ContactStatus.NON_FINITE_INPUT
)
