"""Reconstructor node: contact points from whisker base wrenches (Step 2), batched when behind.

Subscribes
----------
``input_topic`` (default ``wrench``) : WhiskerWrenchArray
    SI: f0 N, m0 N m in the clamp frame C (``frame_id`` / ``frame_ids``), with or without
    the clamp pose X_PC (``pose_frame_id``); an array holds one row per whisker of one tick.
``pose_topic`` (default ``/robot/pose``, only with ``robot``) : RobotPose
    The robot's poses, kept in a frame buffer (``vibrissa.frame_buffer``) with the mounts of
    the robot description.

Publishes
---------
``output_topic`` (default ``contact``) : ContactPointArray
    One per WhiskerWrenchArray (same ``stamp``, ``seq``) with the rows that have a consistent
    contact (status OK or AXIAL_LOAD; possibly none);
    in the pose's frame when the wrench carried one, else in ``map_frame`` (the clamp pose
    interpolated at the wrench's stamp); then an ``EndOfStream`` of its own for every
    ``EndOfStream`` on ``input_topic`` (after the points of the wrenches before it).

Noisy sensors: with the free-rod noise (``noise_force_n``, ``noise_moment_nm``: std per axis)
a whisker is in contact only between a wrench threshold and its release, with hysteresis
(``vibrissa.contact_detection``: enter at ``contact_on_sigmas``, leave below
``contact_off_sigmas``, in units of the noise), so that a free rod's noise never becomes points
on the map; every point then carries its covariance (m^2, from the noise through Step 2,
``vibrissa.uncertainty``), and a contact found past the tip within ``tip_sigmas`` std of s1 is
the tip (status TIP_WITHIN_NOISE). Without a noise model (the default, for simulated
wrenches) every wrench with a force is a contact and points carry no covariance.

Samples without a consistent contact are **counted, not sent**: the codec refuses the NaN a
point-less reconstruction carries, and a point with finite placeholder zeros would be a point
on the map. Counters in this node's ``NodeStatus`` (besides the runtime's received, published,
rejected, lost, anomalies), in rows: ``contacts`` (points published), ``free`` (below the
contact threshold: the rod is free), ``tip_within_noise`` (points published as the tip within
the noise), ``no_covariance`` (points whose covariance is not defined, an axial load: they carry
L^2 I, the rod's reach), ``no_contact`` (valid
wrench, no consistent contact, or a result that overflows to inf near the float limit),
``bad_pose`` (clamp quaternion of zero or non-finite length), ``no_pose`` (no clamp pose at
the wrench's stamp within ``pose_timeout_s``), ``unknown_whisker`` (not in the robot
description), ``wrong_frame`` (measured, by its ``frame_ids``, in another frame than its
whisker's clamp frame: placed there it would get another whisker's mount); and
``robot_poses``, ``bad_robot_pose`` (poses put in the frame buffer, refused: a pose is held
until it is needed, `PoseWait`), ``pose_time_jumps``,
``pose_reparents`` (histories dropped: a new timeline, a new parent frame;
`vibrissa.frame_buffer`), ``batches`` and ``max_batch`` (batches and the largest, in
messages). Undecodable input (wrong type, version,
field type, truncated bytes, NaN) is rejected and counted by the transport (``rejected``) and
the node carries on.

Step 2 in SI, with the clamp pose and each row's ``vibrissa.units.RodScale`` (its whisker's
from ``robot``, else ``rod_length_m`` and ``rod_ei_nm2``), is the core's
``vibrissa.reconstruct.reconstruct_si``.
"""

from __future__ import annotations

import logging
import math
import re
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import compress
from typing import TypeAlias, cast

import numpy as np
import numpy.typing as npt

from vibrissa.contact_detection import (
    OFF_SIGMAS,
    ON_SIGMAS,
    ContactDetector,
    wrench_covariance,
)
from vibrissa.formats.scene_file import load_robot
from vibrissa.frame_buffer import DEFAULT_HISTORY_S, FrameBuffer
from vibrissa.frames import ROBOT_FRAME, WORLD_FRAME, Transform, clamp_frame
from vibrissa.msgs import (
    ContactPointArray,
    ContactStatus,
    EndOfStream,
    Message,
    RobotPose,
    WhiskerWrenchArray,
)
from vibrissa.msgs.codec import decode, encode
from vibrissa.reconstruct import TIP_SIGMAS, reconstruct_si
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main
from vibrissa.runtime.params import require, require_non_negative, require_parsed, require_positive
from vibrissa.scene import Whisker
from vibrissa.units import RodScale, rod_units
from vibrissa.wire.topics import resolve_topic, validate_name
from vibrissa.wire.transport import Received

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

_UNIT_ROD = RodScale()


