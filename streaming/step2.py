"""Step 2 of a batch of ticks: each row's rod and clamp pose, one compiled call, a
ContactPointArray per tick with its counts."""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import accumulate, compress
from typing import TypeAlias, cast

import numpy as np
import numpy.typing as npt

from vibrissa.contact_detection import ContactDetector
from vibrissa.frame_buffer import DEFAULT_HISTORY_S, FrameBuffer
from vibrissa.frames import ROBOT_FRAME, WORLD_FRAME, clamp_frame
from vibrissa.msgs import ContactPointArray, ContactStatus, WhiskerWrenchArray
from vibrissa.reconstruct import TALLY, TIP_SIGMAS, ReconstructionSI, kernel_arguments
from vibrissa.reconstruct_rods import rows_si_tallied
from vibrissa.rods import UNIFORM, RodShape
from vibrissa.scene import Whisker
from vibrissa.units import RodScale, rod_units

FloatArray = npt.NDArray[np.float64]

UNIT_ROD = RodScale()

Rods: TypeAlias = RodScale | Mapping[str, RodScale]
"""One rod for every whisker, or each whisker's by name (the robot description)."""

_MAX_ROW_LISTS = 64
_NO_COVARIANCE = TALLY.index("no_covariance")


class RodTable(Mapping[str, RodScale]):
    """Each whisker's rod by name (its scale, and its shape where it is tapered or pre-curved:
    `vibrissa.rods.RodShape`), and the rods of a tick's rows as Step 2 takes them: an array
    sends the same whiskers tick after tick, so their units are made once."""

    def __init__(self, rods: Mapping[str, RodScale],
                 shapes: Mapping[str, RodShape] | None = None) -> None:
        self._rods = dict(rods)
        self._shapes = {name: shape for name, shape in (shapes or {}).items()
                        if not shape.uniform}
        self._rows: dict[tuple[tuple[str, ...], tuple[str, ...]],
                         tuple[FloatArray, list[int], list[int]]] = {}

    @property
    def shaped(self) -> bool:
        """Whether any whisker is tapered or pre-curved."""
        return bool(self._shapes)

    def shape_rows(self, whiskers: Sequence[str]) -> FloatArray:
        """Each row's `RodShape.params` (N, 3) (an unknown whisker's: the uniform rod's)."""
        return np.array([self._shapes.get(w, UNIFORM).params for w in whiskers],
                        dtype=float).reshape(len(whiskers), 3)

    def __getitem__(self, name: str) -> RodScale:
        return self._rods[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._rods)

    def __len__(self) -> int:
        return len(self._rods)

    def rows(self, whiskers: Sequence[str], frames: Sequence[str]
             ) -> tuple[FloatArray, list[int], list[int]]:
        """The units (N, 3) of the rows' rods (`vibrissa.units.rod_units`; an unknown
        whisker's are L = EI = 1), the rows of whiskers not in the table, and the rows of
        known whiskers measured in ``frames`` other than their clamp frame
        (`vibrissa.frames.clamp_frame`)."""
        key = (tuple(whiskers), tuple(frames))
        found = self._rows.get(key)
        if found is None:
            if len(self._rows) >= _MAX_ROW_LISTS:
                self._rows.clear()
            units = rod_units([self._rods.get(w, UNIT_ROD) for w in key[0]])
            units.flags.writeable = False
            found = self._rows[key] = (
                units, [i for i, w in enumerate(key[0]) if w not in self._rods],
                [i for i, (w, f) in enumerate(zip(*key, strict=True))
                 if w in self._rods and f != clamp_frame(w)])
        return found


@dataclass
class Reconstructed:
    """The outcome of one tick (a WhiskerWrenchArray).

    Attributes
    ----------
    contacts
        Its rows with a consistent contact (possibly none): SI, in the frame of the clamp
        poses the tick carried, else in the map frame; same ``stamp`` and ``seq``.
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
    multi_contact
        Rows of ``no_contact`` whose wrench no single contact gives (MULTI_CONTACT: two
        contacts on the rod, beyond the noise).
    ambiguous
        Points in ``contacts`` of a tapered or pre-curved rod chosen among several that fit
        their wrench without the last contact deciding (AMBIGUOUS_CONTACT).
    """

    contacts: ContactPointArray
    no_contact: int
    bad_pose: int
    no_pose: int = 0
    unknown_whisker: int = 0
    errors: list[str] = field(default_factory=list)
    free: int = 0
    wrong_frame: int = 0
    tip_within_noise: int = 0
    no_covariance: int = 0
    multi_contact: int = 0
    ambiguous: int = 0


