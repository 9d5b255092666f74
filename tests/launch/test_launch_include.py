"""Launch files that include others (``include`` with arguments), nodes added next to a
producer without editing its readiness list (``ready_before``), the errors of both, and the
"did you mean" of a mistyped name."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.launch.test_own_node import run_phase_filter
from vibrissa.cli.launch import main as launch_main
from vibrissa.launch.description import (
    LaunchDescription,
    LaunchFileError,
    check_node_params,
    load_launch_file,
    node_params,
    resolve_launch_file,
)
from vibrissa.nodes.wrench_source import WrenchSourceParams
from vibrissa.runtime.params import ParamError, check_params

LAUNCH = Path(__file__).parents[2] / "launch"
EXAMPLES = Path(__file__).parents[2] / "docs" / "examples"

MY_ROBOT = """\
launch:
  - arg: {name: out, default: out/mine}
  - include:
      file: robot.yaml
      arg:
        - {name: pose_delay, value: "0.05"}
        - {name: rate, value: "$(var out)"}
  - node:
      cmd: ["$(python)", "$(dirname)/counter.py"]
      name: contact_counter
      namespace: /robot
      ready_before: [reconstructor]
"""


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text)
    return path


def spec(description: LaunchDescription, name: str) -> Any:
    return next(n for n in description.nodes if n.name == name)


def params(description: LaunchDescription, name: str) -> dict[str, Any]:
    return {p.name: p.value for p in spec(description, name).params}


def one_line_error(path: Path, overrides: dict[str, str] | None = None) -> str:
    with pytest.raises(LaunchFileError) as error:
        load_launch_file(path, overrides)
    text = str(error.value)
    assert "\n" not in text
    return text


def test_an_included_file_takes_its_arguments_and_a_node_is_added_next_to_it(
        tmp_path: Path) -> None:
    path = write(tmp_path, "my_robot.yaml", MY_ROBOT.replace('"$(var out)"', '"20"'))
    mine = load_launch_file(path, {"out": str(tmp_path / "o"), "noise_force": "0.01",
                                   "noise_moment": "0.001"})
    alone = load_launch_file(LAUNCH / "robot.yaml", {"out": str(tmp_path / "o")})
    # robot.yaml's nodes as they are, then the added one
    assert [n.name for n in mine.nodes] == [*(n.name for n in alone.nodes), "contact_counter"]
    # the include's arg, then the including file's own argument (out), then the command line
    # (an argument only robot.yaml declares), then robot.yaml's defaults
    source = params(mine, "wrench_source")
    assert source["pose_delay_s"] == 0.05 and source["rate_hz"] == 20
    assert source["noise_force_n"] == 0.01 and source["pose_rate_hz"] == 0
    assert params(mine, "mapper")["out_dir"] == str(tmp_path / "o")
    assert mine.arg_values["pose_delay"] == "0.05" and mine.arg_values["out"] == str(tmp_path / "o")
    assert [a.name for a in mine.args] == ["out", *(a.name for a in alone.args if a.name != "out")]
    # the reconstructor waits for the added node too; nothing else changes
    assert params(alone, "reconstructor")["wait_for"] == ["/mapper"]
    assert params(mine, "reconstructor")["wait_for"] == ["/mapper", "/robot/contact_counter"]
    for node in alone.nodes:
        if node.name not in ("reconstructor", "wrench_source"):
            assert spec(mine, node.name) == node
    check_node_params(mine)
    # $(dirname) inside the included file is its own folder
    assert params(mine, "mapper")["scene"] == str(LAUNCH / "robot" / "scene.yaml")


def test_ready_before_adds_a_wait_for_to_a_node_without_one(tmp_path: Path) -> None:
    path = write(tmp_path, "mine.yaml", """\
launch:
  - include: {file: demo.yaml}
  - node: {cmd: [x], name: logger, ready_before: [/mapper, /whisker0/reconstructor]}
  - node: {cmd: [y], name: other, namespace: /n, ready_before: [mapper]}
