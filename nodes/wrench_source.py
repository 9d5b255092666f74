"""Wrench source node: simulated sweeps (Step 1) as WhiskerWrenchArray samples, or a recorded bag.

Subscribes
----------
``path_topic`` (mode ``scene`` when set, e.g. ``/robot/path``) : PathSegment
    the commanded robot: segments of waypoints, driven as they come (`run_commanded`); its
    ``EndOfStream`` ends the stream. Nothing else besides the runtime's ``/vibrissa/status``.

Publishes
---------
``topic`` (default ``wrench``, relative: ``/<namespace>/wrench``) : WhiskerWrenchArray
    mode ``sim``: one sample (a batch of one row) per equilibrium of every sweep, in sweep
    order, stamped from ``epoch_s`` as they go out (`clock_from`), then ``EndOfStream``.
``topic`` : WhiskerWrenchArray
    mode ``sim`` with ``array``: the trails are the whiskers of one rigid array moving together;
    one message per clamp step with a row per whisker, then ``EndOfStream``.
``topic`` : WhiskerWrenchArray, and ``pose_topic`` (default ``/robot/pose``) : RobotPose
    mode ``scene``: a robot's whiskers along its path (``vibrissa simulate`` of ``scene``: read
    from its output folder ``simulated``, or run on start when that is empty): one array per
    path sample with a row per whisker that has a wrench there (an ``unresolved`` sample has
    none), each row in its clamp frame with no pose, stamped ``epoch_s`` + the path's time; and
    the robot's pose X_WR (``world`` -> ``robot_frame``) at ``pose_rate_hz`` on the path's clock
    (and a last one at the path's end; 0: the path's own samples), each published
    ``pose_delay_s`` after its stamp in the stream (stamped as the wrenches); then
    ``EndOfStream`` on both. With ``passes`` N the path is driven N legs forth and back
    (`vibrissa.scene.back_and_forth`, one simulation: the return legs differ by friction);
    with ``loop`` forth and back until stopped (one cycle simulated, played again and again).
    With ``path_topic`` the robot is commanded instead: it stands at the path's first pose
    (published at once) and drives the segments that arrive, each sample simulated as it
    comes (`vibrissa.scene.SceneStream`), the same messages as along a fixed path; then
    ``EndOfStream`` on both after the commander's.
``events_topic`` (default ``events``, relative) : SnapEvent
    mode ``scene`` along a fixed path: each jump of a whisker's path (`vibrissa.scene.snaps`:
    snap-off, snap-through, landing), stamped as the wrench sample it is told at and published
    after it; then ``EndOfStream``.
every WhiskerWrenchArray or RobotPose topic of ``bag`` : the recorded types
    mode ``replay`` (remaps apply to the recorded absolute names): the recorded bytes in
    recorded order (a retired single ``vibrissa/WhiskerWrench`` decodes as an array of one
    row, ``vibrissa.msgs.codec.RETIRED_TYPES``), followed by the
    recorded ``EndOfStream`` (or one of its own when the bag has none, e.g. a cut-off bag).

Units and frames (mode ``sim``): the sweep's world frame W is the message's ``frame_id``; the
clamp frame C is parallel to W (identity quaternion) with z = rod axis. On the wire
``clamp_position = P0 L`` (m), ``f0 = f0' EI/L^2`` (N), ``m0 = m0' EI/L`` (N m), where primes
are the paper's dimensionless values, L = ``rod_length_m`` and EI = ``rod_ei_nm2``
(``vibrissa.units.RodScale``).
"""

from __future__ import annotations

import collections
import contextlib
import heapq
import itertools
import logging
import math
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt

from vibrissa.formats.scene_file import load_scene
from vibrissa.formats.scene_results import read_results
from vibrissa.formats.truth_poses import truth_writer
from vibrissa.frames import ROBOT_FRAME, WORLD_FRAME, clamp_frame
from vibrissa.msgs import EndOfStream, PathSegment, RobotPose, SnapEvent, WhiskerWrenchArray
from vibrissa.msgs.codec import decodes_as
from vibrissa.odometry import OdometryDrift, drift_rng
from vibrissa.paths import CommandedPath, PathLimits
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main
from vibrissa.runtime.params import (
    require,
    require_non_negative,
    require_parsed,
    require_positive,
)
from vibrissa.runtime.playback import play_bag_gated
from vibrissa.scene import (
    SamplePhase,
    Scene,
    SceneStream,
    SimulationStopped,
    Snap,
    StreamSamples,
    WhiskerResult,
    back_and_forth,
    free_at_both_ends,
    robot_path,
    simulate,
    snaps,
)
from vibrissa.status import SweepEnd
from vibrissa.streaming import Warnings
from vibrissa.surfaces import parse_surface
from vibrissa.sweep import CLAMP_TOUCH_L, SweepRun, Trail, first_contact
from vibrissa.ticks import Tick, array_ticks, sequential_ticks
from vibrissa.units import RodScale
from vibrissa.wire.bag import BagReader, check_bag_file
from vibrissa.wire.topics import validate_name
from vibrissa.wire.transport import DEFAULT_HWM, Publisher

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

REPLAY_TYPES = (WhiskerWrenchArray, RobotPose)

IDENTITY_QUATERNION = np.array([0.0, 0.0, 0.0, 1.0])  # (x, y, z, w)

MAX_STEP = 0.1
"""Largest clamp step, units of L: coarser steps jump over the contact episodes."""

MAX_POSES = 10_000_000
"""Most robot poses mode ``scene`` makes of a path at ``pose_rate_hz`` (28 h at 100 Hz): a rate
beyond it is refused rather than filling the memory with poses."""

MAX_EPOCH_S = 2.0**31
"""Largest ``epoch_s`` (the year 2038, excluded): a ROS 2 time holds its seconds as an int32."""


