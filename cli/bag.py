"""``vibrissa bag``: record, play, inspect, export MCAP bags of the node graph; import ROS 2 bags."""

from __future__ import annotations

import argparse
import math
import sys
import threading
from pathlib import Path
from typing import Any

import zmq

from vibrissa.cli.arg_types import seconds
from vibrissa.cli.graph import (
    AFTER_NAMES,
    Names,
    add_endpoint_flags,
    endpoints_from,
    is_graph_name,
    no_graph,
    nothing_heard,
    stop_on_signals,
    take_spilled,
)
from vibrissa.formats.scene_file import SceneError, load_robot
from vibrissa.frames import ROBOT_FRAME, WORLD_FRAME
from vibrissa.nodes import recorder
from vibrissa.runtime import Node
from vibrissa.runtime.node import EXIT_LOST_DATA
from vibrissa.runtime.playback import play_bag_gated
from vibrissa.wire.bag import BagReader, PlayResult, check_bag_file, export_json, play_bag
from vibrissa.wire.ros2_bag import WHISKERS_TOPIC, export_ros2, import_ros2, wrench_topics_of
from vibrissa.wire.transport import Endpoints

_TOPICS_HELP = "only these topics (several, comma-separated or not, or --topics again)"


def register(subparsers: Any) -> None:
    """Add ``bag`` with its subcommands ``record``, ``play``, ``info``, ``export``, ``import``."""
    bag = subparsers.add_parser("bag", help="record, play, inspect, export and import bags (MCAP; ROS 2)")
    sub = bag.add_subparsers(dest="bag_command", required=True, metavar="SUBCOMMAND")

    p = sub.add_parser("record", help="record topics to an MCAP bag")
    p.add_argument("topics", nargs="*", metavar="TOPIC", help="topics to record (default: all)")
    p.add_argument("-o", "--output", required=True, metavar="FILE.mcap")
    p.add_argument("--duration", type=float, default=0.0, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C/SIGTERM)")
    p.add_argument("--until-eos", action="store_true",
                   help="stop once every topic that carried EndOfStream has ended")
    p.add_argument("--eos-grace", type=float, default=1.0, metavar="S",
                   help="with --until-eos, keep recording S seconds after the last end")
    p.add_argument("--name", default="bag_recorder",
                   help="node name in the graph's status (for readiness gates)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing FILE.mcap")
    add_endpoint_flags(p)
    p.set_defaults(func=_record)

    p = sub.add_parser("play", help="publish a bag's messages with their original timing "
                       "(each with its own type, in recorded order per topic)")
    p.add_argument("bag", nargs="?", metavar="FILE.mcap")  # also after --topics (Names)
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--rate", type=float, default=1.0, metavar="R",
                       help="time scale, 2 = twice as fast (default 1)")
    speed.add_argument("--fast", action="store_true", help="publish as fast as possible")
    p.add_argument("--topics", action=Names, is_name=is_graph_name, metavar="TOPIC",
                   help=_TOPICS_HELP)
    p.add_argument("--wait", type=seconds, default=1.0, metavar="S",
                   help="seconds to let subscribers connect before the first message")
    p.add_argument("--wait-for", action=Names, is_name=is_graph_name, default=[],
                   metavar="NODE", help="also wait until these nodes report every played "
                   "topic as received (several, comma-separated or not, or --wait-for again)")
    p.add_argument("--wait-timeout", type=seconds, default=30.0, metavar="S",
                   help="give up on --wait-for after S seconds (default 30)")
    add_endpoint_flags(p)
    p.set_defaults(func=_play)

    p = sub.add_parser("info", help="summarise a bag")
    p.add_argument("bag", metavar="FILE.mcap")
    p.set_defaults(func=_info)

    p = sub.add_parser(
        "export", help="convert to a JSON-encoded MCAP that Foxglove opens, or a ROS 2 bag",
        description="--format json (default): a JSON-encoded MCAP file that Foxglove opens. "
        "--format ros2: a rosbag2 folder (metadata.yaml + MCAP, CDR) for `ros2 bag play` and "
        "Foxglove: WhiskerWrenchArray -> geometry_msgs/WrenchStamped on one topic "
        "<topic>/<whisker> per whisker (a retired single WhiskerWrench: on <topic>) holding "
        "what the sensor reads, the rod's load on the "
        "clamp: force = -f0, torque = -m0 in the clamp frame; contact points -> "
        "sensor_msgs/PointCloud2 (x, y, z, whisker, phase, s1; whisker indexes the JSON list "
        f"of names on {WHISKERS_TOPIC}); RobotPose -> /tf; the --robot mounts -> /tf_static; "
        "SurfaceMesh -> visualization_msgs/Marker; other types are skipped and counted. Each "
        "message is logged at its header stamp, the sensor's time (the names and mounts at the "
        "first stamp), so `ros2 bag play --clock` plays on the stamps' clock at their pace.")
    p.add_argument("bag", nargs="?", metavar="BAG.mcap")  # also after --topics (Names)
    p.add_argument("outdir", nargs="?", metavar="OUT",
                   help="output: OUT.mcap for json, a new folder for ros2 (or -o)")
    p.add_argument("-o", "--output", metavar="OUT", help="output (instead of OUT)")
    p.add_argument("--format", choices=("json", "ros2", "foxglove"), default="json",
                   help="json: JSON-encoded MCAP of vibrissa's messages (default); ros2: rosbag2 "
                   "folder; foxglove: MCAP of the live view's channels in Foxglove's own "
                   "schemas (the 3D panel draws the points, frames and meshes; needs the extra "
                   "view)")
    p.add_argument("--topics", action=Names, is_name=is_graph_name, metavar="TOPIC",
                   help=_TOPICS_HELP)
    p.add_argument("--robot", metavar="SCENE.yaml",
                   help="ros2, foxglove: the robot description (a scene file's whiskers) whose "
                   "mounts go to /tf_static (ros2) or /tf (foxglove)")
    p.add_argument("--robot-frame", default=ROBOT_FRAME, metavar="FRAME",
                   help=f"ros2: parent frame of the mounts (default {ROBOT_FRAME})")
    p.add_argument("--overwrite", action="store_true",
                   help="json, foxglove: replace an existing OUT (never the input bag; a ROS 2 "
                   "bag always goes to a new folder)")
    p.set_defaults(func=_export)

    p = sub.add_parser(
        "import", help="convert a ROS 2 bag (WrenchStamped per whisker, /tf) to a vibrissa bag",
        description="Each --wrench-topic (geometry_msgs/WrenchStamped, the sensor's reading: "
        "f0 = -force, m0 = -torque, in the clamp frame header.frame_id) becomes a "
        "WhiskerWrenchArray of one row on --topic; the /tf transform PARENT -> CHILD of "
        "--tf-frame becomes RobotPose on --pose-topic. Play the result with wrench_source mode "
        "replay. A damaged or cut-off MCAP bag is imported as far as it reads. Exit status: "
        "0 done, 2 not a readable bag or a bad argument (nothing written), 4 written, but the "
        "bag is damaged or messages it lists are lost (counted per topic).")
    p.add_argument("ros2_bag", metavar="ROS2_BAG", help="a rosbag2 folder")
    p.add_argument("output", metavar="OUT.mcap")
    p.add_argument("--wrench-topic", action="append", default=[], metavar="T",
                   help="a WrenchStamped topic, one whisker each (repeat for more; default: "
                   "every WrenchStamped topic of the bag)")
    p.add_argument("--whisker", action="append", default=[], metavar="NAME",
                   help="whisker name of each --wrench-topic, in order, or T=NAME (default: "
                   "the topic's last name, /robot/wrench/w00 -> w00)")
    p.add_argument("--tf-frame", nargs=2, default=(WORLD_FRAME, ROBOT_FRAME),
                   metavar=("PARENT", "CHILD"),
                   help=f"the robot pose on /tf (default {WORLD_FRAME} {ROBOT_FRAME}: the "
                   "reconstructor's map_frame and robot_frame)")
    p.add_argument("--topic", default="/robot/wrench", help="vibrissa wrench topic")
    p.add_argument("--pose-topic", default="/robot/pose", help="vibrissa pose topic")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing OUT.mcap (never a file of the input bag)")
    p.set_defaults(func=_import)


