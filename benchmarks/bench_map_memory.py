"""Live map memory benchmark: the mapper's resident memory over an endless robot run.

Runs ``vibrissa launch launch/robot.yaml out:=OUT loop:=true rate:=500`` (the robot drives its
path forth and back at 500 path samples/s until stopped; its own ZeroMQ domain, ``--domain``)
for ``--minutes`` (10) counted from the mapper's process start (found within 0.2 s), sampling every ``--every`` s
(10) the resident set (``VmRSS`` of /proc/PID/status) of the mapper (the launcher's descendant
whose command line holds ``vibrissa.nodes.mapper``) and of the bag recorder
(``vibrissa.nodes.recorder``; it records /robot/wrench and /robot/pose into robot.mcap for the
whole run), and the bag's size. Then it sends the launch SIGINT (Ctrl-C), times its end and
reads the final report.json.

Printed: the samples (once a minute), the mapper's RSS at its first minute and at the end, its
growth after the first minute (end - 1 min, and the peak after 1 min - 1 min: the target's
figure, < 50 MB), the recorder's, the bag's growth per minute (a least-squares slope after the
first minute), the stop's time, and the report's ``final``, ``ended_by``, ``n_points``,
``merged_points``, ``lost``, ``upstream_lost`` and ``dropped_points`` (nothing lost: lost 0,
dropped_points {}; ``upstream_lost``, messages the nodes before the map did not receive, is
checked apart). The baseline is the run's own first minute: the mapper's memory then holds the
imports and a cycle of the path's points (later cycles repeat it and are merged), and, unless
the machine is slow, the first map of that cycle (at load 12 its fit once ended after the first
minute: the growth then counts it). The machine's load average is printed with the figures. Not a test.

Usage: ``python benchmarks/bench_map_memory.py [--minutes 10] [--every 10] [--rate 500]
[--out DIR] [--domain N]``
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO

import numpy as np

ROBOT = Path(__file__).resolve().parents[1] / "launch" / "robot.yaml"
MAPPER = "vibrissa.nodes.mapper"
RECORDER = "vibrissa.nodes.recorder"
MB = 1024 * 1024


def launch(domain: int, stdout: int | IO[bytes], *words: str, grace_s: float | None = None
           ) -> subprocess.Popen[bytes]:
    """``vibrissa launch [--grace GRACE_S] launch/robot.yaml WORDS`` in domain ``domain`` (no
    VIBRISSA_ variable of this shell passed on), its output and errors to ``stdout``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("VIBRISSA_")}
    grace = [] if grace_s is None else ["--grace", f"{grace_s:g}"]
    return subprocess.Popen([sys.executable, "-m", "vibrissa.cli.main", "launch", *grace,
                             "--domain", str(domain), str(ROBOT), *words],
                            stdout=stdout, stderr=subprocess.STDOUT, env=env)


