"""Explorer node: drives a whiskered robot to explore its workspace, plan by plan
(`vibrissa.planning.Explorer`), and ends the exploration by itself.

Subscribes
----------
``pose_topic`` (default ``pose``) : RobotPose
    The robot's base X_WR (``world`` -> ``base_link``), as the robot's driver publishes it.
``contact_topic`` (default ``contact``) : ContactPointArray
    Each tick's contacts in frame ``world`` (the reconstructor's: one message per tick, with
    the whiskers found free in ``free_ids``), placed at the pose of the tick's stamp. A
    whisker with neither a row nor a place in ``free_ids`` sweeps nothing; a tick without
    ``free_ids`` (a producer that does not tell) frees nothing, and the explorer warns.
``mesh_topic``, ``unknown_mesh_topic`` (default ``surface_mesh``, ``surface_mesh_unknown``) :
SurfaceMesh
    The mapper's known and unknown parts of frame ``world``: the known surfaces are obstacles,
    the unknown part what the ``uncertainty`` planner goes to touch.
``proposal_topic`` (default ``next_sweep``) : SweepProposal
    The mapper's next sweeps of frame ``world``: the points of each section (where the map is
    least sure) are what the ``uncertainty`` planner goes to touch too (the proposals of the
    newest update replace those before).

Publishes
---------
``path_topic`` (default ``path``) : PathSegment
    One segment per plan (a route through cells the rods swept free, then a full turn in
    place), appended once the robot has driven the one before and its contacts have arrived;
    ``EndOfStream`` when the exploration ends (budget spent, nothing left within reach), which
    ends the robot's stream.

What it knows is the robot's: the ``scene`` file's whiskers (mounts, lengths) and its
``explore`` key (start, workspace box, body radius); never its objects. The plans are
`vibrissa.planning.explorer`'s (docs/EXPLORATION.md); the node waits for the robot to reach a
plan's last waypoint (to the bit: a commanded path ends on it) and for the contacts of every
tick up to there before it plans again.
"""

from __future__ import annotations

import bisect
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from vibrissa.formats.scene_file import load_explore, load_robot
from vibrissa.frames import Transform, interpolate
from vibrissa.msgs import (
    ContactPointArray,
    EndOfStream,
    PathSegment,
    RobotPose,
    SurfaceMesh,
    SweepProposal,
)
from vibrissa.planning import FREE, PLANNERS, Explorer, ExploreSettings
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main
from vibrissa.runtime.params import require, require_parsed, require_positive
from vibrissa.wire.topics import validate_name

log = logging.getLogger(__name__)

WORLD = "world"
"""The frame of the poses, contacts, meshes and path segments."""
TICK_WAIT_S = 20.0
"""How long the explorer waits for the robot's last ticks of a plan after the newest one
arrived, s, before it plans without them: a tick the reconstructor could not place (no pose)
never comes, but a reconstructor starved of CPU for seconds is late, and a plan made without
its last look's ticks takes the floor the look swept for hidden."""
LOOKING_RAD = 1.0
"""A robot at a plan's goal position turned this far from the goal's heading is in the plan's
closing full turn, rad."""
POSE_HISTORY = 200_000
"""The most poses kept for placing ticks (400 s at 500 Hz)."""


@dataclass(frozen=True)
class ExplorerParams:
    """Parameters of the explorer node.

    Attributes
    ----------
    scene
        Scene file with the robot's whiskers and its ``explore`` key (start, workspace box,
        body radius); its objects are not read.
    planner
        ``uncertainty`` (default: the map's unknown surface and the unknown floor) or
        ``lawnmower`` (parallel lanes across the workspace).
    budget_m
        The base's path length at most, m.
    cell_m
        Edge of the free-space grid's cells, m.
    skirt_slope
        How far an object's wall may lean out below the lowest rods, per metre of height (see
        `ExploreSettings`).
    speed_mps, turn_rate_rps
        The robot's speed and turn rate along a plan.
    pose_topic, contact_topic, mesh_topic, unknown_mesh_topic, proposal_topic, path_topic
        Topics, relative to the namespace unless absolute.
    wait_for
        Nodes that must subscribe to ``path_topic`` before the first segment goes out (the
        robot's driver).
    """

    scene: str = ""
    planner: str = "uncertainty"
    budget_m: float = 2.0
    cell_m: float = ExploreSettings.cell_m
    skirt_slope: float = ExploreSettings.skirt_slope
    speed_mps: float = 0.05
    turn_rate_rps: float = 1.0
    pose_topic: str = "pose"
    contact_topic: str = "contact"
    mesh_topic: str = "surface_mesh"
    unknown_mesh_topic: str = "surface_mesh_unknown"
    proposal_topic: str = "next_sweep"
    path_topic: str = "path"
    wait_for: tuple[str, ...] = ()
    settings: ExploreSettings = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        require(bool(self.scene), "scene", self.scene, "a scene file with an explore key")
        require(self.planner in PLANNERS, "planner", self.planner, f"one of {', '.join(PLANNERS)}")
        require_positive("speed_mps", self.speed_mps)
        require_positive("turn_rate_rps", self.turn_rate_rps)
        for name in (self.pose_topic, self.contact_topic, self.mesh_topic,
                     self.unknown_mesh_topic, self.proposal_topic, self.path_topic):
            require_parsed("pose_topic/contact_topic/mesh_topic/unknown_mesh_topic/"
                           "proposal_topic/path_topic", name, validate_name)
        for name in self.wait_for:
            require_parsed("wait_for", name, validate_name)
        try:
            settings = ExploreSettings(planner=self.planner, budget_m=self.budget_m,
                                       cell_m=self.cell_m, skirt_slope=self.skirt_slope)
        except ValueError as exc:
            raise ValueError(f"parameter {exc}") from None
        object.__setattr__(self, "settings", settings)


