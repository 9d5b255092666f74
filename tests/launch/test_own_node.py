"""docs/WRITING_NODES.md: its example node runs next to the demo's nodes exactly as printed,
and its launch-format reference names exactly the keys the parser accepts."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from vibrissa.launch.description import LaunchFileError, parse_launch
from vibrissa.status import ContactPhase
from vibrissa.surfaces import parse_surface
from vibrissa.sweep import Trail, simulate_sweeps

DOCS = Path(__file__).parents[2] / "docs"
PAGE = (DOCS / "WRITING_NODES.md").read_text()
STEP = 0.004
DOMAIN = 300 + os.getpid() % 90 * 2  # its own graph: no tool of another test finds it at 0


def code_blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", PAGE, flags=re.S)


def test_the_page_prints_the_example_files_verbatim() -> None:
    assert (DOCS / "examples" / "phase_filter.py").read_text() in code_blocks("python")
    assert (DOCS / "examples" / "tip_map.yaml").read_text() in code_blocks("yaml")
    assert (DOCS / "examples" / "demo_plus_filter.yaml").read_text() in code_blocks("yaml")


def run_phase_filter(launch_file: Path, out: Path, step: float) -> tuple[str, int, int]:
    """Launch ``launch_file`` (the demo with the example node) at ``step``: its output, and
    how many contacts the node kept and dropped, checked against the same sweeps in the
    library (the filter keeps exactly the tip-phase equilibria)."""
    try:
        result = subprocess.run(
            [sys.executable, "-m", "vibrissa.cli.main", "launch", str(launch_file),
             f"out:={out}", f"step:={step}"], capture_output=True, text=True, timeout=600,
            env=os.environ | {"VIBRISSA_DOMAIN_ID": str(DOMAIN)})
    except subprocess.TimeoutExpired as exc:  # what the graph said before it hung
        said = [part.decode(errors="replace") if isinstance(part, bytes) else part or ""
                for part in (exc.stdout, exc.stderr)]
        pytest.fail(f"the launch did not end within 600 s:\n{''.join(said)[-20000:]}")
    text = result.stdout + result.stderr
    assert result.returncode == 0, text
    match = re.search(r"\[phase_filter\] .*kept (\d+) tip contacts, dropped (\d+)", text)
    assert match, text
    kept, dropped = int(match.group(1)), int(match.group(2))
    sweeps = simulate_sweeps(parse_surface("paraboloid:a=0.5,b=1,h=0.4"),
                             [Trail(y, 0.2) for y in (-0.4, -0.2, 0.0, 0.2, 0.4)], step)
    tips = sum(int((s.phase == ContactPhase.TIP).sum()) for s in sweeps)
    assert (kept, kept + dropped) == (tips, sum(s.n_steps for s in sweeps))
    return text, kept, dropped


def test_the_example_node_filters_the_demo_stream_into_a_map(tmp_path: Path) -> None:
    text, kept, dropped = run_phase_filter(DOCS / "examples" / "tip_map.yaml", tmp_path / "map",
                                           STEP)
    assert 0 < kept < kept + dropped
    assert f"map of {kept} contact points written to" in text
    for name in ("wrench_source", "phase_filter", "mapper"):
        assert re.search(rf"\[launch\]\s+{name}\s+exit 0", text), text


def documented_keys(heading: str) -> set[str]:
    section = PAGE.split(heading, 1)[1].split("\n### ", 1)[0]
    return {key for row in re.findall(r"^\| (`[^|]+)\|", section, flags=re.M)
            for key in re.findall(r"`([a-z_]+)`", row)}


def allowed_keys(document: dict[str, object]) -> set[str]:
    with pytest.raises(LaunchFileError) as error:
        parse_launch(document, "probe.yaml")
    return set(re.search(r"allowed: ([^)]*)\)", str(error.value)).group(1).split(", "))  # type: ignore[union-attr]


def test_the_format_reference_names_every_key_the_parser_accepts() -> None:
    assert documented_keys("### `node`") == allowed_keys(
        {"launch": [{"node": {"cmd": ["x"], "name": "n", "bogus": 1}}]})
    assert documented_keys("### `arg`") == allowed_keys(
        {"launch": [{"arg": {"name": "a", "bogus": 1}}]})
    assert documented_keys("### `include`") == allowed_keys(
        {"launch": [{"include": {"file": "x.yaml", "bogus": 1}}]})
    assert documented_keys("### `transport`") == allowed_keys(
        {"launch": [{"transport": {"bogus": 1}}]})
