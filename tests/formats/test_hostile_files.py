"""Input files that are not what they claim: a device, a pipe, a file without newlines, a file
of secrets. Each is refused at once naming the file (and the scene's key), never read without
end and never quoted into the error."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from vibrissa.formats.csv_text import MAX_LINE_CHARS
from vibrissa.formats.errors import SceneError
from vibrissa.formats.scene_file import load_path, load_scene

SCENE = """\
mu: 0.25
whiskers:
  - {name: w0, length_m: 0.05, ei_nm2: 2.0e-5, mount: {position_m: [0.0, 0.0, 0.0]}}
path: {path}
"""
SECRET = "root:$6$SECRETSALT$hashhashhash:19000:0:99999:7:::"


def simulate(scene: Path, out: Path, timeout_s: float = 120.0) -> subprocess.CompletedProcess[str]:
    """``vibrissa simulate`` as a process: a read without end fails the test by its deadline
    (generous: the process only imports the package and reads the files)."""
    code = "import sys; from vibrissa.cli.main import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, "simulate", str(scene), "-o", str(out)],
                          capture_output=True, text=True, timeout=timeout_s, check=False)


def test_a_path_on_a_device_is_refused_naming_the_scene_and_key(tmp_path: Path) -> None:
    (tmp_path / "scene.yaml").write_text(SCENE.replace("{path}", "/dev/zero"))
    done = simulate(tmp_path / "scene.yaml", tmp_path / "out")
    assert done.returncode == 2, done.stderr
    assert "scene.yaml: path: /dev/zero: not a regular file" in done.stderr
    assert done.stderr.count("\n") == 1, done.stderr


def test_a_scene_file_on_a_device_is_refused() -> None:
    with pytest.raises(SceneError, match="/dev/zero: not a regular file"):
        load_scene("/dev/zero")


def test_a_pipe_is_refused_without_waiting_for_a_writer(tmp_path: Path) -> None:
    fifo = tmp_path / "path.csv"
    os.mkfifo(fifo)
    (tmp_path / "scene.yaml").write_text(SCENE.replace("{path}", "path.csv"))
    done = simulate(tmp_path / "scene.yaml", tmp_path / "out")
    assert done.returncode == 2 and "path.csv: not a regular file" in done.stderr, done.stderr


def test_a_line_longer_than_any_csv_line_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "path.csv"
    path.write_text("t,x,y,z,qx,qy,qz,qw\n" + "0" * (2 * MAX_LINE_CHARS))
    with pytest.raises(SceneError, match=f"line 2: longer than {MAX_LINE_CHARS} characters"):
        load_path(path)


@pytest.mark.parametrize("body", [
    SECRET + "\n",                                     # not the header
    "t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n" + SECRET + "\n",  # a row of 1 cell
    "t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.1," + ",".join([SECRET] * 7) + "\n",  # not numbers
])
def test_an_error_never_quotes_the_file(tmp_path: Path, body: str) -> None:
    (tmp_path / "secret.csv").write_text(body)
    (tmp_path / "scene.yaml").write_text(SCENE.replace("{path}", "secret.csv"))
    done = simulate(tmp_path / "scene.yaml", tmp_path / "out")
    assert done.returncode == 2 and "scene.yaml: path: secret.csv" in done.stderr, done.stderr
    assert "SECRET" not in done.stderr and "root" not in done.stderr, done.stderr


def test_a_header_of_the_columns_in_another_order_is_shown_as_read(tmp_path: Path) -> None:
    """Every column there, in another order: the error shows that order (only the column
    names can be in it), not a count of cells."""
    path = tmp_path / "path.csv"
    path.write_text("x,t,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0,1,0,0,0,0,0,1\n")
    with pytest.raises(SceneError, match="header must be t,x,y,z,qx,qy,qz,qw, got "
                                         "x,t,y,z,qx,qy,qz,qw$"):
        load_path(path)


def test_a_missing_path_names_the_scene_file_and_key(tmp_path: Path) -> None:
    (tmp_path / "scene.yaml").write_text(SCENE.replace("{path}", "nopath.csv"))
    with pytest.raises(SceneError, match=r"scene.yaml: path: .*nopath.csv: cannot read \(No such file"):
        load_scene(tmp_path / "scene.yaml")


def test_a_launch_file_on_a_device_or_a_pipe_is_refused(tmp_path: Path) -> None:
    from vibrissa.launch.description import LaunchFileError, load_launch_file

    fifo = tmp_path / "graph.yaml"
    os.mkfifo(fifo)
    for path in ("/dev/zero", str(fifo)):
        with pytest.raises(LaunchFileError, match="not a regular file"):
            load_launch_file(path)
