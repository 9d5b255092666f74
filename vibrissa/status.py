"""Contact phase, reconstruction status flags and how a sweep ends: the one definition of each,
used by the core, the messages and the nodes."""

from __future__ import annotations

import enum


class ContactPhase(enum.IntEnum):
    """Where the rod touches the surface: nowhere, at its tip, or tangentially along it."""

    NONE = 0
    TIP = 1
    TANGENTIAL = 2

    @property
    def label(self) -> str:
        """``none``, ``tip`` or ``tangential``, as in tables and reports."""
        return self.name.lower()


class ContactStatus(enum.IntFlag):
    """Why a wrench has, or has no, consistent single contact.

    ``OK``, ``AXIAL_LOAD`` and ``TIP_WITHIN_NOISE`` carry a usable contact point; every other
    flag means none.
    """

    OK = 0
    NO_FORCE = 1  # |f0| == 0: nothing touches the rod
    CURVATURE_NEVER_VANISHES = 2  # kappa has no zero at finite arc length (k >= 1)
    CONTACT_BEYOND_ROD = 4  # first zero of kappa lies past the rod's tip (s1 > 1)
    NON_FINITE_INPUT = 8  # NaN or inf in p0, f0 or m0, or finite ones near the float limit whose
    # contact point or force overflows (also in the rod's units: f0 = 1e308 N on EI/L^2 < 0.5 N)
    AXIAL_LOAD = 16  # force along the straight rod: taken as tip contact of the straight rod
    TIP_WITHIN_NOISE = 32  # first zero of kappa past the tip, within the noise: taken as the tip
    MULTI_CONTACT = 64  # no single point contact gives the wrench: a moment about the force's
    # own line (m0 . f0) or about the rod's axis at the clamp (m0z) beyond the noise band,
    # as two contacts on the rod give (vibrissa.reconstruct.single_contact_excess)
    AMBIGUOUS_CONTACT = 128  # (tapered or pre-curved rods) more than one point of the rod fits
    # the wrench and the previous contact does not tell which (vibrissa.reconstruct_rods)


#: Flags that leave no usable contact point.
NO_CONTACT = (
    ContactStatus.NO_FORCE
    | ContactStatus.CURVATURE_NEVER_VANISHES
    | ContactStatus.CONTACT_BEYOND_ROD
    | ContactStatus.NON_FINITE_INPUT
    | ContactStatus.MULTI_CONTACT
)


SNAP_KINDS = ("snap-off", "snap-through", "landing")
"""The jumps of a whisker's equilibrium path between two samples (`vibrissa.scene.snaps`): its
contact snaps off, jumps to another branch inside an episode, or lands (on the sample after a
snap-off)."""


class SweepEnd(str, enum.Enum):
    """How a simulated sweep ended (``vibrissa.sweep.Sweep.end``); compares equal to its text."""

    DETACHMENT = "detachment"  # the reactions went to zero continuously
    SNAP_OFF = "snap-off"  # no equilibrium near at finite force (a fold of the branch)
    NO_CONTACT = "no-contact"  # the trail misses the object
    NO_EQUILIBRIUM = "no-equilibrium"  # the solver found none for the first step after the touch
    MAX_STEPS = "max-steps"  # the safety cap on the steps of one sweep
    PATH_END = "path-end"  # the clamp's path ended while in contact
    ANOTHER_OBJECT = "another-object"  # (scenes) the rod, leaning on one object, met another:
    # contact with two objects at once is not modelled

    def __str__(self) -> str:
        return self.value