@dataclass(frozen=True)
class WrenchSourceParams:
    """Parameters of the wrench source node.

    Attributes
    ----------
    mode
        ``sim`` (simulate sweeps), ``scene`` (a robot along its path, ``scene``) or
        ``replay`` (play ``bag``).
    scene
        Mode ``scene``: the scene file (objects, whiskers, path; ``vibrissa simulate``).
    simulated
        Mode ``scene``: the output folder (``-o DIR``) of ``vibrissa simulate`` of ``scene``,
        whose ``<whisker>.csv`` files are played (read strictly with
        `vibrissa.formats.scene_results.read_results` when the parameters load, and again at
        start); empty: simulate on start.
    pose_topic, map_frame, robot_frame
        Mode ``scene``: where the robot's poses go, and the frames they join (with
        ``odom_drift_per_m``, ``map_frame`` is the odometry's frame, REP 105's ``odom``).
    odom_drift_per_m
        Mode ``scene``: the poses are a drifting odometry's (`vibrissa.odometry.OdometryDrift`:
        position and heading random walks of this standard deviation, m and rad, per metre
        travelled, drawn from ``seed``, apart from the wrench noise's draws); the whiskers are
        simulated on the true path. 0: the true poses.
    truth_file
        Mode ``scene``: a CSV (`vibrissa.formats.truth_poses`) of every published pose's truth
        and odometry, written when the stream ends; for evaluation only. Empty: none.
    events_topic
        Mode ``scene``: where each jump of a whisker's path goes, as a `SnapEvent` at the
        stamp of the sample it is told at (`vibrissa.scene.snaps`), after that sample's
        wrench; along a commanded path, as soon as that sample is simulated.
    pose_rate_hz
        Mode ``scene``: robot poses per second of path time, each interpolated on the path (a
        localisation at its own rate); 0: a pose at each path sample, the path's own, so that
        the lookup at a wrench's stamp (a path sample's) is exact on any path. Between two
        poses at a fixed rate the reconstructor interpolates a chord where the path bends.
    pose_delay_s
        Mode ``scene``: each pose goes out this long after its stamp in the stream (a
        localisation that lags), s.
    epoch_s
        Modes ``sim`` and ``scene``: the stamp of the simulated stream's start, s since the
        Unix epoch: path time 0 (``scene``: every wrench and pose is stamped ``epoch_s`` + its
        path time), the first sample (``sim``: ``epoch_s`` + the time since it went out). The
        launch files pass their ``epoch`` argument, by default the time the launch started;
        0: the path's own clock.
    noise_force_n, noise_moment_nm, seed
        Mode ``scene``: standard deviation of Gaussian noise added to each wrench component
        (N, N m), and the seed of the noise.
    passes
        Mode ``scene``: legs of the path, driven forth and back (1: the path once; 3: forth,
        back, forth), simulated as one path so that each whisker's contact state carries over
        the turns; then ``EndOfStream``. More than 1 needs ``simulated`` empty.
    loop
        Mode ``scene``: drive the path forth and back until stopped (``passes`` is then
        unused; ``simulated`` must be empty). One cycle (forth and back) is simulated and
        played again and again, time and ``seq`` running on: exact when every whisker is free
        at both ends of the path (`vibrissa.scene.free_at_both_ends`: the state after a cycle
        is then the state before it); a scene where one is not is refused at start (exit 1).
    workers
        Mode ``scene``: processes of the simulation on start (0: one per core; unused with
        ``simulated``).
    path_topic
        Mode ``scene``: the topic of PathSegment commands; set, the robot is commanded (the
        scene's path gives only its start pose, its first sample); empty: the path is fixed.
    path_rate_hz
        Commanded: path samples per second of path time.
    max_speed_mps, max_turn_rate_rps, max_jump_m, max_jump_rad
        Commanded: the fastest a segment may drive (m/s, rad/s; they set Step 1's step,
        `vibrissa.paths.PathLimits.rod_step`), and how far its first waypoint may be from
        where it starts (m, rad); a command beyond is refused.
    max_queued_s
        Commanded: the most path time queued at once, s; a segment that would queue more is
        refused.
    surface
        Object spec for ``vibrissa.surfaces.parse_surface``, units of L (mode ``sim``).
    y0
        Lateral offsets of the trails, one sweep each, units of L (mode ``sim``).
    mu
        Friction coefficient of every trail (mode ``sim``).
    step
        Clamp displacement per step, units of L (mode ``sim``).
    whisker_id, frame_id
        Written into every sample (mode ``sim``).
    array
        Mode ``sim``: simulate the trails as the whiskers of one rigid array (a row of clamps
        at the offsets ``y0``, all at the same x) and publish a WhiskerWrenchArray per step
        (``vibrissa.ticks.array_ticks``), instead of the sweeps one after the other.
    whisker_ids
        Names of the array's whiskers, one per ``y0`` (default ``whisker0``, ``whisker1``...).
    rate_hz
        Samples per second (mode ``sim``; with ``array``, arrays per second); 0 publishes as
        fast as possible.
    bag
        The ``.mcap`` file to play (mode ``replay``).
    replay_rate
        Time scale of the replay: 1.0 recorded speed, 2.0 twice as fast; 0 as fast as
        possible.
    topic
        Output topic (mode ``sim``), relative to the namespace.
    wait_for
        Node names (relative names resolve in the namespace) whose subscription to the output
        must be up before anything goes out; until then samples are buffered, never dropped.
    pose_wait_for
        Modes ``scene`` and ``replay``: nodes that must subscribe to the pose topic too
        (besides ``wait_for``) before a pose goes out: a node that takes the poses and not
        the wrenches.
    wait_timeout_s
        Give up waiting for ``wait_for`` after this long, s (exit status 1).
    rod_length_m
        L, the rod length, m.
    rod_ei_nm2
        EI, the rod's bending stiffness, N m^2.
    rod
        L and EI as ``vibrissa.units.RodScale`` (derived, not a parameter).
    """

    mode: Literal["sim", "scene", "replay"] = "sim"
    surface: str = "paraboloid:a=0.5,b=1,h=0.4"
    y0: tuple[float, ...] = (0.0,)
    mu: float = 0.0
    step: float = 0.001
    whisker_id: str = "whisker0"
    frame_id: str = "world"
    array: bool = False
    whisker_ids: tuple[str, ...] = ()
    rate_hz: float = 0.0
    bag: str = ""
    replay_rate: float = 1.0
    topic: str = "wrench"
    wait_for: tuple[str, ...] = ()
    pose_wait_for: tuple[str, ...] = ()
    wait_timeout_s: float = 60.0
    rod_length_m: float = 1.0
    rod_ei_nm2: float = 1.0
    scene: str = ""
    simulated: str = ""
    pose_topic: str = "/robot/pose"
    events_topic: str = "events"
    map_frame: str = WORLD_FRAME
    robot_frame: str = ROBOT_FRAME
    pose_rate_hz: float = 100.0
    pose_delay_s: float = 0.0
    epoch_s: float = 0.0
    noise_force_n: float = 0.0
    noise_moment_nm: float = 0.0
    seed: int = 0
    odom_drift_per_m: float = 0.0
    truth_file: str = ""
    passes: int = 1
    loop: bool = False
    workers: int = 0
    path_topic: str = ""
    path_rate_hz: float = 500.0
    max_speed_mps: float = 0.1
    max_turn_rate_rps: float = 1.0
    max_jump_m: float = 0.1
    max_jump_rad: float = 0.5
    max_queued_s: float = 600.0
    rod: RodScale = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        require_positive("rod_length_m", self.rod_length_m)
        require_positive("rod_ei_nm2", self.rod_ei_nm2)
        object.__setattr__(self, "rod", RodScale(self.rod_length_m, self.rod_ei_nm2))
        require_non_negative("rate_hz", self.rate_hz)
        require_non_negative("replay_rate", self.replay_rate)
        require_non_negative("wait_timeout_s", self.wait_timeout_s)
        require(0 <= self.epoch_s < MAX_EPOCH_S, "epoch_s", self.epoch_s,
                f"s since the Unix epoch in [0, {MAX_EPOCH_S:.0f})")
        require_parsed("topic", self.topic, validate_name)
        for key in ("wait_for", "pose_wait_for"):
            for name in getattr(self, key):
                require_parsed(key, name, validate_name)
        if self.mode == "replay":
            require(bool(self.bag), "bag", self.bag, "an .mcap file in mode 'replay'")
            require_parsed("bag", self.bag, check_bag_file)
            return
        if self.mode == "scene":
            require(bool(self.scene), "scene", self.scene, "a scene file in mode 'scene'")
            scene = require_parsed("scene", self.scene, load_scene)
            require(self.passes >= 1, "passes", self.passes, "a count of legs >= 1")
            require(not self.simulated or (self.passes == 1 and not self.loop), "simulated",
                    self.simulated, "empty with passes > 1 or loop (the return legs are "
                    "simulated on start)")
            if self.simulated:
                require_parsed("simulated", self.simulated,
                               lambda folder: read_results(folder, scene))
            if self.path_topic:
                require_parsed("path_topic", self.path_topic, validate_name)
                require(not self.simulated and self.passes == 1 and not self.loop, "path_topic",
                        self.path_topic, "empty with simulated, passes > 1 or loop (the path "
                        "is commanded)")
                require_parsed("path_rate_hz", self.path_rate_hz, lambda _: self.path_limits)
            require_parsed("pose_topic", self.pose_topic, validate_name)
            require_parsed("events_topic", self.events_topic, validate_name)
            for key in ("pose_rate_hz", "pose_delay_s", "noise_force_n", "noise_moment_nm",
                        "workers", "odom_drift_per_m"):
                require_non_negative(key, getattr(self, key))
            t = scene.path.t
            legs = 2 if self.loop else self.passes  # the poses of one simulated stream
            # Python floats: a product past the float range is inf, without numpy's warning
            require(float(t[-1] - t[0]) * legs * self.pose_rate_hz <= MAX_POSES, "pose_rate_hz",
                    self.pose_rate_hz, f"a rate of at most {MAX_POSES:.0e} poses over the "
                    f"path's {t[-1] - t[0]:g} s x {legs} leg(s) (0: one at each of its "
                    f"{len(t)} samples)")
            return
        require_parsed("surface", self.surface, parse_surface)
        require(len(self.y0) > 0 and all(math.isfinite(y) for y in self.y0), "y0", self.y0,
                "one or more finite offsets")
        require_non_negative("mu", self.mu)
        require(math.isfinite(self.step) and 0 < self.step <= MAX_STEP, "step", self.step,
                f"a number in (0, {MAX_STEP:g}] (units of L)")
        require(not self.whisker_ids or len(self.whisker_ids) == len(self.y0), "whisker_ids",
                self.whisker_ids, f"one name per y0 ({len(self.y0)})")

    def odometry(self) -> OdometryDrift:
        """The robot's odometry (``odom_drift_per_m``), its draws from ``seed`` apart from the
        noise's."""
        return OdometryDrift(self.odom_drift_per_m, drift_rng(self.seed))

    @property
    def pose_waits(self) -> tuple[str, ...]:
        """The nodes the poses wait for: ``wait_for`` and ``pose_wait_for``."""
        return tuple(dict.fromkeys(self.wait_for + self.pose_wait_for))

    @property
    def path_limits(self) -> PathLimits:
        """What the commanded robot accepts (``path_topic``)."""
        return PathLimits(self.path_rate_hz, self.max_speed_mps, self.max_turn_rate_rps,
                          self.max_jump_m, self.max_jump_rad, self.max_queued_s)

    @property
    def array_whisker_ids(self) -> list[str]:
        """Names of the array's rows, one per ``y0``."""
        return list(self.whisker_ids) or [f"whisker{i}" for i in range(len(self.y0))]


