"""Reconstructor node: contact points from whisker base wrenches (Step 2), batched when behind.

Subscribes
----------
``input_topic`` (default ``wrench``) : WhiskerWrench or WhiskerWrenchArray
    SI: clamp position m, f0 N, m0 N m (in the clamp frame C), pose X_WC in ``frame_id``;
    an array holds one row per whisker of one tick.

Publishes
---------
``output_topic`` (default ``contact``) : ContactPoint or ContactPointArray
    One ContactPoint per WhiskerWrench with a consistent contact (status OK or AXIAL_LOAD),
    in the wrench's ``frame_id``, same ``stamp``, ``seq`` and ``whisker_id``; one
    ContactPointArray per WhiskerWrenchArray (same ``stamp``, ``seq``, ``frame_id``) with
    the rows that have a consistent contact (possibly none); then an ``EndOfStream`` of its
    own for every ``EndOfStream`` that arrives on the input (after the points before it).

Samples without a consistent contact are **counted, not sent**: the codec refuses the NaN a
point-less reconstruction carries, and a point with finite placeholder zeros would be a point
on the map. Counters in this node's ``NodeStatus`` (besides the runtime's received, published,
rejected, lost): ``contacts`` (points published), ``no_contact`` (valid wrench, no consistent
contact), ``bad_pose`` (clamp quaternion of zero or non-finite length), ``batches`` and
``max_batch`` (batches and the largest, in messages); the first three count array rows. Undecodable input (wrong type,
version, field type, truncated bytes, NaN) is rejected and counted by the transport
(``rejected``) and the node carries on.

Units: the core works in the paper's units; ``vibrissa.units.RodScale`` (L = ``rod_length_m``,
EI = ``rod_ei_nm2``) converts the wrench on the way in and the contact point, arc length and
force on the way out.
"""

from __future__ import annotations

import itertools
import logging
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeAlias

import numpy as np
import numpy.typing as npt

from vibrissa.compiled import compiled
from vibrissa.msgs import (
    ContactPhase,
    ContactPoint,
    ContactPointArray,
    ContactStatus,
    EndOfStream,
    Message,
    WhiskerWrench,
    WhiskerWrenchArray,
    decode,
    encode,
)
from vibrissa.reconstruct import reconstruct_row
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params
from vibrissa.status import NO_CONTACT
from vibrissa.units import RodScale
from vibrissa.wire.transport import Received

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

_UNIT_ROD = RodScale()
_PHASES = {int(p): p for p in ContactPhase}


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
        WhiskerWrenchArray counts as one message; the arrays of a batch share one Step 2
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
        L, m.
    rod_ei_nm2
        EI, N m^2.
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
    rod: RodScale = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "rod", RodScale(self.rod_length_m, self.rod_ei_nm2))  # checks > 0
        if self.drain_limit < 1 or self.max_batch < 1:
            raise ValueError("drain_limit and max_batch must be >= 1, got "
                             f"{self.drain_limit}, {self.max_batch}")


@dataclass
class BatchResult:
    """Outcome of :func:`reconstruct_wrenches`.

    Attributes
    ----------
    contacts
        Points of the wrenches with a consistent contact, in input order.
    no_contact
        Wrenches whose reconstruction has no consistent contact (not in ``contacts``).
    bad_pose
        Wrenches skipped because their clamp quaternion has zero or non-finite length.
    """

    contacts: list[ContactPoint] = field(default_factory=list)
    no_contact: int = 0
    bad_pose: int = 0


