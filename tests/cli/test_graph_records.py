"""The records by which tools name the graphs of a machine: only a live launcher's record of a
bound domain counts; a record of a launcher that is gone is removed."""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from vibrissa.cli.graph import graph_note
from vibrissa.wire.transport import (
    Endpoints,
    GraphRecord,
    Proxy,
    register_graph,
    running_graphs,
    which_graph,
)

DOMAIN = 2000 + os.getpid() % 500 * 2  # +0..+1; away from the other tests' ranges (launch_run: 5000-6499)


@pytest.fixture
def temp_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A temporary folder of the tests' own as the machine's temp dir."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    yield tmp_path
    _wait_until_closed([DOMAIN, DOMAIN + 1])


def _wait_until_closed(domains: list[int], deadline_s: float = 20.0) -> None:
    """Until both ports of each domain refuse connections: ZeroMQ closes a proxy's listening
    sockets in its I/O thread, after ``Proxy.stop`` returns, and the next test binds them."""
    ports = [int(address.rsplit(":", 1)[1]) for domain in domains
             for address in Endpoints.for_domain(domain).addresses]
    deadline = time.monotonic() + deadline_s
    while time.monotonic() < deadline:
        open_ports = []
        for port in ports:
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
                probe.settimeout(0.2)
                if probe.connect_ex(("127.0.0.1", port)) == 0:
                    open_ports.append(port)
        if not open_ports:
            return
        time.sleep(0.05)
    raise AssertionError(f"ports {open_ports} still listening {deadline_s} s after the test")


def test_a_live_launchers_record_of_a_bound_domain_counts(temp_dir: Path) -> None:
    record = GraphRecord.of_this_process(DOMAIN, "/srv/view.yaml")
    path = register_graph(record)
    assert path == temp_dir / f"vibrissa-graphs-{os.getuid()}" / f"domain-{DOMAIN}-{os.getpid()}.json"
    assert path.stat().st_mode & 0o777 == 0o644  # other users' tools read it
    assert running_graphs() == []  # nothing bound on its domain
    with Proxy(Endpoints.for_domain(DOMAIN)):
        assert running_graphs() == [record]
    deadline = time.monotonic() + 20.0  # ZeroMQ closes the listening socket in its I/O thread
    while running_graphs() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert running_graphs() == []


def test_a_record_of_a_launcher_that_is_gone_is_removed(temp_dir: Path) -> None:
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    record = GraphRecord(DOMAIN, "/srv/view.yaml", "2026-01-01T00:00:00+00:00", "ana",
                         int(gone.stdout))
    path = register_graph(record)
    assert path is not None
    broken = path.with_name(f"domain-{DOMAIN}-1.json")
    broken.write_text(json.dumps({"domain": "zero"}))  # not a record: passed over
    with Proxy(Endpoints.for_domain(DOMAIN)):
        assert running_graphs() == []
    assert not path.exists() and broken.exists()


def test_a_pipe_or_a_huge_file_in_a_record_folder_is_passed_over(temp_dir: Path) -> None:
    # a user's own record folder may hold anything: a pipe without a writer (read, it waits
    # forever: every tool of every user would hang) or a file of gigabytes
    record = GraphRecord.of_this_process(DOMAIN, "/srv/view.yaml")
    path = register_graph(record)
    assert path is not None
    os.mkfifo(path.with_name(f"domain-{DOMAIN + 1}-{os.getpid()}.json"))
    with path.with_name(f"domain-{DOMAIN + 2}-{os.getpid()}.json").open("wb") as huge:
        huge.truncate(1 << 30)  # sparse: 1 GiB read as text would take seconds and the memory
    code = ("import tempfile, sys; tempfile.tempdir = sys.argv[1]\n"
            "from vibrissa.wire.transport import running_graphs; print(len(running_graphs()))")
    with Proxy(Endpoints.for_domain(DOMAIN)):
        done = subprocess.run([sys.executable, "-c", code, str(temp_dir)], capture_output=True,
                              text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "1", done.stderr


def test_the_note_names_this_graph_and_the_others(temp_dir: Path) -> None:
    this = GraphRecord.of_this_process(DOMAIN, "/srv/a.yaml")
    register_graph(this)
    with Proxy(Endpoints.for_domain(DOMAIN)), Proxy(Endpoints.for_domain(DOMAIN + 1)):
        note = which_graph(DOMAIN)
        assert note is not None
        assert f"talking to the one on {this.describe()} (others: " in note
        assert f"domain {DOMAIN + 1})" in note or f"domain {DOMAIN + 1};" in note
        args = argparse.Namespace(domain=None, pub=None, sub=None)
        register_graph(GraphRecord.of_this_process(DOMAIN + 1, "/srv/b.yaml"))  # both named:
        assert graph_note(args) is not None  # seen from any domain, the default one (0) too
        args.domain = DOMAIN
        assert graph_note(args) is None  # a graph the user named
