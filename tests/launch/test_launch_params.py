"""Parameters are checked before anything starts; a node that fails at start says why in one
line (its traceback only on request)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from vibrissa.cli.main import main as vibrissa_main
from vibrissa.launch.description import check_node_params, load_launch_file
from vibrissa.launch.launcher import resolve_launch_file
from vibrissa.msgs import EndOfStream
from vibrissa.msgs.codec import encode
from vibrissa.wire.bag import BagWriter


def tiny_bag(path: Path) -> Path:
    with BagWriter(path) as bag:
        bag.write("/whisker0/wrench", encode(EndOfStream(stamp=0.0, source="/x", count=0)), 0)
    return path


@pytest.mark.parametrize("name", ["demo", "record_demo", "replay_demo"])
def test_packaged_launch_files_pass_the_node_checks(name: str, tmp_path: Path) -> None:
    overrides = {"bag": str(tiny_bag(tmp_path / "in.mcap"))} if name == "replay_demo" else {}
    check_node_params(load_launch_file(resolve_launch_file(name), overrides))


@pytest.mark.parametrize(("override", "expected"), [
    ("mu:=abc", "node 'wrench_source': parameter 'mu' expects float, got str ('abc')"),
    ("array:=maybe", "node 'wrench_source': parameter 'array' expects bool, got str ('maybe')"),
    ("surface:=cube:s=1", "node 'wrench_source': parameter 'surface': surface spec 'cube:s=1': "
                          "unknown kind 'cube'"),
    ("step:=-0.001", "node 'wrench_source': parameter 'step' must be a number in (0, 0.1]"),
    ("mu:=-0.1", "node 'wrench_source': parameter 'mu' must be a finite number >= 0, got -0.1"),
    ("surface:=sphere:r=-1", "node 'wrench_source': parameter 'surface'"),
    ("mu:=1" + "0" * 400, "node 'wrench_source': parameter 'mu' expects float, got int (1000"),
])
def test_a_bad_value_is_one_line_before_anything_starts(
    override: str, expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert vibrissa_main(["launch", "demo", override]) == 2
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("vibrissa launch: error: ") and "demo.yaml: " in lines[0]
    assert expected in lines[0]
    assert "[launch]" not in out + err  # no proxy, no node was started


def test_a_missing_or_foreign_replay_bag_is_refused_before_start(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "nope.mcap"
    assert vibrissa_main(["launch", "replay_demo", f"bag:={missing}"]) == 2
    assert f"node 'wrench_source': parameter 'bag': no bag at {missing}" in capsys.readouterr().err
    csv = tmp_path / "sweep.csv"
    csv.write_text("x0,y0\n0,0\n")
    assert vibrissa_main(["launch", "replay_demo", f"bag:={csv}"]) == 2
    assert "is not an MCAP file" in capsys.readouterr().err


def test_overrides_may_follow_the_flags(capsys: pytest.CaptureFixture[str]) -> None:
    assert vibrissa_main(["launch", "demo", "--dry-run", "mu:=0.3", "out:=elsewhere"]) == 0
    out = capsys.readouterr().out
    assert "[wrench_source]   param mu: 0.3" in out
    assert "[mapper]   param out_dir: 'elsewhere'" in out
    with pytest.raises(SystemExit):
        vibrissa_main(["launch", "demo", "--dry-run", "--bogus"])


def run_node(module: str, *args: str, debug: bool = False) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "VIBRISSA_DEBUG"}
    if debug:
        env["VIBRISSA_DEBUG"] = "1"
    return subprocess.run([sys.executable, "-m", module, "--name", "n", *args], env=env,
                          capture_output=True, text=True, timeout=60)


def test_a_node_with_refused_parameters_exits_2_in_one_line(tmp_path: Path) -> None:
    result = run_node("vibrissa.nodes.wrench_source", "--param", "mode:=replay",
                      "--param", f"bag:={tmp_path / 'gone.mcap'}")
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines() == [
        f"ERROR vibrissa.runtime.node: --param: parameter 'bag': no bag at {tmp_path / 'gone.mcap'}"]


def test_a_node_failing_at_start_prints_its_traceback_only_when_asked(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    args = ("vibrissa.nodes.mapper", "--param", f"out_dir:={blocker / 'map'}")
    quiet = run_node(*args)
    assert quiet.returncode == 1
    assert "Traceback" not in quiet.stderr
    lines = quiet.stderr.strip().splitlines()
    assert len(lines) == 1 and "stopped by NotADirectoryError" in lines[0], quiet.stderr
    assert "VIBRISSA_DEBUG=1" in lines[0]
    loud = run_node(*args, debug=True)
    assert loud.returncode == 1
    assert "Traceback (most recent call last)" in loud.stderr
    assert "NotADirectoryError" in loud.stderr


@pytest.mark.parametrize(("override", "expected"), [
    ("rate:=1:30", "node 'wrench_source': parameter 'rate_hz' expects float, got str ('1:30')"),
    ("rate:=1_0", "node 'wrench_source': parameter 'rate_hz' expects float, got str ('1_0')"),
    ("rate:=0x10", "node 'wrench_source': parameter 'rate_hz' expects float, got str ('0x10')"),
    # a float that underflows is not the number written (0: as fast as possible)
    ("rate:=1e-400", "node 'wrench_source': parameter 'rate_hz' expects float, got str ('1e-400')"),
])
def test_a_launch_argument_is_no_yaml_1_1_number(
    override: str, expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``1:30`` is no sexagesimal 90, ``1_0`` no 10, ``0x10`` no 16: YAML 1.2's plain numbers."""
    assert vibrissa_main(["launch", "demo", override, "--dry-run"]) == 2
    assert expected in capsys.readouterr().err


def test_a_text_parameter_takes_a_launch_argument_as_it_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``out:=2026`` is the folder ``2026`` (not refused as an int), ``out:=&a x`` the text
    ``&a x`` (no YAML anchor swallowed); the node reads the same from its parameter file; an
    argument given twice is refused, naming it."""
    import yaml

    from vibrissa.launch.description import node_params
    from vibrissa.nodes.mapper import PARAMS
    from vibrissa.runtime.params import load_params

    for value in ("2026", "&a x", "007"):
        assert vibrissa_main(["launch", "demo", f"out:={value}", "--dry-run"]) == 0
        assert f"[mapper]   param out_dir: {value!r}" in capsys.readouterr().out
    description = load_launch_file(resolve_launch_file("demo"), {"out": "2026", "rate": "200"})
    (mapper,) = [spec for spec in description.nodes if spec.name == "mapper"]
    (tmp_path / "mapper.yaml").write_text(yaml.safe_dump(node_params(mapper)))
    assert load_params(PARAMS, tmp_path / "mapper.yaml").out_dir == "2026"
    (source,) = [spec for spec in description.nodes if spec.name == "wrench_source"]
    assert node_params(source)["rate_hz"] == 200  # a number parameter: what the text reads as
    assert vibrissa_main(["launch", "demo", "out:=a", "out:=b", "--dry-run"]) == 2
    assert "argument 'out' given twice (out:=a, out:=b)" in capsys.readouterr().err
