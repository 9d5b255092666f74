"""A key folder decides who is let in: everything in it must be the user's own and writable by
nobody else, or another local user could put their key there (``authorized/`` made first in
a folder anyone may write). Tested with a real second user where the test runs as root."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from vibrissa.launch.description import LaunchFileError, parse_launch
from vibrissa.wire.security import Keys, KeysError, authorize_keys, create_keys, join_keys

needs_root = pytest.mark.skipif(os.geteuid() != 0 or shutil.which("useradd") is None
                                or shutil.which("runuser") is None,
                                reason="a second local user needs root and useradd/runuser")


@pytest.fixture
def intruder() -> Iterator[str]:
    """A throwaway local user, removed after the test."""
    name = f"vbx{uuid.uuid4().hex[:8]}"
    subprocess.run(["useradd", "--system", "--no-create-home", "--shell", "/bin/sh", name],
                   check=True, capture_output=True)
    try:
        yield name
    finally:
        subprocess.run(["userdel", name], check=False, capture_output=True)


@pytest.fixture
def shared() -> Iterator[Path]:
    """A folder another user can reach (pytest's own temporary folders are private)."""
    folder = Path(tempfile.mkdtemp(prefix="vibrissa-keys-"))
    os.chmod(folder, 0o755)
    try:
        yield folder
    finally:
        shutil.rmtree(folder)


def as_user(user: str, script: str) -> None:
    done = subprocess.run(["runuser", "-u", user, "--", "sh", "-c", script], capture_output=True,
                          text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr


@needs_root
def test_an_authorized_folder_made_by_another_user_is_refused(shared: Path, intruder: str) -> None:
    keys = shared / "keys"
    create_keys(keys)
    os.chmod(keys, 0o777)  # a folder anyone may write: the intruder makes authorized/ first
    theirs = create_keys(shared / "theirs", ("mallory",))[-1]  # authorized/mallory.key
    for path in (shared / "theirs", theirs.parent, theirs):
        os.chmod(path, 0o755)
    as_user(intruder, f"mkdir {keys}/authorized && cp {theirs} {keys}/authorized/")
    assert (keys / "authorized" / "mallory.key").exists()
    with pytest.raises(KeysError, match="may be written by others"):
        Keys.load(keys)  # the folder itself first
    os.chmod(keys, 0o700)
    with pytest.raises(KeysError, match=r"authorized belongs to user id \d+, not to you"):
        Keys.load(keys)
    with pytest.raises(KeysError, match=r"authorized belongs to user id"):
        create_keys(keys, ("laptop",))  # vibrissa keys writes nothing into it
    assert not (keys / "clients" / "laptop").exists()
    done = subprocess.run([sys.executable, "-c", "import sys; from vibrissa.cli.main import main; "
                           "sys.exit(main(sys.argv[1:]))", "keys", str(keys), "--client", "laptop"],
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode != 0 and "belongs to user id" in done.stderr, done.stderr


@needs_root
def test_a_key_file_of_another_user_is_refused(tmp_path: Path, intruder: str) -> None:
    keys = tmp_path / "keys"
    create_keys(keys, ("laptop",))
    uid = int(subprocess.run(["id", "-u", intruder], check=True, capture_output=True,
                             text=True).stdout)
    os.chown(keys / "authorized" / "laptop.key", uid, -1)
    with pytest.raises(KeysError, match="laptop.key belongs to user id"):
        Keys.load(keys)


@pytest.mark.parametrize("mode", [0o777, 0o775, 0o757])
def test_a_key_folder_others_may_write_is_refused(tmp_path: Path, mode: int) -> None:
    keys = tmp_path / "keys"
    create_keys(keys, ("laptop",))
    Keys.load(keys)  # as made: accepted
    for folder in (keys, keys / "authorized"):
        os.chmod(folder, mode)
        with pytest.raises(KeysError, match=f"mode {mode:04o}"):
            Keys.load(keys)
        os.chmod(folder, 0o700)


def test_an_empty_key_folder_name_is_an_error_not_no_keys(tmp_path: Path) -> None:
    with pytest.raises(KeysError, match="empty name"):
        Keys.load("")
    doc = {"launch": [{"transport": {"keys": ""}}]}
    with pytest.raises(LaunchFileError, match="keys.*empty folder name"):
        parse_launch(doc, "graph.yaml")
    for words in (["launch", "demo", "--keys", ""], ["topic", "list", "--keys", ""]):
        done = subprocess.run([sys.executable, "-c", "import sys; from vibrissa.cli.main import main; "
                               "sys.exit(main(sys.argv[1:]))", *words],
                              capture_output=True, text=True, timeout=120, check=False)
        assert done.returncode == 2 and "empty name" in done.stderr, (words, done.stderr)


def test_a_client_made_on_its_own_host_gets_in_with_only_public_keys_travelling(
        tmp_path: Path) -> None:
    graph_dir, client_dir, carried = tmp_path / "robot", tmp_path / "station", tmp_path / "g.key"
    create_keys(graph_dir)
    shutil.copy(graph_dir / "graph.key", carried)  # the graph's public key goes to the client
    written = join_keys(client_dir, "station", carried)
    assert {p.name for p in written} == {"graph.key", "station.key", "station.key_secret"}
    assert os.stat(client_dir / "station.key_secret").st_mode & 0o077 == 0
    client = Keys.load(client_dir)
    graph = Keys.load(graph_dir)
    assert client.name == "station" and not client.serves
    assert client.server_public == graph.server_public
    assert client.public not in graph.allowed
    authorize_keys(graph_dir, (str(client_dir / "station.key"),))  # its public key comes back
    assert client.public in Keys.load(graph_dir).allowed
    with pytest.raises(KeysError, match="holds a secret key"):
        authorize_keys(graph_dir, (str(client_dir / "station.key_secret"),))
    with pytest.raises(KeysError, match="holds a secret key"):
        join_keys(tmp_path / "other", "x", graph_dir / "graph.key_secret")
    with pytest.raises(KeysError, match="another secret key"):
        join_keys(graph_dir, "station", carried)  # the graph's own folder
    with pytest.raises(KeysError, match="not a graph's key folder"):
        authorize_keys(client_dir, (str(client_dir / "station.key"),))
    create_keys(tmp_path / "other-graph")
    with pytest.raises(KeysError, match="another graph's key"):
        join_keys(client_dir, "station", tmp_path / "other-graph" / "graph.key")
