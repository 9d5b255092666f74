"""Localizer node: corrects a drifting odometry from the contacts (`vibrissa.mapping.localize`)
and places the contacts in the map frame (REP 105: ``map -> odom -> base_link``).

Subscribes
----------
``input_topic`` (default ``contact_odom``) : ContactPointArray
    The reconstructor's contacts in ``odom_frame`` (placed with the odometry's poses); its
    ``EndOfStream`` ends the node's streams once every contact is out.
``pose_topic`` (default ``pose``) : RobotPose
    The odometry: ``odom_frame`` -> ``robot_frame`` (other frames, and poses that are not
    finite, are counted, ``ignored_poses``); a contact waits for the pose at its stamp (the travel there), at most
    ``pose_timeout_s``.

Publishes
---------
``output_topic`` (default ``contact``) : ContactPointArray
    Every contact message, in the order it came, in ``map_frame``: its points moved by the
    estimate of ``map -> odom`` of its visit (a translation: forces and covariances keep their
    axes). A message waits for its visit to end (``visit_gap_m`` of travel without contact, or
    ``max_visit_m``), so that the estimate uses the whole visit; then ``EndOfStream``.
``correction_topic`` (default ``map_odom``) : RobotPose
    ``map_frame`` -> ``odom_frame`` each time the estimate changes, stamped as the first
    contact it placed; then ``EndOfStream``.

Counters: ``registered`` and ``unregistered`` visits (with and without contacts near earlier
ones to register against), ``inconsistent`` ones (a registration refused: it moved the visit
further than the odometry allows), ``placed`` contacts, ``refused`` contact messages (not in
``odom_frame``, or not finite), ``late_pose`` messages placed without the pose at their stamp,
``ignored_poses`` (other frames, or not finite).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from vibrissa.frames import ROBOT_FRAME
from vibrissa.mapping.localize import Localizer, LocalizeSettings
from vibrissa.msgs import ContactPointArray, EndOfStream, RobotPose
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main
from vibrissa.runtime.params import require_non_negative, require_parsed
from vibrissa.wire.topics import validate_name

log = logging.getLogger(__name__)

DRAIN = 1000
"""Messages taken from the input at most before the ones waiting are handled."""
RECEIVE_HWM = 200_000
"""Input messages queued at most (the reconstructor's and the mapper's bound): a stream played
faster than the localizer takes it waits in the queue, not lost, up to this many."""


@dataclass(frozen=True)
class LocalizerParams:
    """Parameters of the localizer node.

    Attributes
    ----------
    drift_per_m
        The odometry's drift model (`vibrissa.mapping.localize.LocalizeSettings`): position
        and heading random walk standard deviations per metre travelled; 0: the odometry is
        taken as exact and the contacts pass into ``map_frame`` unchanged, at once.
    point_std_m, match_radius_m, min_separation_m, visit_gap_m, max_visit_m
        As `LocalizeSettings`.
    input_topic, pose_topic, output_topic, correction_topic
        Topics, relative to the namespace unless absolute.
    map_frame, odom_frame, robot_frame
        The frames (REP 105).
    pose_timeout_s
        A contact message waits at most this long for the pose at its stamp, s.
    wait_for
        Nodes that must subscribe to ``output_topic`` before anything goes out.
    """

    drift_per_m: float = LocalizeSettings.drift_per_m
    point_std_m: float = LocalizeSettings.point_std_m
    match_radius_m: float = LocalizeSettings.match_radius_m
    min_separation_m: float = LocalizeSettings.min_separation_m
    visit_gap_m: float = LocalizeSettings.visit_gap_m
    max_visit_m: float = LocalizeSettings.max_visit_m
    input_topic: str = "contact_odom"
    pose_topic: str = "pose"
    output_topic: str = "contact"
    correction_topic: str = "map_odom"
    map_frame: str = "map"
    odom_frame: str = "odom"
    robot_frame: str = ROBOT_FRAME
    pose_timeout_s: float = 5.0
    wait_for: tuple[str, ...] = ()
    settings: LocalizeSettings = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in (self.input_topic, self.pose_topic, self.output_topic,
                     self.correction_topic, *self.wait_for):
            require_parsed("input_topic/pose_topic/output_topic/correction_topic/wait_for",
                           name, validate_name)
        require_non_negative("pose_timeout_s", self.pose_timeout_s)
        try:
            settings = LocalizeSettings(
                drift_per_m=self.drift_per_m, point_std_m=self.point_std_m,
                match_radius_m=self.match_radius_m, min_separation_m=self.min_separation_m,
                visit_gap_m=self.visit_gap_m, max_visit_m=self.max_visit_m)
        except ValueError as exc:
            raise ValueError(f"parameter {exc}") from None
        object.__setattr__(self, "settings", settings)


PARAMS = LocalizerParams
"""The node's parameter dataclass: the launcher checks a launch file's values with it."""


def run(node: Node, params: LocalizerParams) -> None:
    """Correct and place until the input's ``EndOfStream`` (or a stop)."""
    localizer = Localizer(params.settings)
    subscriber = node.create_subscriber({params.input_topic: ContactPointArray,
                                         params.pose_topic: RobotPose}, hwm=RECEIVE_HWM)
    contacts = node.create_publisher(params.output_topic, ContactPointArray,
                                     wait_for=params.wait_for)
    corrections = node.create_publisher(params.correction_topic, RobotPose,
                                        wait_for=params.wait_for)
    input_topic, pose_topic = node.resolve(params.input_topic), node.resolve(params.pose_topic)
    counters = node.counters
    counters.update(registered=0, unregistered=0, inconsistent=0, placed=0, refused=0, late_pose=0,
                    ignored_poses=0)
    waiting: deque[tuple[float, ContactPointArray]] = deque()  # (arrived, message)
    newest_pose = -math.inf
    poses_ended = contacts_ended = False
    published = (math.nan, math.nan)
    node.set_state("running", f"{params.odom_frame} -> {params.map_frame}, drift model "
                   f"{params.drift_per_m:g} per m")

    def publish() -> None:
        nonlocal published
        for placed in localizer.take():
            msg = placed.token
            assert isinstance(msg, ContactPointArray)
            if placed.map_to_odom_m != published:
                published = placed.map_to_odom_m
                corrections.publish(RobotPose(
                    stamp=msg.stamp, frame_id=params.map_frame, child_frame_id=params.odom_frame,
                    position=[*published, 0.0], orientation=[0.0, 0.0, 0.0, 1.0]))
            contacts.publish(dataclasses.replace(msg, frame_id=params.map_frame,
                                                 point=placed.points_m))
        counters.update(registered=localizer.counts.registered,
                        unregistered=localizer.counts.unregistered,
                        inconsistent=localizer.counts.inconsistent,
                        placed=localizer.counts.placed)

    while not node.stop_requested:
        rx = subscriber.receive(0.1)
        taken = 0
        while rx is not None:
            msg = rx.msg
            if isinstance(msg, EndOfStream):
                contacts_ended |= rx.topic == input_topic
                poses_ended |= rx.topic == pose_topic
            elif isinstance(msg, RobotPose):
                if (msg.frame_id == params.odom_frame and msg.child_frame_id == params.robot_frame
                        and np.isfinite(msg.position).all() and math.isfinite(msg.stamp)):
                    localizer.add_pose(msg.stamp, np.asarray(msg.position))
                    newest_pose = max(newest_pose, msg.stamp)
                else:
                    if not counters["ignored_poses"]:
                        log.warning("%s: a pose of %r in %r ignored: the odometry is %r in %r",
                                    node.fqn, msg.child_frame_id, msg.frame_id,
                                    params.robot_frame, params.odom_frame)
                    counters["ignored_poses"] += 1
            elif isinstance(msg, ContactPointArray):
                why = (f"in {msg.frame_id!r}, not {params.odom_frame!r}"
                       if msg.frame_id != params.odom_frame else
                       "" if np.isfinite(msg.point).all() and np.isfinite(msg.force).all()
                       and math.isfinite(msg.stamp) else "not finite")
                if not why:
                    waiting.append((time.monotonic(), msg))
                else:
                    if not counters["refused"]:
                        log.warning("%s: contacts refused: %s (counted in 'refused')", node.fqn,
                                    why)
                    counters["refused"] += 1
            taken += 1
            rx = subscriber.receive(0.0) if taken < DRAIN else None
        now = time.monotonic()
        while waiting:  # in order, each once the odometry has passed its stamp
            arrived, msg = waiting[0]
            late = now - arrived > params.pose_timeout_s
            if not (msg.stamp <= newest_pose or poses_ended or late):
                break
            counters["late_pose"] += late and msg.stamp > newest_pose and not poses_ended
            waiting.popleft()
            localizer.add(msg.stamp, np.reshape(msg.point, (-1, 3)), np.reshape(msg.force, (-1, 3)),
                          msg.whisker_ids, msg.covariance, msg)
        publish()
        if contacts_ended and not waiting:
            break
    localizer.finish()
    publish()
    contacts.publish_end_of_stream(node.fqn)
    corrections.publish_end_of_stream(node.fqn)
    log.info("%s: %s; map -> %s at the end: %.6f, %.6f m", node.fqn,
             ", ".join(f"{k} {v}" for k, v in counters.items()), params.odom_frame,
             *localizer.estimate_m)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the localizer node (see ARCHITECTURE.md for the command line)."""
    args = NodeArgs.parse(argv, prog="python -m vibrissa.nodes.localizer")
    configure_logging()
    params = load_params(LocalizerParams, args.params_file, args.params)
    with Node.from_args(args) as node:
        run(node, params)
    return 0


if __name__ == "__main__":
    run_main(main)