""")
    mine = load_launch_file(path)
    assert params(mine, "mapper")["wait_for"] == ["/logger", "/n/other"]
    assert params(mine, "reconstructor")["wait_for"] == ["/mapper", "/logger"]
    assert mine.nodes[-1].params == ()


def test_an_include_left_out_by_its_condition_is_not_read(tmp_path: Path) -> None:
    path = write(tmp_path, "mine.yaml", """\
launch:
  - arg: {name: with_demo, default: "false"}
  - include: {file: missing.yaml, if: "$(var with_demo)"}
  - node: {cmd: [x], name: alone}
""")
    assert [n.name for n in load_launch_file(path).nodes] == ["alone"]
    assert "missing.yaml" in one_line_error(path, {"with_demo": "true"})


def test_a_missing_included_file_is_one_line_naming_the_entry(tmp_path: Path) -> None:
    path = write(tmp_path, "mine.yaml", "launch:\n  - include: {file: robott.yaml}\n")
    text = one_line_error(path)
    assert text.startswith(f"{path}: launch[0].include.file: no launch file ")
    assert str(tmp_path / "robott.yaml") in text


def test_an_include_cycle_is_one_line_naming_the_chain(tmp_path: Path) -> None:
    write(tmp_path, "a.yaml", "launch:\n  - include: {file: b.yaml}\n"
          "  - node: {cmd: [x], name: a}\n")
    write(tmp_path, "b.yaml", "launch:\n  - include: {file: a.yaml}\n")
    text = one_line_error(tmp_path / "a.yaml")
    assert "launch[0].include.file: include cycle: a.yaml -> b.yaml -> a.yaml" in text
    assert f"(included by {tmp_path / 'a.yaml'}: launch[0].include)" in text
    itself = write(tmp_path, "self.yaml", "launch:\n  - include: {file: self.yaml}\n")
    assert "include cycle: self.yaml -> self.yaml" in one_line_error(itself)


def test_an_unknown_argument_to_an_include_suggests_the_right_one(tmp_path: Path) -> None:
    path = write(tmp_path, "mine.yaml",
                 "launch:\n  - include: {file: robot.yaml, arg: [{name: pose_dely, value: 1}]}\n")
    text = one_line_error(path)
    assert text.startswith(f"{path}: launch[0].include.arg: robot.yaml has no argument "
                           "'pose_dely': did you mean 'pose_delay'? (its arguments: ")


def test_errors_inside_an_included_file_name_it_and_the_include(tmp_path: Path) -> None:
    write(tmp_path, "inner.yaml", "launch:\n  - node: {cmd: [x], name: a, respawn: maybe}\n")
    path = write(tmp_path, "outer.yaml", "launch:\n  - include: {file: inner.yaml}\n")
    assert one_line_error(path) == (
        f"{tmp_path / 'inner.yaml'}: launch[0].node.respawn: expected bool, got 'maybe' "
        f"(included by {path}: launch[0].include)")


def test_two_files_of_a_launch_share_node_names_and_one_transport(tmp_path: Path) -> None:
    write(tmp_path, "inner.yaml", "launch:\n  - transport: {domain: 3}\n"
          "  - node: {cmd: [x], name: a}\n")
    twice = write(tmp_path, "twice.yaml", "launch:\n  - include: {file: inner.yaml}\n"
                  "  - node: {cmd: [y], name: a}\n")
    assert "duplicate node name 'a'" in one_line_error(twice)
    two = write(tmp_path, "two.yaml", "launch:\n  - transport: {domain: 4}\n"
                "  - include: {file: inner.yaml}\n")
    assert "only one transport entry is allowed" in one_line_error(two)
    one = load_launch_file(write(tmp_path, "one.yaml", "launch:\n  - include: {file: inner.yaml}\n"))
    assert one.transport is not None and one.transport.domain == 3


@pytest.mark.parametrize(("entry", "message"), [
    ("{cmd: [x], name: a, ready_before: [mappr]}",
     "launch[1].node.ready_before[0]: no node 'mappr' in the launch: did you mean 'mapper'?"),
    ("{cmd: [x], name: a, ready_before: [wrench_source]}", None),
    ("{cmd: [x], name: a, ready_before: wrench_source}",
     "launch[1].node.ready_before: expected a list"),
])
def test_ready_before_errors(tmp_path: Path, entry: str, message: str | None) -> None:
    path = write(tmp_path, "mine.yaml", f"launch:\n  - include: {{file: demo.yaml}}\n"
                 f"  - node: {entry}\n")
    if message is None:
        assert params(load_launch_file(path), "wrench_source")["wait_for"] == [
            "reconstructor", "/a"]
    else:
        assert message in one_line_error(path)
    recorder = write(tmp_path, "rec.yaml", "launch:\n  - node: {exec: recorder}\n"
                     "  - node: {cmd: [x], name: a, ready_before: [recorder]}\n")
    assert "node 'recorder' (recorder) has no 'wait_for' parameter" in one_line_error(recorder)


def test_a_mistyped_name_suggests_the_right_one(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    robot = LAUNCH / "robot.yaml"
    assert "unknown launch argument 'pose_dely': did you mean 'pose_delay'? (known: out," in (
        one_line_error(robot, {"pose_dely": "0.1"}))
    # on the command line: one line, exit 2
    assert launch_main([str(robot), "pose_dely:=0.1", "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "did you mean 'pose_delay'?" in err
    # a key of an entry, an entry, an argument in $(var ...), a node's parameter
    key = write(tmp_path, "key.yaml", "launch:\n  - node: {cmd: [x], name: a, respwn: true}\n")
    assert "launch[0].node.respwn: unknown key: did you mean 'respawn'? (allowed:" in (
        one_line_error(key))
    entry = write(tmp_path, "entry.yaml", "launch:\n  - includ: {file: demo.yaml}\n")
    assert "unknown entry: did you mean 'include'?" in one_line_error(entry)
    var = write(tmp_path, "var.yaml", "launch:\n  - arg: {name: mu, default: '1'}\n"
                "  - node: {cmd: [x], name: a, args: '$(var muu)'}\n")
    assert "$(var muu): did you mean 'mu'?" in one_line_error(var)
    with pytest.raises(ParamError, match=r"unknown parameter 'stp' for WrenchSourceParams: "
                                         r"did you mean 'step'\? \(known:"):
        check_params(WrenchSourceParams, {"stp": 0.1}, "demo.yaml: node 'wrench_source'")
    far = write(tmp_path, "far.yaml", "launch:\n  - node: {cmd: [x], name: a, zzz: 1}\n")
    assert "unknown key (allowed:" in one_line_error(far)


def test_an_include_resolves_from_the_including_files_folder_then_the_package(
        tmp_path: Path) -> None:
    packaged = Path(resolve_launch_file("demo.yaml", str(tmp_path)))
    assert packaged.read_text() == (LAUNCH / "demo.yaml").read_text()
    write(tmp_path, "demo.yaml", "launch:\n  - node: {cmd: [x], name: local}\n")
    assert resolve_launch_file("demo.yaml", str(tmp_path)) == str(tmp_path / "demo.yaml")
    path = write(tmp_path, "mine.yaml", "launch:\n  - include: {file: demo.yaml}\n")
    assert [n.name for n in load_launch_file(path).nodes] == ["local"]


# -- the demo's array from the command line ------------------------------------------------


def test_the_demos_array_is_shaped_by_launch_arguments() -> None:
    default = load_launch_file(LAUNCH / "demo.yaml")
    assert node_params(spec(default, "wrench_source"))["y0"] == [-0.4, -0.2, 0.0, 0.2, 0.4]
    assert node_params(spec(default, "wrench_source"))["whisker_ids"] == []
    shaped = load_launch_file(LAUNCH / "demo.yaml", {
        "array": "true", "y0": "[-0.3, 0, 0.25]", "whisker_ids": "[left, mid, right]"})
    check_node_params(shaped)
    source = node_params(spec(shaped, "wrench_source"))
    assert source["y0"] == [-0.3, 0, 0.25] and source["whisker_ids"] == ["left", "mid", "right"]
    with pytest.raises(LaunchFileError, match=r"'whisker_ids' must be one name per y0 \(3\)"):
        check_node_params(load_launch_file(LAUNCH / "demo.yaml", {
            "y0": "[-0.3, 0, 0.25]", "whisker_ids": "[left, right]"}))
    with pytest.raises(LaunchFileError, match=r"launch\[\d+\]\.node\.param\[2\]\.value: expected "
                                              r"a list of scalars like \[1, 2\], got '\[-0.3, \[0\]\]'"):
        load_launch_file(LAUNCH / "demo.yaml", {"y0": "[-0.3, [0]]"})


def test_the_demos_array_arguments_reach_the_messages(tmp_path: Path) -> None:
    """A real launch of the demo shaped from the command line: three named whiskers, one
    WhiskerWrenchArray per step with their rows, and the map made of them."""
    tap = write(tmp_path, "tap.py", TAP)
    path = write(tmp_path, "shaped.yaml", f"""\
