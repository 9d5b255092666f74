"""A stream of ticks and robot poses in, contact points out: `Step2Stream`, built from
`StreamSettings`, and `warm_up`, which compiles the kernels it calls."""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from vibrissa.contact_detection import OFF_SIGMAS, ON_SIGMAS, ContactDetector, wrench_covariance
from vibrissa.frame_buffer import DEFAULT_HISTORY_S, FrameBuffer
from vibrissa.frames import ROBOT_FRAME, WORLD_FRAME, Transform
from vibrissa.msgs import RobotPose, WhiskerWrenchArray
from vibrissa.reconstruct import TIP_SIGMAS
from vibrissa.scene import Whisker
from vibrissa.streaming.pose_wait import PoseWait
from vibrissa.streaming.step2 import (
    UNIT_ROD,
    ContactMemory,
    Reconstructed,
    Rods,
    RodTable,
    reconstruct_messages,
    robot_frames,
)
from vibrissa.units import RodScale

log = logging.getLogger(__name__)

COUNTS = ("contacts", "free", "tip_within_noise", "no_covariance", "no_contact", "bad_pose",
          "no_pose", "unknown_whisker", "wrong_frame", "robot_poses", "bad_robot_pose",
          "pose_time_jumps", "pose_reparents", "batches", "max_batch", "multi_contact",
          "ambiguous")
"""The counters of a `Step2Stream`, in this order (`Step2Stream.counts`)."""


@dataclass(frozen=True)
class StreamSettings:
    """What a `Step2Stream` needs to know.

    Attributes
    ----------
    rod
        L and EI of every whisker, without ``whiskers``.
    whiskers
        The robot description: each whisker's L, EI and mount X_RC on ``robot_frame``. With
        it, ticks in clamp frames are placed through the robot's poses; without it, only
        ticks that carry their clamp poses are (the others count as ``no_pose``).
    map_frame, robot_frame
        Frame of the contact points of ticks without clamp poses, and the robot's body frame
        the mounts hang on.
    pose_timeout_s
        How long a tick waits for the robot pose at its stamp (the pose stream may lag), s,
        while the ticks go on; then its rows count as ``no_pose`` (0: no wait; `PoseWait`).
    history_s
        Robot poses kept for interpolation, s; poses more than half of it ahead of the newest
        tick are held back (`PoseWait.lead_s`).
    max_pose_gap_s
        Two robot poses more than this apart are not interpolated between, s.
    noise_force_n, noise_moment_nm
        Std of the free-rod wrench noise per force axis (N) and moment axis (N m): both > 0
        turn on contact detection and the points' covariances; both 0 mean noise-free
        wrenches.
    contact_on_sigmas, contact_off_sigmas
        Contact starts when the wrench's Mahalanobis norm against the noise reaches the first,
        ends when it falls below the second (`vibrissa.contact_detection`).
    tip_sigmas
        A contact found past the tip by at most this many std of s1 is the tip.
    """

    rod: RodScale = UNIT_ROD
    whiskers: tuple[Whisker, ...] = ()
    map_frame: str = WORLD_FRAME
    robot_frame: str = ROBOT_FRAME
    pose_timeout_s: float = 0.5
    history_s: float = DEFAULT_HISTORY_S
    max_pose_gap_s: float = 1.0
    noise_force_n: float = 0.0
    noise_moment_nm: float = 0.0
    contact_on_sigmas: float = ON_SIGMAS
    contact_off_sigmas: float = OFF_SIGMAS
    tip_sigmas: float = TIP_SIGMAS

    def rods(self) -> Rods:
        """Each whisker's rod by name (`RodTable`), or the one rod of every whisker."""
        if not self.whiskers:
            return self.rod
        return RodTable({w.name: w.scale for w in self.whiskers},
                        {w.name: w.shape for w in self.whiskers})

    def detector(self) -> ContactDetector | None:
        """A new contact detector of the noise model, or None without one."""
        if self.noise_force_n <= 0:
            return None
        return ContactDetector(wrench_covariance(self.noise_force_n, self.noise_moment_nm),
                               self.contact_on_sigmas, self.contact_off_sigmas)


_KIND = re.compile(r"'[^']*'|\"[^\"]*\"|[-+]?\.?\d[\w.+-]*")  # names and numbers in a text
_MAX_KINDS = 256
_LOGGED_CHARS = 500


