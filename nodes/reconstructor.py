"""Reconstructor node: contact points from whisker base wrenches (Step 2), batched when behind.

Subscribes
----------
``input_topic`` (default ``wrench``) : WhiskerWrenchArray
    SI: f0 N, m0 N m in the clamp frame C (``frame_ids``), with or without the clamp pose X_PC
    (``pose_frame_id``); one row per whisker of one tick (a single whisker: one row).
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

Step 2 on the stream is `vibrissa.streaming.Step2Stream` (placing through the robot's poses, the
wait for a pose, the noise model and what each counter means are documented there): the node
drains its input into batches, hands them over and publishes what comes back. Counters in this
node's ``NodeStatus`` (besides the runtime's received, published, rejected, lost, anomalies) are
the stream's (`vibrissa.streaming.COUNTS`), in rows: ``contacts``, ``free``,
``tip_within_noise``, ``no_covariance``, ``no_contact``, ``bad_pose``, ``no_pose``,
``unknown_whisker``, ``wrong_frame``, ``multi_contact``, ``ambiguous``; and ``robot_poses``,
``bad_robot_pose``, ``pose_time_jumps``, ``pose_reparents``, ``batches`` and ``max_batch``
(batches and the largest, in messages). Samples without a consistent contact are counted, not sent. Undecodable input
(wrong type, version, field type, truncated bytes, NaN) is rejected and counted by the transport
(``rejected``) and the node carries on.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from vibrissa.formats.scene_file import load_robot
from vibrissa.msgs import (
    ContactPointArray,
    EndOfStream,
    Message,
    RobotPose,
    WhiskerWrenchArray,
)
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main
from vibrissa.runtime.params import require, require_non_negative, require_parsed, require_positive
from vibrissa.streaming import Step2Stream, StreamSettings, Warnings, warm_up
from vibrissa.units import RodScale
from vibrissa.wire.topics import resolve_topic, validate_name
from vibrissa.wire.transport import Received

log = logging.getLogger(__name__)


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
        Receive high-water mark, messages: the backlog the node can hold without loss; its
        output queues as many for a subscriber that is busy (a mapper fitting while the points
        held for it go out at once).
    exit_on_eos
        Exit (status 0) after forwarding the first ``EndOfStream``; by default the node runs
        until stopped, like a sensor driver.
    wait_timeout_s
        With ``exit_on_eos``: how long the points still held for ``wait_for`` subscribers (not
        ready yet: a mapper still starting on a loaded machine) wait for them at the end
        before they are discarded (logged), s.
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
        s, while the wrenches go on (a stalled sensor waits 10 times as long); then its rows
        count as ``no_pose`` and the node moves on.
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
    wait_timeout_s: float = 60.0
    rod_length_m: float = 1.0
    rod_ei_nm2: float = 1.0
    robot: str = ""
    pose_topic: str = "/robot/pose"
    # the defaults of the stream's settings, one definition (vibrissa.streaming.StreamSettings)
    map_frame: str = StreamSettings.map_frame
    robot_frame: str = StreamSettings.robot_frame
    pose_timeout_s: float = StreamSettings.pose_timeout_s
    history_s: float = StreamSettings.history_s
    max_pose_gap_s: float = StreamSettings.max_pose_gap_s
    noise_force_n: float = StreamSettings.noise_force_n
    noise_moment_nm: float = StreamSettings.noise_moment_nm
    contact_on_sigmas: float = StreamSettings.contact_on_sigmas
    contact_off_sigmas: float = StreamSettings.contact_off_sigmas
    tip_sigmas: float = StreamSettings.tip_sigmas
    rod: RodScale = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.robot:
            require_parsed("robot", self.robot, load_robot)
        require_parsed("pose_topic", self.pose_topic, validate_name)
        for key in ("map_frame", "robot_frame"):
            require(bool(getattr(self, key)), key, getattr(self, key), "a frame name")
        require_non_negative("pose_timeout_s", self.pose_timeout_s)
        require_non_negative("wait_timeout_s", self.wait_timeout_s)
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

    def stream_settings(self) -> StreamSettings:
        """The Step 2 stream's settings (`vibrissa.streaming.StreamSettings`), the robot
        description loaded."""
        return StreamSettings(
            rod=self.rod, whiskers=tuple(load_robot(self.robot)) if self.robot else (),
            map_frame=self.map_frame, robot_frame=self.robot_frame,
            pose_timeout_s=self.pose_timeout_s, history_s=self.history_s,
            max_pose_gap_s=self.max_pose_gap_s, noise_force_n=self.noise_force_n,
            noise_moment_nm=self.noise_moment_nm, contact_on_sigmas=self.contact_on_sigmas,
            contact_off_sigmas=self.contact_off_sigmas, tip_sigmas=self.tip_sigmas)


PARAMS = ReconstructorParams
"""The node's parameter dataclass: the launcher checks a launch file's values with it."""


def collect_batch(
    receive: Callable[[float], Received | None], timeout_s: float, max_batch: int,
    on_pose: Callable[[RobotPose], None] = lambda pose: None, end_topic: str | None = None,
    max_span_s: float = math.inf,
) -> tuple[list[WhiskerWrenchArray], EndOfStream | None, bool]:
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
    batch: list[WhiskerWrenchArray] = []
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
    span ``max_span_s`` (see :func:`collect_batch`). ``drained_at`` is the ``clock``'s time
    at which the queue was last seen empty (everything sent before it has been read, poses
    too; -inf before): a process that is not scheduled between this and handling the batch
    has not seen what came meanwhile.
    """

    def __init__(self, receive: Callable[[float], Received | None], drain_limit: int,
                 max_batch: int, on_pose: Callable[[RobotPose], None] = lambda pose: None,
                 end_topic: str | None = None, max_span_s: float = math.inf,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._receive = receive
        self._clock = clock
        self._on_pose = on_pose
        self._end_topic = end_topic
        self.drain_limit = drain_limit
        self.max_batch = max_batch
        self.max_span_s = max_span_s
        self.limit = drain_limit
        self.drained_at = -math.inf

    def collect(self, timeout_s: float) -> tuple[list[WhiskerWrenchArray], EndOfStream | None]:
        """The next batch (see :func:`collect_batch`) and the limit for the one after."""
        batch, eos, backlog = collect_batch(self._seen, timeout_s, self.limit, self._on_pose,
                                            self._end_topic, self.max_span_s)
        self.limit = self.max_batch if backlog else self.drain_limit
        return batch, eos

    def _seen(self, timeout_s: float) -> Received | None:
        """``receive``, noting when it found the queue empty (the time before the call)."""
        before = self._clock()
        rx = self._receive(timeout_s)
        if rx is None:
            self.drained_at = before
        return rx


def run(node: Node, params: ReconstructorParams) -> None:
    """Reconstruct until stopped (or the first ``EndOfStream`` with ``exit_on_eos``)."""
    settings = params.stream_settings()
    stream = Step2Stream(settings, Warnings(node.fqn, log), counts=node.counters)
    topics: dict[str, object] = {params.input_topic: WhiskerWrenchArray}
    if stream.frames is not None:
        topics[params.pose_topic] = RobotPose
    subscriber = node.create_subscriber(topics, hwm=params.receive_hwm)  # type: ignore[arg-type]
    publisher = node.create_publisher(params.output_topic, ContactPointArray,
                                      wait_for=params.wait_for, hwm=params.receive_hwm)
    batches = BatchCollector(subscriber.receive, params.drain_limit, params.max_batch,
                             stream.add_pose, resolve_topic(params.input_topic, node.namespace),
                             max_span_s=params.history_s / 2)
    warm_up(settings)
    node.set_state("running")
    counters = node.counters
    ends: list[EndOfStream] = []  # held until the wrenches before them are out
    while not node.stop_requested:
        batch, eos = batches.collect(min(0.1, stream.wait_s()))
        stream.add_wrenches(batch)
        if eos is not None:
            ends.append(eos)
            stream.end_wrenches()
        for outcome in stream.take(batches.drained_at):
            publisher.publish(outcome.contacts)
        # the poses no wrench waited for, now that the points are out
        stream.apply_poses(batches.drained_at)
        while ends and not len(stream):
            end = ends.pop(0)
            publisher.publish_end_of_stream(node.fqn)
            log.info("%s: EndOfStream from %s (%d samples); %s", node.fqn, end.source,
                     end.count, ", ".join(f"{k} {v}" for k, v in counters.items()))
            if params.exit_on_eos:
                node.close(drain_s=params.wait_timeout_s)
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