PARAMS = WrenchSourceParams
"""The node's parameter dataclass: the launcher checks a launch file's values with it."""


def tick_messages(
    ticks: Iterable[Tick],
    whisker_ids: Sequence[str],
    frame_id: str = "world",
    array: bool = False,
    clock: Callable[[], float] = lambda: 0.0,
) -> Iterator[WhiskerWrenchArray]:
    """Each tick as a WhiskerWrenchArray (``array``) or each of its rows as one of one row.

    Row r of a tick is whisker ``whisker_ids[tick.whiskers[r]]``, measured in its clamp frame
    (`vibrissa.frames.clamp_frame`), with its clamp pose in ``frame_id``: the identity
    orientation (C parallel to W). ``seq`` counts messages from 0; ``stamp`` is ``clock()``
    when the message is made (the node's: `clock_from` its epoch, as a live sensor's).
    """
    seq = 0
    for tick in ticks:
        n = len(tick.whiskers)
        ids = [whisker_ids[w] for w in tick.whiskers]
        if array:
            yield WhiskerWrenchArray(
                stamp=clock(), seq=seq, whisker_ids=ids, frame_ids=[clamp_frame(w) for w in ids],
                f0=tick.f0_C_n, m0=tick.m0_C_nm, pose_frame_id=frame_id,
                clamp_position=tick.p_WC_m, clamp_orientation=np.tile(IDENTITY_QUATERNION, (n, 1)))
            seq += 1
            continue
        for r in range(n):
            yield WhiskerWrenchArray(
                stamp=clock(), seq=seq, whisker_ids=[ids[r]], frame_ids=[clamp_frame(ids[r])],
                f0=tick.f0_C_n[r:r + 1], m0=tick.m0_C_nm[r:r + 1], pose_frame_id=frame_id,
                clamp_position=tick.p_WC_m[r:r + 1], clamp_orientation=IDENTITY_QUATERNION[None])
            seq += 1


