"""Simulated ATI Net F/T node: a UDP device speaking RDT on loopback, reading a whisker's Step 1 wrenches.

Subscribes
----------
nothing (besides the runtime's ``/vibrissa/status``).

Publishes
---------
``pose_topic`` (with ``scene``; empty: none) : RobotPose
    The robot's pose (the scene's path sample of each record), stamped with the time the
    record was measured (``time.time()``): the driver's sensor-time stamps, so that the
    reconstructor places each wrench where the robot was.

On UDP ``host:port`` it answers RDT requests (stream, stop, bias) with records of what the
whisker's sensor reads: the clamp-frame wrenches of Step 1 (a ``vibrissa simulate`` folder,
the scene simulated on start, or one sweep of the paper's trail) turned into the load on a
sensor at the whisker's X_CS (``vibrissa.calibration.clamp_to_sensor``), plus noise, bias and
drift, with loss and reordering (``vibrissa.wire.netft_device``); one record per path sample.
Counters in its status: ``made``, ``dropped``, ``late`` (records), ``biases``.

Run next to a driver: ``vibrissa launch launch/netft.yaml`` (both), or by hand
``python -m vibrissa.nodes.netft_sim --name sensor --param port:=49152``.
"""

from __future__ import annotations

import collections
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vibrissa.calibration import clamp_to_sensor
from vibrissa.formats.scene_file import load_scene
from vibrissa.formats.scene_results import read_results
from vibrissa.frames import ROBOT_FRAME, WORLD_FRAME, Transform
from vibrissa.msgs import RobotPose
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main
from vibrissa.runtime.params import require, require_non_negative, require_parsed, require_positive
from vibrissa.scene import RobotPath, simulate_whisker
from vibrissa.surfaces import parse_surface
from vibrissa.sweep import simulate_sweep
from vibrissa.units import RodScale
from vibrissa.wire.netft import calibration_error
from vibrissa.wire.netft_device import NetFTDevice, SignalSpec
from vibrissa.wire.topics import validate_name

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class NetFTSimParams:
    """Parameters of the simulated Net F/T.

    Attributes
    ----------
    host, port
        Where the device listens (UDP; 0: a free port, logged).
    scene, simulated, whisker
        A scene file, its ``vibrissa simulate`` output folder (empty: the whisker simulated
        on start) and the whisker whose wrenches the sensor reads (its X_CS from the scene);
        without ``scene``: one sweep below.
    surface, y0, mu, step, rod_length_m, rod_ei_nm2
        The sweep (units of L) and the rod that makes it SI.
    rate_hz, loop
        Records per second (up to 7000); replay from the start after the end (else the last
        sample is held, a rod at rest).
    counts_per_force, counts_per_torque, per_datagram, ft_step
        As the device (``vibrissa.wire.netft_device.NetFTDevice``).
    noise_force_n, noise_moment_nm, bias, drift, loss, reorder, seed
        What the device adds (``SignalSpec``): noise std, a constant offset (6 values, N and
        N m), an offset growing per second (6 values), the probability of losing or
        reordering a datagram, the seed.
    pose_topic, wait_for
        With ``scene``: where the robot's pose of each record goes (empty: nowhere), and the
        nodes that must subscribe to it first (buffered until then).
    """

    host: str = "127.0.0.1"
    port: int = 49152
    scene: str = ""
    simulated: str = ""
    whisker: str = ""
    surface: str = "paraboloid:a=0.5,b=1,h=0.4"
    y0: float = 0.2
    mu: float = 0.2
    step: float = 0.001
    rod_length_m: float = 0.05
    rod_ei_nm2: float = 2.3e-4
    rate_hz: float = 1000.0
    loop: bool = True
    counts_per_force: float = 1_000_000.0
    counts_per_torque: float = 1_000_000.0
    per_datagram: int = 10
    ft_step: int = 1
    noise_force_n: float = 0.0
    noise_moment_nm: float = 0.0
    bias: tuple[float, ...] = (0.0,) * 6
    drift: tuple[float, ...] = (0.0,) * 6
    loss: float = 0.0
    reorder: float = 0.0
    seed: int = 0
    pose_topic: str = ""
    wait_for: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        require(0 <= self.port <= 65535, "port", self.port, "a port 0-65535")
        for key in ("rate_hz", "step", "rod_length_m", "rod_ei_nm2"):
            require_positive(key, getattr(self, key))
        for key, kind in (("counts_per_force", "force"), ("counts_per_torque", "torque")):
            error = calibration_error(kind, getattr(self, key))
            if error is not None:
                raise ValueError(f"parameter {key!r}: {error}")
        require(self.rate_hz <= 20000, "rate_hz", self.rate_hz, "at most 20000")
        for key in ("noise_force_n", "noise_moment_nm"):
            require_non_negative(key, getattr(self, key))
        for key in ("loss", "reorder"):
            require(0 <= getattr(self, key) < 1, key, getattr(self, key), "a probability in [0, 1)")
        for key in ("bias", "drift"):
            require(len(getattr(self, key)) == 6, key, getattr(self, key), "6 numbers")
        require(1 <= self.per_datagram <= 40, "per_datagram", self.per_datagram, "1 to 40")
        for name in (self.pose_topic, *self.wait_for) if self.pose_topic else self.wait_for:
            require_parsed("pose_topic/wait_for", name, validate_name)
        if self.scene:
            require(bool(self.whisker), "whisker", self.whisker, "a whisker with 'scene'")
            require_parsed("scene", self.scene, load_scene)
        else:
            require_parsed("surface", self.surface, parse_surface)


