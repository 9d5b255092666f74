"""The layering of docs/ARCHITECTURE.md, checked over every module's imports.

Each folder of the repository is one package of one layer (``package-dir`` in pyproject.toml);
a module may import its own layer and the layers below it, never one above or beside it, and
the core imports no I/O library. Every ``import`` statement counts, also one inside a function.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest
import tomllib

ROOT = Path(__file__).parents[1]

# Layer of each package, lowest first; packages of one rank may not import each other.
RANK = {
    "vibrissa": 0,
    "vibrissa.msgs": 1,
    "vibrissa.formats": 1,
    "vibrissa.mapping": 1,
    "vibrissa.planning": 1,  # where a robot goes next: free space, exploration planners
    "vibrissa.wire": 2,
    "vibrissa.figures": 2,
    "vibrissa.streaming": 2,  # Step 2 on a stream of messages, without sockets
    "vibrissa.studies": 2,  # study grids: grid files, local and Dask runs, the case store
    "vibrissa.runtime": 3,
    "vibrissa.launch": 4,
    "vibrissa.nodes": 4,
    "vibrissa.cli": 5,
    "": 6,  # top-level modules: the command's entry point (_vibrissa_entry.py), above all
}

# Third-party libraries each layer may import besides those of the layers below it (the
# standard library is always allowed).
LIBRARIES = {
    "vibrissa": {"numpy", "scipy", "numba"},
    # skimage: marching cubes, threadpoolctl: one BLAS thread (vibrissa.mapping.gp_surface),
    # open3d: DBSCAN (vibrissa.mapping.objects)
    "vibrissa.mapping": {"skimage", "threadpoolctl", "open3d"},
    # skimage: shortest routes on a grid (vibrissa.planning.explorer)
    "vibrissa.planning": {"skimage"},
    "vibrissa.msgs": {"msgpack", "msgspec"},
    # rosbags, mcap_ros2: ROS 2 bags without ROS (vibrissa.wire.ros2_bag)
    "vibrissa.wire": {"zmq", "mcap", "zstandard", "rosbags", "mcap_ros2"},
    "vibrissa.formats": {"yaml"},
    "vibrissa.figures": {"matplotlib", "mpl_toolkits"},
    "vibrissa.streaming": set(),
    # pyarrow: Parquet tables and the case store; dask, distributed: runs on a cluster
    "vibrissa.studies": {"pyarrow", "dask", "distributed"},
    "vibrissa.runtime": {"yaml", "msgspec"},
    "vibrissa.launch": {"yaml", "msgspec"},
    # foxglove: the live view (nodes/foxglove_bridge.py, the optional extra `view`)
    "vibrissa.nodes": {"foxglove"},
    "vibrissa.cli": set(),
    "": set(),
}


# Modules a package may not import although their layer is below it: a library usable from a
# plain script loads neither the codec nor file formats (nor their libraries).
FORBIDDEN = {
    "vibrissa.streaming": ("vibrissa.msgs.codec", "vibrissa.formats", "msgpack", "msgspec", "yaml"),
}


def package_dirs() -> dict[str, Path]:
    """Package name -> folder, as pyproject.toml installs them."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    dirs = {name: ROOT / folder for name, folder in config["package-dir"].items()}
    return {**dirs, "": ROOT} if config.get("py-modules") else dirs  # top-level modules


