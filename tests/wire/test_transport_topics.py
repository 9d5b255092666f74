"""Topic name resolution (ROS 2 rules) and endpoint derivation."""

from __future__ import annotations

import pytest

from vibrissa.wire import Endpoints, node_fqn, resolve_topic


@pytest.mark.parametrize(
    ("name", "namespace", "expected"),
    [
        ("/whisker0/wrench", "/", "/whisker0/wrench"),
        ("/whisker0/wrench", "/other", "/whisker0/wrench"),
        ("wrench", "/", "/wrench"),
        ("wrench", "/whisker0", "/whisker0/wrench"),
        ("raw/wrench", "/a/b", "/a/b/raw/wrench"),
    ],
)
def test_resolution(name: str, namespace: str, expected: str) -> None:
    assert resolve_topic(name, namespace) == expected


def test_remaps_apply_to_the_resolved_name() -> None:
    remaps = {"wrench": "/sim/wrench", "/x": "y"}
    assert resolve_topic("wrench", "/w0", remaps) == "/sim/wrench"
    assert resolve_topic("/w0/wrench", "/w0", remaps) == "/sim/wrench"
    assert resolve_topic("wrench", "/w1", {"/w0/wrench": "/z"}) == "/w1/wrench"
    assert resolve_topic("/x", "/ns", remaps) == "/ns/y"
    assert resolve_topic("contact", "/w0", remaps) == "/w0/contact"


@pytest.mark.parametrize("bad", ["", "a//b", "a/", "/a/", "1abc", "a-b", "~/x", "a b", "/a/2b"])
def test_invalid_names_are_named(bad: str) -> None:
    with pytest.raises(ValueError, match="invalid topic name"):
        resolve_topic(bad, "/")


def test_invalid_namespace_and_remap_are_named() -> None:
    with pytest.raises(ValueError, match="namespace 'ns'"):
        resolve_topic("x", "ns")
    with pytest.raises(ValueError, match="'bad-target'"):
        resolve_topic("x", "/", {"x": "bad-target"})


def test_node_fqn() -> None:
    assert node_fqn("sensor") == "/sensor"
    assert node_fqn("sensor", "/whisker0") == "/whisker0/sensor"
    with pytest.raises(ValueError, match="node name 'a/b'"):
        node_fqn("a/b")


def test_endpoints_from_env() -> None:
    assert Endpoints.from_env({}) == Endpoints("tcp://127.0.0.1:7400", "tcp://127.0.0.1:7401")
    assert Endpoints.from_env({"VIBRISSA_DOMAIN_ID": "3"}) == Endpoints.for_domain(3)
    assert Endpoints.for_domain(3).sub == "tcp://127.0.0.1:7407"
    env = {"VIBRISSA_PUB_ENDPOINT": "tcp://h:1", "VIBRISSA_SUB_ENDPOINT": "tcp://h:2"}
    assert Endpoints.from_env(env) == Endpoints("tcp://h:1", "tcp://h:2")
    assert Endpoints.from_env(Endpoints("tcp://h:1", "tcp://h:2").to_env()).pub == "tcp://h:1"
    with pytest.raises(ValueError, match="VIBRISSA_DOMAIN_ID"):
        Endpoints.from_env({"VIBRISSA_DOMAIN_ID": "x"})
    with pytest.raises(ValueError, match="both"):
        Endpoints.from_env({"VIBRISSA_PUB_ENDPOINT": "tcp://h:1"})
