"""The docs stay true where a machine can check them: the README's length, every relative link,
every module path and repository file they name, the keys of scene and launch files, the
packaged launch files' arguments, the nodes' parameters, and the scene-file example."""

from __future__ import annotations

import dataclasses
import importlib
import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from vibrissa.formats.scene_file import SceneError, load_robot, load_scene
from vibrissa.launch.description import LaunchFileError, load_launch_file, parse_launch

ROOT = Path(__file__).parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
PAGES = [README, *sorted(DOCS.glob("*.md"))]
LAUNCH_FILES = sorted((ROOT / "launch").glob("*.yaml"))
NODES = ("wrench_source", "reconstructor", "mapper", "recorder", "netft", "netft_sim",
         "foxglove_bridge", "localizer")

_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
_ALLOWED = re.compile(r"allowed: ([^)]*)\)")


def _section(text: str, heading: str) -> str:
    """The text under the first heading line that is ``heading``, up to the next heading of
    the same or a higher level."""
    lines = text.splitlines()
    level = len(heading) - len(heading.lstrip("#"))
    for i, line in enumerate(lines):
        if line.strip() == heading:
            end = next((j for j in range(i + 1, len(lines))
                        if re.match(rf"#{{1,{level}}} ", lines[j])), len(lines))
            return "\n".join(lines[i + 1:end])
    raise AssertionError(f"no heading {heading!r}")


def _table_keys(text: str, column: int = 0) -> list[str]:
    """The backticked names in a column of every table row (not header or rule rows)."""
    keys: list[str] = []
    for line in text.splitlines():
        if not line.startswith("|") or set(line) <= set("|- "):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        keys += re.findall(r"`([^`]+)`", cells[column]) if column < len(cells) else []
    return keys


def _allowed(message: str) -> set[str]:
    match = _ALLOWED.search(message)
    assert match, message
    return {key.strip() for key in match.group(1).split(",")}


def test_the_readme_reads_in_ten_minutes() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines; at most 250"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_relative_links_point_to_files(page: Path) -> None:
    missing = []
    for target in _LINK.findall(page.read_text(encoding="utf-8")):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        if not (page.parent / target.split("#")[0]).exists():
            missing.append(target)
    assert not missing, f"{page.name} links to missing files: {missing}"


_DOTTED = re.compile(r"(?<![\w./-])vibrissa(?:\.[A-Za-z_]\w*)+")
_PLACEHOLDERS = {"vibrissa.nodes.NAME"}  # the node command line's pattern (NODES.md)
_FOLDERS = ("vibrissa", "msgs", "wire", "formats", "mapping", "streaming", "figures", "runtime",
            "launch", "nodes", "cli", "tests", "benchmarks", "scripts", "docs")
_FILE = re.compile(rf"`((?:{'|'.join(_FOLDERS)})/[\w./-]+\.(?:py|yaml|json|md|csv))`")