class ContactMemory:
    """Each tapered or pre-curved whisker's last contact, its arc length s1 (m; NaN: none) and
    whether its choice was ambiguous, by which Step 2 chooses among the points that fit a
    wrench (`vibrissa.reconstruct_rods`): a stream's state, moved on with its rows in order."""

    def __init__(self) -> None:
        self._last: dict[str, tuple[float, bool]] = {}

    def links(self, whiskers: Sequence[str]
              ) -> tuple[FloatArray, npt.NDArray[np.bool_], npt.NDArray[np.int64]]:
        """For rows of ``whiskers`` in order: each row's previous contact from before the
        call (NaN: none), whether that was ambiguous, and the earlier row of its whisker in
        the call (-1: none), as `vibrissa.reconstruct.reconstruct_si` takes them."""
        previous = np.full(len(whiskers), math.nan)
        ambiguous = np.zeros(len(whiskers), dtype=np.bool_)
        chain = np.full(len(whiskers), -1, dtype=np.int64)
        last: dict[str, int] = {}
        for i, name in enumerate(whiskers):
            j = last.get(name)
            if j is None:
                previous[i], ambiguous[i] = self._last.get(name, (math.nan, False))
            else:
                chain[i] = j
            last[name] = i
        return previous, ambiguous, chain

    def update(self, whiskers: Sequence[str], s1_m: FloatArray, valid: npt.NDArray[np.bool_],
               status: npt.NDArray[np.int32]) -> None:
        """Rows of ``whiskers`` reconstructed, in order: their contacts' s1 (m) and status."""
        ambiguous = (status & int(ContactStatus.AMBIGUOUS_CONTACT)) != 0
        for name, s1, ok, unsure in zip(whiskers, s1_m.tolist(), valid.tolist(),
                                        ambiguous.tolist(), strict=True):
            self._last[name] = (s1, unsure) if ok else (math.nan, False)

    def forget(self, whiskers: Sequence[str]) -> None:
        """These whiskers are free: no contact to continue."""
        for name in whiskers:
            self._last.pop(name, None)


@dataclass
class _Rows:
    """The rows of one tick on their way to Step 2: clamp poses in ``frame_id`` where
    ``placed``."""

    q: FloatArray
    p: FloatArray
    placed: npt.NDArray[np.bool_]
    n_placed: int  # rows placed
    units: FloatArray | None  # of each row's rod (N, 3) (None: the one rod of every row)
    frame_id: str
    no_pose: int = 0
    unknown_whisker: int = 0
    errors: list[str] = field(default_factory=list)
    free: int = 0
    wrong_frame: int = 0
    free_rows: npt.NDArray[np.bool_] | None = None  # below the detector's threshold


def _rows(msg: WhiskerWrenchArray, rod: Rods, frames: FrameBuffer | None, map_frame: str,
          detector: ContactDetector | None) -> _Rows:
    whiskers = msg.whisker_ids
    n = len(whiskers)
    errors: list[str] = []
    units: FloatArray | None = None
    table = None if isinstance(rod, RodScale) else rod if isinstance(rod, RodTable) else RodTable(rod)
    missing: list[int] = []  # rows of whiskers the robot description does not have
    wrong: list[int] = []  # rows of its whiskers in another frame than their clamp frame
    wrong_frame: list[int] = []  # (placed through frames only)
    if table is not None:
        units, missing, wrong_frame = table.rows(whiskers, msg.frame_ids)
        if missing:
            errors.append(f"whisker {whiskers[missing[0]]!r} is not in the robot description "
                          f"({', '.join(table)})")
    if msg.pose_frame_id is not None:
        q, p = cast(FloatArray, msg.clamp_orientation), cast(FloatArray, msg.clamp_position)
        frame_id = msg.pose_frame_id
        no_pose = 0
        # every row placed: one shared read-only mask where nothing below changes it
        placed = np.ones(n, bool) if missing or detector is not None else _every_row(n)
    else:
        frame_id = map_frame
        if frames is None:
            q, p = np.zeros((n, 4)), np.zeros((n, 3))
            placed = np.zeros(n, bool)
            errors.append("a wrench without clamp pose needs the robot description (parameter "
                          "'robot') and the robot's poses")
        else:
            sources = msg.frame_ids
            poses = frames.lookup_rows(map_frame, sources, msg.stamp)
            q, p, placed = poses.q_xyzw, poses.p, poses.ok
            errors += poses.errors
            wrong = wrong_frame
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
    free_rows = None
    if detector is not None:  # every row moves its whisker's state, placed or not
        free_rows = placed & ~detector.update(whiskers, msg.f0, msg.m0)[0]
        free = int(np.count_nonzero(free_rows))
        placed &= ~free_rows
    # placed: the rows with a pose, but those of missing and wrong (disjoint) whiskers and the
    # free ones
    return _Rows(q, p, placed, n - no_pose - len(missing) - len(wrong) - free, units, frame_id,
                 no_pose, len(missing), errors, free, len(wrong), free_rows)


