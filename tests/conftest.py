"""Shared fixtures, the ``live`` marker, and results computed once per run.

Fixtures: the paper's 25 sweeps (``paper_sweeps``), computed once per run even when
pytest-xdist runs the tests in several workers (:func:`computed_once`); per test, a ZeroMQ
``context``, a running ``proxy`` on free loopback ports and its ``endpoints``.

Marker ``live``: the test starts a process or opens a socket (ZeroMQ, UDP, TCP); a pool of the
core's worker processes (``simulate(scene, workers=2)``, forked) is no such process. It is set
here, at collection, on every test that uses the ``context``, ``proxy`` or ``endpoints``
fixture, or whose code names one of :data:`LIVE_NAMES` (``subprocess``, ``zmq``, ``socket``,
``sys.executable``, ...): the test function's own code and, followed from it, the functions,
classes and fixtures it refers to that are defined in the tests. A test that does so out of
sight (an in-process command that opens sockets) carries ``@pytest.mark.live`` itself. Every
other test runs with process starts and socket openings refused (:func:`refused_outside_live`),
so a missing mark fails the test, in every run, instead of letting a live test into the fast
selection. ``make check`` runs ``-m "not live"`` (the core, the physics, formats, the codec,
node logic without sockets); ``make test`` runs all: no test is in neither.
"""

from __future__ import annotations

import inspect
import os
import pickle
import socket
import subprocess
import types
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import pytest
import zmq
from filelock import FileLock

from vibrissa.surfaces import parse_surface
from vibrissa.sweep import Sweep, Trail, simulate_sweeps
from vibrissa.wire import Endpoints, Proxy

PAPER_SURFACE = "paraboloid:a=0.5,b=1,h=0.4"
PAPER_Y0 = (-0.4, -0.2, 0.0, 0.2, 0.4)
PAPER_MU = (0.0, 0.1, 0.2, 0.3, 0.4)

LIVE_FIXTURES = frozenset({"context", "proxy", "endpoints"})
# names (globals or attributes) that start a process or open a socket
LIVE_NAMES = frozenset({"subprocess", "Popen", "executable", "socket", "zmq", "Proxy", "Publisher",
                        "Subscriber", "websockets", "start_server"})
TESTS = Path(__file__).parent

T = TypeVar("T")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "live: starts a process or opens a socket (set by "
                            "tests/conftest.py; `make check` leaves these out)")
    config.addinivalue_line("markers", "slow: a long physics battery or scene (seconds of CPU "
                            "each); `make check` leaves these out, `make test` runs them")


def _names(code: types.CodeType) -> Iterator[str]:
    """The global and attribute names of ``code`` and of the functions nested in it."""
    yield from code.co_names
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            yield from _names(const)


def _code_names(obj: object, seen: set[int]) -> Iterator[str]:
    """The names that ``obj`` (a function or class defined in tests/) uses, followed into the
    functions, classes and fixtures of tests/ that it names."""
    if id(obj) in seen:
        return
    seen.add(id(obj))
    obj = getattr(obj, "__wrapped__", obj)  # a fixture's function
    if isinstance(obj, type):
        members: list[Any] = [m for m in vars(obj).values() if inspect.isfunction(m)]
        for member in members:
            yield from _code_names(member, seen)
        return
    if not inspect.isfunction(obj):
        return
    try:
        source = Path(inspect.getfile(obj)).resolve()
    except TypeError:
        return
    if TESTS not in source.parents:
        return
    for name in _names(obj.__code__):
        yield name
        target = obj.__globals__.get(name)
        if target is not None:
            yield from _code_names(target, seen)


def is_live(item: pytest.Item) -> bool:
    """Whether ``item`` starts a process or opens a socket, as far as its code shows."""
    if LIVE_FIXTURES & set(getattr(item, "fixturenames", ())):
        return True
    function = getattr(item, "function", None)
    if function is None:
        return False
    seen: set[int] = set()
    info = getattr(item, "_fixtureinfo", None)  # the fixtures it uses, as pytest resolved them
    for fixturedefs in (info.name2fixturedefs.values() if info is not None else ()):
        for fixturedef in fixturedefs:
            if LIVE_NAMES & set(_code_names(fixturedef.func, seen)):
                return True
    return bool(LIVE_NAMES & set(_code_names(function, seen)))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("live") is None and is_live(item):
            item.add_marker(pytest.mark.live)


def _refuse(what: str) -> Callable[..., Any]:
    def refused(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError(f"this test {what} but is not marked live: mark it "
                             "@pytest.mark.live (see tests/conftest.py)")
    return refused


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    """Outside ``live`` tests (their setup, call and teardown), starting a process and opening a
    socket raise."""
    if item.get_closest_marker("live") is not None:
        yield
        return
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(subprocess.Popen, "_execute_child", _refuse("starts a process"))
        patch.setattr(socket.socket, "__init__", _refuse("opens a socket"))
        patch.setattr(zmq.Context, "socket", _refuse("opens a ZeroMQ socket"))
        yield


def computed_once(tmp_path_factory: pytest.TempPathFactory, name: str, compute: Callable[[], T]) -> T:
    """``compute()``, computed once per run: under pytest-xdist the first worker to ask computes it
    under a file lock and pickles it into the run's temporary folder (shared by the workers of
    one run, new for every run), and the others load it."""
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        return compute()
    path = tmp_path_factory.getbasetemp().parent / f"{name}.pickle"
    with FileLock(f"{path}.lock"):
        if path.is_file():
            value: T = pickle.loads(path.read_bytes())
            return value
        value = compute()
        path.write_bytes(pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
        return value


def compute_paper_sweeps() -> dict[tuple[float, float], Sweep]:
    """The paper's study (Sec. III): a = 0.5, b = 1, h = 0.4, step 0.001, keyed by (y0, mu)."""
    trails = [Trail(y0, mu) for y0 in PAPER_Y0 for mu in PAPER_MU]
    sweeps = simulate_sweeps(parse_surface(PAPER_SURFACE), trails, step=0.001)
    return {(t.y0, t.mu): s for t, s in zip(trails, sweeps, strict=True)}


@pytest.fixture(scope="session")
def paper_sweeps(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[float, float], Sweep]:
    """:func:`compute_paper_sweeps`, once per run."""
    return computed_once(tmp_path_factory, "paper_sweeps", compute_paper_sweeps)


@pytest.fixture
def context() -> Iterator[zmq.Context[Any]]:
    """A ZeroMQ context, destroyed with linger 0 after the test."""
    ctx: zmq.Context[Any] = zmq.Context()
    yield ctx
    ctx.destroy(linger=0)


@pytest.fixture
def proxy(context: zmq.Context[Any]) -> Iterator[Proxy]:
    """A running XSUB/XPUB proxy on free loopback ports."""
    with Proxy(Endpoints.free(), context=context) as running:
        yield running


@pytest.fixture
def endpoints(proxy: Proxy) -> Endpoints:
    """The endpoints of :func:`proxy`, for publishers and subscribers."""
    assert proxy.endpoints is not None
    return proxy.endpoints
