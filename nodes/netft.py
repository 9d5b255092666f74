"""ATI Net F/T driver node: one sensor's RDT stream over UDP as WhiskerWrenchArray in its whisker's clamp frame.

Subscribes
----------
``command_topic`` (default ``sensor_command``) : SensorCommand
    ``bias``: tare the sensor (its own software bias, RDT command 0x0042), only while the rod
    is free (below); otherwise refused, with the reason in the log.

Publishes
---------
``topic`` (default ``wrench``) : WhiskerWrenchArray
    One batch of one row per record of the sensor, in order, never one older than a record
    already sent: ``whisker_ids`` = [``whisker``], ``frame_ids`` = [its clamp frame], no
    pose (the robot graph places it, as its other wrenches); ``f0`` N, ``m0`` N m the clamp's
    reaction on the rod about the clamp point (``vibrissa.calibration.sensor_to_clamp`` with
    the whisker's X_CS from ``robot``); ``stamp`` the record's sensor time on the host clock
    (``stamp: sensor``, from ``ft_sequence``; see ``vibrissa.wire.netft.StreamTracker``) or
    its receive time (``stamp: receive``); ``seq`` counts the published samples. With
    ``samples``: ``EndOfStream`` once the sensor has sent that many records, and the node exits.

The protocol and its books are ``vibrissa.wire.netft``; here are the socket, the stream's
restarts, the free-rod check and the publishing. Counters in the node's status: the
tracker's (``datagrams``, ``records`` and ``records_lost`` (its ``received`` and ``lost``:
records, not the graph's messages), ``reordered``, ``duplicates``, ``malformed``,
``sequence_anomalies``, ``ft_frozen``, ``stalls``, ``status_warnings``, ``status_faults``) and
``foreign`` (datagrams from another address), ``stale`` (records received but more than
``max_latency_s`` behind the newest received when their turn to be published came: not
published), ``non_finite`` (records whose wrench is not finite: not published),
``restarts`` (stream requests after the first), ``biases`` and ``bias_refused``. Records
dropped for a sequence anomaly or a non-finite wrench are logged, at most a line per 10 s.
A calibration outside ``vibrissa.wire.netft.CALIBRATION_RANGE`` (parameters or the sensor's
``netftapi2.xml``) is refused at start (exit 2). Every ``health_every_s`` and at the end the log
says whether these counts are normal (`health`).
"""

from __future__ import annotations

import collections
import ipaddress
import logging
import select
import socket
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import numpy.typing as npt