@dataclass(frozen=True)
class ReconstructorParams:
    """Parameters of the reconstructor node.

    Attributes
    ----------
    input_topic, output_topic
        Topic names, relative to the namespace unless absolute.
    wait_for
        Node names that must be subscribed to ``output_topic`` before points go out
        (buffered until then, never dropped).
    drain_limit
        Most messages taken from the queue before their points are published; a batch that
        reaches it means a backlog, and the next one drains up to ``max_batch``. A
        WhiskerWrenchArray counts as one message; the messages of a batch share one Step 2
        call.
    max_batch
        Most messages taken in one batch (reconstructed, then published) when the node falls
        behind.
    receive_hwm
        Receive high-water mark, messages: the backlog the node can hold without loss.
    exit_on_eos
        Exit (status 0) after forwarding the first ``EndOfStream``; by default the node runs
        until stopped, like a sensor driver.
    rod_length_m
        L, m (every whisker, without ``robot``).
    rod_ei_nm2
        EI, N m^2 (every whisker, without ``robot``).
    robot
        The robot description (a scene file, or a file of its ``whiskers``): each whisker's
        L, EI and mount X_RC on ``robot_frame``. With it, wrenches in clamp frames are placed
        through the robot's poses on ``pose_topic``; without it, only wrenches that carry
        their clamp pose are (the others count as ``no_pose``).
    pose_topic
        RobotPose topic: the pose of ``robot_frame`` in ``map_frame`` (or in a frame whose
        own pose is on the topic too), stamped.
    map_frame, robot_frame
        Frame of the contact points of wrenches without a pose, and the robot's body frame
        the mounts hang on.
    pose_timeout_s
        How long a wrench waits for the robot pose at its stamp (the pose stream may lag),
        s; then its rows count as ``no_pose`` and the node moves on.
    history_s
        Robot poses kept for interpolation, s: a wrench older than the newest pose by more
        than this counts as ``no_pose``. A batch ends once its stamps span half of it.
    max_pose_gap_s
        Two robot poses more than this apart are not interpolated between, s: a wrench
        stamped between them waits for the poses that fill the gap (``pose_timeout_s``), then
        counts as ``no_pose``. Guards against a pose stream that stopped, and one pose
        stamped far ahead of it, being taken for the robot's motion; raise it for a slower
        pose stream.
    noise_force_n, noise_moment_nm
        Std of the free-rod wrench noise on each force axis (N) and moment axis (N m) of every
        whisker's sensor: both > 0 turns on contact detection and the points' covariances,
        both 0 (the default) means noise-free wrenches.
    contact_on_sigmas, contact_off_sigmas
        Contact starts when the wrench's Mahalanobis norm against the noise reaches the first,
        ends when it falls below the second (default 7 and 5: a free sample starts a contact
        with probability 1.5e-8).
    tip_sigmas
        A contact found past the tip by at most this many std of s1 is the tip.
    rod
        L and EI as ``vibrissa.units.RodScale`` (derived, not a parameter).
    """

    input_topic: str = "wrench"
    output_topic: str = "contact"
    wait_for: tuple[str, ...] = ()
    drain_limit: int = 15
    max_batch: int = 4096
    receive_hwm: int = 200_000
    exit_on_eos: bool = False
    rod_length_m: float = 1.0
    rod_ei_nm2: float = 1.0
    robot: str = ""
    pose_topic: str = "/robot/pose"
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
    rod: RodScale = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.robot:
            require_parsed("robot", self.robot, load_robot)
        require_parsed("pose_topic", self.pose_topic, validate_name)
        for key in ("map_frame", "robot_frame"):
            require(bool(getattr(self, key)), key, getattr(self, key), "a frame name")
        require_non_negative("pose_timeout_s", self.pose_timeout_s)
        require_positive("history_s", self.history_s)
        require_positive("max_pose_gap_s", self.max_pose_gap_s)
        require_non_negative("noise_force_n", self.noise_force_n)
        require_non_negative("noise_moment_nm", self.noise_moment_nm)
        require((self.noise_force_n > 0) == (self.noise_moment_nm > 0), "noise_moment_nm",
                self.noise_moment_nm, "> 0 together with noise_force_n (or both 0)")
        require_positive("contact_off_sigmas", self.contact_off_sigmas)
        require(math.isfinite(self.contact_on_sigmas)
                and self.contact_on_sigmas >= self.contact_off_sigmas, "contact_on_sigmas",
                self.contact_on_sigmas, f">= contact_off_sigmas ({self.contact_off_sigmas})")
        require_non_negative("tip_sigmas", self.tip_sigmas)
        require_positive("rod_length_m", self.rod_length_m)
        require_positive("rod_ei_nm2", self.rod_ei_nm2)
        object.__setattr__(self, "rod", RodScale(self.rod_length_m, self.rod_ei_nm2))
        for name in (self.input_topic, self.output_topic, *self.wait_for):
            require_parsed("input_topic/output_topic/wait_for", name, validate_name)
        for key in ("drain_limit", "max_batch", "receive_hwm"):
            value = getattr(self, key)
            require(value >= 1, key, value, "an integer >= 1")


PARAMS = ReconstructorParams
"""The node's parameter dataclass: the launcher checks a launch file's values with it."""


