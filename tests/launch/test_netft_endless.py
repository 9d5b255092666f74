"""launch/netft.yaml with ``samples:=0`` is an endless stream: the driver goes on past the
path's 1700 records (the simulated sensor then holds its last, a rod at rest) until Ctrl-C,
then every node stops cleanly."""

from __future__ import annotations

import os
import re
import signal
from pathlib import Path

from tests.launch.test_netft_launch import LAUNCH, free_udp_port
from tests.system.test_first_hour import Launch

DOMAIN = 8280 + os.getpid() % 12 * 128
PATH_RECORDS = 1700


def test_samples_0_streams_past_the_path_until_ctrl_c(tmp_path: Path) -> None:
    launch = Launch(LAUNCH, f"out:={tmp_path / 'out'}", f"port:={free_udp_port()}",
                    "samples:=0", domain=DOMAIN)
    _, rc = launch.stream_then_stop(  # twice the path: past its end
        "/w0/wrench", DOMAIN, lambda got: sum(len(m.whisker_ids) for m in got) >= 2 * PATH_RECORDS)
    text = launch.text()
    assert rc == 128 + signal.SIGINT, text
    assert re.search(r"netft\s+stopped by launcher \(exit 0\)", text), text
    assert "Traceback" not in text
