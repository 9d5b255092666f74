"""Launch file parsing and validation: every error names the file and the key path."""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import pytest

from vibrissa.launch.description import (
    LaunchFileError,
    NodeSpec,
    Param,
    Remap,
    TransportSpec,
    load_launch_file,
    node_params,
    parse_arg_overrides,
)

DEMO = """\
launch:
  - arg: {name: mu, default: "0.2", description: "friction coefficient"}
  - arg: {name: out, default: "out/demo"}
  - arg: {name: out_file, default: "$(var out)/map.npz"}
  - node:
      pkg: vibrissa
      exec: reconstructor
      name: reconstructor
      namespace: /whisker0
      param:
        - {name: mu, value: "$(var mu)"}
        - {name: output, value: "$(var out_file)"}
        - {name: gains, value: [1, 2.5, "$(var mu)"]}
        - {name: label, value: plain}
      remap:
        - {from: wrench, to: /whisker0/wrench}
      env:
        - {name: FOO, value: bar}
        - {name: HOME_SEEN, value: "$(env VIBRISSA_TEST_HOME)"}
        - {name: MISSING, value: "$(env VIBRISSA_TEST_UNSET fallback value)"}
      respawn: true
      respawn_delay: 0.2
      respawn_max: 5
      required: true
  - node:
      cmd: [python3, "$(dirname)/fixture.py"]
      name: mapper
      args: "--extra 1"
      on_exit: shutdown
"""

ENV = {"VIBRISSA_TEST_HOME": "/home/x"}


