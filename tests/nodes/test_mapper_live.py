"""A real mapper process on loopback maps while its stream goes on: a periodic report.json
(final false) and a SurfaceMesh at most every map_period_s; SIGINT writes the final map of
everything received (ended_by stop, exit 0); silence past timeout_s ends it with "timeout", the
ends of the streams with "streams"."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from vibrissa import launch
from vibrissa.mapping import Accumulator, FrameResult, LiveMap, MapReport
from vibrissa.msgs import (
    ContactPhase,
    ContactPointArray,
    ContactStatus,
    NodeStatus,
    SurfaceMesh,
)
from vibrissa.nodes.mapper import (
    AccumulatorCounts,
    MapperParams,
    fit_frames,
    receive,
    remove_stale_files,
    write_outputs,
)
from vibrissa.wire import STATUS_TOPIC, Endpoints, Publisher, Subscriber

TOPIC = "/w/contact"
MAP_PERIOD_S = 1.0


def contact(i: int) -> ContactPointArray:
    """The i-th contact: rows of 20 points on the plane z = 0.5 m, a whisker per row."""
    row = (i // 20) % 20
    return ContactPointArray(stamp=float(i), seq=i, whisker_ids=[f"w{row}"], frame_id="world",
                             point=[[0.002 * (i % 20), 0.002 * row, 0.5 + 1e-7 * i]], s1=[0.5],
                             phase=[ContactPhase.TIP], force=[[0.0, 0.0, 1.0]],
                             status=[ContactStatus.OK])


def contacts(first: int, end: int) -> ContactPointArray:
    """Contacts first..end-1 (`contact`) in one message, stamped with the last one's."""
    rows = [contact(i) for i in range(first, end)]
    return ContactPointArray(
        stamp=rows[-1].stamp, seq=first, whisker_ids=[r.whisker_ids[0] for r in rows],
        frame_id="world", point=[r.point[0] for r in rows], s1=[0.5] * len(rows),
        phase=[ContactPhase.TIP] * len(rows), force=[[0.0, 0.0, 1.0]] * len(rows),
        status=[ContactStatus.OK] * len(rows))


def start_mapper(tmp_path: Path, endpoints: Endpoints, *params: str) -> subprocess.Popen[str]:
    words = [w for p in [f"topics:=[{TOPIC}]", f"out_dir:={tmp_path}", "plot:=false",
                         "cells:=16", f"map_period_s:={MAP_PERIOD_S}", "write_period_s:=2",
                         *params]
             for w in ("--param", p)]
    return subprocess.Popen(
        [sys.executable, "-m", "vibrissa.nodes.mapper", "--name", "mapper", *words],
        env={**os.environ, **endpoints.to_env()}, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True)


def wait_heard(pub: Publisher, statuses: Subscriber) -> None:
    """Ping until the mapper hears the topic."""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        pub.ping("/test")
        rx = statuses.receive(0.1)
        if rx is not None and rx.msg.node == "/mapper" and TOPIC in rx.msg.seen_topics:
            return
    pytest.fail("the mapper never heard the topic")


def read_report(path: Path) -> dict[str, Any] | None:
    """report.json, or None while it is not there (each write is whole: never half a file)."""
    try:
        report: dict[str, Any] = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    return report


def finish(mapper: subprocess.Popen[str]) -> tuple[int, str]:
    try:
        out, _ = mapper.communicate(timeout=120)
    finally:
        if mapper.poll() is None:
            mapper.kill()
            mapper.communicate()
    return mapper.returncode, out