def clock_from(epoch_s: float) -> Callable[[], float]:
    """A clock that reads ``epoch_s`` on its first call, then ``epoch_s`` plus the time since
    (`time.monotonic`), s: mode ``sim``'s stamps, from the stated epoch at the pace they go out."""
    start: list[float] = []

    def clock() -> float:
        now = time.monotonic()
        if not start:
            start.append(now)
        return epoch_s + (now - start[0])

    return clock


PROGRESS_PERIOD_S = 2.0
"""Seconds between the progress lines of a simulation in the log."""


def run_sim(node: Node, params: WrenchSourceParams) -> int:
    """Simulate the sweeps and publish each sample as soon as it is solved (paced by
    ``rate_hz``); returns the number of messages sent, -1 when ``wait_for`` timed out."""
    publisher = node.create_publisher(
        params.topic, WhiskerWrenchArray,
        wait_for=params.wait_for, hwm=DEFAULT_HWM * 10)
    surface = parse_surface(params.surface)
    trails = [Trail(float(y0), params.mu) for y0 in params.y0]
    x_grid = None
    if params.array:  # one grid for all: from the first touch of any whisker
        touches = [first_contact(surface, trail.y0) for trail in trails]
        x_grid = max((touch[0] for touch in touches if touch is not None), default=0.0)
    run = SweepRun(surface, trails, params.step, x_grid=x_grid)
    for i, trail in enumerate(trails):
        if run.progress(i).end is SweepEnd.NO_CONTACT:
            log.warning("%s: the trail y0=%g (units of L) never touches %s: the straight "
                        "rod clears the object all along it (no contact, no samples)",
                        node.fqn, trail.y0, surface.spec)
    if params.wait_for and not node.wait_for_subscribers(
        params.topic, params.wait_for, params.wait_timeout_s
    ):
        return -1
    node.set_state("running", f"simulating {len(trails)} sweep(s) past {surface.spec}")
    _say_epoch(node, params, "the first sample")
    if x_grid is None:  # one whisker, its sweeps one after the other
        ticks = sequential_ticks(run, params.rod)
        whisker_ids = [params.whisker_id] * len(trails)
    else:
        ticks = array_ticks(run, params.rod)
        whisker_ids = params.array_whisker_ids
    messages = tick_messages(ticks, whisker_ids, params.frame_id, params.array,
                             clock=clock_from(params.epoch_s))
    period = 1.0 / params.rate_hz if params.rate_hz > 0 else 0.0
    t_start = time.monotonic()
    next_report = t_start + PROGRESS_PERIOD_S
    count = 0
    while not node.stop_requested:
        msg = next(messages, None)
        if msg is None:
            break
        if period:
            delay = t_start + count * period - time.monotonic()
            if delay > 0 and not node.sleep(delay):
                break
        publisher.publish(msg)
        count += 1
        if time.monotonic() >= next_report:
            next_report += PROGRESS_PERIOD_S
            log.info("%s: %s", node.fqn, _progress(run, count, time.monotonic() - t_start))
    publisher.publish_end_of_stream(node.fqn)
    state = "stopped" if node.stop_requested else "done"
    log.info("%s: %s; %s: %d messages and EndOfStream on %s", node.fqn,
             _progress(run, count, time.monotonic() - t_start), state, count, publisher.topic)
    return count


def _say_epoch(node: Node, params: WrenchSourceParams, what: str) -> None:
    """Log the epoch the stream is stamped from (``epoch_s``), as s and as UTC."""
    utc = datetime.fromtimestamp(params.epoch_s, timezone.utc).isoformat(timespec="milliseconds")
    log.info("%s: stamps from the epoch %.6f s (%s) at %s", node.fqn, params.epoch_s, utc, what)


def _progress(run: SweepRun, sent: int, elapsed_s: float) -> str:
    """``sweeps ended 2/5 (detachment, snap-off), 4310 published in 4.1 s``; ``no-equilibrium
    at the clamp``: the object met the clamp itself (``SweepProgress.s_touch``)."""
    ends = [(p.end, p.s_touch) for p in (run.progress(i) for i in range(len(run.trails)))]
    ended = [f"{end} at the clamp" if end is SweepEnd.NO_EQUILIBRIUM and s_touch < CLAMP_TOUCH_L
             else str(end) for end, s_touch in ends if end is not None]
    return (f"sweeps ended {len(ended)}/{len(ends)}" + (f" ({', '.join(ended)})" if ended else "")
            + f", {sent} published in {elapsed_s:.1f} s")


TruthSink = Callable[[float, FloatArray, FloatArray, FloatArray, FloatArray], None]
"""Takes each published pose's stamp (s), true position and quaternion, and the odometry's."""