from vibrissa.calibration import sensor_to_clamp
from vibrissa.formats.scene_file import load_robot
from vibrissa.frames import Transform, clamp_frame
from vibrissa.msgs import SensorCommand, WhiskerWrenchArray
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main
from vibrissa.runtime.params import (
    ParamError,
    require,
    require_non_negative,
    require_parsed,
    require_positive,
)
from vibrissa.wire.netft import (
    RDT_PORT,
    Command,
    NetFTConfig,
    Records,
    StreamTracker,
    calibration_error,
    pack_request,
    read_config,
    to_si,
)
from vibrissa.wire.topics import validate_name

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class NetFTParams:
    """Parameters of the Net F/T driver.

    Attributes
    ----------
    whisker
        The whisker on this sensor: its name in ``robot`` and the messages' ``whisker_id``.
    robot
        The robot description (a scene file or a file of its ``whiskers``): the whisker's
        ``sensor`` pose X_CS; empty: the sensor frame is the clamp frame.
    address, port
        The sensor (IPv4 address or host name; its RDT port, 49152).
    local_port
        UDP port this node receives on (0: any free one).
    counts_per_force, counts_per_torque
        Counts per N and per N m (the sensor's ``cfgcpf``/``cfgcpt`` in N and N m), within
        ``vibrissa.wire.netft.CALIBRATION_RANGE``.
    read_config, http_port
        Read the counts from the sensor's ``netftapi2.xml`` over HTTP at start instead.
    mode
        ``realtime`` (RDT 0x0002, a record per datagram) or ``buffered`` (0x0003).
    ft_rate_hz
        Rate of the sensor's ``ft_sequence`` (its internal sample rate), Hz.
    stall_s
        A stream without records, or with ``ft_sequence`` frozen, this long is stalled, s.
    restart_s
        While stalled, the stream is requested again this often, s.
    fault_mask
        Status bits that mean a fault (record not published); other bits are warnings.
    max_latency_s
        Records this far (sensor time) behind the newest received are stale: not published.
    stamp
        ``sensor`` (sequence-derived sensor time on the host clock) or ``receive``.
    topic, command_topic
        The wrench topic and the command topic.
    bias_at_start
        Tare once at start, when the rod is free (default off: never forced on the user).
    free_samples, free_force_n, free_moment_nm
        The rod is free when the last ``free_samples`` samples all have |f0| and |m0| below
        these (N, N m), once this driver has tared the sensor. Before that the level is the
        sensor's offset, not the load: the rod counts as free when the samples stay within
        these of their mean (at rest; a rod resting on an object passes too, so tare the first
        time with the rod free).
    receive_buffer_bytes
        The socket's receive buffer (SO_RCVBUF).
    wait_for
        Nodes that must subscribe to ``topic`` first (buffered until then).
    samples
        Records to request (the RDT sample count): once the sensor has sent that many (counted
        across restarts; lost ones included), the stream ends: ``EndOfStream`` on ``topic``
        and the node exits. 0: stream until stopped.
    health_every_s
        The health line (`health`) in the log this often while streaming (and at the end), s;
        0: at the end only.
    """

    whisker: str = "whisker0"
    robot: str = ""
    address: str = "192.168.1.1"
    port: int = RDT_PORT
    local_port: int = 0
    counts_per_force: float = 1_000_000.0
    counts_per_torque: float = 1_000_000.0
    read_config: bool = False
    http_port: int = 80
    mode: Literal["realtime", "buffered"] = "realtime"
    ft_rate_hz: float = 7000.0
    stall_s: float = 0.2
    restart_s: float = 0.5
    fault_mask: int = 0x80000000
    max_latency_s: float = 0.05
    stamp: Literal["sensor", "receive"] = "sensor"
    topic: str = "wrench"
    command_topic: str = "sensor_command"
    bias_at_start: bool = False
    free_samples: int = 100
    free_force_n: float = 0.05
    free_moment_nm: float = 0.005
    receive_buffer_bytes: int = 1 << 20
    wait_for: tuple[str, ...] = ()
    samples: int = 0
    health_every_s: float = 30.0
    X_CS: Transform = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        require(bool(self.whisker), "whisker", self.whisker, "a whisker name")
        require(bool(self.address), "address", self.address, "the sensor's address")
        for key in ("port", "http_port"):
            require(1 <= getattr(self, key) <= 65535, key, getattr(self, key), "a port 1-65535")
        require(0 <= self.local_port <= 65535, "local_port", self.local_port, "a port 0-65535")
        for key in ("ft_rate_hz", "stall_s", "restart_s", "free_force_n", "free_moment_nm"):
            require_positive(key, getattr(self, key))
        for key, kind in (("counts_per_force", "force"), ("counts_per_torque", "torque")):
            error = calibration_error(kind, getattr(self, key))
            if error is not None:
                raise ValueError(f"parameter {key!r}: {error}")
        for key in ("max_latency_s", "health_every_s", "samples"):
            require_non_negative(key, getattr(self, key))
        require(0 <= self.fault_mask < 1 << 32, "fault_mask", self.fault_mask, "a 32-bit mask")
        require(self.free_samples >= 1, "free_samples", self.free_samples, "an integer >= 1")
        require(self.receive_buffer_bytes >= 4096, "receive_buffer_bytes", self.receive_buffer_bytes,
                "at least 4096")
        for name in (self.topic, self.command_topic, *self.wait_for):
            require_parsed("topic/command_topic/wait_for", name, validate_name)
        X_CS = Transform()
        if self.robot:
            require_parsed("robot", self.robot, load_robot)
            whiskers = {w.name: w for w in load_robot(self.robot)}
            require(self.whisker in whiskers, "whisker", self.whisker,
                    f"a whisker of {self.robot} ({', '.join(whiskers)})")
            X_CS = whiskers[self.whisker].X_CS
        object.__setattr__(self, "X_CS", X_CS)