def resolve(dotted: str) -> object:
    """The object a dotted name names: its longest importable module prefix, then attributes
    (``vibrissa.msgs.codec.RETIRED_TYPES``). ImportError or AttributeError when it names
    nothing."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            found: object = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError as exc:
            if exc.name is None or not ".".join(parts[:cut]).startswith(exc.name):
                raise  # a module that exists but fails to import
            continue
        for attribute in parts[cut:]:
            found = getattr(found, attribute)
        return found
    raise ImportError(dotted)


def dotted_names(text: str) -> set[str]:
    """Every ``vibrissa.x.y`` path in ``text`` (not a file path, not a placeholder; a trailing
    full stop is the sentence's)."""
    return {name.rstrip(".") for name in _DOTTED.findall(text)} - _PLACEHOLDERS


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_module_path_named_imports(page: Path) -> None:
    missing = []
    for name in sorted(dotted_names(page.read_text(encoding="utf-8"))):
        try:
            resolve(name)
        except (ImportError, AttributeError) as exc:
            missing.append(f"{name} ({exc})")
    assert not missing, f"{page.name} names what does not exist: {missing}"


def test_a_stale_module_path_is_caught() -> None:
    text = ("`vibrissa.mapping.fit_frame`, `vibrissa.msgs.codec.RETIRED_TYPES`; the stale "
            "`vibrissa.gp_surface`, `vibrissa.nodes.surface_fit` and `vibrissa.msgs.encode`.")
    names = dotted_names(text)
    assert names == {"vibrissa.mapping.fit_frame", "vibrissa.msgs.codec.RETIRED_TYPES",
                     "vibrissa.gp_surface", "vibrissa.nodes.surface_fit", "vibrissa.msgs.encode"}
    for stale in ("vibrissa.gp_surface", "vibrissa.nodes.surface_fit", "vibrissa.msgs.encode"):
        with pytest.raises((ImportError, AttributeError)):
            resolve(stale)
    resolve("vibrissa.mapping.fit_frame")
    resolve("vibrissa.msgs.codec.RETIRED_TYPES")


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_repository_file_named_exists(page: Path) -> None:
    missing = sorted({path for path in _FILE.findall(page.read_text(encoding="utf-8"))
                      if not (ROOT / path).exists()})
    assert not missing, f"{page.name} names files that do not exist: {missing}"


def test_a_stale_file_path_is_caught() -> None:
    assert _FILE.findall("`vibrissa/gp_surface.py` and `mapping/gp_surface.py`") == [
        "vibrissa/gp_surface.py", "mapping/gp_surface.py"]
    assert not (ROOT / "vibrissa/gp_surface.py").exists()


# -- scene files -----------------------------------------------------------------------------

SCENE_PAGE = (DOCS / "SCENE_FILE.md").read_text(encoding="utf-8")
PATH_CSV = "t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n1,0.01,0,0,0,0,0,1\n"
_VALUES: dict[str, Any] = {
    "mu": 0.2, "path": "path.csv", "name": None, "position_m": [0.0, 0.0, 0.1],
    "quaternion_xyzw": [0.0, 0.0, 0.0, 1.0], "radius_m": 0.01, "semi_axes_m": [0.01, 0.02, 0.03],
    "a_per_m": 10.0, "b_per_m": 20.0, "h_m": 0.05, "length_m": 0.05, "ei_nm2": 2e-5,
}
_SHAPES = ("sphere", "ellipsoid", "paraboloid")


def _documented_scene_keys() -> dict[str, set[str]]:
    keys: dict[str, set[str]] = {}
    for line in _section(SCENE_PAGE, "## Keys").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and len(cells) > 2 and cells[1].startswith("`"):
            keys.setdefault(cells[0], set()).add(cells[1].strip("`"))
    return keys


def _scene(tmp_path: Path, doc: dict[str, Any]) -> Path:
    (tmp_path / "path.csv").write_text(PATH_CSV, encoding="utf-8")
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(json.loads(json.dumps(doc))), encoding="utf-8")  # no aliases
    return path


def _full_scene(keys: dict[str, set[str]]) -> dict[str, Any]:
    """A scene that uses every documented key, with plausible values."""
    def body(section: str, name: str | None = None) -> dict[str, Any]:
        return {key: name if key == "name" else _VALUES[key] for key in keys[section]
                if key in _VALUES}
    objects = [{**body("object", f"o_{shape}"), "shape": shape, **body(shape)}
               for shape in _SHAPES]
    pose = {"mount": body("mount"), "sensor": body("sensor")}
    whisker = {**body("whisker", "w0"), **{k: pose[k] for k in keys["whisker"] if k in pose}}
    return {**body("scene"), "objects": objects, "whiskers": [whisker]}


def _loader_keys(tmp_path: Path) -> dict[str, set[str]]:
    """The keys the loader accepts, per section: the 'allowed' list of its unknown-key error."""
    base = _full_scene(_documented_scene_keys())
    found: dict[str, set[str]] = {}

    def probe(section: str, change: Any) -> None:
        doc = yaml.safe_load(yaml.safe_dump(base))
        change(doc)
        with pytest.raises(SceneError) as info:
            load_scene(_scene(tmp_path, doc))
        found[section] = _allowed(str(info.value))

    probe("scene", lambda d: d.update(zz_unknown=1))
    for i, shape in enumerate(_SHAPES):
        probe(shape, lambda d, i=i: d["objects"][i].update(zz_unknown=1))
    probe("whisker", lambda d: d["whiskers"][0].update(zz_unknown=1))
    probe("mount", lambda d: d["whiskers"][0]["mount"].update(zz_unknown=1))
    probe("sensor", lambda d: d["whiskers"][0].update(sensor={"zz_unknown": 1}))
    return found


