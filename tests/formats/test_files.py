"""Output files written whole or not at all (`vibrissa.formats.files`), through the CSV writer
and the command that streams the most (`vibrissa reconstruct --scene`)."""

from __future__ import annotations

import os
import select
import signal
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from vibrissa.formats.csv_text import csv_writer
from vibrissa.formats.files import is_stream, whole_file

ROBOT_SCENE = Path(__file__).parents[2] / "launch" / "robot" / "scene.yaml"


def write_rows(path: Path, rows: int, fail_after: int | None = None) -> None:
    with csv_writer(path, ["a"]) as writer:
        for i in range(rows):
            if i == fail_after:
                raise RuntimeError("the input went bad")
            writer.writerow([str(i)])


def test_an_error_leaves_the_old_file_and_no_other(tmp_path: Path) -> None:
    out = tmp_path / "out.csv"
    out.write_text("old\n")
    with pytest.raises(RuntimeError):
        write_rows(out, 100, fail_after=50)
    assert out.read_text() == "old\n" and sorted(os.listdir(tmp_path)) == ["out.csv"]
    write_rows(out, 3)
    assert out.read_text() == "a\n0\n1\n2\n" and sorted(os.listdir(tmp_path)) == ["out.csv"]


def test_a_link_is_written_at_its_target_and_a_mode_is_kept(tmp_path: Path) -> None:
    target, link = tmp_path / "real.csv", tmp_path / "link.csv"
    target.write_text("precious\n")
    target.chmod(0o600)
    link.symlink_to(target.name)
    with pytest.raises(RuntimeError):
        write_rows(link, 100, fail_after=50)
    assert target.read_text() == "precious\n"
    write_rows(link, 1)
    assert link.is_symlink() and target.read_text() == "a\n0\n"
    assert stat.S_IMODE(target.stat().st_mode) == 0o600
    umask = os.umask(0)
    os.umask(umask)
    write_rows(tmp_path / "new.csv", 1)
    assert stat.S_IMODE((tmp_path / "new.csv").stat().st_mode) == 0o666 & ~umask


def test_the_temporary_name_is_new_each_time(tmp_path: Path) -> None:
    """A file that has the name a fixed temporary name would have (one left by a killed run,
    or a link planted there) is neither read over nor followed."""
    out = tmp_path / "p.csv"
    victim = tmp_path / "victim.txt"
    victim.write_text("victim\n")
    (tmp_path / ".p.csv.partial").symlink_to(victim.name)
    (tmp_path / ".p.partial.csv").write_text("left over\n")
    write_rows(out, 2)
    assert victim.read_text() == "victim\n" and (tmp_path / ".p.partial.csv").read_text() == "left over\n"
    assert out.read_text() == "a\n0\n1\n"


def test_an_unwritable_folder_is_named_as_given(tmp_path: Path) -> None:
    blocked = tmp_path / "file"
    blocked.write_text("")
    with pytest.raises(OSError, match=rf"cannot write {blocked}/x.csv: "), whole_file(blocked / "x.csv"):
        pass


def test_a_stop_just_as_the_temporary_file_is_made_removes_it(tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """SIGTERM arriving right after the temporary file exists (as under load, when the process
    is put aside there) to another thread of the process (as to a test runner's), still leaves
    nothing behind."""
    made = os.open

    def made_then_stopped(name: str, flags: int, *args: int, **kwargs: int) -> int:
        handle = made(name, flags, *args, **kwargs)
        if flags & os.O_CREAT:
            signal.pthread_kill(waiting.ident or 0, signal.SIGTERM)
            select.select([tripped], [], [], 60.0)  # its handler has run in the other thread
        return handle

    def stop(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)

    other = threading.Event()
    waiting = threading.Thread(target=other.wait, daemon=True)
    waiting.start()
    tripped, trips = os.pipe()
    os.set_blocking(trips, False)
    monkeypatch.setattr(os, "open", made_then_stopped)
    previous = signal.signal(signal.SIGTERM, stop)
    previous_fd = signal.set_wakeup_fd(trips)
    try:
        with pytest.raises(SystemExit), whole_file(tmp_path / "out" / "x.csv") as partial:
            partial.write_text("never\n")
    finally:
        signal.set_wakeup_fd(previous_fd)
        signal.signal(signal.SIGTERM, previous)
        monkeypatch.undo()
        other.set()
        os.close(tripped)
        os.close(trips)
    assert list((tmp_path / "out").iterdir()) == []


def test_streams_are_pipes_devices_and_dev_names(tmp_path: Path) -> None:
    assert is_stream(Path("/dev/stdout")) and is_stream(Path("/dev/null"))
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    assert is_stream(fifo)
    (tmp_path / "file").write_text("")
    assert not is_stream(tmp_path / "file") and not is_stream(tmp_path / "new")


def test_a_terminated_reconstruct_leaves_nothing_behind(tmp_path: Path) -> None:
    """SIGTERM (as `timeout` sends) unwinds the command as Ctrl-C does: status 143, and no
    half-written or temporary file."""
    sim = tmp_path / "sim"
    subprocess.run([sys.executable, "-m", "vibrissa.cli.main", "simulate", str(ROBOT_SCENE), "-o",
                    str(sim)], check=True, capture_output=True)
    lines = (sim / "wrenches.csv").read_text().splitlines()
    wrenches = tmp_path / "many.csv"
    wrenches.write_text("\n".join([lines[0], *(lines[1:] * 30)]) + "\n")  # 408 000 rows
    out = tmp_path / "out" / "points.csv"
    proc = subprocess.Popen([sys.executable, "-m", "vibrissa.cli.main", "reconstruct", str(wrenches),
                             "--scene", str(ROBOT_SCENE), "-o", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60.0
    while not any(out.parent.glob(".points.*")) and time.monotonic() < deadline:
        time.sleep(0.01)  # until the temporary file is being written
    assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=30) == 128 + signal.SIGTERM
    assert list(out.parent.iterdir()) == []