def descendant(root: int, module: str) -> int | None:
    """The pid of the first descendant of ``root`` whose command line holds ``module``."""
    parents: dict[int, int] = {}
    commands: dict[int, str] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            commands[int(entry.name)] = (entry / "cmdline").read_bytes().replace(
                b"\0", b" ").decode(errors="replace")
        except OSError:  # ended meanwhile
            continue
        parents[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
    for pid, command in sorted(commands.items()):
        ancestor = parents.get(pid)
        while ancestor is not None and ancestor != root:
            ancestor = parents.get(ancestor)
        if ancestor == root and module in command.split():
            return pid
    return None


def rss_bytes(pid: int) -> float:
    """VmRSS of ``pid``, bytes (NaN once it ended)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return float(line.split()[1]) * 1024
    except OSError:
        pass
    return float("nan")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="run length from the "
                        "mapper's start, min")
    parser.add_argument("--every", type=float, default=10.0, help="sampling period, s")
    parser.add_argument("--rate", type=float, default=500.0, help="path samples per second")
    parser.add_argument("--out", type=Path, default=None,
                        help="the mapper's output folder (default: a temporary one)")
    parser.add_argument("--domain", type=int, default=9800 + os.getpid() % 100 * 2,
                        help="the launch's ZeroMQ domain (default: one of 9800-9998, away from "
                        "the tests')")
    parser.add_argument("--grace", type=float, default=None,
                        help="the launcher's --grace, s (default: its own, 5): how long each "
                        "node has after the SIGINT, and after the SIGTERM that follows, "
                        "before its SIGKILL")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp) / "robot"
        out.mkdir(parents=True, exist_ok=True)
        with (out / "launch.log").open("wb") as log:
            proc = launch(args.domain, log, f"out:={out}", "loop:=true", f"rate:={args.rate:g}",
                          grace_s=args.grace)
        try:
            return measure(proc, out, args.minutes * 60, args.every)
        finally:
            if proc.poll() is None:
                proc.kill()


def measure(proc: subprocess.Popen[bytes], out: Path, run_s: float, every_s: float) -> int:
    """Sample the mapper and the recorder of the launch ``proc`` for ``run_s`` from the mapper's
    start, stop the launch, print the figures; 0 when every check of the run holds."""
    deadline = time.monotonic() + 120
    mapper = recorder = None
    while (mapper is None or recorder is None) and time.monotonic() < deadline:
        mapper, recorder = descendant(proc.pid, MAPPER), descendant(proc.pid, RECORDER)
        if proc.poll() is not None:
            break
        time.sleep(0.2)
    if mapper is None or recorder is None:
        print(f"no mapper or recorder started (launch exit {proc.poll()}):\n"
              + (out / "launch.log").read_text())
        return 1
    t0 = time.monotonic()  # the mapper started within the last poll
    bag = out / "robot.mcap"
    samples: list[tuple[float, float, float, float]] = []  # t s, mapper, recorder, bag bytes
    print(f"launch pid {proc.pid}, mapper {mapper}, recorder {recorder}; {run_s / 60:g} min "
          f"sampled every {every_s:g} s", flush=True)
    print(f"{'t s':>6} {'mapper MB':>10} {'recorder MB':>12} {'bag MB':>8} {'points':>8} "
          f"{'merged':>8} {'load':>5}", flush=True)
    k = 0
    while True:
        due = t0 + k * every_s
        if due > t0 + run_s + 1e-9:
            break
        time.sleep(max(0.0, due - time.monotonic()))
        if proc.poll() is not None:
            print("the launch ended by itself:\n" + (out / "launch.log").read_text())
            return 1
        t = time.monotonic() - t0
        samples.append((t, rss_bytes(mapper), rss_bytes(recorder),
                        float(bag.stat().st_size) if bag.exists() else 0.0))
        if k % max(1, round(60 / every_s)) == 0:
            report = _report(out)
            print(f"{t:6.0f} {samples[-1][1] / MB:10.1f} {samples[-1][2] / MB:12.1f} "
                  f"{samples[-1][3] / MB:8.1f} {report.get('n_points', '-'):>8} "
                  f"{report.get('merged_points', '-'):>8} {os.getloadavg()[0]:5.1f}", flush=True)
        k += 1
    load = os.getloadavg()
    proc.send_signal(signal.SIGINT)
    stop = time.monotonic()
    try:
        rc = proc.wait(300)
    except subprocess.TimeoutExpired:
        rc = None
    stop_s = time.monotonic() - stop
    t, m_rss, r_rss, size = (np.array(column) for column in zip(*samples, strict=True))
    after = t >= 60 - 1e-6
    first = int(np.argmax(after))
    report = _report(out)
    growth_end, growth_peak = m_rss[-1] - m_rss[first], np.nanmax(m_rss[after]) - m_rss[first]
    bag_slope = float(np.polyfit(t[after] / 60, size[after], 1)[0]) if after.sum() > 1 else np.nan
    print(f"load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} (1/5/15 min) at the end "
          f"of the run, {os.cpu_count()} cores")
    print(f"{'':9} {'at 1 min MB':>12} {'end MB':>8} {'growth MB':>10} {'peak growth MB':>15}")
    for name, rss in (("mapper", m_rss), ("recorder", r_rss)):
        print(f"{name:9} {rss[first] / MB:12.1f} {rss[-1] / MB:8.1f} "
              f"{(rss[-1] - rss[first]) / MB:10.1f} "
              f"{(np.nanmax(rss[after]) - rss[first]) / MB:15.1f}")
    print(f"bag robot.mcap: {size[-1] / MB:.1f} MB at {t[-1]:.0f} s, "
          f"{bag_slope / MB:.2f} MB/min after the first minute")
    print(f"SIGINT -> launch ended in {stop_s:.1f} s (exit {rc})")
    keys = ("final", "ended_by", "n_points", "merged_points", "lost", "upstream_lost",
            "dropped_points", "updates")
    print("report.json: " + ", ".join(f"{key} {report.get(key)!r}" for key in keys))
    checks = {
        "mapper growth after 1 min < 50 MB": growth_peak < 50 * MB and growth_end < 50 * MB,
        "final report, ended by stop": (report.get("final"), report.get("ended_by"))
        == (True, "stop"),
        "nothing lost": report.get("lost") == 0 and report.get("dropped_points") == {},
        "nothing short upstream": report.get("upstream_lost") == 0,
        "the launch ended": rc is not None,
    }
    for name, ok in checks.items():
        print(f"{'met' if ok else 'NOT MET'}: {name}")
    return 0 if all(checks.values()) else 1


def _report(out: Path) -> dict[str, object]:
    """report.json of ``out`` as it is now ({} before the first; each write is whole)."""
    try:
        report: dict[str, object] = json.loads((out / "report.json").read_text())
    except (OSError, ValueError):
        return {}
    return report


if __name__ == "__main__":
    sys.exit(main())