def scene_stream(scene: Scene, results: Sequence[WhiskerResult], params: WrenchSourceParams,
                 repeat: bool = False, truth: TruthSink | None = None
                 ) -> Iterator[tuple[float, WhiskerWrenchArray | RobotPose]]:
    """The messages of mode ``scene`` in publishing order, each with its time in the stream
    (the path's clock): a WhiskerWrenchArray per path sample at its time, and the robot's
    poses at ``pose_rate_hz`` (and at the path's end; 0: the path's samples), each
    ``pose_delay_s`` after its path time, its odometry's (``odom_drift_per_m``; the truth of
    each goes to ``truth``); a pose goes before a wrench of the same stream time.
    Every message is stamped ``params.epoch_s`` + its path time.

    ``repeat``: the path (one that ends where it starts) again and again without end, each
    time from its second sample and pose (its first is the previous one's last), shifted by
    the path's duration; ``seq`` runs on and the noise is drawn anew each time."""
    t = scene.path.t
    names = [r.name for r in results]
    frame_ids = [clamp_frame(name) for name in names]
    f0_clean = np.stack([r.f0_n for r in results], axis=1)  # (samples, whiskers, 3)
    m0_clean = np.stack([r.m0_nm for r in results], axis=1)
    has = np.stack([r.phase != SamplePhase.UNRESOLVED for r in results], axis=1)
    rng = np.random.default_rng(params.seed)
    if params.pose_rate_hz:
        pose_t = np.append(np.arange(t[0], t[-1], 1.0 / params.pose_rate_hz), t[-1])
        _, p_WR, R_WR = scene.path.at(pose_t)
    else:
        pose_t, p_WR, R_WR = t, scene.path.p_WR, scene.path.R_WR
    q_WR = R_WR.as_quat()
    duration = float(t[-1] - t[0])

    def passes() -> Iterable[int]:
        return itertools.count() if repeat else range(1)

    def wrenches() -> Iterator[tuple[float, int, WhiskerWrenchArray | RobotPose]]:
        seq = 0
        for n in passes():
            f0, m0 = f0_clean, m0_clean
            if params.noise_force_n:
                f0 = f0 + rng.normal(0.0, params.noise_force_n, f0.shape)
            if params.noise_moment_nm:
                m0 = m0 + rng.normal(0.0, params.noise_moment_nm, m0.shape)
            for k in range(1 if n else 0, len(t)):
                stamp = float(t[k]) + n * duration
                rows = np.flatnonzero(has[k])
                yield stamp, 1, WhiskerWrenchArray(
                    stamp=params.epoch_s + stamp, seq=seq, whisker_ids=[names[i] for i in rows],
                    frame_ids=[frame_ids[i] for i in rows], f0=f0[k, rows], m0=m0[k, rows])
                seq += 1

    odometry = params.odometry()

    def poses() -> Iterator[tuple[float, int, WhiskerWrenchArray | RobotPose]]:
        for n in passes():
            first = 1 if n else 0
            p_OR, q_OR, _ = odometry.odom(p_WR[first:], q_WR[first:])
            for j in range(first, len(pose_t)):
                at = float(pose_t[j]) + n * duration
                if truth is not None:
                    truth(params.epoch_s + at, p_WR[j], q_WR[j], p_OR[j - first], q_OR[j - first])
                yield at + params.pose_delay_s, 0, _pose(params, at, p_OR[j - first],
                                                          q_OR[j - first])

    # by stream time, a pose before a wrench of the same time
    for stream_t, _, msg in heapq.merge(poses(), wrenches(), key=lambda e: (e[0], e[1])):
        yield stream_t, msg


def snap_event(stamp: float, whisker_id: str, frame_id: str, snap: Snap,
               before: tuple[FloatArray, FloatArray], after: tuple[FloatArray, FloatArray]
               ) -> SnapEvent:
    """``snap`` as told on the wire, with the wrenches (f0, m0) of its samples before and
    after; an unresolved sample's (NaN) is left out."""
    wrenches = [pair if all(np.isfinite(a).all() for a in pair) else (None, None)
                for pair in (before, after)]
    return SnapEvent(stamp=stamp, whisker_id=whisker_id, frame_id=frame_id, kind=snap.kind,
                     object=snap.object, f0_before=wrenches[0][0], m0_before=wrenches[0][1],
                     f0_after=wrenches[1][0], m0_after=wrenches[1][1])


def scene_events(scene: Scene, results: Sequence[WhiskerResult], params: WrenchSourceParams,
                 repeat: bool = False) -> Iterator[tuple[float, SnapEvent]]:
    """The jumps of every whisker's path (`vibrissa.scene.snaps`) as `SnapEvent`s, each with
    its time in the stream (the sample it is told at), in time order; with ``repeat`` as
    `scene_stream` repeats the path (a cycle's jumps again, shifted by its duration)."""
    t = scene.path.t
    names = [obj.name for obj in scene.objects]
    found = sorted(((float(t[snap.after]), result, snap) for result in results
                    for snap in snaps(result, names)), key=lambda e: e[0])
    duration = float(t[-1] - t[0])
    for n in itertools.count() if repeat else range(1):
        for at, result, snap in found:
            stamp = at + n * duration
            yield stamp, snap_event(params.epoch_s + stamp, result.name, clamp_frame(result.name),
                                    snap, (result.f0_n[snap.before], result.m0_nm[snap.before]),
                                    (result.f0_n[snap.after], result.m0_nm[snap.after]))
        if not found:
            return


def _pose(params: WrenchSourceParams, stamp: float, p: FloatArray, q: FloatArray) -> RobotPose:
    return RobotPose(stamp=params.epoch_s + float(stamp), frame_id=params.map_frame,
                     child_frame_id=params.robot_frame, position=p, orientation=q)


class TruthLog:
    """The truth of the poses made (`told`, in order), written to a ``truth_file`` row as each
    is published (`published`): a pose made but never sent (a stop) is not in the file."""

    def __init__(self, add: TruthSink | None) -> None:
        self._add = add
        self._rows: collections.deque[tuple[float, FloatArray, FloatArray, FloatArray,
                                            FloatArray]] = collections.deque()

    def told(self, stamp_s: float, p_map: FloatArray, q_map: FloatArray, p_odom: FloatArray,
             q_odom: FloatArray) -> None:
        if self._add is not None:
            self._rows.append((stamp_s, p_map, q_map, p_odom, q_odom))

    def published(self) -> None:
        if self._rows:
            assert self._add is not None
            self._add(*self._rows.popleft())


def _send(msg: WhiskerWrenchArray | RobotPose | SnapEvent, wrenches: Publisher,
          poses: Publisher, events: Publisher, truth: TruthLog) -> None:
    """A message of mode ``scene`` on its topic (a pose's truth into the truth log)."""
    if isinstance(msg, RobotPose):
        poses.publish(msg)
        truth.published()
    else:
        (events if isinstance(msg, SnapEvent) else wrenches).publish(msg)