@functools.lru_cache(maxsize=_MAX_ROW_LISTS)
def _every_row(n: int) -> npt.NDArray[np.bool_]:
    """A read-only mask of ``n`` rows, all set (a tick's sizes repeat)."""
    every = np.ones(n, bool)
    every.flags.writeable = False
    return every


@functools.lru_cache(maxsize=_MAX_ROW_LISTS)
def _group_ends(sizes: tuple[int, ...]) -> npt.NDArray[np.int64]:
    """The ends of groups of ``sizes`` rows (a batch's ticks), read-only as the compiled Step 2
    takes them (a tick's sizes repeat)."""
    ends = np.fromiter(accumulate(sizes), np.int64, len(sizes))
    ends.flags.writeable = False
    return ends


def reconstruct_messages(msgs: Sequence[WhiskerWrenchArray], rod: Rods = UNIT_ROD,
                         frames: FrameBuffer | None = None, map_frame: str = WORLD_FRAME,
                         detector: ContactDetector | None = None,
                         tip_sigmas: float = TIP_SIGMAS,
                         memory: ContactMemory | None = None) -> list[Reconstructed]:
    """Reconstruct a batch of ticks in one Step 2 call (``vibrissa.reconstruct.reconstruct_si``).

    A row's clamp pose is the one its tick carries, else its clamp frame in ``map_frame`` at
    the tick's stamp from ``frames`` (`FrameBuffer.lookup_rows`); its rod is ``rod``, or its
    whisker's from the mapping. The rows of every tick of the batch, in order, go through one
    compiled call, so a backlog costs one call instead of one per tick (on a few dozen rows
    the cost is the calls, not the rows). Step 2 works row by row: a row's point does not
    depend on the batch it arrived in (batches follow arrival timing), so a replayed bag gives
    the live run's points bit for bit, and a tick of one row gives the same bits as the same
    row of a larger tick. A message's ``free_ids`` name its zero wrenches; with a ``detector``
    (the sensors' noise), also the rows below its threshold, which are left out (``free``),
    and points carry their covariance; the detector's state moves on with the
    rows, in order. A tapered or pre-curved whisker's point is chosen among the points that
    fit its wrench by continuity with its last contact (``memory``, moved on with the rows;
    without one, each batch starts afresh).
    """
    parts = [_rows(msg, rod, frames, map_frame, detector) for msg in msgs]
    whole = len(parts) == 1 and parts[0].n_placed == len(parts[0].placed)  # rows as they are
    if whole:
        part, msg = parts[0], msgs[0]
        q, p0, f0, m0 = part.q, part.p, msg.f0, msg.m0
    else:
        q, p0 = (np.vstack([getattr(part, name)[part.placed] for part in parts])
                 for name in ("q", "p"))
        f0, m0 = (np.vstack([getattr(msg, name)[part.placed] for msg, part
                             in zip(msgs, parts, strict=True)]) for name in ("f0", "m0"))
    rods: RodScale | FloatArray
    if isinstance(rod, RodScale):
        rods = rod
    elif whole:
        rods = cast(FloatArray, parts[0].units)
    else:
        rods = np.vstack([cast(FloatArray, part.units)[part.placed] for part in parts])
    table = rod if isinstance(rod, RodTable) else None
    shapes = previous = uncertain = chain = None
    names: list[str] = []
    if table is not None and table.shaped:
        names = [w for msg, part in zip(msgs, parts, strict=True)
                 for w in compress(msg.whisker_ids, part.placed.tolist())]
        if memory is not None:
            memory.forget([w for msg, part in zip(msgs, parts, strict=True)
                           if part.free_rows is not None
                           for w in compress(msg.whisker_ids, part.free_rows.tolist())])
        shapes = table.shape_rows(names)
        previous, uncertain, chain = (memory or ContactMemory()).links(names)
    q, p0, f0, m0 = (_kernel_input(q), _kernel_input(p0), _kernel_input(f0),
                     _kernel_input(m0))
    if not isinstance(rods, RodScale):
        rods = _kernel_input(rods)
    floats, ints, pose_ok, tallies = rows_si_tallied(q, p0, f0, m0, *kernel_arguments(
        len(q), rods, None if detector is None else detector.covariance, tip_sigmas, shapes,
        previous, chain, uncertain), _group_ends(tuple(part.n_placed for part in parts)))
    # fresh arrays of this call, their fields views: messages take them as they are
    floats.flags.writeable = ints.flags.writeable = False
    result = ReconstructionSI.of_blocks(floats, ints, pose_ok, detector is not None)
    counts = tallies.tolist()
    valid: npt.NDArray[np.bool_] | None = None  # made where needed (not for a tick all valid)
    if memory is not None and names:
        valid = result.valid
        memory.update(names, result.s1_m, valid, result.status)
    covariance = result.covariance_m2
    # with a noise model, a point that has no covariance (an axial load) gets the rod's
    # reach, L^2 I
    if covariance is not None and any(tick[_NO_COVARIANCE] for tick in counts):
        valid = result.valid
        no_covariance = valid & ~np.isfinite(covariance).all(axis=(1, 2))
        length_m = (np.full(len(valid), rods.length_m) if isinstance(rods, RodScale)
                    else rods[:, 0])
        covariance = covariance.copy()
        covariance[no_covariance] = np.eye(3) * length_m[no_covariance, None, None] ** 2
        covariance.flags.writeable = False
    fields: list[npt.NDArray[np.generic]] = [  # point, s1, phase, force, status
        result.point_m, result.s1_m, result.phase, result.force_n, result.status]
    if covariance is not None:
        fields.append(covariance)
    outcomes = []
    first = 0
    for msg, part, (good, kept, multi, ambiguous, tip_within_noise, no_covariance) in zip(
            msgs, parts, counts, strict=True):
        n = part.n_placed
        rows = slice(first, first + n)
        whisker_ids = msg.whisker_ids
        if kept == len(whisker_ids):  # every row of the message: views of the call's arrays
            kept_fields = fields if n == len(pose_ok) else [value[rows] for value in fields]
            whisker_ids = list(whisker_ids)
            free_ids: list[str] = []
        else:
            # free: a zero wrench, or below the detector's threshold
            free_mask = ~(msg.f0.any(axis=1) | msg.m0.any(axis=1))
            if part.free_rows is not None:
                free_mask |= part.free_rows
            free_ids = list(compress(whisker_ids, free_mask.tolist()))
            if valid is None:
                valid = result.valid
            in_message = np.zeros(len(whisker_ids), bool)  # the kept rows of the message
            in_message[part.placed] = valid[rows]
            whisker_ids = list(compress(whisker_ids, in_message.tolist()))
            rows_kept = first + np.flatnonzero(valid[rows])
            kept_fields = [value[rows_kept] for value in fields]
            for value in kept_fields:
                value.flags.writeable = False
        # Step 2's own output, as construction would make it: read-only arrays of the fields'
        # dtypes, sized alike, phases and statuses its kernel wrote, finite where valid; the
        # whisker ids of a decoded message (tests/streaming/test_step2.py: the same bytes as
        # the checked constructor)
        contacts = ContactPointArray.unchecked(
            stamp=msg.stamp, seq=msg.seq, frame_id=part.frame_id, whisker_ids=whisker_ids,
            point=kept_fields[0], s1=kept_fields[1], phase=kept_fields[2],
            force=kept_fields[3], status=kept_fields[4],
            covariance=None if covariance is None else kept_fields[5], free_ids=free_ids)
        outcomes.append(Reconstructed(
            contacts, no_contact=good - kept, bad_pose=n - good, no_pose=part.no_pose,
            unknown_whisker=part.unknown_whisker, errors=part.errors, free=part.free,
            wrong_frame=part.wrong_frame, tip_within_noise=tip_within_noise,
            no_covariance=no_covariance, multi_contact=multi, ambiguous=ambiguous))
        first += n
    return outcomes


def _kernel_input(array: FloatArray) -> FloatArray:
    """``array`` as the compiled Step 2 takes a stream's: float64, C-contiguous and read-only,
    as a decoded message's arrays are (one compiled variant for every call); a copy where it
    is not contiguous, a read-only view where it is writable (the caller's stays so)."""
    flags = array.flags
    if flags.c_contiguous and not flags.writeable:  # as decoded
        return array
    if not flags.c_contiguous:
        array = np.ascontiguousarray(array)
    view = array.view()
    view.flags.writeable = False
    return view


def robot_frames(whiskers: Sequence[Whisker], robot_frame: str = ROBOT_FRAME,
                 history_s: float = DEFAULT_HISTORY_S, max_gap_s: float = math.inf
                 ) -> FrameBuffer:
    """A frame buffer with the mounts of the robot description: each whisker's clamp frame
    (`vibrissa.frames.clamp_frame`) at X_RC in ``robot_frame``."""
    frames = FrameBuffer(history_s, max_gap_s, gap_name="max_pose_gap_s")
    for whisker in whiskers:
        frames.set_static(robot_frame, clamp_frame(whisker.name), whisker.X_RC)
    return frames