def write(tmp_path: Path, text: str, name: str = "demo.yaml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def error_of(tmp_path: Path, text: str, overrides: dict[str, str] | None = None) -> str:
    path = write(tmp_path, text)
    with pytest.raises(LaunchFileError) as info:
        load_launch_file(path, overrides, environ=ENV)
    message = str(info.value)
    assert message.startswith(f"{path}: "), message
    return message


def test_full_example_parses(tmp_path: Path) -> None:
    path = write(tmp_path, DEMO)
    desc = load_launch_file(path, environ=ENV)
    assert [a.name for a in desc.args] == ["mu", "out", "out_file"]
    assert desc.args[0].description == "friction coefficient"
    assert dict(desc.arg_values) == {"mu": "0.2", "out": "out/demo", "out_file": "out/demo/map.npz"}
    assert desc.transport is None
    recon, mapper = desc.nodes
    assert recon == NodeSpec(
        name="reconstructor", namespace="/whisker0", pkg="vibrissa", executable="reconstructor",
        params=(Param("mu", 0.2, "0.2"), Param("output", "out/demo/map.npz", "out/demo/map.npz"),
                Param("gains", [1, 2.5, 0.2]), Param("label", "plain")),
        remaps=(Remap("wrench", "/whisker0/wrench"),),
        env=(("FOO", "bar"), ("HOME_SEEN", "/home/x"), ("MISSING", "fallback value")),
        respawn=True, respawn_delay=0.2, respawn_max=5, required=True,
    )
    assert recon.fqn == "/whisker0/reconstructor"
    assert mapper.cmd == ("python3", f"{tmp_path.resolve()}/fixture.py")
    assert mapper.executable is None
    assert mapper.args == ("--extra", "1")
    assert mapper.on_exit == "shutdown"
    assert mapper.namespace == "/" and mapper.fqn == "/mapper"


def test_dataclasses_are_frozen(tmp_path: Path) -> None:
    desc = load_launch_file(write(tmp_path, DEMO), environ=ENV)
    with pytest.raises(AttributeError):
        desc.nodes[0].name = "x"  # type: ignore[misc]


def test_arg_override_changes_values_and_types(tmp_path: Path) -> None:
    desc = load_launch_file(write(tmp_path, DEMO), {"mu": "0.35", "out": "elsewhere"},
                            environ=ENV)
    params = node_params(desc.nodes[0])
    assert params["mu"] == 0.35
    assert params["output"] == "elsewhere/map.npz"  # a later default sees the override


def test_unknown_override_lists_known_arguments(tmp_path: Path) -> None:
    message = error_of(tmp_path, DEMO, {"nu": "1"})
    assert "unknown launch argument 'nu'" in message
    assert "known: mu, out, out_file" in message


def test_parse_arg_overrides() -> None:
    assert parse_arg_overrides(["a:=1", "b:=x:=y", "c:="]) == {"a": "1", "b": "x:=y", "c": ""}
    with pytest.raises(LaunchFileError, match="bad argument 'a=1': expected NAME:=VALUE"):
        parse_arg_overrides(["a=1"])
    with pytest.raises(LaunchFileError, match=r"argument 'a' given twice \(a:=1, a:=2\)"):
        parse_arg_overrides(["a:=1", "b:=x", "a:=2"])


def test_arg_override_home_is_expanded_as_a_shell_would(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HOME", "/home/robot")
    assert parse_arg_overrides(["out:=~/runs/a", "h:=~", "u:=~nobody9/x", "t:=a~/b"]) == {
        "out": "/home/robot/runs/a", "h": "/home/robot", "u": "~nobody9/x", "t": "a~/b"}


def test_argument_without_default_must_be_given(tmp_path: Path) -> None:
    text = """\
    launch:
      - arg: {name: run}
      - node: {cmd: [echo, "$(var run)"], name: e}
    """
    message = error_of(tmp_path, text)
    assert "launch[0].arg: argument 'run' has no default" in message
    desc = load_launch_file(write(tmp_path, text), {"run": "r1"})
    assert desc.nodes[0].cmd == ("echo", "r1")


def test_transport_entries(tmp_path: Path) -> None:
    node = "  - node: {cmd: [x], name: n}\n"
    desc = load_launch_file(write(tmp_path, "launch:\n  - transport: {domain: 3}\n" + node))
    assert desc.transport == TransportSpec(domain=3)
    desc = load_launch_file(write(tmp_path, (
        "launch:\n  - transport: {pub_endpoint: 'tcp://127.0.0.1:9000', "
        "sub_endpoint: 'tcp://127.0.0.1:9001'}\n" + node)))
    assert desc.transport == TransportSpec(None, "tcp://127.0.0.1:9000", "tcp://127.0.0.1:9001")
    desc = load_launch_file(write(tmp_path, (
        "launch:\n  - transport: {keys: '$(dirname)/keys', max_message_bytes: 4096}\n" + node)))
    assert desc.transport == TransportSpec(keys=f"{tmp_path}/keys", max_message_bytes=4096)
    assert TransportSpec().max_message_bytes == 64 << 20
    desc = load_launch_file(write(tmp_path, (
        "launch:\n  - transport: {max_buffered_bytes: 2097152}\n" + node)))
    assert desc.transport == TransportSpec(max_buffered_bytes=2 << 20)
    assert TransportSpec().max_buffered_bytes is None  # each subscriber's default


def test_substituted_bool_is_retyped(tmp_path: Path) -> None:
    text = """\
    launch:
      - arg: {name: again, default: "true"}
      - node: {cmd: [x], name: n, respawn: "$(var again)", respawn_max: "$(var n)"}
      - arg: {name: n, default: 3}
    """
    node = load_launch_file(write(tmp_path, text)).nodes[0]
    assert node.respawn is True and node.respawn_max == 3


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        # wrong types
        ("  - node: {cmd: [x], name: n, respawn: yes}\n",
         "launch[0].node.respawn: expected bool, got 'yes'"),
        ("  - node: {cmd: [x], name: n, required: 1}\n",
         "launch[0].node.required: expected bool, got 1"),
        ("  - node: {cmd: [x], name: n, respawn: true, respawn_delay: soon}\n",
         "launch[0].node.respawn_delay: expected a number, got 'soon'"),
        ("  - node: {cmd: [x], name: n, respawn: true, respawn_delay: -1}\n",
         "launch[0].node.respawn_delay: expected a finite number >= 0, got -1"),
        ("  - node: {cmd: [x], name: n, respawn: true, respawn_delay: 1" + "0" * 400 + "}\n",
         "launch[0].node.respawn_delay: expected a finite number >= 0, got 1000"),
        ("  - node: {cmd: [x], name: n, respawn: true, respawn_max: 1.5}\n",
         "launch[0].node.respawn_max: expected int, got 1.5"),
        ("  - node: {cmd: x, name: n}\n", "launch[0].node.cmd: expected a list, got 'x'"),
        ("  - node: {cmd: [], name: n}\n", "launch[0].node.cmd: expected a non-empty list"),
        ("  - node: {cmd: [[a]], name: n}\n", "launch[0].node.cmd[0]: expected str, got ['a']"),
        ("  - node: {cmd: [x], name: n, param: {mu: 1}}\n",
         "launch[0].node.param: expected a list, got {'mu': 1}"),
        ("  - node: {cmd: [x], name: n, param: [{name: mu}]}\n",
         "launch[0].node.param[0].value: missing required key"),
        ("  - node: {cmd: [x], name: n, param: [{name: a, value: 1}, {name: a, value: 2}]}\n",
         "launch[0].node.param[1].name: duplicate parameter 'a'"),
        ("  - node: {cmd: [x], name: n, remap: [{from: a}]}\n",
         "launch[0].node.remap[0].to: missing required key"),
        ("  - node: {cmd: [x], name: n, remap: [{from: a, to: 'b c'}]}\n",
         "launch[0].node.remap[0].to: invalid topic name 'b c'"),
        ("  - node: {cmd: [x], name: n, env: [{name: 1, value: x}]}\n",
         "launch[0].node.env[0].name: expected str, got 1"),
        ("  - node: {cmd: [x], name: n, env: [{name: A-B, value: x}]}\n",
         "launch[0].node.env[0].name: invalid environment variable 'A-B'"),
        ("  - node: {cmd: [x], name: n, on_exit: restart}\n",
         "launch[0].node.on_exit: expected one of shutdown, got 'restart'"),
        ("  - node: {cmd: [x], name: n, namespace: '/a b'}\n",
         "launch[0].node.namespace: invalid namespace '/a b'"),
        ("  - node: {cmd: [x], name: a/b}\n", "launch[0].node.name: invalid node name 'a/b'"),
        # unknown and missing keys
        ("  - node: {cmd: [x], name: n, respwan: true}\n",
         "launch[0].node.respwan: unknown key: did you mean 'respawn'? (allowed: pkg, exec, cmd"),
        ("  - node: {cmd: [x], name: n, param: [{name: a, value: 1, type: int}]}\n",
         "launch[0].node.param[0].type: unknown key (allowed: name, value)"),
        ("  - node: {cmd: [x]}\n",
         "launch[0].node.name: missing required key (needed with 'cmd')"),
        ("  - node: {name: n}\n",
         "launch[0].node: expected exactly one of 'exec' (with optional 'pkg') or 'cmd'"),
        ("  - node: {exec: talker, cmd: [x]}\n",
         "launch[0].node: expected exactly one of 'exec'"),
        ("  - node: {cmd: [x], pkg: vibrissa, name: n}\n",
         "launch[0].node.pkg: not allowed together with 'cmd'"),
        ("  - node: {cmd: [x], name: n, respawn_delay: 1}\n",
         "launch[0].node.respawn_delay: has no effect without 'respawn: true'"),
        ("  - nodes: {cmd: [x]}\n",
         "launch[0].nodes: unknown entry: did you mean 'node'? (allowed: arg, include, node, "
         "transport)"),
        ("  - arg: {name: a, value: 1}\n  - node: {cmd: [x], name: n}\n",
         "launch[0].arg.value: unknown key (allowed: name, default, description)"),
        ("  - arg: {default: 1}\n  - node: {cmd: [x], name: n}\n",
         "launch[0].arg.name: missing required key"),
        ("  - node: {cmd: [x], name: n}\n  - node: {cmd: [y], name: n}\n",
         "launch[1].node.name: duplicate node name 'n'"),
        ("  - arg: {name: a, default: 1}\n  - arg: {name: a, default: 2}\n"
         "  - node: {cmd: [x], name: n}\n", "launch[1].arg.name: duplicate argument 'a'"),
        ("  - node: {cmd: [x], name: n}\n    extra: 1\n",
         "launch[0]: expected a mapping with one key (arg, include, node, transport)"),
        # substitutions
        ("  - node: {cmd: [x, '$(var nope)'], name: n}\n",
         "launch[0].node.cmd[1]: unknown launch argument in $(var nope) (known: none)"),
        ("  - node: {cmd: [x], name: n, param: [{name: a, value: {k: ['$(var nope)']}}]}\n",
         "launch[0].node.param[0].value.k[0]: unknown launch argument in $(var nope)"),
        ("  - node: {cmd: [x, '$(env VIBRISSA_TEST_UNSET)'], name: n}\n",
         "launch[0].node.cmd[1]: environment variable 'VIBRISSA_TEST_UNSET' is not set"),
        ("  - node: {cmd: [x, '$(find pkg)'], name: n}\n",
         "launch[0].node.cmd[1]: bad substitution '$(find pkg)'"),
        ("  - node: {cmd: [x, '$(var a'], name: n}\n",
         "launch[0].node.cmd[1]: unterminated substitution"),
        # transport
        ("  - transport: {domain: -1}\n  - node: {cmd: [x], name: n}\n",
         "launch[0].transport.domain: expected an int in [0, 29067], got -1"),
        ("  - transport: {domain: 1, pub_endpoint: 'tcp://a:1'}\n  - node: {cmd: [x], name: n}\n",
         "launch[0].transport: give either domain or pub_endpoint/sub_endpoint, not both"),
        ("  - transport: {pub_endpoint: 'tcp://a:1'}\n  - node: {cmd: [x], name: n}\n",
         "launch[0].transport.sub_endpoint: missing"),
        ("  - transport: {pub_endpoint: a, sub_endpoint: b}\n  - node: {cmd: [x], name: n}\n",
         "launch[0].transport.pub_endpoint: expected a ZeroMQ endpoint"),
        ("  - transport: {max_message_bytes: 100}\n  - node: {cmd: [x], name: n}\n",
         "launch[0].transport.max_message_bytes: expected an int >= 1024, got 100"),
        ("  - transport: {max_buffered_bytes: 1000}\n  - node: {cmd: [x], name: n}\n",
         "launch[0].transport.max_buffered_bytes: expected an int >= 1048576, got 1000"),
        ("  - transport: {keys: [a]}\n  - node: {cmd: [x], name: n}\n",
         "launch[0].transport.keys: expected str"),
        ("  - transport: {}\n  - transport: {}\n  - node: {cmd: [x], name: n}\n",
         "launch[1].transport: only one transport entry is allowed"),
    ],
)
def test_validation_errors_name_file_and_key(tmp_path: Path, body: str, expected: str) -> None:
    message = error_of(tmp_path, "launch:\n" + body)
    assert expected in message, message


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", ": empty file"),
        ("[1, 2]\n", ": expected a mapping, got [1, 2]"),
        ("launch: {}\n", ": launch: expected a list, got {}"),
        ("launch: []\n", ": launch: no node entries"),
        ("nodes: []\n", ": .nodes: unknown key (allowed: launch)"),
        ("launch:\n  - node: {cmd: [x], name: n, name: m}\n", "line 2, column 31: duplicate key"),
        ("launch: [\n", ": line 2, column 1:"),
    ],
)
def test_whole_file_errors(tmp_path: Path, text: str, expected: str) -> None:
    message = error_of(tmp_path, text)
    assert expected in message, message


