"""Shared fixtures: the paper's 25 sweeps are computed once per test session.

Per test: a ZeroMQ ``context``, a running ``proxy`` on free loopback ports and its ``endpoints``.
"""

from collections.abc import Iterator
from typing import Any

import pytest
import zmq

from vibrissa.surfaces import parse_surface
from vibrissa.sweep import Sweep, Trail, simulate_sweeps
from vibrissa.wire import Endpoints, Proxy

PAPER_SURFACE = "paraboloid:a=0.5,b=1,h=0.4"
PAPER_Y0 = (-0.4, -0.2, 0.0, 0.2, 0.4)
PAPER_MU = (0.0, 0.1, 0.2, 0.3, 0.4)


@pytest.fixture(scope="session")
def paper_sweeps() -> dict[tuple[float, float], Sweep]:
    """The paper's study (Sec. III): a = 0.5, b = 1, h = 0.4, step 0.001, keyed by (y0, mu)."""
    trails = [Trail(y0, mu) for y0 in PAPER_Y0 for mu in PAPER_MU]
    sweeps = simulate_sweeps(parse_surface(PAPER_SURFACE), trails, step=0.001)
    return {(t.y0, t.mu): s for t, s in zip(trails, sweeps, strict=False)}


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
