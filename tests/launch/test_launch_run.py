"""The launcher with real processes: fixture nodes from tests/fixtures run through ``cmd:``.

Every wait has a deadline so that a hang fails fast.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from vibrissa.cli.launch import main as launcher_main
from vibrissa.launch.description import NodeSpec, Remap
from vibrissa.launch.launcher import (
    PARAMS_DIR_PREFIX,
    RUN_MODULE,
    node_command,
    remove_orphaned_params_dirs,
)
from vibrissa.runtime.node import EXIT_LOST_DATA

FIXTURES = Path(__file__).parents[1] / "fixtures"
TIMEOUT_S = 30.0


def fixture_node(name: str, script: str, **params: Any) -> dict[str, Any]:
    """A ``- node:`` entry running ``tests/fixtures/<script>.py`` with ``params``."""
    body: dict[str, Any] = {"cmd": [sys.executable, str(FIXTURES / f"{script}.py")], "name": name}
    if params:
        body["param"] = [{"name": k, "value": v} for k, v in params.items()]
    return body


def write_launch(tmp_path: Path, *entries: dict[str, Any]) -> Path:
    """Write a launch file; an entry that is not ``{arg|transport|node: ...}`` is a node."""
    wrapped = [e if len(e) == 1 and next(iter(e)) in ("arg", "transport", "node")
               else {"node": e} for e in entries]
    path = tmp_path / "test.launch.yaml"
    path.write_text(yaml.safe_dump({"launch": wrapped}, sort_keys=False))
    return path


def start(path: Path, *words: str, grace: float = 2.0, module: str = "vibrissa.cli.launch",
          env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", module]
    if module == "vibrissa.cli.main":
        cmd.append("launch")
    cmd += ["--grace", str(grace), str(path), *words]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=None if env is None else {**os.environ, **env})


def finish(proc: subprocess.Popen[str]) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"launcher did not finish in {TIMEOUT_S} s\n{out}\n{err}")
    return proc.returncode, out, err


def launch(path: Path, *words: str, **kwargs: Any) -> tuple[int, str, str]:
    return finish(start(path, *words, **kwargs))


def wait_for(predicate: Callable[[], bool], what: str, timeout: float = TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.02)
    pytest.fail(f"timed out waiting for {what}")


def pids(path: Path) -> list[int]:
    return [int(x) for x in path.read_text().split()] if path.exists() else []


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie left for a non-reaping init counts as gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


@pytest.fixture
def launcher_procs() -> Iterator[list[subprocess.Popen[str]]]:
    """Launchers started by a test; killed if the test left them running."""
    procs: list[subprocess.Popen[str]] = []
    yield procs
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def test_node_command_for_package_nodes() -> None:
    spec = NodeSpec(name="reconstructor", namespace="/whisker0", executable="reconstructor",
                    remaps=(Remap("wrench", "/whisker0/wrench"),), args=("--verbose",))
    assert node_command(spec, "/tmp/p.yaml", python="py") == [
        "py", "-c", RUN_MODULE, "vibrissa.nodes.reconstructor", "--name", "reconstructor",
        "--namespace", "/whisker0", "--params-file", "/tmp/p.yaml",
        "--remap", "wrench:=/whisker0/wrench", "--verbose",
    ]


def test_output_is_prefixed_and_node_gets_its_command_line(tmp_path: Path) -> None:
    printer = fixture_node("printer", "printer", mu="$(var mu)", label="x")
    printer.update(namespace="/whisker0", remap=[{"from": "wrench", "to": "/w/wrench"}],
                   env=[{"name": "FOO", "value": "bar"}], args=["--", "extra1"])
    other = fixture_node("other", "printer")
    path = write_launch(tmp_path, {"arg": {"name": "mu", "default": "0.2"}}, printer, other)

    rc, out, err = launch(path, "mu:=0.35", module="vibrissa.cli.main")

    assert rc == 0, err
    lines = out.splitlines()
    assert lines and all(line.startswith(("[printer] ", "[other] ")) for line in lines), out
    mine = [line for line in lines if line.startswith("[printer] ")]
    assert "[printer] name=printer namespace=/whisker0" in mine
    assert "[printer] param mu=0.35" in mine  # the override, typed as a float
    assert "[printer] param label='x'" in mine
    assert "[printer] remap wrench:=/w/wrench" in mine
    assert "[printer] extra extra1" in mine
    assert "[printer] env FOO=bar" in mine
    assert "[printer] env PYTHONUNBUFFERED=1" in mine
    assert "[printer] no newline at the end" in mine
    assert any(line.startswith("[printer] env VIBRISSA_PUB_ENDPOINT=tcp://127.0.0.1:")
               for line in mine)
    assert "[other] env FOO=None" in lines
    assert "[printer] to stderr" in err.splitlines()
    assert "[other] to stderr" in err.splitlines()
    assert "[launch] launch finished" in err


def test_the_transport_byte_bound_reaches_every_node(tmp_path: Path) -> None:
    path = write_launch(tmp_path, {"transport": {"max_buffered_bytes": 8 << 20}},
                        fixture_node("printer", "printer"))
    rc, out, err = launch(path)
    assert rc == 0, err
    assert f"[printer] env VIBRISSA_MAX_BUFFERED_BYTES={8 << 20}" in out.splitlines()


def test_bad_file_or_argument_exits_2_and_starts_nothing(tmp_path: Path) -> None:
    pid_file = tmp_path / "pids"
    sleeper = fixture_node("sleeper", "sleeper", pid_file=str(pid_file), seconds=0.1)
    bad = fixture_node("bad", "printer")
    bad["respawn"] = "yes"
    path = write_launch(tmp_path, sleeper, bad)
    rc, out, err = launch(path)
    assert rc == 2
    assert f"{path}: launch[1].node.respawn: expected bool, got 'yes'" in err
    assert out == ""

    path = write_launch(tmp_path, {"arg": {"name": "mu", "default": "1"}}, sleeper)
    rc, _, err = launch(path, "nu:=3")
    assert rc == 2
    assert "unknown launch argument 'nu' (known: mu)" in err
    time.sleep(0.2)
    assert not pid_file.exists()


def test_a_private_name_exits_2_naming_file_and_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    node = fixture_node("printer", "printer")
    node["remap"] = [{"from": "~wrench", "to": "/whisker0/wrench"}]
    path = write_launch(tmp_path, node)
    assert launcher_main([str(path)]) == 2
    out, err = capsys.readouterr()
    assert f"{path}: launch[0].node.remap[0].from: invalid topic name '~wrench'" in err, err
    assert "[launch]" not in err and out == ""


def test_kill_9_with_respawn_restarts_and_completes(
    tmp_path: Path, launcher_procs: list[subprocess.Popen[str]]
) -> None:
    pid_file = tmp_path / "pids"
    sleeper = fixture_node("sleeper", "sleeper", pid_file=str(pid_file), first_seconds=30,
                           seconds=0.3)
    sleeper.update(respawn=True, respawn_delay=0.1, required=True)
    proc = start(write_launch(tmp_path, sleeper))
    launcher_procs.append(proc)

    wait_for(lambda: len(pids(pid_file)) == 1, "the first start")
    os.kill(pids(pid_file)[0], signal.SIGKILL)
    rc, out, err = finish(proc)

    assert rc == 0, err
    first, second = pids(pid_file)
    assert first != second
    assert "'sleeper' was killed by SIGKILL; respawn 1 in 0.1 s" in err
    assert f"respawned 'sleeper' (pid {second})" in err
    assert out.count("[sleeper] sleeper done") == 1
    summary = err[err.index("[launch] summary:"):]
    assert "sleeper" in summary and "exit 0" in summary and "respawns 1" in summary


def test_required_node_failure_stops_the_launch_and_names_it(tmp_path: Path) -> None:
    pid_file = tmp_path / "pids"
    sleeper = fixture_node("sleeper", "sleeper", pid_file=str(pid_file), seconds=30)
    crasher = fixture_node("crasher", "crasher", delay=0.3, exit_code=3)
    crasher["required"] = True
    t0 = time.monotonic()
    rc, out, err = launch(write_launch(tmp_path, sleeper, crasher))
    assert rc == 1
    assert time.monotonic() - t0 < 15
    assert "[crasher] crasher crashing" in out
    assert "[sleeper] sleeper interrupted" in out  # stopped with SIGINT, cleanly
    last = err.strip().splitlines()[-1]
    assert last == "[launch] launch failed: required node 'crasher' exited with code 3"
    assert not any(alive(pid) for pid in pids(pid_file))


def test_respawn_limit_then_required_failure(tmp_path: Path) -> None:
    crasher = fixture_node("crasher", "crasher", exit_code=5)
    crasher.update(respawn=True, respawn_max=2, required=True)
    rc, out, err = launch(write_launch(tmp_path, crasher))
    assert rc == 1
    assert out.count("[crasher] crasher crashing") == 3
    assert err.strip().splitlines()[-1] == (
        "[launch] launch failed: required node 'crasher' exited with code 5"
        " (respawn limit reached)")
    assert "starts 3  respawns 2" in err


def test_failure_of_optional_node_lets_others_finish(tmp_path: Path) -> None:
    crasher = fixture_node("crasher", "crasher", exit_code=5)
    sleeper = fixture_node("sleeper", "sleeper", seconds=0.5)
    missing = {"cmd": [str(tmp_path / "no-such-program")], "name": "missing"}
    rc, out, err = launch(write_launch(tmp_path, crasher, sleeper, missing))
    assert rc == 1
    assert "[sleeper] sleeper done" in out
    assert "'crasher' exited with code 5; not required, continuing" in err
    assert "'missing' could not start: [Errno 2]" in err
    assert err.strip().splitlines()[-1].startswith("[launch] launch failed: node 'crasher'")


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_signal_stops_all_children_at_once_and_escalates_per_node(
    tmp_path: Path, launcher_procs: list[subprocess.Popen[str]], signum: int
) -> None:
    pid_file, grandchild_file = tmp_path / "pids", tmp_path / "grandchild"
    first = fixture_node("first", "sleeper", pid_file=str(pid_file),
                         grandchild_pid_file=str(grandchild_file))
    second = fixture_node("second", "sleeper", pid_file=str(pid_file))
    stubborn = fixture_node("stubborn", "sleeper", pid_file=str(pid_file), ignore_sigint=True)
    proc = start(write_launch(tmp_path, first, second, stubborn), grace=0.5)
    launcher_procs.append(proc)

    wait_for(lambda: len(pids(pid_file)) == 3 and len(pids(grandchild_file)) == 1,
             "three nodes and a grandchild")
    wait_for(lambda: all(alive(pid) for pid in pids(pid_file)), "nodes running")
    proc.send_signal(signum)
    rc, out, err = finish(proc)

    assert rc == 128 + signum
    children = pids(pid_file) + pids(grandchild_file)
    wait_for(lambda: not any(alive(pid) for pid in children), "no child left")
    assert "'stubborn' still running 0.5 s after SIGINT; escalating" in err
    assert "[second] second interrupted" in out and "[first] first interrupted" in out
    assert "stopped by launcher (killed by SIGTERM)" in err  # stubborn
    assert "stopped by launcher (exit 0)" in err


def test_on_exit_shutdown_ends_the_launch_cleanly(tmp_path: Path) -> None:
    pid_file = tmp_path / "pids"
    worker = fixture_node("worker", "sleeper", pid_file=str(pid_file), seconds=30)
    mapper = fixture_node("mapper", "crasher", delay=0.3, exit_code=0)
    mapper["on_exit"] = "shutdown"
    rc, out, err = launch(write_launch(tmp_path, worker, mapper))
    assert rc == 0, err
    assert "'mapper' has on_exit: shutdown; shutting down" in err
    assert "[worker] worker interrupted" in out
    assert not any(alive(pid) for pid in pids(pid_file))


def test_show_args_and_dry_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    arg = {"arg": {"name": "length", "default": "0.2", "description": "rod length"}}
    node = {"exec": "reconstructor", "namespace": "/whisker0",
            "param": [{"name": "rod_length_m", "value": "$(var length)"}]}
    path = write_launch(tmp_path, arg, {"node": node})
    assert launcher_main([str(path), "--show-args"]) == 0
    assert "length: rod length  [default: '0.2']" in capsys.readouterr().out
    assert launcher_main(["--dry-run", str(path), "length:=0.5"]) == 0
    out = capsys.readouterr().out
    assert "vibrissa.nodes.reconstructor --name reconstructor --namespace /whisker0" in out
    assert "[reconstructor]   param rod_length_m: 0.5" in out


@pytest.mark.parametrize("transport", [None, {"domain": 5000 + os.getpid() % 1500}])
def test_nodes_talk_through_the_launcher_proxy(
    tmp_path: Path, transport: dict[str, Any] | None
) -> None:
    talker = fixture_node("talker", "relay", role="pub")
    listener = fixture_node("listener", "relay", role="sub", seconds=10)
    listener.update(on_exit="shutdown", required=True)
    entries = [talker, listener] if transport is None else [{"transport": transport},
                                                           talker, listener]
    rc, out, err = launch(write_launch(tmp_path, *entries))
    assert rc == 0, err
    assert "[listener] received hello from talker" in out
    if transport is not None:
        port = 7400 + 2 * transport["domain"]
        assert f"publishers -> tcp://127.0.0.1:{port}, subscribers -> " \
               f"tcp://127.0.0.1:{port + 1}" in err


def test_nodes_die_with_a_killed_launcher_and_the_next_launch_cleans_up(tmp_path: Path) -> None:
    pid_file = tmp_path / "pids"
    sleeper = fixture_node("sleeper", "sleeper", pid_file=str(pid_file), seconds=120)
    path = write_launch(tmp_path, sleeper)
    temp_dir = tmp_path / "tmp"  # its own: launches of other tests clean up orphans in /tmp
    temp_dir.mkdir()
    proc = start(path, env={"TMPDIR": str(temp_dir)})
    try:
        wait_for(lambda: len(pids(pid_file)) == 1, "the node to start")
        node_pid = pids(pid_file)[0]
        left = list(temp_dir.glob(f"{PARAMS_DIR_PREFIX}{proc.pid}-*"))
        assert len(left) == 1
        proc.kill()  # SIGKILL: the launcher cleans up nothing
        proc.communicate(timeout=TIMEOUT_S)
        wait_for(lambda: not alive(node_pid), "the node to die with its launcher")
        assert left[0].exists()  # nobody removed it yet
        assert str(left[0]) in remove_orphaned_params_dirs(str(temp_dir))  # what the next launch does first
        assert not left[0].exists()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


@pytest.mark.parametrize("finite", [False, True])
def test_a_required_node_ending_while_the_graph_runs_fails_it_unless_finite(
    tmp_path: Path, finite: bool
) -> None:
    """Once a required node whose heartbeat had failed exited 0 and the launcher carried on
    without it; a node that must keep running may not end early, whatever its status."""
    early = fixture_node("early", "sleeper", seconds=0.3)
    early.update(required=True, finite=finite)
    waiting = fixture_node("waiting", "sleeper", seconds=2.0)
    rc, out, err = launch(write_launch(tmp_path, early, waiting))
    if finite:
        assert rc == 0, err
        assert "[waiting] waiting done" in out  # the graph ran to its end
    else:
        assert rc == 1
        assert err.strip().splitlines()[-1] == (
            "[launch] launch failed: required node 'early' ended (exit 0) while the graph "
            "still runs (a node whose work ends by itself is marked finite: true)")
        # stopped before its 2 s were up (on a loaded machine it may not have started yet)
        assert "[waiting] waiting done" not in out
        if "[waiting] waiting sleeping" in out:
            assert "[waiting] waiting interrupted" in out


@pytest.mark.parametrize("allow_loss", [False, True])
def test_a_run_that_lost_data_says_so_in_its_exit_status(tmp_path: Path,
                                                         allow_loss: bool) -> None:
    lossy = fixture_node("lossy", "lossy", lost=3)
    lossy["allow_loss"] = allow_loss
    rc, out, err = launch(write_launch(tmp_path, lossy))
    assert "[lossy] lost 3" in out, out + err
    assert re.search(r"lossy .* received 3  lost 3", err), err
    assert "data did not arrive in full: 'lossy' lost 3 and refused 0" in err
    if allow_loss:
        assert rc == 0 and "(allow_loss)" in err and "launch finished" in err
    else:
        assert rc == EXIT_LOST_DATA, err
        assert "launch finished, but data were lost" in err
