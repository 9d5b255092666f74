"""The mapper's interactive page (map.html): one file with everything in it, names that cannot
break out of it, and a real browser (headless Chromium) that draws the scene from it: the
contacts in their whiskers' colours, the meshes in the colour scale, no script error."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.mapping.test_mapper_objects import accumulate, messages, write_outputs, write_scene
from vibrissa.figures.map_figure import MapLayers
from vibrissa.figures.map_page import embedded_json, write_page
from vibrissa.nodes.mapper import MapperParams

WINDOW = (1200, 900)
KEY_WIDTH = 340  # the legend panel on the right of the page (its colour bar is not the scene)
TAB10 = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd"]  # map.png's first colours
HOSTILE = "</script><script>document.title='owned'</script>&amp;<!--"


def chromium() -> str:
    """The browser: a missing one fails the test (CI installs it), it does not skip it."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        pytest.fail("chromium is not installed: run scripts/ensure_test_deps.sh (or "
                    "`apt-get install chromium`); the map page is tested in a real browser")
    return found


def browse(page: Path, tmp: Path, *action: str, fragment: str = "") -> subprocess.CompletedProcess[str]:
    """Open ``page`` (with ``#fragment``) in headless Chromium (its own profile in ``tmp``)
    and do ``action`` (``--screenshot=...`` or ``--dump-dom``); the browser's log is in
    stderr."""
    return subprocess.run(
        [chromium(), "--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run",
         f"--user-data-dir={tmp / 'profile'}", f"--window-size={WINDOW[0]},{WINDOW[1]}",
         "--virtual-time-budget=1000", "--enable-logging=stderr", "--v=0", *action,
         page.as_uri() + (f"#{fragment}" if fragment else "")],
        capture_output=True, text=True, timeout=120, check=False)


def page_data(html: str) -> dict[str, Any]:
    """The JSON the page embeds."""
    found = re.search(r'<script type="application/json" id="map-data">(.*?)</script>', html,
                      re.S)
    assert found is not None
    data: dict[str, Any] = json.loads(found.group(1))
    return data


def rgb(hex_colour: str) -> np.ndarray:
    return np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)], dtype=np.float64)