def _record(args: argparse.Namespace) -> int:
    params = recorder.RecorderParams(
        output=args.output,
        topics=tuple(args.topics),
        stop_on_eos=args.until_eos,
        eos_grace_s=args.eos_grace,
        duration_s=args.duration,
        overwrite=args.overwrite,
    )
    what = ", ".join(params.topics) if params.topics else "all topics"
    print(f"recording {what} to {params.output}", file=sys.stderr, flush=True)
    endpoints = endpoints_from(args)
    with Node(args.name, endpoints=endpoints) as node:  # SIGINT/SIGTERM stop it
        result = recorder.run(node, params)
    print(f"{result.count} messages written to {params.output} ({result.reason}; "
          f"lost {result.lost}, rejected {result.rejected})", file=sys.stderr)
    if not result.count:
        print(f"vibrissa bag record: {nothing_heard(args, endpoints)}", file=sys.stderr)
    return 0


def _play(args: argparse.Namespace) -> int:
    wrong = take_spilled(args, "bag")
    if wrong:
        print(f"vibrissa bag play: error: {wrong}", file=sys.stderr)
        return 2
    rate = None if args.fast else args.rate
    if rate is not None and not (rate > 0 and math.isfinite(rate)):
        print(f"vibrissa bag play: --rate must be > 0, got {rate}", file=sys.stderr)
        return 2
    endpoints = endpoints_from(args)
    if args.topics:
        _say_missing_topics("play", args.bag, args.topics)
    with stop_on_signals() as stop:
        if args.wait_for:
            result = _play_gated(args, rate, endpoints, stop)
        else:
            context: zmq.Context[Any] = zmq.Context()
            try:
                result = play_bag(args.bag, rate=rate, topics=args.topics, wait_s=args.wait,
                                  endpoints=endpoints, context=context, stop=stop)
            finally:
                context.term()  # returns once queued messages left (linger drain_s)
    stopped = stop.is_set()  # Ctrl-C or SIGTERM; else an interrupted play timed out its gate
    state = ("interrupted" if stopped else f"--wait-for not ready after {args.wait_timeout:g} s"
             if result.interrupted else "done")
    print(f"published {result.total} messages in {result.wall_s:.3f} s ({state})",
          file=sys.stderr)
    nobody = no_graph(args, endpoints) if result.total else None
    if nobody is not None:
        print(f"vibrissa bag play: nobody received them: {nobody}", file=sys.stderr)
    return 130 if stopped else 1 if result.interrupted else 0