def test_unreadable_file_is_named(tmp_path: Path) -> None:
    missing = tmp_path / "nope.yaml"
    with pytest.raises(LaunchFileError, match=re.escape(f"{missing}: cannot read")):
        load_launch_file(missing)


@pytest.mark.parametrize(("key", "value", "words"), [
    ("remap", "[{from: ~wrench, to: /w}]", "private names '~' are not supported"),
    ("remap", "[{from: wrench, to: 'a//b'}]", "token ''"),
    ("namespace", "/bad-ns", "invalid namespace"),
    ("name", "two.tokens", "invalid node name"),
])
def test_names_follow_the_wire_rules(tmp_path: Path, key: str, value: str, words: str) -> None:
    # The launch file checks names with the same rules the node applies at start, so a name
    # the node would refuse (exit 2 at start) is refused before anything starts.
    message = error_of(tmp_path, f"launch:\n  - node: {{exec: reconstructor, {key}: {value}}}\n")
    assert f"launch[0].node.{key}" in message and words in message, message


def test_an_unknown_node_is_refused_before_anything_starts(tmp_path: Path) -> None:
    message = error_of(tmp_path, "launch:\n  - node: {pkg: vibrissa, exec: reconstuctor}\n")
    assert "launch[0].node.exec: package 'vibrissa' has no node 'reconstuctor'" in message
    assert ("known: explorer, foxglove_bridge, localizer, mapper, netft, netft_sim, "
            "reconstructor, recorder, wrench_source") in message
    message = error_of(tmp_path, "launch:\n  - node: {pkg: nopkg, exec: reconstructor}\n")
    assert "no installed package 'nopkg' registers nodes" in message