def test_the_map_is_written_while_the_stream_goes_on_and_sigint_writes_the_final_map(
    tmp_path: Path, endpoints: Endpoints
) -> None:
    mapper = start_mapper(tmp_path, endpoints)
    periodic: list[dict[str, Any]] = []
    mesh_times: list[float] = []
    mesh_stamps: list[float] = []
    try:
        with Publisher(TOPIC, ContactPointArray, endpoints) as pub, \
                Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as statuses, \
                Subscriber({"/surface_mesh": SurfaceMesh}, endpoints) as meshes:
            wait_heard(pub, statuses)
            i = 0
            deadline = time.monotonic() + 120
            # an endless stream at about 200 points a second, until two periodic reports
            # came (the files are rewritten) and a few meshes were published
            while time.monotonic() < deadline and (len(periodic) < 2 or len(mesh_times) < 4):
                for _ in range(10):
                    pub.publish(contact(i))
                    i += 1
                rx = meshes.receive(0.05)
                while rx is not None:
                    mesh_times.append(time.monotonic())
                    mesh_stamps.append(rx.msg.stamp)
                    rx = meshes.receive(0.0)
                report = read_report(tmp_path / "report.json")
                if report is not None and (not periodic or report != periodic[-1]):
                    periodic.append(report)
                assert mapper.poll() is None
            assert len(periodic) >= 2 and len(mesh_times) >= 4, (periodic, mesh_times)
            last = read_report(tmp_path / "report.json")
            assert last is not None
            mapper.send_signal(signal.SIGINT)
            for _ in range(50):  # more points after the signal: not taken in any more
                pub.publish(contact(i))
                i += 1
            rc, out = finish(mapper)
    finally:
        if mapper.poll() is None:
            mapper.kill()
    assert rc == 0, out
    for report in periodic:
        assert (report["final"], report["ended_by"]) == (False, None), report
        assert report["updates"] >= 1 and report["n_points"] > 0
    assert periodic[1]["updates"] > periodic[0]["updates"]
    final = read_report(tmp_path / "report.json")
    assert final is not None
    assert (final["final"], final["ended_by"]) == (True, "stop")
    assert last["n_points"] <= final["n_points"] <= i
    assert final["updates"] >= last["updates"]
    assert "final map (ended by stop)" in (tmp_path / "report.txt").read_text()
    assert final["n_points"] > 0 and (tmp_path / "cloud.ply").is_file()
    # the updates go out at most every map_period_s (the times they arrived here jitter)
    span = mesh_times[-1] - mesh_times[0]
    assert (len(mesh_times) - 1) * MAP_PERIOD_S <= span + 0.5, mesh_times
    # each stamped with the newest of its points (contact i: stamp i), so never going back
    assert all(0 <= b - a for a, b in zip(mesh_stamps, mesh_stamps[1:], strict=False))
    assert all(stamp == int(stamp) < i for stamp in mesh_stamps)
    assert "Traceback" not in out
    # the final map holds the first n points (ZeroMQ keeps their order, none repeats another)
    assert final["merged_points"] == 0 and sum(final["update_fits"].values()) >= final["updates"]
    single = single_fit(tmp_path / "single", final["n_points"])
    assert (tmp_path / "cloud.ply").read_bytes() == (tmp_path / "single" / "cloud.ply").read_bytes()
    assert final["frames"][0]["n_points"] == single["frames"][0]["n_points"]


def single_fit(out: Path, n: int) -> dict[str, Any]:
    """The report of a single fit (`write_outputs`) on the first n contacts."""
    acc = Accumulator(1)
    for k in range(n):
        receive(acc, contact(k))
    report, _ = write_outputs(acc, MapperParams(out_dir=str(out), plot=False, cells=16), out)
    return report.as_dict()