@pytest.fixture(scope="module")
def page(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The map of tests/mapping/test_mapper_objects.py (two objects, the scene known) and its
    page."""
    tmp = tmp_path_factory.mktemp("map_page")
    params = MapperParams(out_dir=str(tmp / "out"), scene=str(write_scene(tmp)))
    report, _ = write_outputs(accumulate(messages()), params, tmp / "out")
    html = (tmp / "out" / "map.html").read_text(encoding="utf-8")
    return {"report": report, "path": tmp / "out" / "map.html", "html": html,
            "data": page_data(html), "tmp": tmp}


def test_the_page_is_one_file_beside_the_png_with_the_map_in_it(page: dict[str, Any]) -> None:
    files = page["report"]["frames"][0]["files"]
    assert files["html"] == str(page["path"]) and Path(files["png"]).parent == page["path"].parent
    html = page["html"]
    # nothing to fetch: no address, no external script, style sheet or image
    assert not re.search(r"https?://|<link|\bsrc=|@import|url\(", html)
    assert len(html.encode()) < 1_000_000
    data = page["data"]
    frame = page["report"]["frames"][0]
    assert data["title"].startswith("world map: 2 objects, 282 contacts from 5 whiskers")
    # the contacts in an object in mm (um steps), their whiskers; the strays are noise
    assert len(data["points"]) == 3 * 280 and len(data["w"]) == 280
    assert len(data["noise"]) == 3 * frame["noise_points"] == 6
    points = np.reshape(data["points"], (-1, 3))
    assert np.all(np.abs(points[:, 2] - 40.0) < 20.0)  # the objects sit ~40 mm up
    assert np.allclose(points * 1e3, np.round(points * 1e3))
    assert [w["colour"] for w in data["whiskers"]] == TAB10  # the palette of map.png
    assert [w["name"] for w in data["whiskers"]] == ["w0", "w1", "w2", "w3", "w4"]
    meshes = {m["name"]: m for m in data["meshes"]}
    for obj in frame["objects"]:  # the known and the unknown part of each object's mesh
        mesh = meshes[obj["name"]]
        assert len(mesh["t"]) == 3 * obj["n_triangles"] == 3 * len(mesh["c"])
        assert len(mesh["ut"]) == 3 * obj["unknown_triangles"] > 0
    assert sorted(t["name"] for t in data["true"]) == ["ball", "egg", "pebble"]
    assert data["path"] is not None and len(data["path"]["mounts"]) == 5


def test_names_from_the_network_cannot_break_out_of_the_page(tmp_path: Path) -> None:
    text = embedded_json({"name": HOSTILE})
    assert not set(text) & set("<>&") and json.loads(text) == {"name": HOSTILE}
    layers = MapLayers(title=f"map of {HOSTILE}", points=np.array([[0.0, 0.0, 0.0],
                                                                   [0.001, 0.0, 0.0]]),
                       whisker_ids=[HOSTILE, "w1"], labels=np.array([0, 0]))
    path = tmp_path / "map.html"
    write_page(path, layers)
    html = path.read_text(encoding="utf-8")
    assert HOSTILE not in html and html.count("</script>") == 2  # the page's own two
    assert [w["name"] for w in page_data(html)["whiskers"]] == sorted([HOSTILE, "w1"])
    # in the browser: the name is text in the legend and the title, the page is drawn
    run = browse(path, tmp_path, "--dump-dom")
    assert run.returncode == 0, run.stderr[-2000:]
    assert re.search(r'data-drawn="[1-9]', run.stdout), run.stderr[-2000:]
    assert run.stdout.count("<script") == 2 and "<title>owned</title>" not in run.stdout
    assert "&lt;/script&gt;&lt;script&gt;" in run.stdout


def test_a_script_error_would_be_seen(page: dict[str, Any], tmp_path: Path) -> None:
    # the check of the next test can fail: a page whose script breaks is not marked drawn
    broken = tmp_path / "broken.html"
    broken.write_text(page["html"].replace('"use strict";', '"use strict"; noSuchThing();', 1))
    run = browse(broken, tmp_path, "--dump-dom")
    assert run.returncode == 0 and "<body" in run.stdout
    assert "data-drawn" not in run.stdout and "Uncaught ReferenceError" in run.stderr


def test_a_browser_draws_the_scene(page: dict[str, Any], tmp_path: Path) -> None:
    dom = browse(page["path"], tmp_path, "--dump-dom")
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert "Uncaught" not in dom.stderr, dom.stderr[-2000:]
    drawn = re.search(r'data-drawn="(\d+)"', dom.stdout)
    known = sum(len(m["c"]) for m in page["data"]["meshes"])
    assert drawn is not None and int(drawn.group(1)) > known + 280

    # the screenshot, and one of the same page with the contacts and the known meshes off:
    # what those two layers add is in their colours; both zoomed in twice on the objects (the
    # view opens on the robot too: its path runs 100 mm beside them)
    zoomed = page["html"].replace("zoom = 1;", "zoom = 2;", 1)
    assert zoomed != page["html"]
    scene_page = tmp_path / "scene.html"
    scene_page.write_text(zoomed)
    scene = screenshot(scene_page, tmp_path)
    bare_page = tmp_path / "bare.html"
    bare_page.write_text(zoomed.replace("contacts: true, noise: true, known: true",
                                        "contacts: false, noise: true, known: false", 1))
    bare = screenshot(bare_page, tmp_path)
    # not blank: many colours, a fair share of the window not background white
    codes = scene.astype(np.int64) @ np.array([1 << 16, 1 << 8, 1])
    assert len(np.unique(codes)) > 200
    assert np.mean(np.any(scene < 245, axis=1)) > 0.02
    # every whisker with contacts on an object: its discs in its colour (its mounts, drawn in
    # both, are in its colour too)
    for w, colour in enumerate(TAB10[:4]):
        near = [np.sum(np.linalg.norm(s - rgb(colour), axis=1) < 30) for s in (scene, bare)]
        assert near[0] - near[1] > 100, f"whisker w{w}: {near} pixels near {colour}"
    # the known meshes: pixels in a colour of the scale, flat-shaded (a multiple of it)
    used = np.unique(np.concatenate([m["c"] for m in page["data"]["meshes"]]))
    scale = np.array([rgb(page["data"]["lut"][i]) for i in used])
    scale /= np.linalg.norm(scale, axis=1, keepdims=True)
    meshy = [in_scale(s, scale) for s in (scene, bare)]
    assert meshy[0] > 2000 and meshy[1] < 0.1 * meshy[0], meshy


def screenshot(page: Path, tmp: Path) -> np.ndarray:
    """The part of the window left of the legend, as browsed: RGB rows (K, 3), 0..255."""
    import matplotlib.image

    shot = tmp / f"{page.stem}.png"
    run = browse(page, tmp, f"--screenshot={shot}")
    assert run.returncode == 0, run.stderr[-2000:]
    pixels = matplotlib.image.imread(shot)
    assert pixels.shape[:2] == (WINDOW[1], WINDOW[0])
    return (pixels[:, : WINDOW[0] - KEY_WIDTH, :3] * 255).reshape(-1, 3).astype(np.float64)


def in_scale(pixels: np.ndarray, scale: np.ndarray) -> int:
    """Pixels (K, 3) whose colour is a multiple of one of ``scale`` (M, 3, unit rows)."""
    bright = pixels[(pixels.max(axis=1) - pixels.min(axis=1)) > 40]  # not grey
    cosine = (bright / np.linalg.norm(bright, axis=1, keepdims=True)) @ scale.T
    return int(np.sum(cosine.max(axis=1) > 0.999))


def test_the_key_folds_away_from_what_it_covers(page: dict[str, Any], tmp_path: Path) -> None:
    shown = browse(page["path"], tmp_path, "--dump-dom")
    folded = browse(page["path"], tmp_path, "--dump-dom", fragment="nokey")
    assert 'id="key"' in shown.stdout and 'id="key" class="folded"' not in shown.stdout
    assert ">hide key</button>" in shown.stdout
    assert 'id="key" class="folded"' in folded.stdout and ">show key</button>" in folded.stdout
    assert re.search(r'data-drawn="[1-9]', folded.stdout), folded.stderr[-2000:]


def test_at_1200x900_the_key_covers_no_part_of_the_robot_path(page: dict[str, Any],
                                                              tmp_path: Path) -> None:
    import matplotlib.image

    # the robot path alone (black): all of it in the window left of the key, clear of its edges
    only_path = tmp_path / "path.html"
    only_path.write_text(page["html"].replace(
        "{contacts: true, noise: true, known: true, unknown: true, truth: true, path: true}",
        "{contacts: false, noise: false, known: false, unknown: false, truth: false, "
        "path: true}", 1))
    shot = tmp_path / "path.png"
    run = browse(only_path, tmp_path, f"--screenshot={shot}")
    assert run.returncode == 0, run.stderr[-2000:]
    pixels = (matplotlib.image.imread(shot)[:, :, :3] * 255).astype(np.int64)
    scene = pixels[:, : WINDOW[0] - KEY_WIDTH]
    rows, cols = np.nonzero(scene.max(axis=2) < 40)  # black: the path and the mount dots
    head = rows > 80  # below the title
    rows, cols = rows[head], cols[head]
    assert len(cols) > 300, len(cols)
    margin = 8  # px
    assert cols.min() >= margin and cols.max() < WINDOW[0] - KEY_WIDTH - margin, (
        cols.min(), cols.max())
    assert rows.max() < WINDOW[1] - margin
    # the key's column is not part of the scene: below the key (this one ends above 500 px)
    # it is blank, nothing of the robot runs on past the window's scene part
    assert np.all(pixels[500:, WINDOW[0] - KEY_WIDTH:] == 255), "the robot is drawn under the key"


def test_the_status_line_is_text_under_the_title(tmp_path: Path) -> None:
    status = f"final map (ended by stop), 282 points, {HOSTILE}, 2026-11-29 03:12:04 UTC"
    points = np.array([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0]])
    plain, live = tmp_path / "plain.html", tmp_path / "live.html"
    write_page(plain, MapLayers(title="world map", points=points, whisker_ids=["w0", "w1"],
                                labels=np.array([0, 0])))
    write_page(live, MapLayers(title="world map", points=points, whisker_ids=["w0", "w1"],
                               labels=np.array([0, 0]), status=status))
    html = live.read_text(encoding="utf-8")
    assert page_data(html)["status"] == status and page_data(plain.read_text())["status"] == ""
    assert HOSTILE not in html and html.count("</script>") == 2
    # in the browser: the line under the title, as text; none without a status
    shown = browse(live, tmp_path, "--dump-dom")
    assert shown.returncode == 0 and re.search(r'data-drawn="[1-9]', shown.stdout), shown.stderr
    found = re.search(r'<h1 id="title">world map</h1><p id="status">(.*?)</p>', shown.stdout)
    assert found is not None, shown.stdout[:3000]
    assert found.group(1) == status.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    assert "<title>owned</title>" not in shown.stdout
    bare = browse(plain, tmp_path, "--dump-dom")
    assert '<p id="status"></p>' in bare.stdout, bare.stderr[-2000:]