def alias_bomb(levels: int) -> str:
    """A YAML document whose aliases expand to 10**levels leaves in a few hundred bytes."""
    lines = ['l0: &l0 ["x","x","x","x","x","x","x","x","x","x"]']
    for i in range(1, levels):
        lines.append(f"l{i}: &l{i} [{','.join([f'*l{i - 1}'] * 10)}]")
    return "\n".join(lines) + f"\nlaunch: [*l{levels - 1}]\n"


@pytest.mark.parametrize("text", [alias_bomb(5), "launch: &x [*x]\n",
                                  "launch:\n  - arg: &a {name: a}\n  - arg: *a\n"])
def test_aliases_are_refused_where_they_stand(tmp_path: Path, text: str) -> None:
    path = tmp_path / "alias.yaml"
    path.write_text(text)
    with pytest.raises(LaunchFileError, match=r"alias\.yaml.*line \d+, column \d+: aliases "
                                              r"\(\*\w+\) are not allowed"):
        load_launch_file(path)


def test_a_file_that_is_not_utf8_names_the_place(tmp_path: Path) -> None:
    path = tmp_path / "latin1.yaml"
    path.write_bytes('launch:\n  - arg: {name: a, default: "caf\xe9"}\n'.encode("latin-1"))
    with pytest.raises(LaunchFileError, match=r"latin1.yaml: line 2, column 33: not UTF-8 text "
                                              r"\(byte 0xe9\)"):
        load_launch_file(path)