PUBLISH_SLICE = 64
"""Records published between two drains of the socket (a few ms of Python)."""

PARAMS = NetFTParams
"""The node's parameter dataclass: the launcher checks a launch file's values with it."""


class NetFTReader:
    """The driver without sockets: datagrams in, clamp-frame wrenches out, and the free-rod
    check of the last ``free_samples`` samples.

    ``read_many(datagrams, t_receive)`` feeds what one drain of the socket gave (``read``: one
    datagram); ``take(limit)`` returns the oldest ``limit`` records not yet taken as ``(stamp
    (N,), f0_C (N, 3) N, m0_C (N, 3) N m)``. Records more than ``max_latency_s`` (sensor time)
    behind the newest received are left out and counted ``stale``, whether they arrived
    behind newer ones in one drain or waited too long to be taken: the backlog stays short.
    Records whose wrench or stamp is not finite (what the codec refuses) are left out and
    counted ``non_finite``: every record received is taken, stale or non-finite.
    """

    def __init__(self, params: NetFTParams, config: NetFTConfig) -> None:
        self.params = params
        self.config = config
        self.tracker = StreamTracker(ft_rate_hz=params.ft_rate_hz, stall_s=params.stall_s,
                                     fault_mask=params.fault_mask)
        self.counters = self.tracker.counters
        self.counters.update(stale=0, non_finite=0)
        self._pending: list[Records] = []
        # calibrated, not yet taken: sensor time (N,), stamp (N,), f0 (N, 3), m0 (N, 3)
        self._t_sensor = np.zeros(0)
        self._stamp = np.zeros(0)
        self._f0 = np.zeros((0, 3))
        self._m0 = np.zeros((0, 3))
        self._window: collections.deque[FloatArray] = collections.deque(
            maxlen=params.free_samples)  # the last samples' (f0, m0), N and N m
        self.tared = False

    def read(self, data: bytes, t_receive: float) -> None:
        self.read_many((data,), t_receive)

    def read_many(self, datagrams: Sequence[bytes], t_receive: float) -> None:
        records = self.tracker.feed_many(datagrams, t_receive)
        if len(records):
            self._pending.append(records)

    def __len__(self) -> int:
        """Records received and not yet taken (stale ones included until ``take``)."""
        return len(self._t_sensor) + sum(len(r) for r in self._pending)

    def take(self, limit: int | None = None) -> tuple[FloatArray, FloatArray, FloatArray]:
        pending, self._pending = self._pending, []
        if pending:
            t_sensor = np.concatenate([r.t_sensor for r in pending])
            t_receive = np.concatenate([r.t_receive for r in pending])
            counts = np.concatenate([r.counts for r in pending])
            fresh = t_sensor >= t_sensor.max() - self.params.max_latency_s
            self.counters["stale"] += int(np.count_nonzero(~fresh))
            with np.errstate(over="ignore", invalid="ignore"):  # counted below
                f_S, m_S = to_si(counts[fresh], self.config.counts_per_force,
                                 self.config.counts_per_torque)
                f0, m0 = sensor_to_clamp(f_S, m_S, self.params.X_CS)
            stamp = t_sensor[fresh] if self.params.stamp == "sensor" else t_receive[fresh]
            # what the codec would refuse: a non-finite value
            finite = np.isfinite(np.hstack([f0, m0, stamp[:, None]])).all(axis=1)
            self.counters["non_finite"] += int(np.count_nonzero(~finite))
            f0, m0, stamp = f0[finite], m0[finite], stamp[finite]
            self._window.extend(np.hstack([f0, m0])[-self.params.free_samples:])
            self._t_sensor = np.concatenate([self._t_sensor, t_sensor[fresh][finite]])
            self._stamp = np.concatenate([self._stamp, stamp])
            self._f0 = np.concatenate([self._f0, f0])
            self._m0 = np.concatenate([self._m0, m0])
        if not len(self._t_sensor):
            return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
        # the backlog's oldest may have waited too long behind the newest: stale as well
        first = int(np.searchsorted(self._t_sensor,
                                    self._t_sensor[-1] - self.params.max_latency_s))
        self.counters["stale"] += first
        end = len(self._t_sensor) if limit is None else min(len(self._t_sensor), first + limit)
        out = self._stamp[first:end], self._f0[first:end], self._m0[first:end]
        for array in out:  # read-only: a message takes its rows as they are, without a copy
            array.flags.writeable = False
        self._t_sensor, self._stamp = self._t_sensor[end:], self._stamp[end:]
        self._f0, self._m0 = self._f0[end:], self._m0[end:]
        return out

    def why_not_free(self) -> str | None:
        """``None`` when the rod is free, else why not: every one of the last
        ``free_samples`` samples below the thresholds after a tare, within them of their mean
        before the first (see ``NetFTParams``)."""
        n, need = len(self._window), self.params.free_samples
        if n < need:
            return f"only {n} of the {need} samples the free-rod check needs have arrived"
        window = np.array(self._window)
        if not self.tared:
            window = window - window.mean(axis=0)
        force = float(np.linalg.norm(window[:, :3], axis=1).max())
        moment = float(np.linalg.norm(window[:, 3:], axis=1).max())
        if force < self.params.free_force_n and moment < self.params.free_moment_nm:
            return None
        what = ("the rod is not free: over the last {need} samples |f0| reaches {f:.3g} N, "
                "|m0| {m:.3g} N m" if self.tared else
                "the rod is not free or not still (before the first tare the level is the "
                "sensor's offset, so a free rod is one at rest): over the last {need} samples "
                "f0 moves {f:.3g} N, m0 {m:.3g} N m from their mean")
        return (what.format(need=need, f=force, m=moment)
                + f" (limits {self.params.free_force_n} N, {self.params.free_moment_nm} N m)")

    def free_noise(self) -> tuple[float, float]:
        """Std of the last samples per force axis (N) and moment axis (N m), the mean of the
        three of each: the free-rod noise when the rod is free."""
        std = np.array(self._window).std(axis=0)
        return float(std[:3].mean()), float(std[3:].mean())

    @property
    def checked(self) -> bool:
        """Whether enough samples arrived for the free-rod check."""
        return len(self._window) >= self.params.free_samples

    def biased(self) -> None:
        """The sensor was tared: the samples before say nothing about the next ones."""
        self._window.clear()
        self.tared = True