PARAMS = ExplorerParams
"""The node's parameter dataclass: the launcher checks a launch file's values with it."""


class Poses:
    """The robot's recent poses by stamp, for placing ticks (interpolated between two)."""

    def __init__(self) -> None:
        self.stamps: list[float] = []
        self.poses: list[Transform] = []

    def add(self, stamp: float, pose: Transform) -> None:
        if self.stamps and stamp <= self.stamps[-1]:
            return  # out of order: the robot's stream runs forward
        self.stamps.append(stamp)
        self.poses.append(pose)
        if len(self.stamps) > POSE_HISTORY:
            del self.stamps[:POSE_HISTORY // 2], self.poses[:POSE_HISTORY // 2]

    def at(self, stamp: float) -> Transform | None:
        """The pose at ``stamp`` (None: not covered yet, or older than the history)."""
        k = bisect.bisect_left(self.stamps, stamp)
        if k < len(self.stamps) and self.stamps[k] == stamp:
            return self.poses[k]
        if k == 0 or k == len(self.stamps):
            return None
        t0, t1 = self.stamps[k - 1], self.stamps[k]
        return interpolate(self.poses[k - 1], self.poses[k], (stamp - t0) / (t1 - t0))


def _pose(msg: RobotPose) -> Transform:
    return Transform.from_quaternion(msg.orientation, msg.position)


def run(node: Node, params: ExplorerParams) -> str:
    """Explore until the planner is done or a stop; why it ended."""
    explore = load_explore(params.scene)
    if explore is None:
        raise ValueError(f"parameter 'scene': {params.scene} has no explore key")
    explorer = Explorer(load_robot(params.scene), explore.body_radius_m, explore.workspace_min_m,
                        explore.workspace_max_m, explore.start, params.settings)
    subscriber = node.create_subscriber({
        params.pose_topic: RobotPose, params.contact_topic: ContactPointArray,
        params.mesh_topic: SurfaceMesh, params.unknown_mesh_topic: SurfaceMesh,
        params.proposal_topic: SweepProposal})
    mesh_topic = node.resolve(params.mesh_topic)
    path = node.create_publisher(params.path_topic, PathSegment, wait_for=params.wait_for)
    poses = Poses()
    pending: list[ContactPointArray] = []  # ticks whose pose has not come yet
    surfaces = {True: np.zeros((0, 3)), False: np.zeros((0, 3))}
    proposals: dict[tuple[str, int], np.ndarray] = {}  # the newest update's sections
    proposal_stamp = -np.inf
    goal: Transform | None = None  # where the last plan ends: plan once it is reached
    reached_stamp: float | None = -np.inf  # the stamp of the pose that reached it (the start)
    looking = False  # the robot is in the plan's last turn
    placed_stamp = -np.inf  # the newest tick placed
    segments = 0
    last_tick = time.monotonic()  # when the last tick arrived
    why = "stopped"
    node.set_state("running", "waiting for the robot's pose")
    while not node.stop_requested:
        rx = subscriber.receive(0.1)
        if rx is not None:
            msg = rx.msg
            if isinstance(msg, EndOfStream):
                if rx.topic == node.resolve(params.pose_topic):
                    why = "the robot's stream ended"
                    break
            elif isinstance(msg, RobotPose):
                if msg.frame_id == WORLD and msg.child_frame_id == "base_link":
                    X = _pose(msg)
                    poses.add(msg.stamp, X)
                    if goal is not None and reached_stamp is None and np.allclose(
                            X.translation, goal.translation, rtol=0, atol=1e-9):
                        # a plan ends with a full turn where it began: the goal is reached
                        # at the turn's end, not as the turn starts
                        turned = (X.rotation.inv() * goal.rotation).magnitude()
                        looking |= turned > LOOKING_RAD
                        if looking and turned < 1e-9:
                            reached_stamp = msg.stamp
            elif isinstance(msg, ContactPointArray):
                last_tick = time.monotonic()
                if msg.frame_id == WORLD:
                    pending.append(msg)
            elif isinstance(msg, SurfaceMesh) and msg.frame_id == WORLD:
                surfaces[rx.topic == mesh_topic] = np.reshape(msg.vertices, (-1, 3))
                explorer.observe_surface(surfaces[True], np.vstack([surfaces[False],
                                                                    *proposals.values()]))
            elif (isinstance(msg, SweepProposal) and msg.frame_id == WORLD
                  and msg.stamp >= proposal_stamp):
                if msg.stamp > proposal_stamp:  # a newer update: its proposals replace
                    proposals, proposal_stamp = {}, msg.stamp
                proposals[(msg.object, msg.rank)] = np.reshape(msg.line, (-1, 3))
                explorer.observe_surface(surfaces[True], np.vstack([surfaces[False],
                                                                    *proposals.values()]))
        while pending:
            at = poses.at(pending[0].stamp)
            if at is None and poses.stamps and pending[0].stamp < poses.stamps[0]:
                pending.pop(0)  # before the first pose it heard: never placed
                node.counters["unplaced_ticks"] = node.counters.get("unplaced_ticks", 0) + 1
                continue
            if at is None:
                break
            tick = pending.pop(0)
            contacts = dict(zip(tick.whisker_ids, np.reshape(tick.point, (-1, 3)), strict=True))
            if tick.free_ids is None:
                if not node.counters.get("ticks_without_free_ids"):
                    log.warning("the contacts on %s do not tell which whiskers were free "
                                "(free_ids): their rods free no floor", params.contact_topic)
                node.counters["ticks_without_free_ids"] = (
                    node.counters.get("ticks_without_free_ids", 0) + 1)
            explorer.observe(at, contacts, set(tick.free_ids or ()))
            node.counters["ticks"] = node.counters.get("ticks", 0) + 1
            placed_stamp = tick.stamp
        if reached_stamp is None or (segments and placed_stamp < reached_stamp
                                     and time.monotonic() - last_tick < TICK_WAIT_S):
            continue  # still driving, or its last ticks on their way
        if segments and placed_stamp < reached_stamp:
            node.counters["plans_without_ticks"] = node.counters.get("plans_without_ticks", 0) + 1
            log.warning("plan %d without the ticks after %.3f s of robot time: none came for "
                        "%.0f s", segments + 1, reached_stamp - placed_stamp, TICK_WAIT_S)
        here = poses.poses[-1] if poses.poses else explore.start
        plan = explorer.plan(here)
        if plan is None:
            why = (f"{explorer.done_because} ({node.counters.get('ticks', 0)} ticks placed; "
                   f"{100 * float(np.mean(explorer.space.state == FREE)):.1f} % of the floor free)")
            break
        segments += 1
        path.publish(PathSegment(stamp=time.time(), frame_id=WORLD, segment_id=segments,
                                 mode="append", position=plan.position,
                                 orientation=plan.orientation, speed_mps=params.speed_mps,
                                 turn_rate_rps=params.turn_rate_rps))
        goal = Transform.from_quaternion(plan.orientation[-1], plan.position[-1])
        reached_stamp, looking = None, False
        node.set_state("running", f"plan {segments}: {plan.purpose}; travelled "
                                  f"{explorer.travelled_m:.3f} of {params.budget_m} m")
        log.info("plan %d: %s (travelled %.3f m; %d ticks placed; %.1f %% of the floor free)",
                 segments, plan.purpose, explorer.travelled_m, node.counters.get("ticks", 0),
                 100 * float(np.mean(explorer.space.state == FREE)))
    path.publish_end_of_stream(node.fqn)
    print(f"exploration ended: {why}; {segments} plan(s), {explorer.travelled_m:.3f} m "
          f"travelled ({params.planner})", flush=True)
    return why


def main(argv: Sequence[str] | None = None) -> int:
    """Run the explorer node."""
    args = NodeArgs.parse(argv, prog="python -m vibrissa.nodes.explorer")
    configure_logging()
    params = load_params(ExplorerParams, args.params_file, args.params)
    with Node.from_args(args) as node:
        run(node, params)
    return 0


if __name__ == "__main__":
    run_main(main)