Wrenches: TypeAlias = WhiskerWrenchArray

Rods: TypeAlias = RodScale | Mapping[str, RodScale]
"""One rod for every whisker, or each whisker's by name (the robot description)."""

_MAX_ROW_LISTS = 64


class RodTable(Mapping[str, RodScale]):
    """Each whisker's rod by name, and the rods of a message's rows as Step 2 takes them: an
    array sends the same whiskers tick after tick, so their units are made once."""

    def __init__(self, rods: Mapping[str, RodScale]) -> None:
        self._rods = dict(rods)
        self._rows: dict[tuple[str, ...], tuple[FloatArray, list[int]]] = {}
        self._frames: dict[tuple[tuple[str, ...], tuple[str, ...]], list[int]] = {}

    def __getitem__(self, name: str) -> RodScale:
        return self._rods[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._rods)

    def __len__(self) -> int:
        return len(self._rods)

    def rows(self, whiskers: Sequence[str]) -> tuple[FloatArray, list[int]]:
        """The units (N, 3) of the rows' rods (`vibrissa.units.rod_units`; an unknown
        whisker's are L = EI = 1), and the rows of whiskers not in the table."""
        key = tuple(whiskers)
        found = self._rows.get(key)
        if found is None:
            if len(self._rows) >= _MAX_ROW_LISTS:
                self._rows.clear()
            units = rod_units([self._rods.get(w, _UNIT_ROD) for w in key])
            units.flags.writeable = False
            found = self._rows[key] = (units, [i for i, w in enumerate(key) if w not in self._rods])
        return found

    def wrong_frames(self, whiskers: Sequence[str], frames: Sequence[str]) -> list[int]:
        """The rows of known whiskers measured in another frame than their clamp frame
        (`vibrissa.frames.clamp_frame`)."""
        key = (tuple(whiskers), tuple(frames))
        found = self._frames.get(key)
        if found is None:
            if len(self._frames) >= _MAX_ROW_LISTS:
                self._frames.clear()
            found = self._frames[key] = [i for i, (w, f) in enumerate(zip(*key, strict=True))
                                         if w in self._rods and f != clamp_frame(w)]
        return found


@dataclass
class Reconstructed:
    """The outcome of one input message.

    Attributes
    ----------
    contacts
        A ContactPointArray of the input's rows with a consistent contact (possibly none). SI, in
        the frame of the clamp pose the input carried, else in the map frame; same ``stamp``
        and ``seq``.
    no_contact
        Rows whose reconstruction has no consistent contact (not in ``contacts``).
    bad_pose
        Rows skipped because their clamp quaternion has zero or non-finite length.
    no_pose
        Rows without a clamp pose: none came with them and the frame buffer has none at their
        stamp (``errors`` says why).
    unknown_whisker
        Rows of a whisker the robot description does not list (``errors`` names it).
    wrong_frame
        Rows of a whisker measured in another frame than its clamp frame (``errors`` names
        it).
    free
        Rows below the contact threshold (with a noise model): the rod is free.
    tip_within_noise
        Points in ``contacts`` that are the tip within the noise.
    no_covariance
        Points in ``contacts`` whose covariance is not defined (they carry L^2 I).
    """

    contacts: ContactPointArray | None
    no_contact: int
    bad_pose: int
    no_pose: int = 0
    unknown_whisker: int = 0
    errors: list[str] = field(default_factory=list)
    free: int = 0
    wrong_frame: int = 0
    tip_within_noise: int = 0
    no_covariance: int = 0


@dataclass
class _Rows:
    """The rows of one message on their way to Step 2: clamp poses in ``frame_id`` where
    ``placed``."""

    q: FloatArray
    p: FloatArray
    f0: FloatArray
    m0: FloatArray
    placed: npt.NDArray[np.bool_]
    units: FloatArray | None  # of each row's rod (N, 3) (None: the one rod of every row)
    frame_id: str
    no_pose: int = 0
    unknown_whisker: int = 0
    errors: list[str] = field(default_factory=list)
    free: int = 0
    wrong_frame: int = 0


