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
rejected, lost, anomalies): ``contacts`` (points published), ``no_contact`` (valid wrench, no
consistent contact, or a result that overflows to inf near the float limit), ``bad_pose``
(clamp quaternion of zero or non-finite length), ``batches`` and ``max_batch`` (batches and
the largest, in messages); the first three count rows. Undecodable
input (wrong type, version, field type, truncated bytes, NaN) is rejected and counted by the
transport (``rejected``) and the node carries on.

Step 2 in SI, with the clamp pose and ``vibrissa.units.RodScale`` (L = ``rod_length_m``, EI =
``rod_ei_nm2``), is the core's ``vibrissa.reconstruct.reconstruct_si``; a WhiskerWrench is a
tick of one row, so both message shapes take the same path.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TypeAlias

import numpy as np
import numpy.typing as npt

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
from vibrissa.reconstruct import reconstruct_si
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main
from vibrissa.runtime.params import require, require_parsed, require_positive
from vibrissa.status import NO_CONTACT
from vibrissa.units import RodScale
from vibrissa.wire.topics import validate_name
from vibrissa.wire.transport import Received

log = logging.getLogger(__name__)

_NO_CONTACT = int(NO_CONTACT)

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


Wrenches: TypeAlias = WhiskerWrench | WhiskerWrenchArray


@dataclass
class Reconstructed:
    """The outcome of one input message.

    Attributes
    ----------
    contacts
        For a WhiskerWrench, its ContactPoint, or None without a consistent contact; for a
        WhiskerWrenchArray, a ContactPointArray of its rows with one (possibly none). SI, in
        the input's ``frame_id``, same ``stamp`` and ``seq``.
    no_contact
        Rows whose reconstruction has no consistent contact (not in ``contacts``).
    bad_pose
        Rows skipped because their clamp quaternion has zero or non-finite length.
    """

    contacts: ContactPoint | ContactPointArray | None
    no_contact: int
    bad_pose: int


def reconstruct_messages(msgs: Sequence[Wrenches], rod: RodScale = _UNIT_ROD
                         ) -> list[Reconstructed]:
    """Reconstruct a batch of messages in one Step 2 call (``vibrissa.reconstruct.reconstruct_si``).

    A WhiskerWrench is a tick of one row: the rows of every message of the batch, in order,
    go through one compiled call, so a backlog costs one call instead of one per message (on
    a few dozen rows the cost is the calls, not the rows). Step 2 works row by row: a row's
    point does not depend on the batch it arrived in (batches follow arrival timing), so a
    replayed bag gives the live run's points bit for bit, and a wrench gives the same bits as
    the same row of an array.
    """
    counts = [1 if isinstance(msg, WhiskerWrench) else len(msg.whisker_ids) for msg in msgs]
    columns = ("clamp_orientation", "clamp_position", "f0", "m0")
    if len(msgs) == 1:  # (N, ...) rows as they are; a wrench's (3,) as its one row
        values = [getattr(msgs[0], name) for name in columns]
        q, p0, f0, m0 = values if values[0].ndim == 2 else (value[None] for value in values)
    else:  # vstack takes a wrench's (3,) as one row too
        q, p0, f0, m0 = (np.vstack([getattr(msg, name) for msg in msgs]) for name in columns)
    result = reconstruct_si(q, p0, f0, m0, rod)
    point, s1, phase, force, status = (result.point_m, result.s1_m, result.phase,
                                       result.force_n, result.status)
    pose_ok, flags = result.pose_ok.tolist(), status.tolist()
    # A row whose result overflows (finite inputs near the float limit, rotated) has no
    # contact that can be published: it counts as no consistent contact.
    finite = (np.isfinite(point).all(axis=1) & np.isfinite(force).all(axis=1)
              & np.isfinite(s1)).tolist()
    valid = [ok and fin and not flag & _NO_CONTACT
             for ok, fin, flag in zip(pose_ok, finite, flags, strict=True)]
    for value in (point, s1, phase, force, status):
        value.flags.writeable = False  # fresh arrays of this call: messages take them as they are
    s1s, phases = s1.tolist(), phase.tolist()
    outcomes = []
    first = 0
    for msg, n in zip(msgs, counts, strict=True):
        last = first + n
        good, kept = sum(pose_ok[first:last]), sum(valid[first:last])
        contacts: ContactPoint | ContactPointArray | None = None
        if isinstance(msg, WhiskerWrench):
            if kept:
                contacts = ContactPoint(
                    stamp=msg.stamp, seq=msg.seq, whisker_id=msg.whisker_id, frame_id=msg.frame_id,
                    point=point[first], s1=s1s[first], phase=ContactPhase(phases[first]),
                    force=force[first], status=ContactStatus(flags[first]))
        else:
            if kept == n:
                rows_kept: slice | list[int] = slice(first, last)
                whisker_ids = msg.whisker_ids
            else:
                rows_kept = [i for i in range(first, last) if valid[i]]
                whisker_ids = [msg.whisker_ids[i - first] for i in rows_kept]
            contacts = ContactPointArray(
                stamp=msg.stamp, seq=msg.seq, frame_id=msg.frame_id, whisker_ids=whisker_ids,
                point=point[rows_kept], s1=s1[rows_kept], phase=phase[rows_kept],
                force=force[rows_kept], status=status[rows_kept])
        outcomes.append(Reconstructed(contacts, no_contact=good - kept, bad_pose=n - good))
        first = last
    return outcomes


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


def _count(counters: dict[str, int], outcome: Reconstructed) -> None:
    contacts = outcome.contacts
    counters["contacts"] += (len(contacts.whisker_ids) if isinstance(contacts, ContactPointArray)
                             else int(contacts is not None))
    counters["no_contact"] += outcome.no_contact
    counters["bad_pose"] += outcome.bad_pose


def _compile_kernels(rod: RodScale) -> None:
    """Compile Step 2 for the arrays the node will see (or load it from numba's cache) now, so
    that the first wrench is not late by the compile time (~3 s on a fresh install): decoded
    messages hold read-only arrays, a backlog of ticks is concatenated into writable ones."""
    tick = decode(encode(WhiskerWrenchArray(
        stamp=0.0, seq=0, frame_id="world", whisker_ids=["warm-up"], clamp_position=[[0.0, 0.0, 0.0]],
        clamp_orientation=[[0.0, 0.0, 0.0, 1.0]], f0=[[0.1 * rod.force_n, 0.0, 0.0]],
        m0=[[0.0, 0.05 * rod.moment_nm, 0.0]])), WhiskerWrenchArray)
    wrench = decode(encode(WhiskerWrench(
        stamp=0.0, seq=0, whisker_id="warm-up", frame_id="world", clamp_position=[0.0, 0.0, 0.0],
        clamp_orientation=[0.0, 0.0, 0.0, 1.0], f0=tick.f0[0], m0=tick.m0[0])), WhiskerWrench)
    for batch in ([tick], [tick, tick], [wrench]):
        reconstruct_messages(batch, rod)


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
        for outcome in reconstruct_messages(batch, rod) if batch else ():
            if outcome.contacts is not None:
                publisher.publish(outcome.contacts)
            _count(counters, outcome)
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
    run_main(main)