class Warnings:
    """Warnings logged once per kind, then every 1000th of it with its count: a kind is the
    text without its quoted names and its numbers, so a stamp in each "no pose at t=..." does
    not make every wrench a kind of its own, nor use up what other kinds get. At most
    `_MAX_KINDS` kinds (then one more, "other"); a text is logged to `_LOGGED_CHARS`
    characters (names come off the wire), after ``prefix`` on ``logger``."""

    def __init__(self, prefix: str, logger: logging.Logger = log) -> None:
        self.prefix = prefix
        self.logger = logger
        self._counts: dict[str, int] = {}

    def __call__(self, text: str) -> None:
        kind = _KIND.sub("#", text[:_LOGGED_CHARS])
        if kind not in self._counts and len(self._counts) >= _MAX_KINDS:
            kind = "other"
        count = self._counts[kind] = self._counts.get(kind, 0) + 1
        if count == 1 or count % 1000 == 0:
            shown = text if len(text) <= _LOGGED_CHARS else text[:_LOGGED_CHARS - 3] + "..."
            self.logger.warning("%s: %s%s", self.prefix, shown,
                                f" ({count} of this kind so far)" if count > 1 else "")


def pose_handler(frames: FrameBuffer, counts: dict[str, int], warn: Callable[[str], None]
                 ) -> Callable[[RobotPose], None]:
    """What puts a robot pose into ``frames``, counting it (``robot_poses``, ``bad_robot_pose``,
    ``pose_reparents``, ``pose_time_jumps``) and warning of what it refuses or drops."""
    def on_pose(pose: RobotPose) -> None:
        if pose.child_frame_id not in frames:  # no clamp hangs under it: of no use, and a
            counts["bad_robot_pose"] += 1      # stream of invented names would fill the buffer
            warn(f"robot pose refused: {pose.child_frame_id!r} is neither the robot's frame nor "
                 "above it (a frame comes above it as the parent in a pose)")
            return
        parent = frames.parent(pose.child_frame_id)
        try:
            forgotten = frames.add_pose(pose.frame_id, pose.child_frame_id, pose.stamp,
                                        pose.position, pose.orientation)
        except ValueError as exc:  # a zero quaternion, a frame that would close a loop, ...
            counts["bad_robot_pose"] += 1
            warn(f"robot pose refused: {exc}")
            return
        counts["robot_poses"] += 1
        if parent is not None and parent != pose.frame_id:
            counts["pose_reparents"] += 1
            warn(f"the poses of {pose.child_frame_id!r} now come in {pose.frame_id!r}, no longer "
                 f"in {parent!r}: its history there is dropped")
        if forgotten is not None:
            counts["pose_time_jumps"] += 1
            warn(f"the poses of {pose.child_frame_id!r} in {pose.frame_id!r} start again at "
                 f"t={pose.stamp!r}, behind the kept history (newest t={forgotten!r}): that "
                 "history is dropped")
    return on_pose


def _ignore(pose: RobotPose) -> None:
    """Without a robot description no pose is of use."""