def _rows(msg: Wrenches, rod: Rods, frames: FrameBuffer | None, map_frame: str,
          detector: ContactDetector | None) -> _Rows:
    whiskers = msg.whisker_ids
    f0, m0 = msg.f0, msg.m0
    n = len(whiskers)
    placed = np.ones(n, bool)
    errors: list[str] = []
    units: FloatArray | None = None
    table = None if isinstance(rod, RodScale) else rod if isinstance(rod, RodTable) else RodTable(rod)
    missing: list[int] = []  # rows of whiskers the robot description does not have
    wrong: list[int] = []  # rows of its whiskers in another frame than their clamp frame
    if table is not None:
        units, missing = table.rows(whiskers)
        if missing:
            errors.append(f"whisker {whiskers[missing[0]]!r} is not in the robot description "
                          f"({', '.join(table)})")
    if msg.has_pose:
        q, p = msg.clamp_orientation, msg.clamp_position
        frame_id = msg.pose_frame_id
        no_pose = 0
    else:
        frame_id = map_frame
        if frames is None:
            q, p = np.zeros((n, 4)), np.zeros((n, 3))
            placed[:] = False
            errors.append("a wrench without clamp pose needs the robot description (parameter "
                          "'robot') and the robot's poses")
        else:
            sources = msg.frame_ids
            poses = frames.lookup_rows(map_frame, sources, msg.stamp)
            q, p, placed = poses.q_xyzw, poses.p, poses.ok
            errors += poses.errors
            if table is not None:
                wrong = table.wrong_frames(whiskers, sources)
                if wrong:
                    errors.append(f"whisker {whiskers[wrong[0]]!r} measured in frame "
                                  f"{sources[wrong[0]]!r}, not in its clamp frame "
                                  f"{clamp_frame(whiskers[wrong[0]])!r}")
        if missing or wrong:
            placed[missing + wrong] = True  # counted as such, not as rows without a pose
        no_pose = n - int(np.count_nonzero(placed))
    if missing or wrong:
        placed[missing + wrong] = False
    free = 0
    if detector is not None:  # every row moves its whisker's state, placed or not
        free_rows = placed & ~detector.update(whiskers, f0, m0)[0]
        free = int(np.count_nonzero(free_rows))
        placed &= ~free_rows
    return _Rows(q, p, f0, m0, placed, units, frame_id, no_pose, len(missing), errors, free,
                 len(wrong))


def reconstruct_messages(msgs: Sequence[Wrenches], rod: Rods = _UNIT_ROD,
                         frames: FrameBuffer | None = None, map_frame: str = WORLD_FRAME,
                         detector: ContactDetector | None = None,
                         tip_sigmas: float = TIP_SIGMAS) -> list[Reconstructed]:
    """Reconstruct a batch of messages in one Step 2 call (``vibrissa.reconstruct.reconstruct_si``).

    A row's clamp pose is the one its message carries, else its clamp frame in ``map_frame``
    at the message's stamp from ``frames`` (`FrameBuffer.lookup_rows`); its rod is ``rod``, or
    its whisker's from the mapping. The rows of every
    message of the batch, in order, go through one compiled call, so a backlog costs one call
    instead of one per message (on a few dozen rows the cost is the calls, not the rows).
    Step 2 works row by row: a row's point does not depend on the batch it arrived in
    (batches follow arrival timing), so a replayed bag gives the live run's points bit for
    bit. With a ``detector``
    (the sensors' noise), rows of a free rod are left out (``free``) and points carry their
    covariance; the detector's state moves on with the rows, in order.
    """
    parts = [_rows(msg, rod, frames, map_frame, detector) for msg in msgs]
    whole = len(parts) == 1 and parts[0].placed.all()  # the rows as they are
    if whole:
        part = parts[0]
        q, p0, f0, m0 = part.q, part.p, part.f0, part.m0
    else:
        q, p0, f0, m0 = (np.vstack([getattr(part, name)[part.placed] for part in parts])
                         for name in ("q", "p", "f0", "m0"))
    rods: RodScale | FloatArray
    if isinstance(rod, RodScale):
        rods = rod
    elif whole:
        rods = cast(FloatArray, parts[0].units)
    else:
        rods = np.vstack([cast(FloatArray, part.units)[part.placed] for part in parts])
    if detector is None:
        result = reconstruct_si(q, p0, f0, m0, rods)
    else:
        result = reconstruct_si(q, p0, f0, m0, rods, detector.covariance, tip_sigmas)
    point, s1, phase, force, status = (result.point_m, result.s1_m, result.phase,
                                       result.force_n, result.status)
    # a row whose result overflows (finite inputs near the float limit) is flagged
    # NON_FINITE_INPUT by Step 2: not valid, so it counts as no consistent contact
    valid = result.valid
    covariance = result.covariance_m2
    # with a noise model: per row, a point that is the tip within the noise, or that has no
    # covariance (an axial load: it gets the rod's reach, L^2 I)
    tip_within_noise = no_covariance = None
    if covariance is not None:
        tip_within_noise = valid & ((status & int(ContactStatus.TIP_WITHIN_NOISE)) != 0)
        no_covariance = valid & ~np.isfinite(covariance).all(axis=(1, 2))
        if no_covariance.any():
            length_m = (np.full(len(valid), rods.length_m) if isinstance(rods, RodScale)
                        else rods[:, 0])
            covariance[no_covariance] = np.eye(3) * length_m[no_covariance, None, None] ** 2
        covariance.flags.writeable = False
    for value in (point, s1, phase, force, status):
        value.flags.writeable = False  # fresh arrays of this call: messages take them as they are
    outcomes = []
    first = 0
    for msg, part in zip(msgs, parts, strict=True):
        n = int(np.count_nonzero(part.placed))
        rows = slice(first, first + n)
        good = int(np.count_nonzero(result.pose_ok[rows]))
        kept = int(np.count_nonzero(valid[rows]))
        whisker_ids = msg.whisker_ids
        rows_kept: slice | npt.NDArray[np.intp] = rows
        if kept < len(whisker_ids):
            valid_rows = valid[rows]
            in_message = np.zeros(len(whisker_ids), bool)  # the kept rows of the message
            in_message[part.placed] = valid_rows
            whisker_ids = list(compress(whisker_ids, in_message.tolist()))
            rows_kept = first + np.flatnonzero(valid_rows)
        contacts = ContactPointArray(
            stamp=msg.stamp, seq=msg.seq, frame_id=part.frame_id, whisker_ids=whisker_ids,
            point=point[rows_kept], s1=s1[rows_kept], phase=phase[rows_kept],
            force=force[rows_kept], status=status[rows_kept],
            covariance=None if covariance is None else covariance[rows_kept])
        outcomes.append(Reconstructed(
            contacts, no_contact=good - kept, bad_pose=n - good, no_pose=part.no_pose,
            unknown_whisker=part.unknown_whisker, errors=part.errors, free=part.free,
            wrong_frame=part.wrong_frame,
            tip_within_noise=(0 if tip_within_noise is None
                              else int(np.count_nonzero(tip_within_noise[rows]))),
            no_covariance=(0 if no_covariance is None
                           else int(np.count_nonzero(no_covariance[rows])))))
        first += n
    return outcomes


