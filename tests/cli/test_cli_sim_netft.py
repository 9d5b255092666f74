"""``vibrissa sim netft``: a real process on loopback answers an RDT request with records of the
node's signal (its options mapped onto the node's parameters), stops on SIGTERM or Ctrl-C with
status 0, and refuses a bad value with one line and status 2. Every receive has a timeout."""

from __future__ import annotations

import re
import select
import signal
import socket
import struct
import subprocess
import sys

import numpy as np
import pytest

from vibrissa.cli.main import main
from vibrissa.nodes.netft_sim import NetFTSimParams, sensor_signal

TIMEOUT_S = 60.0  # a deadline: the simulator process starts (imports) in over 10 s at a load of 20
RECORD = struct.Struct(">III6i")  # rdt_sequence, ft_sequence, status, Fx Fy Fz Tx Ty Tz counts
BIAS = (0.01, -0.02, 0.003, 0.0004, -0.0005, 0.0006)


def start(*options: str) -> tuple[subprocess.Popen[str], int]:
    """``vibrissa sim netft --port 0 OPTIONS`` and the port it printed."""
    proc = subprocess.Popen([sys.executable, "-m", "vibrissa.cli.main", "sim", "netft", "--port", "0",
                             *options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], TIMEOUT_S)
    if not ready:
        proc.kill()
        pytest.fail(f"no address printed within {TIMEOUT_S} s: {proc.communicate()[1]}")
    line = proc.stdout.readline()
    found = re.search(r"listening on udp://127\.0\.0\.1:(\d+)", line)
    assert found, line
    return proc, int(found.group(1))


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT])
def test_streams_the_nodes_signal_and_stops_on_a_signal(stop: signal.Signals) -> None:
    options = ["--step", "0.01", "--rate-hz", "2000", "--counts-per-force", "100000",
               "--bias", *map(str, BIAS), "--no-loop"]
    proc, port = start(*options)
    try:
        n = 150
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
            client.settimeout(TIMEOUT_S)
            client.sendto(struct.pack(">HHI", 0x1234, 0x0002, n), ("127.0.0.1", port))
            records = [RECORD.unpack(client.recvfrom(1024)[0]) for _ in range(n)]
        assert proc.poll() is None
        proc.send_signal(stop)
        _, err = proc.communicate(timeout=TIMEOUT_S)
        assert proc.returncode == 0, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    rdt = np.array([r[0] for r in records])
    np.testing.assert_array_equal(rdt, np.arange(rdt[0], rdt[0] + n))  # consecutive, none lost
    # the node's signal for the same values, plus the bias, in counts (no noise: exact)
    signal_S = sensor_signal(NetFTSimParams(step=0.01))[:n] + np.array(BIAS)
    expected = np.rint(signal_S * np.array([1e5] * 3 + [1e6] * 3)).astype(int)
    np.testing.assert_array_equal(np.array([r[3:] for r in records]), expected)
    assert np.abs(expected[60:, :3] - expected[0, :3]).max() > 1000  # the rows reach the contact
    assert f"stopped after {n} records (0 dropped, 0 sent late)" in err


@pytest.mark.parametrize(("options", "message"), [
    (["--loss", "1.5"], "parameter 'loss' must be a probability in [0, 1), got 1.5"),
    (["--bias", "1", "2"], "parameter 'bias' must be 6 numbers, got (1.0, 2.0)"),
    (["--port", "abc"], "parameter 'port' expects int, got str ('abc')"),
    (["--port", "70000"], "parameter 'port' must be a port 0-65535, got 70000"),
    (["--rate-hz", "0"], "parameter 'rate_hz' must be a finite number > 0, got 0.0"),
    (["--noise-force-n=-1e-3"], "parameter 'noise_force_n' must be a finite number >= 0"),
    (["--surface", "cube:a=1"], "parameter 'surface': "),
    (["--scene", "scene.yaml"], "parameter 'whisker' must be a whisker with 'scene'"),
    (["--drift", "0", "0", "0", "0", "0", "[1"], "parameter 'drift': '[1' is not a value"),
])
def test_a_bad_value_is_one_line_and_status_2(capsys: pytest.CaptureFixture[str], options: list[str],
                                              message: str) -> None:
    assert main(["sim", "netft", "--port", "0", *options]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("vibrissa sim netft: error: ") and message in captured.err
    assert captured.err.count("\n") == 1 and not captured.out, captured.err


def test_help_names_every_parameter(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["sim", "netft", "--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    for name in NetFTSimParams.__dataclass_fields__:
        assert f"--{name.replace('_', '-')}" in text
    assert "not a node of the graph" in text