@pytest.mark.parametrize(("params", "ended_by"), [(("timeout_s:=3",), "timeout"), ((), "streams")])
def test_silence_or_the_end_of_the_streams_writes_the_final_map_ended_by_it(
    tmp_path: Path, endpoints: Endpoints, params: tuple[str, ...], ended_by: str
) -> None:
    mapper = start_mapper(tmp_path, endpoints, *params)
    try:
        with Publisher(TOPIC, ContactPointArray, endpoints) as pub, \
                Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as statuses:
            wait_heard(pub, statuses)
            for i in range(40):
                pub.publish(contact(i))
            if ended_by == "streams":  # else no end of stream: the silence ends it
                pub.publish_end_of_stream("/test")
            rc, out = finish(mapper)
    finally:
        if mapper.poll() is None:
            mapper.kill()
    assert rc == 0, out
    final = read_report(tmp_path / "report.json")
    assert final is not None
    assert (final["final"], final["ended_by"], final["n_points"]) == (True, ended_by, 40)
    assert final["updates"] >= 1
    # after the streams or a silence, the single fit's map on the same points, bit for bit
    single = single_fit(tmp_path / "single", 40)
    got, want = final["frames"][0], single["frames"][0]
    assert {k for k in want if k not in ("files", "objects") and got[k] != want[k]} == set()
    assert ([dict(o, files=None) for o in got["objects"]]
            == [dict(o, files=None) for o in want["objects"]])  # each its mesh file of its own


def test_points_no_update_held_go_out_in_an_update_at_the_end_before_the_final_map(
    tmp_path: Path, endpoints: Endpoints
) -> None:
    """An update after the first 60 points, then none for a long map_period_s: at the end of the
    stream the 6 more are published in one more update (conditioned on them), then the final
    map (a full fit)."""
    mapper = start_mapper(tmp_path, endpoints, "map_period_s:=3600")
    stamps: list[float] = []
    try:
        with Publisher(TOPIC, ContactPointArray, endpoints) as pub, \
                Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as statuses, \
                Subscriber({"/surface_mesh": SurfaceMesh}, endpoints) as meshes:
            wait_heard(pub, statuses)
            pub.publish(contacts(0, 60))  # one message: the first update holds them all
            deadline = time.monotonic() + 120
            while not stamps and time.monotonic() < deadline:  # the first update's mesh
                rx = meshes.receive(0.1)
                if rx is not None:
                    stamps.append(rx.msg.stamp)
            if not stamps:
                mapper.kill()
                pytest.fail(f"no first update: {mapper.communicate()[0]}")
            pub.publish(contacts(60, 66))
            pub.publish_end_of_stream("/test")
            rc, out = finish(mapper)
            rx = meshes.receive(5.0)
            while rx is not None:
                if isinstance(rx.msg, SurfaceMesh):  # not its EndOfStream
                    stamps.append(rx.msg.stamp)
                rx = meshes.receive(0.5)
    finally:
        if mapper.poll() is None:
            mapper.kill()
    assert rc == 0, out
    final = read_report(tmp_path / "report.json")
    assert final is not None and final["n_points"] == 66
    assert final["updates"] == 3, final["update_fits"]  # the first, the end's, the final map
    assert final["update_fits"]["conditioned"] == 1, final["update_fits"]
    assert stamps == [59.0, 65.0, 65.0], stamps


