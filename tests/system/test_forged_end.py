"""In a keyless graph anyone on the machine may publish; an EndOfStream is honoured only from a
publisher the subscriber has heard on that topic, so a forged one cannot end the demo's map
early (real processes: the demo and a forger on its domain)."""

from __future__ import annotations

import json
import queue
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

from vibrissa.msgs import ContactPointArray
from vibrissa.wire.transport import Endpoints, Publisher

DEADLINE_S = 300.0  # generous: the demo takes 10-20 s idle, minutes at load 20


def test_a_forged_end_of_stream_does_not_end_the_map(tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "vibrissa.cli.launch", "demo", "rate:=2000",
                             f"out:={out}"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    lines: queue.Queue[str] = queue.Queue()
    assert proc.stderr is not None
    stderr = proc.stderr
    threading.Thread(target=lambda: [lines.put(line) for line in stderr], daemon=True).start()
    seen: list[str] = []
    deadline = time.monotonic() + DEADLINE_S
    try:
        domain = None
        while domain is None:
            seen.append(lines.get(timeout=max(0.1, deadline - time.monotonic())))
            found = re.search(r"\(domain (\d+)", seen[-1])
            domain = int(found.group(1)) if found else None
        with Publisher("/whisker0/contact", ContactPointArray, Endpoints.for_domain(domain)) as forger:
            while proc.poll() is None:  # ends forged again and again, until the demo ends
                assert time.monotonic() < deadline, "".join(seen)
                forger.publish_end_of_stream("/whisker0/reconstructor")
                time.sleep(0.2)
        rc = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    while not lines.empty():
        seen.append(lines.get())
    err = "".join(seen)
    assert rc == 0, err
    assert "never heard on this topic: ignored" in err
    report = json.loads((out / "report.json").read_text())
    streams = report["streams"]
    assert [s["lost"] for s in streams] == [0], streams  # the one real stream, complete
    assert report["frames"][0]["n_points"] > 3000, report["frames"][0]["n_points"]
