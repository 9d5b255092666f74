"""A graph launched with keys, attacked by processes without them: real processes, loopback.

While the graph runs, an intruder process floods the reconstructor's input with wrenches and
the mapper's input with a forged end of stream, and the tools read without keys: nothing gets
in, nothing is read, the refusals are counted, and the map is the one of an undisturbed run.
An allowed client (``vibrissa keys --client``) reads the same graph.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from tests.system.test_first_hour import Launch, demo_with
from vibrissa.wire.security import create_keys

DOMAIN = 28100 + os.getpid() % 900

INTRUDER = r"""
import sys, time
from vibrissa.msgs import ContactPoint, EndOfStream, WhiskerWrench
from vibrissa.wire import Endpoints, Publisher
endpoints = Endpoints.for_domain(int(sys.argv[1]))  # no keys
wrench = Publisher("/whisker0/wrench", WhiskerWrench, endpoints)
contact = Publisher("/whisker0/contact", ContactPoint, endpoints)
deadline = time.monotonic() + float(sys.argv[2])
while time.monotonic() < deadline:
    wrench.publish(WhiskerWrench(stamp=0.0, seq=0, whisker_id="whisker0", frame_id="world",
                                 clamp_position=[0.0, 0.0, 0.0],
                                 clamp_orientation=[0.0, 0.0, 0.0, 1.0],
                                 f0=[0.0, 1.0, 0.0], m0=[0.0, 0.0, 0.5]))
    contact.publish(EndOfStream(stamp=0.0, source="/whisker0/reconstructor", count=0))
    time.sleep(0.002)
"""


def tool(domain: int, *words: str) -> subprocess.Popen[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("VIBRISSA_")}
    return subprocess.Popen([sys.executable, "-m", "vibrissa.cli.main", *words,
                             "--domain", str(domain)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)


def test_without_the_key_nothing_gets_in_and_nothing_is_read(tmp_path: Path) -> None:
    keys = tmp_path / "keys"
    create_keys(keys, ("laptop",))
    launch = Launch(demo_with(tmp_path, y0=[0.0], rate_hz=250), f"out:={tmp_path / 'map'}",
                    "--keys", str(keys), domain=DOMAIN)
    try:
        launch.wait_line(r"wrench_source\] .*sweeps ended")  # the graph is streaming
        intruder = subprocess.Popen([sys.executable, "-c", INTRUDER, str(DOMAIN), "2.0"],
                                    env={k: v for k, v in os.environ.items()
                                         if not k.startswith("VIBRISSA_")})
        spy = tool(DOMAIN, "topic", "echo", "/whisker0/wrench", "--timeout", "1.5")
        client = tool(DOMAIN, "topic", "echo", "/whisker0/wrench", "-n", "3", "--timeout", "5",
                      "--keys", str(keys / "clients" / "laptop"))
        spy_out, spy_err = spy.communicate(timeout=30)
        client_out, client_err = client.communicate(timeout=30)
        assert intruder.wait(30) == 0
        rc = launch.wait()
    finally:
        if launch.proc.poll() is None:
            launch.proc.kill()
    text = launch.text()

    assert spy.returncode == 1 and spy_out == ""
    assert "launched with keys" in spy_err and "--keys" in spy_err
    assert client.returncode == 0, client_err
    assert client_out.count('whisker_id: "whisker0"') == 3

    assert rc == 0, text
    published = int(re.search(r"wrench_source .* published (\d+)", text).group(1))  # type: ignore[union-attr]
    received = int(re.search(r"reconstructor .* received (\d+)", text).group(1))  # type: ignore[union-attr]
    assert received == published + 1  # its samples and their end of stream, nothing injected
    refused = re.search(r"refused (\d+) connection\(s\) without an allowed key", text)
    assert refused is not None and int(refused.group(1)) >= 3, text  # 2 publishers, 1 reader
    assert "data did not arrive in full" not in text
    report = (tmp_path / "map" / "report.txt").read_text()
    assert f"contact points: {published} (sources: /whisker0/reconstructor)" in report, report
    assert (f"input /whisker0/contact from /whisker0/reconstructor: {published} sent, "
            f"{published} received, 0 lost") in report, report  # the forged end was not heard