class Step2Stream:
    """Step 2 on a stream: ticks (WhiskerWrenchArray) and robot poses in, in arrival order;
    a ContactPointArray per tick out, in the same order, with its counts.

    A tick waits (`PoseWait`) until the robot poses cover its stamp, or ``pose_timeout_s``;
    the ticks let through together go through one Step 2 call (`reconstruct_messages`).
    ``counts`` sums the outcomes' rows (`COUNTS`: ``contacts``, ``free``, ...), the robot
    poses (``robot_poses``, ...) and the Step 2 calls (``batches``, and ``max_batch`` the
    most ticks in one); each outcome's ``errors`` go to ``warn``.

    Parameters
    ----------
    settings
        Rods, robot description, frames, timeouts and noise model.
    warn
        Takes each warning's text (default: `Warnings`, logged once per kind).
    clock
        Seconds, monotonic: when a tick or pose arrived, for the timeouts.
    counts
        The dict to count in (e.g. a node's status counters); its `COUNTS` start at 0.
    """

    def __init__(self, settings: StreamSettings, warn: Callable[[str], None] | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 counts: dict[str, int] | None = None) -> None:
        self.settings = settings
        self.counts = {} if counts is None else counts
        self.counts.update(dict.fromkeys(COUNTS, 0))
        self._warn = Warnings("step 2") if warn is None else warn
        self.rods = settings.rods()
        self.frames = (robot_frames(settings.whiskers, settings.robot_frame, settings.history_s,
                                    settings.max_pose_gap_s) if settings.whiskers else None)
        self.detector = settings.detector()
        self.memory = ContactMemory()
        self._wait = PoseWait(self.frames, settings.map_frame, settings.pose_timeout_s, clock,
                              _ignore if self.frames is None
                              else pose_handler(self.frames, self.counts, self._warn),
                              lead_s=settings.history_s / 2)

    def __len__(self) -> int:
        """Ticks waiting for their poses."""
        return len(self._wait)

    def add_pose(self, pose: RobotPose) -> None:
        """Take a robot pose: held until a tick needs it, or until `apply_poses`."""
        self._wait.hold(pose)

    def add_poses(self, poses: Iterable[RobotPose]) -> None:
        """Take robot poses, in arrival order (`add_pose`)."""
        for pose in poses:
            self._wait.hold(pose)

    def add_wrenches(self, ticks: Sequence[WhiskerWrenchArray]) -> None:
        """Take ticks, in arrival order."""
        self._wait.add(ticks)

    def end_wrenches(self) -> None:
        """The ticks' input has ended (its EndOfStream): the waiting ticks time out
        ``pose_timeout_s`` after they came (`PoseWait.end`)."""
        self._wait.end()

    def take(self, drained_at: float | None = None) -> Sequence[Reconstructed]:
        """The outcomes of the ticks that are ready (or had waited ``pose_timeout_s`` when the
        input was last seen empty, at the clock's ``drained_at``, None: now, and a tick came
        that long after them or the input ended; 10 x that under a backlog or a silent
        sensor: `PoseWait.take`), in arrival order, counted."""
        ready = self._wait.take(drained_at)
        if not ready:
            return ()
        outcomes = reconstruct_messages(ready, self.rods, self.frames, self.settings.map_frame,
                                        self.detector, self.settings.tip_sigmas, self.memory)
        counts = self.counts
        for outcome in outcomes:
            counts["contacts"] += len(outcome.contacts.whisker_ids)
            counts["no_contact"] += outcome.no_contact
            counts["bad_pose"] += outcome.bad_pose
            counts["no_pose"] += outcome.no_pose
            counts["unknown_whisker"] += outcome.unknown_whisker
            counts["wrong_frame"] += outcome.wrong_frame
            counts["free"] += outcome.free
            counts["tip_within_noise"] += outcome.tip_within_noise
            counts["no_covariance"] += outcome.no_covariance
            counts["multi_contact"] += outcome.multi_contact
            counts["ambiguous"] += outcome.ambiguous
            for error in outcome.errors:
                self._warn(error)
        counts["batches"] += 1
        counts["max_batch"] = max(counts["max_batch"], len(ready))
        return outcomes

    def apply_poses(self, drained_at: float | None = None) -> None:
        """Put the held poses no tick waited for into the frame buffer; call it after
        publishing what `take` gave, so the points do not wait for it (``drained_at``: when
        the input was last seen empty, `PoseWait.apply_poses`)."""
        self._wait.apply_poses(drained_at)

    def wait_s(self) -> float:
        """Seconds until the front tick times out (inf with none waiting)."""
        return self._wait.wait_s()


def warm_up(settings: StreamSettings) -> None:
    """Compile Step 2 and the frame kernels a `Step2Stream` of ``settings`` calls (or load
    them from numba's cache) now, so that the first tick is not late by the compile time (~3 s
    on a fresh install, 4-6 ms a kernel from the cache): one tick and a batch of two through
    Step 2 (with the noise model's detector when there is one, its state dropped after), and
    a robot tick's clamps from the pose at its stamp, from the two around it and up a chain of
    frames. Ticks as received are read-only; Step 2 copies what its kernels take."""
    rods = settings.rods()
    one = rods if isinstance(rods, RodScale) else next(iter(rods.values()), UNIT_ROD)
    tick = WhiskerWrenchArray(
        stamp=0.0, seq=0, whisker_ids=["warm-up"], frame_ids=["warm-up/clamp"],
        f0=[[0.1 * one.force_n, 0.0, 0.0]], m0=[[0.0, 0.05 * one.moment_nm, 0.0]],
        pose_frame_id="world", clamp_position=[[0.0, 0.0, 0.0]],
        clamp_orientation=[[0.0, 0.0, 0.0, 1.0]])
    for batch in ([tick], [tick, tick]):
        reconstruct_messages(batch, one)
        detector = settings.detector()
        if detector is not None:
            reconstruct_messages(batch, one, detector=detector, tip_sigmas=settings.tip_sigmas)
    frames = robot_frames([Whisker("warm-up", 1.0, 1.0)])
    for stamp in (0.0, 1.0):  # the robot in odom, odom in world
        frames.add("odom", ROBOT_FRAME, stamp, Transform())
        frames.add("world", "odom", stamp, Transform())
    for target, stamp in (("odom", 0.5), ("odom", 1.0), ("world", 0.5)):  # between two poses,
        frames.lookup_rows(target, ["warm-up/clamp"] * 2, stamp)  # at the newest, up a chain