launch:
  - include: {{file: demo.yaml}}
  - node:
      cmd: ["$(python)", "{tap}"]
      name: tap
      namespace: /whisker0
      finite: true
      ready_before: [wrench_source]
""")
    result = subprocess.run(
        [sys.executable, "-m", "vibrissa.cli.main", "launch", str(path), f"out:={tmp_path / 'o'}",
         "step:=0.01", "array:=true", "y0:=[-0.3, 0.0, 0.3]", "whisker_ids:=[left, mid, right]"],
        capture_output=True, text=True, timeout=600)
    text = result.stdout + result.stderr
    assert result.returncode == 0, text
    match = re.search(r"\[tap\] .*ids (\S+) messages (\d+)", text)
    assert match, text
    assert match.group(1) == "left,mid,right"
    # the source ends by itself, or, when the mapper's end shuts the launch down first (a
    # loaded machine), is stopped by the launcher after it sent everything: exit 0 either way
    published = re.search(r"^\S*\s*wrench_source\s+(?:stopped by launcher \()?exit 0\)? .*"
                          r"published (\d+)", text, flags=re.M)
    assert published, text
    assert int(match.group(2)) == int(published.group(1)) > 0  # every array, the first included


TAP = '''\
"""Counts the wrench arrays of the demo's source and the whisker names in them."""
import logging
from vibrissa.msgs import EndOfStream, WhiskerWrenchArray
from vibrissa.runtime import Node, NodeArgs, configure_logging, run_main