class _AnomalyLog:
    """A warning when records were dropped for what no sensor sends (implausible sequence
    jumps, non-finite values), at most one line per ``every_s``, with the counts since the
    last line: a hostile or broken sensor cannot flood the log."""

    KINDS = {"sequence_anomalies": "with an implausible sequence jump",
             "non_finite": "whose wrench is not finite"}

    def __init__(self, fqn: str, every_s: float = 10.0) -> None:
        self.fqn = fqn
        self.every_s = every_s
        self.logged = dict.fromkeys(self.KINDS, 0)
        self.last = -np.inf

    def check(self, counters: dict[str, int]) -> None:
        now = time.monotonic()
        if now - self.last < self.every_s or all(counters[k] == n for k, n in self.logged.items()):
            return
        what = [f"{counters[k] - self.logged[k]} record(s) {text}"
                for k, text in self.KINDS.items() if counters[k] > self.logged[k]]
        log.warning("%s: dropped %s (counted in its status; this line at most every %g s)",
                    self.fqn, " and ".join(what), self.every_s)
        self.logged = {k: counters[k] for k in self.KINDS}
        self.last = now


LOOPBACK_LOSS = 0.0
"""Fraction of records a loopback link loses when the machine keeps up: none."""

NETWORK_LOSS = 1e-3
"""Fraction of records lost or reordered above which a wired network link is not healthy."""