def collect_batch(
    receive: Callable[[float], Received | None], timeout_s: float, max_batch: int,
    on_pose: Callable[[RobotPose], None] = lambda pose: None, end_topic: str | None = None,
    max_span_s: float = math.inf,
) -> tuple[list[Wrenches], EndOfStream | None, bool]:
    """Wait up to ``timeout_s`` for one message, then drain what is already queued.

    Draining stops at ``max_batch`` messages (a WhiskerWrenchArray counts as one), once the
    stamps taken (the wrenches' and the poses') span more than ``max_span_s`` (under a backlog
    of a stream played faster than real time: poses applied far ahead of a batch's first
    wrench would push the poses it needs out of a frame buffer's history), or at an
    ``EndOfStream`` (on ``end_topic`` when given: the end of the pose stream is not the end of
    the wrenches), which is returned separately so that it goes downstream after the points of
    the wrenches before it. A RobotPose goes to ``on_pose`` as it comes. Returns the batch, the
    EndOfStream, and whether draining stopped before the queue was empty (a backlog).
    """
    batch: list[Wrenches] = []
    first, last = math.inf, -math.inf  # the stamps taken so far span [first, last]
    rx = receive(timeout_s)
    while rx is not None:
        msg: Message = rx.msg
        if isinstance(msg, EndOfStream) and end_topic in (None, rx.topic):
            return batch, msg, False
        if isinstance(msg, (WhiskerWrenchArray, RobotPose)):
            if isinstance(msg, RobotPose):
                on_pose(msg)
            else:
                batch.append(msg)
            first, last = min(first, msg.stamp), max(last, msg.stamp)
            if len(batch) >= max_batch or last - first > max_span_s:
                return batch, None, True
        rx = receive(0.0)
    return batch, None, False


class BatchCollector:
    """Batches from a queue: per burst while the node keeps up, large under a backlog.

    A batch holds at most ``drain_limit`` messages, so the first wrench of a burst (a tick of
    many whiskers) goes out after at most that many decodes, not after the whole burst. A
    batch that reaches its limit means a backlog: the next one drains up to ``max_batch``
    and the limit drops back once a batch ends below it. A batch also ends once its stamps
    span ``max_span_s`` (see :func:`collect_batch`). ``drained`` says whether the last batch
    ended on an empty queue (everything sent before it has been read, poses too).
    """

    def __init__(self, receive: Callable[[float], Received | None], drain_limit: int,
                 max_batch: int, on_pose: Callable[[RobotPose], None] = lambda pose: None,
                 end_topic: str | None = None, max_span_s: float = math.inf) -> None:
        self._receive = receive
        self._on_pose = on_pose
        self._end_topic = end_topic
        self.drain_limit = drain_limit
        self.max_batch = max_batch
        self.max_span_s = max_span_s
        self.limit = drain_limit
        self.drained = True

    def collect(self, timeout_s: float) -> tuple[list[Wrenches], EndOfStream | None]:
        """The next batch (see :func:`collect_batch`) and the limit for the one after."""
        batch, eos, backlog = collect_batch(self._receive, timeout_s, self.limit, self._on_pose,
                                            self._end_topic, self.max_span_s)
        self.drained = eos is None and not backlog
        self.limit = self.max_batch if backlog else self.drain_limit
        return batch, eos


BACKLOG_TIMEOUTS = 10.0
"""Under a backlog that never drains, a wrench waits this many ``pose_timeout_s`` for its pose."""

MAX_HELD_POSES = 20_000
"""The most robot poses `PoseWait` holds (200 s at 100 Hz, about 12 MB)."""