def test_scene_file_keys_are_the_loaders(tmp_path: Path) -> None:
    documented = _documented_scene_keys()
    loader = _loader_keys(tmp_path)
    for section in ("scene", "whisker", "mount", "sensor"):
        assert documented[section] == loader[section], section
    for shape in _SHAPES:
        assert documented["object"] | documented[shape] == loader[shape], shape


def test_a_scene_with_every_documented_key_loads(tmp_path: Path) -> None:
    scene = load_scene(_scene(tmp_path, _full_scene(_documented_scene_keys())))
    assert [o.shape for o in scene.objects] == list(_SHAPES)
    assert load_robot(tmp_path / "scene.yaml")[0].X_CS.translation[2] == pytest.approx(0.1)


def test_the_scene_file_example_loads(tmp_path: Path) -> None:
    example = _section(SCENE_PAGE, "## A complete small example")
    (scene_yaml,) = re.findall(r"```yaml\n(.*?)```", example, flags=re.DOTALL)
    (make_path,) = re.findall(r"<<'EOF'\n(.*?)EOF\n", example, flags=re.DOTALL)
    (tmp_path / "scene.yaml").write_text(scene_yaml, encoding="utf-8")
    subprocess.run([sys.executable, "-c", make_path], cwd=tmp_path, check=True, timeout=60)
    scene = load_scene(tmp_path / "scene.yaml")
    assert len(scene.path.t) == 300 and scene.whiskers[0].name == "w0"


# -- launch files ----------------------------------------------------------------------------

LAUNCH_PAGE = (DOCS / "LAUNCH_FILES.md").read_text(encoding="utf-8")


@pytest.mark.parametrize("kind, entry", [
    ("arg", {"arg": {"name": "a", "zz_unknown": 1}}),
    ("transport", {"transport": {"zz_unknown": 1}}),
    ("node", {"node": {"exec": "mapper", "zz_unknown": 1}}),
])
def test_launch_file_keys_are_the_parsers(kind: str, entry: dict[str, Any]) -> None:
    document = {"launch": [entry, {"node": {"exec": "mapper"}}]}
    with pytest.raises(LaunchFileError) as info:
        parse_launch(document, "probe.yaml")
    heading = next(line for line in LAUNCH_PAGE.splitlines() if line.startswith(f"### `{kind}`"))
    documented = set(_table_keys(_section(LAUNCH_PAGE, heading)))
    assert documented == _allowed(str(info.value))


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_packaged_launch_arguments_are_documented(path: Path) -> None:
    section = _section(LAUNCH_PAGE, f"### {path.name}")
    documented = set(_table_keys(section))
    overrides = {"bag": "x.mcap"} if path.name == "replay_demo.yaml" else {}
    declared = {arg.name for arg in load_launch_file(path, overrides).args}
    assert documented == declared


# -- nodes -----------------------------------------------------------------------------------

NODES_PAGE = (DOCS / "NODES.md").read_text(encoding="utf-8")


@pytest.mark.parametrize("node", NODES)
def test_node_parameters_are_documented(node: str) -> None:
    params = importlib.import_module(f"vibrissa.nodes.{node}").PARAMS
    fields = {f.name for f in dataclasses.fields(params) if f.init}
    heading = next(line for line in NODES_PAGE.splitlines()
                   if line.startswith("## ") and f"`nodes/{node}.py`" in line)
    section = _section(NODES_PAGE, heading)
    table = next(t for t in re.split(r"\n\s*\n", section)
                 if t.lstrip().startswith("| parameter |") and
                 (node != "netft_sim" or "`loop`" in t) and (node != "netft" or "`mode`" in t))
    assert set(_table_keys(table)) == fields