PARAMS = NetFTSimParams


def sensor_signal(params: NetFTSimParams) -> np.ndarray:
    """(N, 6) what the sensor reads along the run, N and N m in S (free samples: zero)."""
    if params.scene:
        scene = load_scene(params.scene)
        whiskers = {w.name: w for w in scene.whiskers}
        if params.whisker not in whiskers:
            raise ValueError(f"whisker {params.whisker!r} is not in {params.scene} "
                             f"({', '.join(whiskers)})")
        if params.simulated:
            result = next(r for r in read_results(params.simulated, scene)
                          if r.name == params.whisker)
        else:
            result = simulate_whisker(scene, whiskers[params.whisker])
        f0, m0 = np.nan_to_num(result.f0_n), np.nan_to_num(result.m0_nm)  # unresolved: as free
        X_CS = whiskers[params.whisker].X_CS
    else:
        sweep = simulate_sweep(parse_surface(params.surface), params.y0, params.mu, params.step)
        f0, m0 = RodScale(params.rod_length_m, params.rod_ei_nm2).wrench_to_si(sweep.f0, sweep.m0)
        f0 = np.vstack([np.zeros((50, 3)), f0, np.zeros((50, 3))])  # free before and after
        m0 = np.vstack([np.zeros((50, 3)), m0, np.zeros((50, 3))])
        X_CS = Transform()
    f_S, m_S = clamp_to_sensor(f0, m0, X_CS)
    return np.hstack([f_S, m_S])


def open_device(params: NetFTSimParams,
                emitted: collections.deque[tuple[int, float]] | None = None) -> NetFTDevice:
    """The simulated sensor of ``params``, listening on ``device.address`` and streaming on
    request until closed (a context manager). The node and ``vibrissa sim netft`` both run it.
    ``emitted``: see ``NetFTDevice``.

    Raises
    ------
    ValueError
        A whisker that is not in the scene, or a results folder that does not fit it.
    OSError
        ``host:port`` cannot be bound.
    """
    signal = sensor_signal(params)
    spec = SignalSpec(noise=(params.noise_force_n, params.noise_moment_nm), bias=params.bias,
                      drift=params.drift, loss=params.loss, reorder=params.reorder, seed=params.seed)
    return NetFTDevice(signal, params.rate_hz, counts_per_force=params.counts_per_force,
                       counts_per_torque=params.counts_per_torque, spec=spec,
                       per_datagram=params.per_datagram, ft_step=params.ft_step, loop=params.loop,
                       host=params.host, port=params.port, emitted=emitted)


class PosePlayer:
    """The robot's pose of each record the device made, on ``params.pose_topic``."""

    def __init__(self, node: Node, params: NetFTSimParams, path: RobotPath) -> None:
        self.publisher = node.create_publisher(params.pose_topic, RobotPose,
                                               wait_for=params.wait_for)
        self.loop = params.loop
        self.p_WR, self.q_WR = path.p_WR, path.R_WR.as_quat()
        self.last_row: int | None = None  # of the newest pose, until a stream's end

    def _publish(self, row: int, stamp: float) -> None:
        self.publisher.publish(RobotPose(stamp=stamp, frame_id=WORLD_FRAME,
                                         child_frame_id=ROBOT_FRAME, position=self.p_WR[row],
                                         orientation=self.q_WR[row]))

    def play(self, emitted: collections.deque[tuple[int, float]], streaming: bool) -> None:
        """Publish the poses of ``emitted`` (taken off it); after a stream's end, the robot
        still at its last pose, stamped now (the driver's stamp of the last record, a moment
        after it was measured, falls before it)."""
        n = len(self.p_WR)
        while emitted:
            row, stamp = emitted.popleft()
            self.last_row = row % n if self.loop else min(row, n - 1)
            self._publish(self.last_row, stamp)
        if self.last_row is not None and not streaming:
            self._publish(self.last_row, time.time())
            self.last_row = None


def main(argv: Sequence[str] | None = None) -> int:
    args = NodeArgs.parse(argv, prog="netft_sim")
    configure_logging()
    params = load_params(NetFTSimParams, args.params_file, args.params)
    emitted: collections.deque[tuple[int, float]] = collections.deque()
    with Node.from_args(args) as node:
        path = load_scene(params.scene).path if params.scene and params.pose_topic else None
        if params.scene:
            node.set_state("running", "simulating the whisker along the path"
                           if not params.simulated else f"reading {params.simulated}")
        with open_device(params, emitted if path else None) as device:
            log.info("%s: Net F/T on udp://%s:%d, %d samples at %g Hz", node.fqn,
                     *device.address, len(device.wrench_S), params.rate_hz)
            node.set_state("running", f"udp://{device.address[0]}:{device.address[1]}")
            poses = None if path is None else PosePlayer(node, params, path)
            while node.sleep(0.01):
                if poses is not None:
                    poses.play(emitted, device.streaming)
                stats = device.stats
                node.counters.update(made=stats.made, dropped=stats.dropped, late=stats.late,
                                     biases=stats.biases)
    return 0


if __name__ == "__main__":
    run_main(main)