def reconstruct_wrenches(wrenches: Sequence[WhiskerWrench], rod: RodScale = _UNIT_ROD
                         ) -> BatchResult:
    """Reconstruct a batch of wrenches, each in one compiled call (quaternion, units, Step 2).

    The same compiled row as a ``WhiskerWrenchArray``'s rows (``vibrissa.reconstruct.
    reconstruct_row``): a wrench's point never depends on the batch it arrived in (batches
    follow arrival timing), so a replayed bag gives the live run's points bit for bit, and a
    wrench gives the same bits as the same row of an array.

    Parameters
    ----------
    wrenches
        SI samples; each may have its own clamp pose X_WC.
    rod
        L and EI of the rod.

    Returns
    -------
    BatchResult
        A ContactPoint (SI, in the wrench's ``frame_id``) for every wrench whose status is OK
        or AXIAL_LOAD; the others are only counted.
    """
    result = BatchResult()
    length, force_n, moment_nm = rod.length_m, rod.force_n, rod.moment_nm
    for w in wrenches:
        good, px, py, pz, s1, phase, fx, fy, fz, status = _wrench_si(
            w.clamp_orientation, w.clamp_position, w.f0, w.m0, length, force_n, moment_nm)
        if not good:
            result.bad_pose += 1
        elif status & _NO_CONTACT:
            result.no_contact += 1
        else:
            result.contacts.append(ContactPoint(
                stamp=w.stamp, seq=w.seq, whisker_id=w.whisker_id, frame_id=w.frame_id,
                point=[px, py, pz], s1=s1, phase=_PHASES[phase], force=[fx, fy, fz],
                status=ContactStatus(status)))
    return result


_NO_CONTACT = int(NO_CONTACT)


@dataclass
class ArrayResult:
    """Outcome of :func:`reconstruct_array`.

    Attributes
    ----------
    contacts
        The rows with a consistent contact, in input order (possibly none).
    no_contact
        Rows whose reconstruction has no consistent contact (not in ``contacts``).
    bad_pose
        Rows skipped because their clamp quaternion has zero or non-finite length.
    """

    contacts: ContactPointArray
    no_contact: int
    bad_pose: int


def reconstruct_array(msg: WhiskerWrenchArray, rod: RodScale = _UNIT_ROD) -> ArrayResult:
    """Reconstruct one tick of a whisker array in one Step 2 call.

    Every row with a usable pose goes through ``vibrissa.reconstruct.reconstruct_row``, as the
    wrenches of :func:`reconstruct_wrenches` do: the same row gives the same bits either way.

    Parameters
    ----------
    msg
        SI rows, each with its own clamp pose X_WC in ``msg.frame_id``.
    rod
        L and EI of the rod.

    Returns
    -------
    ArrayResult
        A ContactPointArray (SI, in ``msg.frame_id``, same ``stamp`` and ``seq``) of the rows
        whose status is OK or AXIAL_LOAD; the others are only counted.
    """
    return reconstruct_arrays([msg], rod)[0]


