"""An exit that is the node's answer is not a crash: it is not respawned, and a node that
exits ``EXIT_LOST_DATA`` with ``on_exit: shutdown`` ends the launch with that status. Absurd
respawn delays are refused before anything starts."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

from vibrissa.launch.description import MAX_RESPAWN_DELAY_S, LaunchFileError, parse_launch
from vibrissa.runtime.node import EXIT_LOST_DATA


def _launch_run() -> ModuleType:
    """The launcher tests' helpers (test files are not importable as modules by name)."""
    spec = importlib.util.spec_from_file_location("_launch_run", Path(__file__).with_name(
        "test_launch_run.py"))
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


_run = _launch_run()
alive, fixture_node, launch, pids, write_launch = (
    _run.alive, _run.fixture_node, _run.launch, _run.pids, _run.write_launch)


@pytest.mark.parametrize("exit_code", [EXIT_LOST_DATA, 3, 2])
def test_an_answer_is_not_respawned(tmp_path: Path, exit_code: int) -> None:
    pid_file = tmp_path / "pids"
    worker = fixture_node("worker", "sleeper", pid_file=str(pid_file), seconds=60)
    mapper = fixture_node("mapper", "crasher", delay=0.3, exit_code=exit_code)
    mapper.update(on_exit="shutdown", respawn=True, respawn_delay=0.1)
    rc, out, err = launch(write_launch(tmp_path, worker, mapper))
    assert out.count("[mapper] mapper crashing") == 1, err  # started once, never again
    assert "respawn 1" not in err
    if exit_code != EXIT_LOST_DATA:
        assert f"(not respawned: exit {exit_code} is the node's answer)" in err
    assert "'mapper' has on_exit: shutdown; shutting down" in err or exit_code != EXIT_LOST_DATA
    assert rc == (EXIT_LOST_DATA if exit_code == EXIT_LOST_DATA else 1), err
    assert not any(alive(pid) for pid in pids(pid_file))


def test_a_crash_is_still_respawned(tmp_path: Path) -> None:
    mapper = fixture_node("mapper", "crasher", delay=0.1, exit_code=1)
    mapper.update(respawn=True, respawn_delay=0.1, respawn_max=2)
    rc, out, err = launch(write_launch(tmp_path, mapper))
    assert out.count("[mapper] mapper crashing") == 3, err
    assert "respawn limit reached" in err


@pytest.mark.parametrize("delay", [1e300, MAX_RESPAWN_DELAY_S * 2])
def test_an_absurd_respawn_delay_is_refused(delay: float) -> None:
    doc = {"launch": [{"node": {"cmd": ["true"], "name": "n", "respawn": True,
                                "respawn_delay": delay}}]}
    with pytest.raises(LaunchFileError, match="respawn_delay: expected at most 3600"):
        parse_launch(doc, "graph.yaml")