def test_conditions_leave_nodes_out_and_substitutions_nest(tmp_path: Path) -> None:
    text = """\
    launch:
      - arg: {name: mode, default: scene}
      - node: {cmd: [rec], name: recorder, unless: "$(equals $(var mode) replay)"}
      - node: {cmd: [sim, "$(var mode)"], name: source, if: "$(not-equals $(var mode) replay)"}
      - node: {cmd: [play, "$(env VIBRISSA_TEST_UNSET $(var mode))"], name: source,
               if: "$(equals replay $(var mode))"}
    """
    path = write(tmp_path, text)
    scene = load_launch_file(path)
    assert [(n.name, n.cmd) for n in scene.nodes] == [("recorder", ("rec",)),
                                                      ("source", ("sim", "scene"))]
    replay = load_launch_file(path, {"mode": "replay"})
    assert [(n.name, n.cmd) for n in replay.nodes] == [("source", ("play", "replay"))]
    # a value is not read again as a substitution
    again = load_launch_file(path, {"mode": "$(dirname)"})
    assert [n.cmd for n in again.nodes] == [("rec",), ("sim", "$(dirname)")]


def test_if_chooses_a_value_by_a_condition(tmp_path: Path) -> None:
    path = write(tmp_path, """\
    launch:
      - arg: {name: drift, default: "0"}
      - node: {cmd: [src, "$(if $(equals $(var drift) 0) world odom)"], name: source}
    """)
    assert load_launch_file(path).nodes[0].cmd == ("src", "world")
    assert load_launch_file(path, {"drift": "0.02"}).nodes[0].cmd == ("src", "odom")
    bad = write(tmp_path, """\
    launch:
      - node: {cmd: [src, "$(if maybe a b)"], name: source}
    """)
    with pytest.raises(LaunchFileError, match=r"\$\(if C A B\) needs C true or false, got 'maybe'"):
        load_launch_file(bad)


@pytest.mark.parametrize(
    ("node", "expected"),
    [
        ("{cmd: [x], name: n, if: maybe}", "launch[0].node.if: expected bool, got 'maybe'"),
        ("{cmd: [x], name: n, if: true, unless: false}",
         "launch[0].node: give 'if' or 'unless', not both"),
        ("{cmd: [x], name: n, if: '$(equals a)'}", "bad substitution '$(equals a)'"),
        ("{cmd: [x], name: n, if: '$(equals $(dirname) b'}", "unterminated substitution"),
        # a node left out is still checked
        ("{cmd: [x], name: n, if: false, respawn: 3}",
         "launch[0].node.respawn: expected bool, got 3"),
    ],
)
def test_bad_conditions_are_named(tmp_path: Path, node: str, expected: str) -> None:
    with pytest.raises(LaunchFileError, match=re.escape(expected)):
        load_launch_file(write(tmp_path, f"launch:\n  - node: {node}\n"))