def health(counters: Mapping[str, int], elapsed_s: float, loopback: bool) -> str:
    """One line on whether the stream's counts are normal: ``health: normal (...)``, or
    ``health: ABNORMAL: ...`` naming each count that is not, with what it means.

    ``counters`` are the driver's (`StreamTracker` names: ``received``, ``lost``, ...; and
    ``stale``, ``restarts``, ``foreign``, ``non_finite``), over ``elapsed_s`` of streaming;
    ``loopback``: the sensor is on this machine (a simulated one), where nothing is lost,
    reordered or late unless the machine is too busy to run the sensor and the driver."""
    c = {k: counters.get(k, 0) for k in (
        "received", "lost", "reordered", "duplicates", "malformed", "sequence_anomalies",
        "ft_frozen", "stalls", "status_warnings", "status_faults", "stale", "non_finite",
        "foreign", "restarts")}
    sent = c["received"] + c["lost"] + c["reordered"] + c["status_faults"] + c["ft_frozen"]
    limit = LOOPBACK_LOSS if loopback else NETWORK_LOSS
    busy = ("this machine is too busy to run the simulated sensor and the driver on time"
            if loopback else "the driver is starved of the CPU, or the network is congested")
    why = ("loopback loses and reorders nothing: the simulated sensor's loss or reorder "
           "parameters, or " + busy if loopback else "the network drops or reorders datagrams")
    problems = []
    for key, what in (("lost", "records lost (gaps in rdt_sequence)"),
                      ("reordered", "records came after a newer one (not published)")):
        if c[key] > limit * max(sent, 1):
            problems.append(f"{c[key]} of {sent} {what}, {c[key] / max(sent, 1):.2%}: {why}")
    for key, text in (
            ("stale", "records dropped as stale (more than max_latency_s behind the newest "
             f"when their turn came): {busy}"),
            ("stalls", "stalls (no records, or ft_sequence frozen, for stall_s): the sensor "
             f"stopped sending, or {busy}"),
            ("restarts", "stream requests after the first (after a stall): the sensor starts "
             "its rdt_sequence anew, and records around the restart may be lost"),
            ("duplicates", "records that came twice: another client requested this sensor's "
             "stream, or the network duplicates datagrams"),
            ("malformed", "datagrams from the sensor's address that are not RDT records: "
             "another program sends from that address and port"),
            ("sequence_anomalies", "records with an implausible sequence jump: a rebooted "
             "sensor or a corrupted stream"),
            ("ft_frozen", "records whose ft_sequence did not move: the sensor's sampling "
             "stopped"),
            ("status_faults", "records with a fault bit in the status word (not published)"),
            ("status_warnings", "records with a warning bit in the status word"),
            ("non_finite", "records whose wrench is not finite (not published)"),
            ("foreign", "datagrams from another address (ignored)")):
        if c[key]:
            problems.append(f"{c[key]} {text}")
    rate = c["received"] / elapsed_s if elapsed_s > 0 else 0.0
    what = f"{c['received']} records in {elapsed_s:.1f} s ({rate:.0f} per s)"
    if problems:
        return f"health: ABNORMAL: {'; '.join(problems)} ({what})"
    return (f"health: normal ({what}; none lost, stale, reordered, duplicated or malformed, "
            "no stalls or restarts)")


def sensor_config(params: NetFTParams) -> NetFTConfig:
    """The counts per N and N m: the parameters, or the sensor's netftapi2.xml."""
    if params.read_config:
        try:
            config = read_config(params.address, port=params.http_port)
        except ValueError as exc:  # the sensor's configuration refused: as a parameter is
            raise ParamError(f"http://{params.address}:{params.http_port}/{exc}") from None
        log.info("counts from http://%s:%d/netftapi2.xml: %g per N, %g per N m (%s, %s)",
                 params.address, params.http_port, config.counts_per_force,
                 config.counts_per_torque, config.force_unit, config.torque_unit)
        return config
    return NetFTConfig(params.counts_per_force, params.counts_per_torque)


