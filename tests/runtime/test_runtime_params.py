"""Node command line and strict parameter loading."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pytest

from vibrissa.runtime import NodeArgs, load_params


@dataclass(frozen=True)
class Rod:
    length_m: float = 0.1
    ei_nm2: float = 1e-4


@dataclass(frozen=True)
class Params:
    whisker_id: str
    rate_hz: float = 100.0
    count: int = 10
    verbose: bool = False
    label: str | None = None
    gains: tuple[float, ...] = (1.0, 2.0)
    names: list[str] = field(default_factory=list)
    rod: Rod = field(default_factory=Rod)


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "params.yaml"
    path.write_text(text)
    return path


def test_node_args_parse() -> None:
    args = NodeArgs.parse([
        "--name", "reconstruct", "--namespace", "/whisker0", "--params-file", "p.yaml",
        "--param", "rate_hz:=250", "--param", "label:=a:=b", "--remap", "wrench:=/sim/wrench",
    ])
    assert args.name == "reconstruct" and args.namespace == "/whisker0"
    assert args.params_file == Path("p.yaml")
    assert args.params == {"rate_hz": "250", "label": "a:=b"}
    assert args.remaps == {"wrench": "/sim/wrench"}
    assert args.fqn == "/whisker0/reconstruct"
    assert NodeArgs.parse(["--name", "n"]) == NodeArgs("n")


def test_node_args_param_home_is_expanded(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HOME", "/home/robot")
    args = NodeArgs.parse(["--name", "n", "--param", "out_dir:=~/map", "--param", "x:=a~/b"])
    assert args.params == {"out_dir": "/home/robot/map", "x": "a~/b"}


@pytest.mark.parametrize(
    "argv",
    [[], ["--name", "a/b"], ["--name", "n", "--namespace", "rel"], ["--name", "n", "--param", "x"],
     ["--name", "n", "--remap", "a:=b-c"]],
)
def test_node_args_errors_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        NodeArgs.parse(argv)
    assert info.value.code == 2
    assert "error" in capsys.readouterr().err


def test_defaults_file_then_overrides(tmp_path: Path) -> None:
    path = write(tmp_path, "whisker_id: w0\nrate_hz: 200\ngains: [3, 4.5]\nrod: {length_m: 0.2}\n")
    params = load_params(Params, path, {"count": "7", "verbose": "true", "whisker_id": "123"})
    assert params == Params(whisker_id="123", rate_hz=200.0, count=7, verbose=True,
                            gains=(3.0, 4.5), rod=Rod(length_m=0.2))
    assert isinstance(params.rate_hz, float) and isinstance(params.gains, tuple)
    assert load_params(Params, None, {"whisker_id": "w", "label": "null"}).label is None
    assert load_params(Params, None, {"whisker_id": "w", "label": "x"}).label == "x"


def test_unknown_key_names_file_and_key(tmp_path: Path) -> None:
    path = write(tmp_path, "whisker_id: w0\nrate: 200\n")
    with pytest.raises(ValueError, match=r"params\.yaml.*unknown parameter 'rate'"):
        load_params(Params, path)
    path = write(tmp_path, "whisker_id: w0\nrod: {length: 1}\n")
    with pytest.raises(ValueError, match=r"params\.yaml.*unknown parameter 'rod\.length'"):
        load_params(Params, path)
    with pytest.raises(ValueError, match=r"--param: unknown parameter 'nope'"):
        load_params(Params, None, {"whisker_id": "w", "nope": "1"})


@pytest.mark.parametrize(
    ("text", "key", "expected", "actual"),
    [
        ("whisker_id: w0\nrate_hz: fast\n", "rate_hz", "float", "str"),
        ("whisker_id: w0\ncount: 1.5\n", "count", "int", "float"),
        ("whisker_id: w0\ncount: true\n", "count", "int", "bool"),
        ("whisker_id: 5\n", "whisker_id", "str", "int"),
        ("whisker_id: w0\ngains: [1, x]\n", "gains[1]", "float", "str"),
        ("whisker_id: w0\nrod: {ei_nm2: big}\n", "rod.ei_nm2", "float", "str"),
    ],
)
def test_wrong_type_names_key_expected_and_actual(
    tmp_path: Path, text: str, key: str, expected: str, actual: str
) -> None:
    with pytest.raises(ValueError) as info:
        load_params(Params, write(tmp_path, text))
    message = str(info.value)
    assert "params.yaml" in message and f"'{key}'" in message
    assert f"expects {expected}" in message and f"got {actual}" in message


def test_override_type_error_and_missing_required(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"--param: parameter 'count' expects int, got str"):
        load_params(Params, None, {"whisker_id": "w", "count": "many"})
    with pytest.raises(ValueError, match=r"missing required parameter.*whisker_id"):
        load_params(Params, write(tmp_path, "count: 3\n"))
    with pytest.raises(ValueError, match=r"params\.yaml: expected a mapping"):
        load_params(Params, write(tmp_path, "- 1\n- 2\n"))


def test_an_exponent_without_a_decimal_point_is_a_float_in_every_yaml_file(tmp_path) -> None:
    # PyYAML's YAML 1.1 reads "1e-5" as a string; people (and YAML 1.2) mean a number.
    from vibrissa.formats import yaml_numbers
    from vibrissa.formats.scene_file import load_robot

    assert yaml_numbers.load("[1e-5, -2E3, +7e0, 1.5e-3, 1e, e5, 12]") == [
        1e-5, -2000.0, 7.0, 1.5e-3, "1e", "e5", 12]
    robot = tmp_path / "robot.yaml"
    robot.write_text("whiskers:\n  - {name: w0, length_m: 5e-2, ei_nm2: 1e-4, mount: {}}\n")
    (whisker,) = load_robot(robot)
    assert (whisker.length_m, whisker.ei_nm2) == (0.05, 1e-4)