def test_a_signal_again_ends_at_once_and_the_launchers_sigterm_after_a_sigint_does_not() -> None:
    """The mapper's handlers (`SignalHandlers` with ``once``): SIGINT asks to stop, the
    launcher's SIGTERM after its grace asks again, a second SIGINT ends the process at once."""
    code = ("import os, signal, sys\n"
            "from vibrissa.runtime.signals import SignalHandlers\n"
            "seen = []\n"
            "with SignalHandlers(seen.append, once=True):\n"
            "    for signum in (signal.SIGINT, signal.SIGTERM):\n"
            "        os.kill(os.getpid(), signum)\n"
            "    print(seen, flush=True)\n"
            "    os.kill(os.getpid(), signal.SIGINT)\n"
            "    print('survived', flush=True)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == -signal.SIGINT, done
    assert done.stdout == f"[{signal.SIGINT.value}, {signal.SIGTERM.value}]\n", done


@pytest.mark.parametrize("truth", [{"true_surface": "paraboloid:a=0.5,b=1,h=0.4"},
                                   {"scene": "robot/scene.yaml"}])
def test_with_a_truth_to_measure_against_an_update_without_new_points_keeps_the_map(
        truth: dict[str, str]) -> None:
    """The truth (true_surface or a scene's objects) is the same at every update: an update
    with no new point (as a stop's final map is, when the last update held every point)
    returns the last map and refits nothing."""
    if "scene" in truth:
        truth = {"scene": str(Path(launch.__file__).parent / truth["scene"])}
    params = MapperParams(out_dir="/tmp/unused", plot=False, cells=16, **truth)
    acc = Accumulator(1)
    for i in range(60):
        receive(acc, contact(i))
    live = LiveMap()
    first = fit_frames(acc, params, live, final=False)
    again = fit_frames(acc, params, live, final=False)
    assert [a is b for a, b in zip(first, again, strict=True)] == [True]
    assert live.fits["unchanged"] == 1 and live.fits["clustered"] == 1


def test_a_map_without_an_object_of_the_one_before_removes_that_objects_file(
        tmp_path: Path) -> None:
    def report(*objects: str) -> MapReport:
        files = {f"mesh_{name}": str(tmp_path / f"mesh_{name}.ply") for name in objects}
        frame = FrameResult("world", 10, "gp", 3, 1, None,
                            files={"cloud": str(tmp_path / "cloud.ply"), **files})
        return MapReport(10, (), (frame,), files={"report_json": str(tmp_path / "report.json")})

    kept = tmp_path / "notes.txt"  # not the mapper's
    for path in ("cloud.ply", "mesh_a.ply", "mesh_a-2.ply", "report.json", "notes.txt"):
        (tmp_path / path).write_text("x")
    on_disk = remove_stale_files(set(), report("a", "a-2"))
    assert len(on_disk) == 4 and (tmp_path / "mesh_a-2.ply").exists()
    on_disk = remove_stale_files(on_disk, report("a"))  # a-2 merged into a
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "cloud.ply", "mesh_a.ply", "notes.txt", "report.json"]
    assert kept.exists() and len(on_disk) == 3


def test_a_final_map_whose_files_are_written_already_gets_pictures_that_say_final(
        tmp_path: Path) -> None:
    """A stop after an update that held every point writes only the reports again, and the
    pictures with the final map's line (they said "map so far")."""
    params = MapperParams(out_dir=str(tmp_path), cells=16)
    acc = Accumulator(1)
    for i in range(60):
        receive(acc, contact(i))
    frames = fit_frames(acc, params, LiveMap(), final=False)
    periodic, _ = write_outputs(acc, params, tmp_path, frames=frames, final=False,
                                ended_by=None, updates=1)
    assert "map so far" in (tmp_path / "map.html").read_text()
    cloud = (tmp_path / "cloud.ply").stat().st_mtime_ns
    write_outputs(acc, params, tmp_path, frames=frames, written=periodic.frames, final=True,
                  ended_by="stop", updates=1)
    assert "final map (ended by stop): 60 contact points" in (tmp_path / "map.html").read_text()
    assert (tmp_path / "cloud.ply").stat().st_mtime_ns == cloud  # not written again
    assert json.loads((tmp_path / "report.json").read_text())["ended_by"] == "stop"


def test_a_periodic_write_reports_the_counts_as_of_its_submission(tmp_path: Path) -> None:
    """The periodic files are written in a thread while points go on arriving: what the
    report says of the accumulator is its counts when the write was handed over."""
    params = MapperParams(out_dir=str(tmp_path), plot=False, cells=16)
    acc = Accumulator(1)
    for i in range(60):
        receive(acc, contact(i))
    frames = fit_frames(acc, params, LiveMap(), final=False)
    counts = AccumulatorCounts.of(acc)
    for i in range(60, 80):  # meanwhile
        receive(acc, contact(i))
    report, messages = write_outputs(counts, params, tmp_path, frames=frames, final=False,
                                     ended_by=None, updates=1)
    assert messages == [] and report.n_points == 60 and acc.n_points == 80
    written = json.loads((tmp_path / "report.json").read_text())
    assert written["n_points"] == 60 and written["final"] is False
    assert (tmp_path / "cloud.ply").exists()