@contextlib.contextmanager
def _truth(params: WrenchSourceParams) -> Iterator[TruthLog]:
    """The poses' truth log: into ``truth_file`` (written whole at the end), or nowhere."""
    if not params.truth_file:
        yield TruthLog(None)
        return
    with truth_writer(Path(params.truth_file)) as add:
        yield TruthLog(add)


def run_scene(node: Node, params: WrenchSourceParams) -> int:
    """Read the scene's results from ``simulated`` (or simulate it: ``passes`` legs forth and
    back, or with ``loop`` one cycle), then play them (paced by ``rate_hz``: path samples per
    second; with ``loop`` until stopped); returns the number of messages sent, -1 when
    ``wait_for`` timed out or a ``loop`` cannot repeat exactly."""
    wrenches = node.create_publisher(params.topic, WhiskerWrenchArray, wait_for=params.wait_for,
                                     hwm=DEFAULT_HWM * 10)
    poses = node.create_publisher(params.pose_topic, RobotPose, wait_for=params.pose_waits,
                                  hwm=DEFAULT_HWM * 10)
    events = node.create_publisher(params.events_topic, SnapEvent)
    scene = load_scene(params.scene)
    legs = 2 if params.loop else params.passes
    if legs > 1:
        scene = replace(scene, path=back_and_forth(scene.path, legs))
    t0 = time.monotonic()
    if params.simulated:
        node.set_state("running", f"reading the results in {params.simulated}")
        results = read_results(params.simulated, scene)
    else:
        node.set_state("running", f"simulating {len(scene.whiskers)} whisker(s) along the path")
        log.info("%s: simulating %d whisker(s) along the path (%d samples)", node.fqn,
                 len(scene.whiskers), len(scene.path.t))
        try:
            results = simulate(scene, workers=params.workers or None,
                               stop=lambda: node.stop_requested)
        except SimulationStopped as exc:
            log.info("%s: %s while simulating", node.fqn, exc)
            for publisher in (wrenches, poses, events):
                publisher.publish_end_of_stream(node.fqn)
            return 0
    size = f"{len(results)} whisker(s) x {len(scene.path.t)} path samples"
    how = f"read {size} from {params.simulated}" if params.simulated else f"simulated {size}"
    log.info("%s: %s in %.1f s: %s", node.fqn, how, time.monotonic() - t0,
             "; ".join(f"{r.name} {r.counts()}" for r in results))
    held = free_at_both_ends(results) if params.loop else []
    if held:
        log.error("%s: loop: %s not free at both ends of the path: a cycle does not end in "
                  "the state it began with, and repeating it would not be the robot's stream",
                  node.fqn, ", ".join(held))
        for publisher in (wrenches, poses, events):
            publisher.publish_end_of_stream(node.fqn)
        return -1
    for topic, names in ((params.topic, params.wait_for), (params.pose_topic, params.pose_waits)):
        if names and not node.wait_for_subscribers(topic, names, params.wait_timeout_s):
            return -1
    node.set_state("running", f"playing {params.scene}")
    _say_epoch(node, params, "path time 0")
    t = scene.path.t
    wall_per_s = (len(t) - 1) / (params.rate_hz * (t[-1] - t[0])) if params.rate_hz else 0.0
    start = time.monotonic()
    count = 0
    with _truth(params) as truth:
        # the jumps after the wrench of their sample
        stream = heapq.merge(scene_stream(scene, results, params, params.loop, truth.told),
                             scene_events(scene, results, params, repeat=params.loop),
                             key=lambda e: (e[0], isinstance(e[1], SnapEvent)))
        for stream_t, msg in stream:
            if node.stop_requested:
                break
            if wall_per_s:
                delay = start + (stream_t - t[0]) * wall_per_s - time.monotonic()
                if delay > 0 and not node.sleep(delay):
                    break
            _send(msg, wrenches, poses, events, truth)
            count += 1
    for publisher in (wrenches, poses, events):
        publisher.publish_end_of_stream(node.fqn)
    log.info("%s: %d messages and EndOfStream on %s, %s and %s in %.1f s", node.fqn, count,
             wrenches.topic, poses.topic, events.topic, time.monotonic() - start)
    return count


COMMAND_CHUNK = 100
"""Commanded samples simulated at a time (0.2 s of path at 500 Hz): their messages go out
together, and Step 1 looks at most 32 samples ahead (`vibrissa.scene.SceneStream`)."""