def _say_missing_topics(command: str, bag: str, topics: list[str]) -> None:
    """A warning on stderr naming the ``topics`` asked for that ``bag`` does not hold, and
    the topics it does."""
    present = BagReader(bag).topic_names()
    missing = [topic for topic in topics if topic not in present]
    if missing:
        print(f"vibrissa bag {command}: warning: {', '.join(missing)}: no such topic in {bag} "
              f"(its topics: {', '.join(present) or 'none'})", file=sys.stderr)


def _play_gated(args: argparse.Namespace, rate: float | None, endpoints: Endpoints,
                stop: threading.Event) -> PlayResult:
    """Play as node ``bag_player``: each publisher is held until ``--wait-for`` nodes are up."""
    with Node("bag_player", endpoints=endpoints, handle_signals=False) as node:
        node.set_state("running")
        result, _ = play_bag_gated(node, args.bag, args.wait_for, args.wait_timeout, rate=rate,
                                   topics=args.topics, stop=stop)
        return result


def _info(args: argparse.Namespace) -> int:
    print(BagReader(args.bag).info().format())
    return 0


def _export(args: argparse.Namespace) -> int:
    wrong = take_spilled(args, "bag", "outdir")
    if wrong:
        print(f"vibrissa bag export: error: {wrong}", file=sys.stderr)
        return 2
    output = args.output or args.outdir
    if output is None or (args.output and args.outdir):
        hint = AFTER_NAMES if output is None and args.topics else ""
        print(f"vibrissa bag export: error: name the output once (OUT or -o OUT){hint}",
              file=sys.stderr)
        return 2
    out = Path(output)
    check_bag_file(args.bag)  # no bag: refused before anything is made
    if args.format != "ros2" and out.exists():  # a ROS 2 bag refuses any existing OUT itself
        if Path(args.bag).exists() and out.samefile(args.bag):
            print(f"vibrissa bag export: error: {output} would overwrite the input bag",
                  file=sys.stderr)
            return 2
        if not args.overwrite:
            print(f"vibrissa bag export: error: {output} exists (--overwrite replaces it)",
                  file=sys.stderr)
            return 2
    if args.topics:
        _say_missing_topics("export", args.bag, args.topics)
    out.parent.mkdir(parents=True, exist_ok=True)  # as every output file's folder
    if args.format == "json":
        info, _ = export_json(args.bag, output, topics=args.topics)  # damage: logged
        print(f"wrote {info.message_count} JSON messages to {output}", file=sys.stderr)
        return 0
    if args.format == "foxglove":
        from vibrissa.nodes import foxglove_bridge  # the optional extra, on first use

        try:
            params = foxglove_bridge.FoxgloveBridgeParams(robot=args.robot or "")
            counts = foxglove_bridge.export_bag(args.bag, output, params, topics=args.topics)
        except (SceneError, ValueError, FileNotFoundError) as exc:
            print(f"vibrissa bag export: error: {exc}", file=sys.stderr)
            return 2
        print(f"wrote the live view of {args.bag} to {output}: " + (", ".join(
            f"{k} {v}" for k, v in counts.items() if v) or "no messages"), file=sys.stderr)
        return 0
    try:
        whiskers = load_robot(args.robot) if args.robot else ()
        result = export_ros2(args.bag, output, whiskers=whiskers, robot_frame=args.robot_frame,
                             topics=args.topics)
    except (SceneError, ValueError, FileNotFoundError) as exc:
        print(f"vibrissa bag export: error: {exc}", file=sys.stderr)
        return 2
    print(result.summary(), file=sys.stderr)
    return 0


