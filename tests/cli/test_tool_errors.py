"""Tool errors are one line and an honest exit status, never a traceback."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from vibrissa.cli.main import main as vibrissa_main
from vibrissa.msgs import WhiskerWrenchArray
from vibrissa.msgs.codec import encode
from vibrissa.wire.bag import BagWriter


def vibrissa(*words: str, **kwargs: object) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "VIBRISSA_DEBUG"}
    return subprocess.run([sys.executable, "-m", "vibrissa.cli.main", *words], env=env,
                          capture_output=True, text=True, timeout=60, **kwargs)  # type: ignore[call-overload]


@pytest.mark.parametrize("words", [
    ("bag", "play", "{missing}"),
    ("bag", "export", "{missing}", "-o", "{tmp}/out.mcap"),
    ("bag", "info", "{missing}"),
])
def test_a_missing_bag_is_one_line_and_exit_2(tmp_path: Path, words: tuple[str, ...]) -> None:
    missing = tmp_path / "nope.mcap"
    result = vibrissa(*(w.format(missing=missing, tmp=tmp_path) for w in words))
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert result.stderr.strip() == f"vibrissa bag {words[1]}: error: no bag at {missing}"


def test_bag_info_of_a_csv_says_it_is_not_mcap(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    csv = tmp_path / "sweep.csv"
    csv.write_text("x0,y0,phase\n0.8,0.0,tip\n")
    assert vibrissa_main(["bag", "info", str(csv)]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert f"{csv} is not an MCAP file" in err


def test_bag_info_into_a_closed_pipe_ends_quietly(tmp_path: Path) -> None:
    bag = tmp_path / "many.mcap"
    with BagWriter(bag) as writer:
        for i in range(2000):  # a line per topic: more than a pipe holds (64 KiB)
            msg = WhiskerWrenchArray(stamp=0.0, seq=0, whisker_ids=["w"], frame_ids=["w/clamp"],
                                     pose_frame_id="world", clamp_position=[[0, 0, 0]],
                                     clamp_orientation=[[0, 0, 0, 1]], f0=[[0, 0, 0]],
                                     m0=[[0, 0, 0]])
            writer.write(f"/w{i}/wrench", encode(msg), i)
    result = subprocess.run(
        f"{sys.executable} -m vibrissa.cli.main bag info {bag} | head -1; "
        "echo status ${PIPESTATUS[0]}", shell=True, executable="/bin/bash",
        capture_output=True, text=True, timeout=60)
    assert result.stdout.splitlines()[1:] == ["status 141"]  # 128 + SIGPIPE, as `cat` would
    assert "Traceback" not in result.stderr and "BrokenPipeError" not in result.stderr


def test_bag_record_refuses_an_existing_file_unless_asked(tmp_path: Path) -> None:
    existing = tmp_path / "keep.mcap"
    existing.write_bytes(b"precious")
    env_domain = str(9900 + os.getpid() % 1000)  # nobody publishes there (ports below the ephemeral ones)
    refused = vibrissa("bag", "record", "-o", str(existing), "--duration", "0.2",
                       "--domain", env_domain)
    assert refused.returncode == 2
    assert "exists: overwrite it" in refused.stderr and "--overwrite" in refused.stderr
    assert existing.read_bytes() == b"precious"
    replaced = vibrissa("bag", "record", "-o", str(existing), "--duration", "0.2", "--overwrite",
                        "--domain", env_domain)
    assert replaced.returncode == 0, replaced.stderr
    assert existing.read_bytes().startswith(b"\x89MCAP0\r\n")


def test_keys_that_cannot_be_used_stop_a_launch_before_anything_starts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nowhere"
    assert vibrissa_main(["launch", "demo", "--keys", str(missing), "--dry-run"]) == 2
    assert f"key folder {missing} does not exist" in capsys.readouterr().err
    loose = tmp_path / "keys"
    assert vibrissa_main(["keys", str(loose)]) == 0
    os.chmod(loose / "graph.key_secret", 0o644)
    launch_file = tmp_path / "keyed.yaml"
    launch_file.write_text(f"launch:\n  - transport: {{keys: {loose}}}\n"
                           "  - node: {cmd: [x], name: n}\n")
    capsys.readouterr()
    assert vibrissa_main(["launch", str(launch_file), "--dry-run"]) == 2
    assert "accessible by others (mode 0644): chmod 600" in capsys.readouterr().err
    assert vibrissa_main(["topic", "list", "--keys", str(loose)]) == 2
    assert "chmod 600" in capsys.readouterr().err


@pytest.mark.parametrize("fmt", ["json", "foxglove"])
def test_bag_export_never_writes_over_its_input_nor_silently_over_a_file(
        tmp_path: Path, fmt: str) -> None:
    bag = tmp_path / "rec.mcap"
    with BagWriter(bag) as out:
        out.write("/w/wrench", encode(WhiskerWrenchArray(
            stamp=0.0, seq=0, whisker_ids=["w0"], frame_ids=["w0/clamp"], f0=[[1, 0, 0]],
            m0=[[0, 0, 0]])), 1)
    before = bag.read_bytes()
    for target in (bag, tmp_path / "." / "rec.mcap"):  # the input by any path
        result = vibrissa("bag", "export", "--format", fmt, str(bag), str(target), "--overwrite")
        assert result.returncode == 2 and "Traceback" not in result.stderr
        assert result.stderr.strip() == (f"vibrissa bag export: error: {target} would overwrite "
                                         "the input bag")
    assert bag.read_bytes() == before
    other = tmp_path / "other.mcap"
    other.write_bytes(b"keep me")
    result = vibrissa("bag", "export", "--format", fmt, str(bag), str(other))
    assert result.returncode == 2
    assert result.stderr.strip() == (f"vibrissa bag export: error: {other} exists (--overwrite "
                                     "replaces it)")
    assert other.read_bytes() == b"keep me"
    result = vibrissa("bag", "export", "--format", fmt, str(bag), str(other), "--overwrite")
    assert result.returncode == 0, result.stderr
    assert other.read_bytes()[:8] == b"\x89MCAP0\r\n"


@pytest.mark.parametrize("words", [("--mu", "0.3"), ("--mu=0.3",)])
def test_a_launch_argument_given_as_a_flag_is_answered_with_its_form(
        words: tuple[str, ...]) -> None:
    result = vibrissa("launch", "demo", *words)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.splitlines()[-1].endswith(
        "unrecognized arguments: " + " ".join(words) + " (a launch argument is NAME:=VALUE: mu:=...)")


def test_a_relative_topic_is_answered_with_the_absolute_one() -> None:
    result = vibrissa("topic", "echo", "nope", "--timeout", "0.1")
    assert result.returncode != 0 and "Traceback" not in result.stderr
    assert "topic 'nope' is relative: on the wire a topic is absolute (/nope" in result.stderr


@pytest.mark.parametrize("words", [("info",), ("play", "--fast"), ("export", "{tmp}/out.mcap")])
def test_an_empty_file_is_no_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                 words: tuple[str, ...]) -> None:
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    assert vibrissa_main(["bag", words[0], str(empty),
                          *(w.format(tmp=tmp_path) for w in words[1:])]) == 2
    assert capsys.readouterr().err == (f"vibrissa bag {words[0]}: error: {empty} is empty "
                                       "(0 bytes), not an MCAP file\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.mcap"]


def wrench_bag(path: Path) -> Path:
    with BagWriter(path) as out:
        for i, topic in enumerate(("/w0/wrench", "/w1/wrench")):
            out.write(topic, encode(WhiskerWrenchArray(
                stamp=0.0, seq=0, whisker_ids=[f"w{i}"], frame_ids=[f"w{i}/clamp"],
                f0=[[1, 0, 0]], m0=[[0, 0, 0]])), 1 + i)
    return path


@pytest.mark.live  # bag play, in process, opens ZeroMQ sockets
def test_bag_topics_in_any_order_and_the_ones_a_bag_lacks_are_named(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--topics takes topics comma-separated, repeated or several after it, and never
    swallows the bag after it (a path is no topic); a topic the bag does not hold is a warning
    that lists the bag's topics; the output's folder is made as for every other output file."""
    bag = wrench_bag(tmp_path / "rec.mcap")
    out = tmp_path / "no" / "folder" / "x.mcap"
    assert vibrissa_main(["bag", "export", "--topics", "/w1/wrench,/nope", str(bag), str(out)]) == 0
    assert capsys.readouterr().err.splitlines() == [
        f"vibrissa bag export: warning: /nope: no such topic in {bag} (its topics: /w0/wrench, "
        "/w1/wrench)", f"wrote 1 JSON messages to {out}"]
    again = tmp_path / "again.mcap"
    assert vibrissa_main(["bag", "export", str(bag), str(again), "--topics", "/w0/wrench",
                          "--topics", "/w1/wrench"]) == 0
    assert capsys.readouterr().err.splitlines() == [f"wrote 2 JSON messages to {again}"]
    several = tmp_path / "several.mcap"
    assert vibrissa_main(["bag", "export", str(bag), "--topics", "/w0/wrench", "/w1/wrench",
                          str(several)]) == 0
    assert capsys.readouterr().err.splitlines() == [f"wrote 2 JSON messages to {several}"]
    assert vibrissa_main(["bag", "export", "--topics", "/w0/wrench", str(bag), str(several),
                          "extra.mcap"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "vibrissa bag export: error: unrecognized arguments: extra.mcap"]
    assert vibrissa_main(["bag", "play", "--topics", "/w0/wrench"]) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith("vibrissa bag play: error: the following arguments are required: "
                           "bag; a word after --topics or --wait-for that could be a name is "
                           "read as one")
    # no topic at all: the bag after --topics is no topic, and nothing is played
    with pytest.raises(SystemExit) as exc:
        vibrissa_main(["bag", "export", "--topics", str(bag), str(several)])
    assert exc.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"vibrissa bag export: error: argument --topics: expected a name, got {str(bag)!r} (a "
        "path? put it before the option or after --)")
    # a second --topics after the bag is the option's again
    assert vibrissa_main(["bag", "export", "--topics", "/w0/wrench", str(bag), "--topics",
                          "/w1/wrench", str(several), "--overwrite"]) == 0
    assert capsys.readouterr().err.splitlines() == [f"wrote 2 JSON messages to {several}"]
    domain = str(9900 + os.getpid() % 1000)  # nobody listens there
    assert vibrissa_main(["bag", "play", "--fast", "--wait", "0", "--topics", "/w0/wrench",
                          "/nope", str(bag), "--domain", domain]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("vibrissa bag play: warning: /nope: no such topic in ")
    err = err[1:]
    assert err[0].startswith("published 1 messages in ")
    assert err[1].startswith(f"vibrissa bag play: nobody received them: no running graph heard "
                             f"on domain {domain} ")


@pytest.mark.live  # bag play, in process, opens ZeroMQ sockets
def test_a_play_whose_nodes_never_come_says_so_and_exits_1(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--wait-for a node that never comes: status 1 and why, not Ctrl-C's 130."""
    bag = wrench_bag(tmp_path / "rec.mcap")
    domain = str(9900 + os.getpid() % 1000)  # nobody listens there
    assert vibrissa_main(["bag", "play", str(bag), "--wait-for", "mapper", "--wait-timeout",
                          "0.3", "--domain", domain]) == 1
    assert capsys.readouterr().err.splitlines()[-1].endswith(
        "(--wait-for not ready after 0.3 s)")


@pytest.mark.parametrize(("words", "message"), [
    (("bag", "play", "x.mcap", "--wait", "-1"), "argument --wait: expected a number >= 0, got '-1'"),
    (("bag", "play", "x.mcap", "--wait-timeout", "nan"),
     "argument --wait-timeout: expected a number >= 0, got 'nan'"),
    (("bag", "play", "x.mcap", "--topics", "/a,,/b"),
     "argument --topics: expected NAME[,NAME...], got '/a,,/b'"),
    (("topic", "echo", "/x", "-n", "0"), "argument --count/-n: expected an integer >= 1, got '0'"),
    (("topic", "echo", "/x", "-n", "-1"), "argument --count/-n: expected an integer >= 1, got '-1'"),
    (("topic", "echo", "/x", "--timeout", "-2"),
     "argument --timeout: expected a number >= 0, got '-2'"),
])
def test_counts_and_waits_that_mean_nothing_are_refused(
        capsys: pytest.CaptureFixture[str], words: tuple[str, ...], message: str) -> None:
    with pytest.raises(SystemExit) as exc:
        vibrissa_main(list(words))
    assert exc.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(message)


# The child waits inside the import of GATE, as if that import were slow, until the signal comes.
# SIGINT as a shell leaves it: a test run may have left it ignored in the worker, the child's parent.
GATE = """\
import signal, sys, time

signal.signal(signal.SIGINT, signal.default_int_handler)

class Gate:
    def find_spec(self, name, path=None, target=None):
        if name == {module!r}:
            sys.meta_path.remove(self)
            print("ready", flush=True)
            time.sleep(120)  # until SIGINT
        return None

sys.meta_path.insert(0, Gate())
sys.argv = ["vibrissa", "sweep", "--help"]
from _vibrissa_entry import main
sys.exit(main())
"""


@pytest.mark.parametrize("module", ["vibrissa", "numba"])  # the package's first module, one deep in
def test_ctrl_c_while_the_package_loads_ends_quietly_with_130(module: str) -> None:
    """The command's entry point (``vibrissa`` runs ``_vibrissa_entry:main``) catches a Ctrl-C
    during the package's import (numpy, scipy, numba: 0.3-0.5 s), which the interpreter would
    otherwise end with a traceback of the import. The child says ``ready`` from inside the
    import of ``module`` (within the entry point's ``try``) and waits there for the signal, so
    that the signal lands during the import however slowly the child or the test is scheduled."""
    (script,) = [ep for ep in entry_points(group="console_scripts") if ep.name == "vibrissa"]
    assert script.value == "_vibrissa_entry:main"
    proc = subprocess.Popen([sys.executable, "-c", GATE.format(module=module)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline() == "ready\n"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=240)
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    assert proc.returncode == 130


@pytest.mark.parametrize("stop, status", [(SystemExit(128 + signal.SIGTERM), 143),
                                          (KeyboardInterrupt(), 130)])
def test_a_stop_inside_a_compiled_kernel_ends_with_its_status_and_no_error(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        stop: BaseException, status: int) -> None:
    """SIGTERM or Ctrl-C while numba's kernel calls back into Python comes out of the kernel
    as a SystemError caused by the stop (`vibrissa simulate` ended 1 with "CPUDispatcher(...)
    returned a result with an exception set"): it ends as the stop does, quietly."""
    import vibrissa.cli.scenes

    def stopped_in_a_kernel(args: object) -> int:
        try:
            raise stop
        except BaseException as exc:
            raise SystemError("CPUDispatcher(<function newton>) returned a result with an "
                              "exception set") from exc

    monkeypatch.setattr(vibrissa.cli.scenes, "run_simulate", stopped_in_a_kernel)
    assert vibrissa_main(["simulate", "scene.yaml", "-o", "out"]) == status
    assert capsys.readouterr().err == ""