class CommandedMessages:
    """The messages of the commanded robot's samples, as mode ``scene`` makes them along a
    fixed path (`scene_stream`): a WhiskerWrenchArray per sample with a row per whisker that
    has a wrench there, stamped ``epoch_s`` + its path time, ``seq`` from 0, noise drawn per
    sample; poses at ``pose_rate_hz`` of path time (0: one per sample) and one at the last
    sample of each batch (a wrench never waits for the next batch's simulation to be placed),
    ``pose_delay_s`` late, the odometry's (``odom_drift_per_m``; the truth of each goes to
    ``truth``). Each with its time in the stream; a pose before a wrench of the same time.
    ``unresolved_rows`` counts the rows left out (no equilibrium found: `SamplePhase.UNRESOLVED`),
    and the start of each whisker's run of them is logged."""

    def __init__(self, scene: Scene, params: WrenchSourceParams,
                 truth: TruthSink | None = None) -> None:
        self.params = params
        self.odometry = params.odometry()
        self.truth = truth
        self.names = [w.name for w in scene.whiskers]
        self.frame_ids = [clamp_frame(name) for name in self.names]
        self.rng = np.random.default_rng(params.seed)
        self.seq = 0
        self.before: tuple[float, FloatArray, FloatArray] | None = None  # the last sample
        self.next_pose = 0  # index of the next pose time on the pose_rate_hz grid
        self.unresolved_rows = 0
        self._unresolved: set[int] = set()  # whiskers whose last sample was unresolved
        self._warn = Warnings("wrench_source", log)  # once per kind, then every 1000th

    def start(self, p_WR: FloatArray, q_WR: FloatArray
              ) -> list[tuple[float, int, WhiskerWrenchArray | RobotPose | SnapEvent]]:
        """The pose at path time 0, where the robot stands before any command."""
        self.next_pose, self.before = 1, (0.0, p_WR, q_WR)
        return [(self.params.pose_delay_s + t, 0, pose)
                for t, pose in self._published([(0.0, p_WR, q_WR)])]

    def of(self, samples: StreamSamples
           ) -> list[tuple[float, int, WhiskerWrenchArray | RobotPose | SnapEvent]]:
        """Messages of ``samples``, the poses up to the last of them, and the jumps told at
        them (a `SnapEvent` after the wrench of its sample)."""
        params = self.params
        out: list[tuple[float, int, WhiskerWrenchArray | RobotPose | SnapEvent]] = []
        f0, m0 = samples.f0_n, samples.m0_nm
        if params.noise_force_n:
            f0 = f0 + self.rng.normal(0.0, params.noise_force_n, f0.shape)
        if params.noise_moment_nm:
            m0 = m0 + self.rng.normal(0.0, params.noise_moment_nm, m0.shape)
        unresolved = samples.phase == SamplePhase.UNRESOLVED
        self.unresolved_rows += int(np.count_nonzero(unresolved))
        for k, t in enumerate(samples.t.tolist()):
            self._tell_unresolved(t, np.flatnonzero(unresolved[k]).tolist())
            rows = np.flatnonzero(~unresolved[k])
            out.append((t, 1, WhiskerWrenchArray(
                stamp=params.epoch_s + t, seq=self.seq, whisker_ids=[self.names[i] for i in rows],
                frame_ids=[self.frame_ids[i] for i in rows], f0=f0[k, rows], m0=m0[k, rows])))
            self.seq += 1
        out += [(t + params.pose_delay_s, 0, pose)
                for t, pose in self._published(self._poses(samples))]
        out += [(told.snap.t, 2, snap_event(
            params.epoch_s + told.snap.t, self.names[told.whisker], self.frame_ids[told.whisker],
            told.snap, (told.f0_before, told.m0_before), (told.f0_after, told.m0_after)))
            for told in samples.snaps]
        if len(samples.t):
            self.before = (float(samples.t[-1]), samples.p_WR[-1], samples.q_WR[-1])
        return sorted(out, key=lambda e: (e[0], e[1]))

    def _tell_unresolved(self, t: float, whiskers: list[int]) -> None:
        """Log the whiskers whose rows are left out from path time ``t`` on."""
        for i in sorted(set(whiskers) - self._unresolved):
            self._warn(f"whisker {self.names[i]!r}: no equilibrium found from path time "
                       f"{t:.4f} s on: its rows are left out until it has one (a clamp or the "
                       "rod inside an object?)")
        self._unresolved = set(whiskers)

    def _published(self, poses: list[tuple[float, FloatArray, FloatArray]]
                   ) -> list[tuple[float, RobotPose]]:
        """The odometry's messages of true poses (path time, X_WR), their truth told."""
        if not poses:
            return []
        p_OR, q_OR, _ = self.odometry.odom(np.array([p for _, p, _ in poses]),
                                           np.array([q for _, _, q in poses]))
        out = []
        for k, (t, p, q) in enumerate(poses):
            if self.truth is not None:
                self.truth(self.params.epoch_s + t, p, q, p_OR[k], q_OR[k])
            out.append((t, _pose(self.params, t, p_OR[k], q_OR[k])))
        return out

    def _poses(self, samples: StreamSamples
               ) -> list[tuple[float, FloatArray, FloatArray]]:
        new = samples.t > self.before[0] if self.before is not None else samples.t >= 0
        if not self.params.pose_rate_hz:  # the start's pose is out already
            return list(zip(samples.t[new].tolist(), samples.p_WR[new], samples.q_WR[new],
                            strict=True))
        if self.before is None or not new.any():
            return []
        t = np.concatenate([[self.before[0]], samples.t[new]])
        path = robot_path(t, np.vstack([self.before[1][None], samples.p_WR[new]]),
                          np.vstack([self.before[2][None], samples.q_WR[new]]))
        period = 1.0 / self.params.pose_rate_hz
        grid = np.arange(self.next_pose, int(np.floor(t[-1] / period)) + 2)
        grid = grid[grid * period <= t[-1]]  # k period may round past t[-1]: not covered yet
        if len(grid):
            self.next_pose = int(grid[-1]) + 1
        at = grid * period
        at = at[at > t[0]]
        if not len(at) or at[-1] < t[-1]:
            at = np.append(at, t[-1])
            # a grid time that is t[-1] but for round-off is this pose: not a second one
            self.next_pose = max(self.next_pose, int(np.floor(t[-1] / period + 1e-6)) + 1)
        _, p, rotations = path.at(at)
        return list(zip(at.tolist(), p, rotations.as_quat(), strict=True))


def run_commanded(node: Node, params: WrenchSourceParams) -> int:
    """Drive the robot along the segments that arrive on ``path_topic``, each sample simulated
    as it comes, its messages published as it is final; returns the number of messages sent,
    -1 when ``wait_for`` timed out."""
    with _truth(params) as truth:
        return _run_commanded(node, params, truth)