def reconstruct_arrays(msgs: Sequence[WhiskerWrenchArray], rod: RodScale = _UNIT_ROD
                       ) -> list[ArrayResult]:
    """:func:`reconstruct_array` of each message, with one Step 2 call for the rows of all.

    A backlog of ticks costs one call instead of one per tick (on a few dozen rows the cost is
    the calls, not the rows). Step 2 works row by row, so a row's result does not depend on the
    other rows of the call: a message's points are the same bits whatever batch it arrived in,
    and a replayed bag gives the live run's points exactly.
    """
    if len(msgs) == 1:
        msg = msgs[0]
        q, p0, f0, m0 = msg.clamp_orientation, msg.clamp_position, msg.f0, msg.m0
    else:
        q, p0, f0, m0 = (np.concatenate([getattr(m, name) for m in msgs]) for name in
                         ("clamp_orientation", "clamp_position", "f0", "m0"))
    good, point, s1, phase, force, status = _rows_si(q, p0, f0, m0, rod.length_m, rod.force_n,
                                                     rod.moment_nm)
    all_good = np.count_nonzero(good) == len(good)
    valid = (status & _NO_CONTACT) == 0
    columns: tuple[npt.NDArray[Any], ...] = (point, s1, phase, force, status)
    if not all_good:  # the rows of a bad pose are not in the call's results
        columns, valid = tuple(value[good] for value in columns), valid[good]
    all_valid = all_good and np.count_nonzero(valid) == len(valid)
    good_rows = None if all_good else np.cumsum(good)  # good rows up to and including each row
    results = []
    row = first = 0  # the message's first row in q, and in the good rows
    for msg in msgs:
        n = len(msg.whisker_ids)
        if good_rows is None:
            last = first + n
        else:
            last = int(good_rows[row + n - 1]) if n else first
        whisker_ids = msg.whisker_ids
        if all_valid:
            outputs = tuple(value[first:last] for value in columns)
        else:
            msg_good = np.flatnonzero(good[row:row + n])
            msg_valid = valid[first:last]
            whisker_ids = [whisker_ids[i] for i in msg_good[msg_valid].tolist()]
            outputs = tuple(value[first:last][msg_valid] for value in columns)
        for value in outputs:  # fresh arrays of this call: the message takes them without a copy
            value.flags.writeable = False
        point, s1, phase, force, status = outputs
        contacts = ContactPointArray(
            stamp=msg.stamp, seq=msg.seq, frame_id=msg.frame_id, whisker_ids=whisker_ids,
            point=point, s1=s1, phase=phase, force=force, status=status,
        )
        results.append(ArrayResult(contacts, no_contact=last - first - len(whisker_ids),
                                   bad_pose=n - (last - first)))
        row, first = row + n, last
    return results


@compiled
def _quaternion_matrix(q_xyzw: FloatArray, rotation: FloatArray) -> float:
    """Write R(q / |q|) of a quaternion (4,) (x, y, z, w) into ``rotation`` (3, 3); returns
    |q|^2 (the matrix is not a rotation unless that is finite and > 0)."""
    x, y, z, w = q_xyzw[0], q_xyzw[1], q_xyzw[2], q_xyzw[3]
    norm2 = x * x + y * y + z * z + w * w
    s = 2.0 / norm2 if norm2 > 0.0 else math.nan
    r = rotation
    r[0, 0], r[0, 1], r[0, 2] = 1.0 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)
    r[1, 0], r[1, 1], r[1, 2] = s * (x * y + z * w), 1.0 - s * (x * x + z * z), s * (y * z - x * w)
    r[2, 0], r[2, 1], r[2, 2] = s * (x * z - y * w), s * (y * z + x * w), 1.0 - s * (x * x + y * y)
    return norm2