class PoseWait:
    """Wrenches waiting for the robot pose at their stamp, in arrival order.

    A wrench is ready when it carries its clamp pose, or when every frame it was measured in
    can be looked up in the map frame at its stamp (the pose stream has passed it; a frame the
    robot description does not have is left out: its rows count as ``unknown_whisker``); one that
    has waited ``timeout_s`` is let through too, and its rows then count as ``no_pose``, but
    only once the input queue has been drained since (``take(drained=True)``): under a
    backlog the pose it waits for may be queued behind other wrenches, and a pose that was
    sent is not missing. A permanent backlog still ends the wait, after
    ``BACKLOG_TIMEOUTS`` x ``timeout_s``. The order of the wrenches is kept: one that waits
    holds back those behind it.

    Robot poses given to `hold` go to ``on_pose`` (into ``frames``) in arrival order: as many
    as the front wrench needs when it is not ready without them (in `take`, before any wrench
    times out), the others at `apply_poses`, which the node calls once the points of what `take`
    let through are out. So a tick that arrives with the next pose (a pose stream ahead of the
    wrenches) is not late by that pose's handling (a tenth of a millisecond live, on one tick in
    ten at 1 kHz ticks and 100 Hz poses). `apply_poses` also keeps back a pose stamped more
    than ``lead_s`` past the newest wrench until it has been held for ``timeout_s`` with no
    wrench coming meanwhile: poses that arrive far ahead of their wrenches (a recording played
    as fast as possible, its poses and wrenches on separate sockets) would push the poses the
    wrenches behind them need out of the frames' history. At most `MAX_HELD_POSES` are held
    (then the oldest goes in). A lookup between two kept poses does not depend on newer ones
    (`vibrissa.frame_buffer`), so the points are the same bits whenever a pose goes in.
    """

    def __init__(self, frames: FrameBuffer | None, map_frame: str, timeout_s: float,
                 clock: Callable[[], float] = time.monotonic,
                 on_pose: Callable[[RobotPose], None] = lambda pose: None,
                 lead_s: float = math.inf) -> None:
        self.frames = frames
        self.map_frame = map_frame
        self.timeout_s = timeout_s
        self.lead_s = lead_s
        self._clock = clock
        self._on_pose = on_pose
        self._queue: deque[tuple[float, Wrenches]] = deque()
        self._poses: deque[tuple[float, RobotPose]] = deque()  # held since, in arrival order
        self._newest = -math.inf  # the newest wrench's stamp
        self._last_wrench = -math.inf  # when the last wrench arrived

    def __len__(self) -> int:
        return len(self._queue)

    def add(self, msgs: Sequence[Wrenches]) -> None:
        now = self._clock()
        self._queue.extend((now, msg) for msg in msgs)
        if msgs:
            self._newest = max([self._newest, *(msg.stamp for msg in msgs)])
            self._last_wrench = now

    def hold(self, pose: RobotPose) -> None:
        """Keep a robot pose until a wrench needs it, or until `apply_poses`."""
        self._poses.append((self._clock(), pose))
        if len(self._poses) > MAX_HELD_POSES:
            self._on_pose(self._poses.popleft()[1])

    def apply_poses(self) -> None:
        """Hand the held robot poses to ``on_pose``, in arrival order, up to the first stamped
        more than ``lead_s`` past the newest wrench that has not waited ``timeout_s`` without
        a wrench coming."""
        limit = self._newest + self.lead_s if self.lead_s < math.inf else math.inf
        quiet_since = self._clock() - self.timeout_s
        while self._poses:
            held_since, pose = self._poses[0]
            if pose.stamp > limit and max(held_since, self._last_wrench) > quiet_since:
                break
            self._poses.popleft()
            self._on_pose(pose)

    def take(self, drained: bool = True) -> list[Wrenches]:
        """The wrenches from the front that are ready or have waited long enough: ``timeout_s``
        when the input queue is ``drained``, ``BACKLOG_TIMEOUTS`` x ``timeout_s`` when not.
        While the front one is not ready and poses are held, they go in, oldest first."""
        out = self._take(drained, expire=not self._poses)
        while self._queue and self._poses:  # the front one's pose may be held
            self._on_pose(self._poses.popleft()[1])
            out += self._take(drained, expire=not self._poses)
        return out

    def _take(self, drained: bool, expire: bool) -> list[Wrenches]:
        out: list[Wrenches] = []
        deadline = (self._clock() - self.timeout_s * (1.0 if drained else BACKLOG_TIMEOUTS)
                    if expire else -math.inf)
        while self._queue:
            arrived, msg = self._queue[0]
            if arrived > deadline and not self._ready(msg):
                break
            out.append(self._queue.popleft()[1])
        return out

    def wait_s(self) -> float:
        """Seconds until the front wrench times out (inf with none waiting)."""
        if not self._queue:
            return math.inf
        return max(0.0, self._queue[0][0] + self.timeout_s - self._clock())

    def _ready(self, msg: Wrenches) -> bool:
        if msg.has_pose or self.frames is None:
            return True
        sources = msg.frame_ids
        newest = self.frames.newest_rows(self.map_frame, sources)
        return (newest is not None and newest >= msg.stamp
                and not self.frames.has_gap_rows(self.map_frame, sources, msg.stamp))