def main(argv=None):
    args = NodeArgs.parse(argv, prog="tap")
    configure_logging()
    ids, count = set(), 0
    with Node.from_args(args) as node:
        wrenches = node.create_subscriber({"wrench": WhiskerWrenchArray})
        node.set_state("running")
        while not node.stop_requested:
            rx = wrenches.receive(0.1)
            if rx is None:
                continue
            if isinstance(rx.msg, EndOfStream):
                break
            ids.update(rx.msg.whisker_ids)
            count += 1
    logging.getLogger("tap").info("ids %s messages %d", ",".join(sorted(ids)), count)
    return 0

if __name__ == "__main__":
    run_main(main)
'''


# -- a node of one's own next to the demo, from an include, with real processes -------------


def test_the_added_node_hears_every_message_of_the_included_graph(tmp_path: Path) -> None:
    """docs/examples/demo_plus_filter.yaml: demo.yaml included as it is, the example node of
    docs/WRITING_NODES.md added with ``ready_before: [reconstructor]``; it receives every
    contact message the reconstructor publishes, the first ones included."""
    text, _, _ = run_phase_filter(EXAMPLES / "demo_plus_filter.yaml", tmp_path / "map", 0.004)
    published = re.search(r"^\S*\s*reconstructor\s+.*published (\d+)", text, flags=re.M)
    received = re.search(r"^\S*\s*phase_filter\s+exit 0 .*received (\d+)(.*)$", text, flags=re.M)
    assert published and received, text
    # every message the reconstructor sent, and its end; nothing lost
    assert int(received.group(1)) == int(published.group(1)) + 1
    assert "lost" not in received.group(2) and "rejected" not in received.group(2)