def imported_modules(path: Path) -> set[str]:
    """Absolute names of every module ``path`` imports (relative imports are not used)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}: relative import"
            assert node.module is not None
            names.add(node.module)
    return names


def package_of(module: str) -> str | None:
    """The vibrissa package ``module`` belongs to, or None outside vibrissa."""
    if module != "vibrissa" and not module.startswith("vibrissa."):
        return None
    parts = module.split(".")
    return ".".join(parts[:2]) if len(parts) > 1 and ".".join(parts[:2]) in RANK else "vibrissa"


def violations(package: str, path: Path) -> list[str]:
    """The imports of module ``path`` of ``package`` that break the layering."""
    allowed = set().union(*(LIBRARIES[p] for p, rank in RANK.items() if rank < RANK[package]),
                          LIBRARIES[package])
    where = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
    found = []
    for module in sorted(imported_modules(path)):
        target = package_of(module)
        if any(module == name or module.startswith(name + ".")
               for name in FORBIDDEN.get(package, ())):
            found.append(f"{where}: {package} may not import {module}")
        elif target is None:
            top = module.split(".")[0]
            if top not in sys.stdlib_module_names and top not in allowed:
                found.append(f"{where}: {package} may not import {module}")
        elif target != package and RANK[target] >= RANK[package]:
            found.append(f"{where}: {package} (layer {RANK[package]}) imports "
                         f"{module} (layer {RANK[target]})")
    return found


def layer_violations() -> list[str]:
    found = []
    for package, folder in package_dirs().items():
        for path in sorted(folder.glob("*.py")):
            found += violations(package, path)
    return found


def test_every_package_has_a_layer() -> None:
    assert set(package_dirs()) == set(RANK)


def test_imports_point_down_only() -> None:
    assert layer_violations() == []


@pytest.mark.parametrize(("package", "module"), [
    ("vibrissa", "vibrissa.msgs"),            # the core reaching up into the wire
    ("vibrissa.wire", "vibrissa.runtime"),    # the wire reaching into the node runtime
    ("vibrissa.runtime", "vibrissa.nodes"),   # the runtime importing a node
    ("vibrissa.nodes", "vibrissa.launch"),    # nodes and launch are siblings
    ("vibrissa.launch", "vibrissa.cli.bag"),  # the launch system is not a command
    ("vibrissa", "zmq"),                      # the core does no I/O
    ("vibrissa.mapping", "zmq"),              # the map is a library, not a process
    ("vibrissa.mapping", "vibrissa.nodes.mapper"),  # nor does it reach into its node
    ("vibrissa.mapping", "vibrissa.formats.ply"),   # it writes no files
    ("vibrissa.mapping", "matplotlib"),       # it draws nothing
    ("vibrissa.figures", "vibrissa.wire"),    # pictures are beside the wire
    ("vibrissa.streaming", "zmq"),            # the stream library has no sockets
    ("vibrissa.streaming", "vibrissa.wire.transport"),
    ("vibrissa.streaming", "vibrissa.msgs.codec"),  # nor the codec (a layer below it)
    ("vibrissa.streaming", "msgpack"),
    ("vibrissa.streaming", "vibrissa.formats.scene_file"),
    ("vibrissa.streaming", "vibrissa.runtime"),
])
def test_a_planted_upward_import_is_found(tmp_path: Path, package: str, module: str) -> None:
    planted = tmp_path / "planted.py"
    planted.write_text(f"def f():\n    import {module}\n")
    assert violations(package, planted), f"{package} importing {module} was not caught"


def test_the_map_library_loads_no_wire_runtime_or_file_format() -> None:
    """``import vibrissa.mapping`` in a fresh interpreter: no message, transport, runtime or
    file format module, and no ZeroMQ, msgpack or YAML beyond what numba itself loads."""
    probe = ("import sys, {0}; print(' '.join(sorted(m for m in sys.modules if m in {1})))")
    banned = ["zmq", "msgpack", "yaml", "vibrissa.msgs", "vibrissa.wire", "vibrissa.formats",
              "vibrissa.runtime", "matplotlib", "open3d"]

    def loaded(module: str) -> set[str]:
        out = subprocess.run([sys.executable, "-c", probe.format(module, banned)], cwd=ROOT,
                             capture_output=True, text=True, check=True, timeout=120).stdout
        return set(out.split())

    from_numba = loaded("numba")  # numba.core.config imports yaml when it is installed
    assert from_numba <= {"yaml"}
    assert loaded("vibrissa.mapping") <= from_numba
def test_the_stream_library_loads_no_socket_codec_file_format_or_runtime() -> None:
    """What `import vibrissa.streaming` loads, in a fresh interpreter (the planted cases above
    check the source; this checks what the imports pull in on the way). numba loads yaml for
    its own configuration: what numba loads by itself is not the library's."""
    forbidden = ["zmq", "msgpack", "yaml", "vibrissa.msgs.codec", "vibrissa.wire",
                 "vibrissa.formats", "vibrissa.runtime"]
    script = ("import sys; import numba; by_numba = set(sys.modules); import vibrissa.streaming; "
              f"print(sorted(m for m in {forbidden!r} if m in sys.modules and m not in by_numba), "
              "'yaml' in by_numba)")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=120, check=True)
    assert out.stdout.split()[0] == "[]", out.stdout + out.stderr