def _count(counters: dict[str, int], outcome: Reconstructed) -> None:
    contacts = outcome.contacts
    counters["contacts"] += len(contacts.whisker_ids) if contacts is not None else 0
    counters["no_contact"] += outcome.no_contact
    counters["bad_pose"] += outcome.bad_pose
    counters["no_pose"] += outcome.no_pose
    counters["unknown_whisker"] += outcome.unknown_whisker
    counters["wrong_frame"] += outcome.wrong_frame
    counters["free"] += outcome.free
    counters["tip_within_noise"] += outcome.tip_within_noise
    counters["no_covariance"] += outcome.no_covariance


def robot_frames(whiskers: Sequence[Whisker], robot_frame: str = ROBOT_FRAME,
                 history_s: float = DEFAULT_HISTORY_S, max_gap_s: float = math.inf
                 ) -> FrameBuffer:
    """A frame buffer with the mounts of the robot description: each whisker's clamp frame
    (`vibrissa.frames.clamp_frame`) at X_RC in ``robot_frame``."""
    frames = FrameBuffer(history_s, max_gap_s, gap_name="max_pose_gap_s")
    for whisker in whiskers:
        frames.set_static(robot_frame, clamp_frame(whisker.name), whisker.X_RC)
    return frames


def _compile_kernels(rod: Rods, detector: ContactDetector | None) -> None:
    """Compile Step 2 and the frame kernels for the arrays the node will see (or load them
    from numba's cache) now, so that the first wrench is not late by the compile time (~3 s
    on a fresh install, 4-6 ms a kernel from the cache): decoded messages hold read-only
    arrays, a backlog of ticks is concatenated into writable ones, and a robot tick's clamps
    come from the pose at its stamp or from the two around it. A detector's warm-up state is
    dropped after."""
    one = rod if isinstance(rod, RodScale) else next(iter(rod.values()), _UNIT_ROD)
    tick = decode(encode(WhiskerWrenchArray(
        stamp=0.0, seq=0, whisker_ids=["warm-up"], frame_ids=["warm-up/clamp"],
        f0=[[0.1 * one.force_n, 0.0, 0.0]], m0=[[0.0, 0.05 * one.moment_nm, 0.0]],
        pose_frame_id="world", clamp_position=[[0.0, 0.0, 0.0]],
        clamp_orientation=[[0.0, 0.0, 0.0, 1.0]])), WhiskerWrenchArray)
    for batch in ([tick], [tick, tick]):
        reconstruct_messages(batch, one)
        if detector is not None:
            warm_up = ContactDetector(detector.covariance, detector.on_sigmas,
                                      detector.off_sigmas)
            reconstruct_messages(batch, one, detector=warm_up)
    frames = robot_frames([Whisker("warm-up", 1.0, 1.0)])
    for stamp in (0.0, 1.0):  # the robot in odom, odom in world
        frames.add("odom", ROBOT_FRAME, stamp, Transform())
        frames.add("world", "odom", stamp, Transform())
    for target, stamp in (("odom", 0.5), ("odom", 1.0), ("world", 0.5)):  # between two poses,
        frames.lookup_rows(target, ["warm-up/clamp"] * 2, stamp)  # at the newest, up a chain


_KIND = re.compile(r"'[^']*'|\"[^\"]*\"|[-+]?\.?\d[\w.+-]*")  # names and numbers in a text
_MAX_KINDS = 256
_LOGGED_CHARS = 500


class Warnings:
    """Warnings logged once per kind, then every 1000th of it with its count: a kind is the
    text without its quoted names and its numbers, so a stamp in each "no pose at t=..." does
    not make every wrench a kind of its own, nor use up what other kinds get. At most
    `_MAX_KINDS` kinds (then one more, "other"); a text is logged to `_LOGGED_CHARS`
    characters (names come off the wire)."""

    def __init__(self, fqn: str) -> None:
        self.fqn = fqn
        self._counts: dict[str, int] = {}

    def __call__(self, text: str) -> None:
        kind = _KIND.sub("#", text[:_LOGGED_CHARS])
        if kind not in self._counts and len(self._counts) >= _MAX_KINDS:
            kind = "other"
        count = self._counts[kind] = self._counts.get(kind, 0) + 1
        if count == 1 or count % 1000 == 0:
            shown = text if len(text) <= _LOGGED_CHARS else text[:_LOGGED_CHARS - 3] + "..."
            log.warning("%s: %s%s", self.fqn, shown,
                        f" ({count} of this kind so far)" if count > 1 else "")