def run(node: Node, params: NetFTParams, clock: Callable[[], float] = time.time) -> int:
    """Stream from the sensor until the node is asked to stop, or until the sensor has sent
    ``samples`` records (then ``EndOfStream``). Until the sensor first answers (a simulated
    one may still be starting), the stream is requested every ``restart_s``: neither a stall
    nor a restart."""
    reader = NetFTReader(params, sensor_config(params))
    counters = reader.counters
    counters.update(foreign=0, restarts=0, biases=0, bias_refused=0)
    # The tracker's books in the node's status; records are not the transport's messages, so
    # its received and lost get names of their own (a launch reads "lost" as lost messages).
    renamed = {"received": "records", "lost": "records_lost"}

    def report() -> None:
        node.counters.update({renamed.get(k, k): v for k, v in counters.items()})

    report()
    anomalies = _AnomalyLog(node.fqn)
    wrenches = node.create_publisher(params.topic, WhiskerWrenchArray, wait_for=params.wait_for)
    commands = node.create_subscriber({params.command_topic: SensorCommand})
    frame_id = clamp_frame(params.whisker)
    sensor = (socket.gethostbyname(params.address), params.port)
    loopback = ipaddress.ip_address(sensor[0]).is_loopback

    def sent() -> int:
        """Records the sensor sent, as far as the books tell (lost ones included)."""
        return sum(counters[k] for k in ("received", "lost", "reordered", "status_faults",
                                         "ft_frozen"))

    def stream() -> bytes:
        """The stream's request, for the records still wanted."""
        count = max(params.samples - sent(), 1) if params.samples else 0
        return pack_request(Command.BUFFERED if params.mode == "buffered" else Command.REALTIME,
                            count)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, params.receive_buffer_bytes)
        sock.bind(("", params.local_port))
        sock.setblocking(False)
        sock.sendto(stream(), sensor)
        reader.tracker.restart(clock())  # the tracker's times are all on ``clock``
        log.info("%s: streaming from %s:%d (%s) as %s", node.fqn, *sensor, params.mode, frame_id)
        node.set_state("running", f"streaming from {sensor[0]}:{sensor[1]}")
        seq = 0
        bias_wanted = params.bias_at_start
        next_restart = clock() + params.restart_s
        next_command = 0.0
        was_stalled = False
        started: float | None = None  # when the sensor first answered
        heard_last = 0.0  # when it last did
        next_health = np.inf
        ended = False
        asked_again = False
        def drain() -> None:
            """Everything queued now into the reader, so nothing waits behind stale data."""
            datagrams = []
            while True:
                try:
                    data, sender = sock.recvfrom(65536)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError as exc:  # e.g. ICMP port unreachable: the sensor is not there yet
                    log.debug("%s: receive: %s", node.fqn, exc)
                    break
                if sender != sensor:
                    counters["foreign"] += 1
                    continue
                datagrams.append(data)
            if datagrams:
                nonlocal heard_last
                heard_last = clock()
                reader.read_many(datagrams, heard_last)

        def publish(limit: int | None) -> None:
            nonlocal seq
            stamps, f0, m0 = reader.take(limit)
            for i, stamp in enumerate(stamps.tolist()):
                wrenches.publish(WhiskerWrenchArray(
                    stamp=stamp, seq=seq, whisker_ids=[params.whisker], frame_ids=[frame_id],
                    f0=f0[i:i + 1], m0=m0[i:i + 1]))
                seq += 1

        while not node.stop_requested:
            # The socket first: publishing goes in slices of PUBLISH_SLICE between drains, so
            # a burst of records never leaves the kernel's buffer to overflow meanwhile.
            ready, _, _ = select.select([sock], [], [], 0.0 if len(reader) else 0.005)
            if ready:
                drain()
            publish(PUBLISH_SLICE)
            anomalies.check(counters)
            now = clock()
            if params.samples and sent() >= params.samples:
                ended = True
                break
            if started is None and counters["datagrams"]:
                started = now
                next_health = now + (params.health_every_s or np.inf)
            elif started is None and now >= next_restart:  # the sensor is not there yet
                if not asked_again:
                    log.info("%s: no answer from %s:%d yet; asking again every %g s", node.fqn,
                             *sensor, params.restart_s)
                    asked_again = True
                sock.sendto(stream(), sensor)
                next_restart = now + params.restart_s
            if started is not None and now >= next_health:
                log.info("%s: %s", node.fqn, health(counters, now - started, loopback))
                next_health = now + params.health_every_s
            stalled = started is not None and reader.tracker.check_stall(now)
            if stalled and not was_stalled:
                log.warning("%s: the sensor stalled: %s for %.2f s; requesting the stream again",
                            node.fqn, "ft_sequence frozen" if reader.tracker.heard_at is not None
                            and now - reader.tracker.heard_at < params.stall_s else "no records",
                            params.stall_s)
                report()  # the stall in this status, which goes out at once
                node.set_state("running", f"stalled ({counters['stalls']} so far)")
            elif was_stalled and not stalled:
                log.info("%s: the stream is back", node.fqn)
                node.set_state("running", f"streaming from {sensor[0]}:{sensor[1]}")
            was_stalled = stalled
            if stalled and now >= next_restart:
                drain()  # what the old stream queued goes in its own books, not the new one's
                sock.sendto(pack_request(Command.STOP), sensor)
                sock.sendto(stream(), sensor)
                reader.tracker.restart(now)
                counters["restarts"] += 1
                next_restart = now + params.restart_s
            if now >= next_command:
                next_command = now + 0.02
                rx = commands.receive(0)
                if rx is not None and isinstance(rx.msg, SensorCommand) and rx.msg.command == "bias":
                    log.info("%s: bias requested by %s", node.fqn, rx.msg.sender or "?")
                    bias_wanted = True
            if bias_wanted:
                reason = reader.why_not_free()
                if reason is None:
                    noise_f, noise_m = reader.free_noise()
                    sock.sendto(pack_request(Command.BIAS), sensor)
                    reader.biased()
                    counters["biases"] += 1
                    log.info("%s: sensor biased (tared) with the rod free; free-rod noise over "
                             "the last %d samples: %.3g N, %.3g N m std per axis (the "
                             "reconstructor's noise_force_n, noise_moment_nm)", node.fqn,
                             params.free_samples, noise_f, noise_m)
                    bias_wanted = False
                elif reader.checked or stalled:
                    counters["bias_refused"] += 1
                    log.warning("%s: bias refused: %s", node.fqn, reason)
                    bias_wanted = False
            report()
        sock.sendto(pack_request(Command.STOP), sensor)
        # The records sent before the stop arrived: taken and published, not left unread, until
        # the stream has been quiet for stall_s (by the driver's own measure, it has ended).
        quiet_until, deadline = time.monotonic() + params.stall_s, time.monotonic() + 1.0
        while time.monotonic() < min(quiet_until, deadline):
            if select.select([sock], [], [], 0.01)[0]:
                drain()
                quiet_until = time.monotonic() + params.stall_s
        publish(None)
        if ended:
            wrenches.publish_end_of_stream(node.fqn)
            log.info("%s: the sensor sent the %d records requested; EndOfStream on %s",
                     node.fqn, params.samples, wrenches.topic)
        anomalies.check(counters)
        report()
    finally:
        sock.close()
    log.info("%s: %s", node.fqn, ", ".join(f"{k} {v}" for k, v in counters.items()))
    line = health(counters, heard_last - started if started is not None else 0.0, loopback)
    (log.info if line.startswith("health: normal") else log.warning)("%s: %s", node.fqn, line)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = NodeArgs.parse(argv, prog="netft")
    configure_logging()
    params = load_params(NetFTParams, args.params_file, args.params)
    with Node.from_args(args) as node:
        return run(node, params)


if __name__ == "__main__":
    run_main(main)