@compiled
def quaternion_matrices(q_xyzw: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Rotation matrices (N, 3, 3) of quaternions (N, 4) (x, y, z, w), normalised first, and
    their squared norms (N,); rows of a zero or non-finite quaternion are not rotations."""
    n = q_xyzw.shape[0]
    rotation, norm2 = np.empty((n, 3, 3)), np.empty(n)
    for i in range(n):
        norm2[i] = _quaternion_matrix(q_xyzw[i], rotation[i])
    return rotation, norm2


@compiled
def _row_si(q_xyzw: FloatArray, p0: FloatArray, f0: FloatArray, m0: FloatArray, length_m: float,
            force_n: float, moment_nm: float, point: FloatArray, force: FloatArray
            ) -> tuple[bool, float, int, int]:
    """Step 2 of one SI row (clamp pose q (4,), p0 (3,) m; f0 N, m0 N m in C): whether the
    quaternion is usable (nonzero, finite), then ``reconstruct_row``'s s1 (m), phase and status,
    with the point (m) and force (N) written into ``point`` and ``force``."""
    rotation = np.empty((3, 3))
    norm2 = _quaternion_matrix(q_xyzw, rotation)
    if not (norm2 > 0.0 and norm2 < math.inf):
        return False, math.nan, 0, 0
    p0_L, f0_L, m0_L = np.empty(3), np.empty(3), np.empty(3)
    for j in range(3):
        p0_L[j], f0_L[j], m0_L[j] = p0[j] / length_m, f0[j] / force_n, m0[j] / moment_nm
    s1, phase, _psi, status = reconstruct_row(p0_L, f0_L, m0_L, True, rotation, point, force)
    for j in range(3):
        point[j] *= length_m
        force[j] *= force_n
    return True, s1 * length_m, phase, status


@compiled
def _wrench_si(q_xyzw: FloatArray, p0: FloatArray, f0: FloatArray, m0: FloatArray,
               length_m: float, force_n: float, moment_nm: float
               ) -> tuple[bool, float, float, float, float, int, float, float, float, int]:
    """:func:`_row_si` of one wrench in plain numbers: good, point, s1, phase, force, status."""
    point, force = np.empty(3), np.empty(3)
    good, s1, phase, status = _row_si(q_xyzw, p0, f0, m0, length_m, force_n, moment_nm, point,
                                      force)
    return good, point[0], point[1], point[2], s1, phase, force[0], force[1], force[2], status


@compiled
def _rows_si(q_xyzw: FloatArray, p0: FloatArray, f0: FloatArray, m0: FloatArray,
             length_m: float, force_n: float, moment_nm: float
             ) -> tuple[npt.NDArray[np.bool_], FloatArray, FloatArray, npt.NDArray[np.int32],
                        FloatArray, npt.NDArray[np.int32]]:
    """:func:`_row_si` of every row (N, ...): good, point, s1, phase, force, status, with phase
    and status as the int32 of ``ContactPointArray``."""
    n = q_xyzw.shape[0]
    good = np.empty(n, dtype=np.bool_)
    point, force, s1 = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
    phase, status = np.empty(n, dtype=np.int32), np.empty(n, dtype=np.int32)
    for i in range(n):
        good[i], s1[i], phase[i], status[i] = _row_si(
            q_xyzw[i], p0[i], f0[i], m0[i], length_m, force_n, moment_nm, point[i], force[i])
    return good, point, s1, phase, force, status


Wrenches: TypeAlias = WhiskerWrench | WhiskerWrenchArray


def collect_batch(
    receive: Callable[[float], Received | None], timeout_s: float, max_batch: int
) -> tuple[list[Wrenches], EndOfStream | None]:
    """Wait up to ``timeout_s`` for one message, then drain what is already queued.

    Draining stops at ``max_batch`` messages (a WhiskerWrenchArray counts as one) or at an
    ``EndOfStream``, which is returned separately so that it goes downstream after the points
    of the wrenches before it.
    """
    batch: list[Wrenches] = []
    rx = receive(timeout_s)
    while rx is not None:
        msg: Message = rx.msg
        if isinstance(msg, EndOfStream):
            return batch, msg
        if isinstance(msg, (WhiskerWrench, WhiskerWrenchArray)):
            batch.append(msg)
        if len(batch) >= max_batch:
            break
        rx = receive(0.0)
    return batch, None


class BatchCollector:
    """Batches from a queue: per burst while the node keeps up, large under a backlog.

    A batch holds at most ``drain_limit`` messages, so the first wrench of a burst (a tick of
    many whiskers) goes out after at most that many decodes, not after the whole burst. A
    batch that reaches its limit means a backlog: the next one drains up to ``max_batch``
    and the limit drops back once a batch ends below it.
    """

    def __init__(self, receive: Callable[[float], Received | None], drain_limit: int,
                 max_batch: int) -> None:
        self._receive = receive
        self.drain_limit = drain_limit
        self.max_batch = max_batch
        self.limit = drain_limit

    def collect(self, timeout_s: float) -> tuple[list[Wrenches], EndOfStream | None]:
        """The next batch (see :func:`collect_batch`) and the limit for the one after."""
        batch, eos = collect_batch(self._receive, timeout_s, self.limit)
        self.limit = self.max_batch if len(batch) >= self.limit else self.drain_limit
        return batch, eos


def _count(counters: dict[str, int], contacts: int, no_contact: int, bad_pose: int) -> None:
    counters["contacts"] += contacts
    counters["no_contact"] += no_contact
    counters["bad_pose"] += bad_pose


def _compile_kernels(rod: RodScale) -> None:
    """Compile Step 2 for the arrays the node will see (or load it from numba's cache) now, so
    that the first wrench is not late by the compile time (~3 s on a fresh install): decoded
    messages hold read-only arrays, a backlog of ticks is concatenated into writable ones."""
    tick = decode(encode(WhiskerWrenchArray(
        stamp=0.0, seq=0, frame_id="world", whisker_ids=["warm-up"], clamp_position=[[0.0, 0.0, 0.0]],
        clamp_orientation=[[0.0, 0.0, 0.0, 1.0]], f0=[[0.1 * rod.force_n, 0.0, 0.0]],
        m0=[[0.0, 0.05 * rod.moment_nm, 0.0]])), WhiskerWrenchArray)
    reconstruct_arrays([tick], rod)
    reconstruct_arrays([tick, tick], rod)
    reconstruct_wrenches([decode(encode(WhiskerWrench(
        stamp=0.0, seq=0, whisker_id="warm-up", frame_id="world", clamp_position=[0.0, 0.0, 0.0],
        clamp_orientation=[0.0, 0.0, 0.0, 1.0], f0=tick.f0[0], m0=tick.m0[0])), WhiskerWrench)], rod)


def run(node: Node, params: ReconstructorParams) -> None:
    """Reconstruct until stopped (or the first ``EndOfStream`` with ``exit_on_eos``)."""
    counters = node.counters
    counters.update(contacts=0, no_contact=0, bad_pose=0, batches=0, max_batch=0)
    subscriber = node.create_subscriber(
        {params.input_topic: (WhiskerWrench, WhiskerWrenchArray)}, hwm=params.receive_hwm)
    publisher = node.create_publisher(params.output_topic, (ContactPoint, ContactPointArray),
                                      wait_for=params.wait_for)
    batches = BatchCollector(subscriber.receive, params.drain_limit, params.max_batch)
    rod = params.rod
    _compile_kernels(rod)
    node.set_state("running")
    while not node.stop_requested:
        batch, eos = batches.collect(0.1)
        for kind, group in itertools.groupby(batch, type):  # runs of one type, in arrival order
            if kind is WhiskerWrenchArray:
                for array in reconstruct_arrays(
                        [m for m in group if isinstance(m, WhiskerWrenchArray)], rod):
                    publisher.publish(array.contacts)
                    _count(counters, len(array.contacts.whisker_ids), array.no_contact,
                           array.bad_pose)
            else:
                result = reconstruct_wrenches([m for m in group if isinstance(m, WhiskerWrench)],
                                              rod)
                for point in result.contacts:
                    publisher.publish(point)
                _count(counters, len(result.contacts), result.no_contact, result.bad_pose)
        if batch:
            counters["batches"] += 1
            counters["max_batch"] = max(counters["max_batch"], len(batch))
        if eos is not None:
            publisher.publish_end_of_stream(node.fqn)
            log.info("%s: EndOfStream from %s (%d samples); %s", node.fqn, eos.source,
                     eos.count, ", ".join(f"{k} {v}" for k, v in counters.items()))
            if params.exit_on_eos:
                break


def main(argv: Sequence[str] | None = None) -> int:
    """Run the reconstructor node (see ARCHITECTURE.md for the command line)."""
    args = NodeArgs.parse(argv, prog="python -m vibrissa.nodes.reconstructor")
    configure_logging()
    params = load_params(ReconstructorParams, args.params_file, args.params)
    with Node.from_args(args) as node:
        run(node, params)
    return 0


if __name__ == "__main__":
    sys.exit(main())