def _on_pose(frames: FrameBuffer, counters: dict[str, int], warn: Warnings
             ) -> Callable[[RobotPose], None]:
    def on_pose(pose: RobotPose) -> None:
        if pose.child_frame_id not in frames:  # no clamp hangs under it: of no use, and a
            counters["bad_robot_pose"] += 1    # stream of invented names would fill the buffer
            warn(f"robot pose refused: {pose.child_frame_id!r} is neither the robot's frame nor "
                 "above it (a frame comes above it as the parent in a pose)")
            return
        parent = frames.parent(pose.child_frame_id)
        try:
            forgotten = frames.add_pose(pose.frame_id, pose.child_frame_id, pose.stamp,
                                        pose.position, pose.orientation)
        except ValueError as exc:  # a zero quaternion, a frame that would close a loop, ...
            counters["bad_robot_pose"] += 1
            warn(f"robot pose refused: {exc}")
            return
        counters["robot_poses"] += 1
        if parent is not None and parent != pose.frame_id:
            counters["pose_reparents"] += 1
            warn(f"the poses of {pose.child_frame_id!r} now come in {pose.frame_id!r}, no longer "
                 f"in {parent!r}: its history there is dropped")
        if forgotten is not None:
            counters["pose_time_jumps"] += 1
            warn(f"the poses of {pose.child_frame_id!r} in {pose.frame_id!r} start again at "
                 f"t={pose.stamp!r}, behind the kept history (newest t={forgotten!r}): that "
                 "history is dropped")
    return on_pose


def run(node: Node, params: ReconstructorParams) -> None:
    """Reconstruct until stopped (or the first ``EndOfStream`` with ``exit_on_eos``)."""
    counters = node.counters
    counters.update(contacts=0, free=0, tip_within_noise=0, no_covariance=0, no_contact=0,
                    bad_pose=0, no_pose=0, unknown_whisker=0, wrong_frame=0, robot_poses=0,
                    bad_robot_pose=0,
                    pose_time_jumps=0, pose_reparents=0, batches=0, max_batch=0)
    whiskers = load_robot(params.robot) if params.robot else ()
    rod: Rods = RodTable({w.name: w.scale for w in whiskers}) if whiskers else params.rod
    frames = (robot_frames(whiskers, params.robot_frame, params.history_s, params.max_pose_gap_s)
              if whiskers else None)
    topics: dict[str, object] = {params.input_topic: WhiskerWrenchArray}
    if frames is not None:
        topics[params.pose_topic] = RobotPose
    subscriber = node.create_subscriber(topics, hwm=params.receive_hwm)  # type: ignore[arg-type]
    publisher = node.create_publisher(params.output_topic, ContactPointArray,
                                      wait_for=params.wait_for)
    warn = Warnings(node.fqn)
    wait = PoseWait(frames, params.map_frame, params.pose_timeout_s,
                    on_pose=_on_pose(frames, counters, warn) if frames is not None else (
                        lambda pose: None), lead_s=params.history_s / 2)
    batches = BatchCollector(subscriber.receive, params.drain_limit, params.max_batch, wait.hold,
                             resolve_topic(params.input_topic, node.namespace),
                             max_span_s=params.history_s / 2)
    detector = None
    if params.noise_force_n > 0:
        detector = ContactDetector(wrench_covariance(params.noise_force_n,
                                                     params.noise_moment_nm),
                                   params.contact_on_sigmas, params.contact_off_sigmas)
    _compile_kernels(rod, detector)
    node.set_state("running")
    ends: list[EndOfStream] = []  # held until the wrenches before them are out
    while not node.stop_requested:
        batch, eos = batches.collect(min(0.1, wait.wait_s()))
        wait.add(batch)
        if eos is not None:
            ends.append(eos)
        ready = wait.take(batches.drained)
        outcomes = reconstruct_messages(ready, rod, frames, params.map_frame, detector,
                                        params.tip_sigmas) if ready else ()
        for outcome in outcomes:
            if outcome.contacts is not None:
                publisher.publish(outcome.contacts)
            _count(counters, outcome)
            for error in outcome.errors:
                warn(error)
        if ready:
            counters["batches"] += 1
            counters["max_batch"] = max(counters["max_batch"], len(ready))
        wait.apply_poses()  # the poses no wrench waited for, now that the points are out
        while ends and not len(wait):
            end = ends.pop(0)
            publisher.publish_end_of_stream(node.fqn)
            log.info("%s: EndOfStream from %s (%d samples); %s", node.fqn, end.source,
                     end.count, ", ".join(f"{k} {v}" for k, v in counters.items()))
            if params.exit_on_eos:
                return


def main(argv: Sequence[str] | None = None) -> int:
    """Run the reconstructor node (see ARCHITECTURE.md for the command line)."""
    args = NodeArgs.parse(argv, prog="python -m vibrissa.nodes.reconstructor")
    configure_logging()
    params = load_params(ReconstructorParams, args.params_file, args.params)
    with Node.from_args(args) as node:
        run(node, params)
    return 0


if __name__ == "__main__":
    run_main(main)