def _run_commanded(node: Node, params: WrenchSourceParams, truth: TruthLog) -> int:
    wrenches = node.create_publisher(params.topic, WhiskerWrenchArray, wait_for=params.wait_for,
                                     hwm=DEFAULT_HWM * 10)
    poses = node.create_publisher(params.pose_topic, RobotPose, wait_for=params.pose_waits,
                                  hwm=DEFAULT_HWM * 10)
    events = node.create_publisher(params.events_topic, SnapEvent)
    commands = node.create_subscriber({params.path_topic: PathSegment})
    scene = load_scene(params.scene)
    limits = params.path_limits
    stream = SceneStream(scene, [limits.rod_step(w.X_RC, w.length_m) for w in scene.whiskers])
    p0, q0 = scene.path.p_WR[0], scene.path.R_WR[0].as_quat()
    path = CommandedPath(limits, p0, q0)
    out = CommandedMessages(scene, params, truth.told)
    for topic, names in ((params.topic, params.wait_for), (params.pose_topic, params.pose_waits)):
        if names and not node.wait_for_subscribers(topic, names, params.wait_timeout_s):
            return -1
    node.set_state("running", f"{len(scene.whiskers)} whisker(s) commanded on "
                   f"{node.resolve(params.path_topic)}")
    _say_epoch(node, params, "path time 0")
    stream.extend([0.0], p0[None], q0[None])  # the robot stands at the start
    counters = node.counters
    counters.update(commands_accepted=0, commands_rejected=0, unresolved_rows=0)
    count, taken, ended = 0, 1, False
    pace = params.rate_hz / params.path_rate_hz if params.rate_hz else 0.0
    anchor: tuple[float, float] | None = None  # (wall, stream time) the pacing runs from

    def publish(messages: list[tuple[float, int, WhiskerWrenchArray | RobotPose | SnapEvent]]
                ) -> bool:
        nonlocal count, anchor
        for stream_t, _, msg in messages:
            if pace:
                if anchor is None:
                    anchor = (time.monotonic(), stream_t)
                delay = anchor[0] + (stream_t - anchor[1]) / (pace * params.path_rate_hz) \
                    - time.monotonic()
                if delay > 0 and not node.sleep(delay):
                    return False
            _send(msg, wrenches, poses, events, truth)
            count += 1
        return True

    publish(out.start(p0, q0))  # where the robot stands (its wrench once it is final)
    while not node.stop_requested and (path.queued or not ended):
        rx = commands.receive(0.0 if path.queued or ended else 0.1)
        while rx is not None:
            msg = rx.msg
            if ended:  # the commander said it was done: what it sends after is not driven
                if isinstance(msg, PathSegment):
                    counters["commands_rejected"] += 1
                    log.warning("%s: path segment %d refused: it came after the commander's "
                                "EndOfStream", node.fqn, msg.segment_id)
            elif isinstance(msg, EndOfStream):
                ended = True
            elif isinstance(msg, PathSegment):
                why = (f"frame {msg.frame_id!r} is not {params.map_frame!r}"
                       if msg.frame_id != params.map_frame else
                       path.command(msg.position, msg.orientation, msg.speed_mps,
                                    msg.turn_rate_rps, replace=msg.mode == "replace"))
                key = "commands_rejected" if why else "commands_accepted"
                counters[key] += 1
                if why:
                    log.warning("%s: path segment %d refused: %s", node.fqn, msg.segment_id, why)
                else:
                    log.info("%s: path segment %d (%s): %d waypoint(s), %d sample(s) queued",
                             node.fqn, msg.segment_id, msg.mode, len(msg.position), path.queued)
            rx = commands.receive(0.0)
        if not path.queued:
            anchor = None  # the robot waits: pacing starts again with the next segment
            continue
        p, q = path.take(COMMAND_CHUNK)
        stream.extend(np.arange(taken, taken + len(p)) / params.path_rate_hz, p, q)
        taken += len(p)
        # the queue ran empty: the robot stops there and every sample up to it goes out; each
        # batch ends with a pose at its last sample (off the pose_rate_hz grid: the poses cover
        # every wrench published, and where the robot stands)
        sent = publish(out.of(stream.advance(hold=bool(path.queued))))
        counters["unresolved_rows"] = out.unresolved_rows
        if not sent:
            break
    if not node.stop_requested:
        publish(out.of(stream.finish()))
        counters["unresolved_rows"] = out.unresolved_rows
    for publisher in (wrenches, poses, events):
        publisher.publish_end_of_stream(node.fqn)
    log.info("%s: %d messages and EndOfStream on %s, %s and %s; %s", node.fqn, count,
             wrenches.topic, poses.topic, events.topic,
             ", ".join(f"{k} {v}" for k, v in counters.items()))
    return count


def replay_topics(bag: str) -> dict[str, set[str]]:
    """Topics of ``bag`` whose payloads decode as ``REPLAY_TYPES`` -> their type names (with
    ``EndOfStream``'s when the bag ends the stream there)."""
    info = BagReader(bag).info()
    types: dict[str, set[str]] = {}
    for t in info.topics:
        types.setdefault(t.topic, set()).add(t.type_name)
    return {topic: names for topic, names in types.items()
            if any(decodes_as(name) in REPLAY_TYPES for name in names)}


def run_replay(node: Node, params: WrenchSourceParams) -> int:
    """Play the bag's wrench topics, held until ``wait_for`` nodes are ready (the pose topics
    until ``pose_wait_for`` nodes too: ``vibrissa.runtime.playback.play_bag_gated``); messages
    sent, -1 on failure."""
    topics = replay_topics(params.bag)
    if not topics:
        log.error("%s: %s has no %s topic", node.fqn, params.bag, " or ".join(t.TYPE_NAME for t in REPLAY_TYPES))
        return -1
    node.set_state("running", f"replaying {params.bag}")
    poses = {topic: params.pose_wait_for for topic, names in topics.items()
             if any(decodes_as(name) is RobotPose for name in names)}
    result, publishers = play_bag_gated(
        node, params.bag, params.wait_for, params.wait_timeout_s, rate=params.replay_rate or None,
        topics=list(topics), topic_wait_for=poses)
    if result.interrupted and not node.stop_requested:
        return -1
    for topic, names in topics.items():
        if EndOfStream.TYPE_NAME not in names:  # e.g. a bag cut off: end the stream ourselves
            publishers[topic].publish_end_of_stream(node.fqn)
    log.info("%s: replayed %d message(s) from %s in %.3f s", node.fqn, result.total,
             params.bag, result.wall_s)
    return result.total


def main(argv: Sequence[str] | None = None) -> int:
    """Run the wrench source node (see ARCHITECTURE.md for the command line)."""
    args = NodeArgs.parse(argv, prog="python -m vibrissa.nodes.wrench_source")
    configure_logging()
    params = load_params(WrenchSourceParams, args.params_file, args.params)
    with Node.from_args(args) as node:
        run = {"sim": run_sim, "scene": run_commanded if params.path_topic else run_scene,
               "replay": run_replay}[params.mode]
        sent = run(node, params)
        if sent < 0:
            node.set_state("error", "downstream not ready or replay failed")
            return 1
        # the stream's tail (its EndOfStream too) still queued for a subscriber behind it (a
        # bag played as fast as possible) gets up to wait_timeout_s to leave, unless stopped
        node.close(drain_s=1.0 if node.stop_requested else params.wait_timeout_s)
    return 0


if __name__ == "__main__":
    run_main(main)