def _import(args: argparse.Namespace) -> int:
    out, bag = Path(args.output), Path(args.ros2_bag)
    inside = bag.is_dir() and out.resolve().parent == bag.resolve()
    if inside or (out.exists() and bag.is_dir()
                  and any(out.samefile(f) for f in bag.iterdir() if f.is_file())):
        print(f"vibrissa bag import: error: {args.output} would write into the input bag "
              f"{args.ros2_bag}", file=sys.stderr)
        return 2
    if out.is_dir() or (out.exists() and not args.overwrite):
        print(f"vibrissa bag import: error: {args.output} exists"
              + (" and is a folder" if out.is_dir() else " (--overwrite replaces it)"),
              file=sys.stderr)
        return 2
    topics: list[str] = args.wrench_topic
    if not topics:
        try:
            topics = wrench_topics_of(args.ros2_bag)
        except (ValueError, FileNotFoundError) as exc:
            print(f"vibrissa bag import: error: {exc}", file=sys.stderr)
            return 2
        if not topics:
            print(f"vibrissa bag import: error: {args.ros2_bag} has no "
                  "geometry_msgs/msg/WrenchStamped topic", file=sys.stderr)
            return 2
    mapping = {t: t.rstrip("/").rsplit("/", 1)[-1] for t in topics}
    positional = [w for w in args.whisker if "=" not in w]
    if positional and len(positional) != len(topics):
        print(f"vibrissa bag import: error: {len(positional)} --whisker name(s) for "
              f"{len(topics)} --wrench-topic(s)", file=sys.stderr)
        return 2
    mapping.update(zip(topics, positional, strict=False))
    for item in args.whisker:
        if "=" in item:
            topic, name = item.split("=", 1)
            if topic not in mapping:
                print(f"vibrissa bag import: error: --whisker {item}: {topic} is no "
                      "--wrench-topic", file=sys.stderr)
                return 2
            mapping[topic] = name
    try:
        result = import_ros2(args.ros2_bag, args.output, mapping, topic=args.topic,
                             pose_topic=args.pose_topic, map_frame=args.tf_frame[0],
                             robot_frame=args.tf_frame[1])
    except (ValueError, FileNotFoundError) as exc:
        print(f"vibrissa bag import: error: {exc}", file=sys.stderr)
        return 2
    print(result.summary(), file=sys.stderr)
    return EXIT_LOST_DATA if result.lost or result.damage else 0
