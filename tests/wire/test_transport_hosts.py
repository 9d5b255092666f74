"""The rules of a graph over several hosts, socket-free where they can be: addresses off
loopback need keys, which announced endpoints a subscriber follows, the tools' ``--graph``,
the launch file's host keys."""

from __future__ import annotations

import argparse
import textwrap
from pathlib import Path
from typing import Any

import pytest
import zmq

from vibrissa.cli.graph import graph_address
from vibrissa.launch.description import LaunchFileError, TransportSpec, load_launch_file
from vibrissa.wire.security import KeysError
from vibrissa.wire.transport import Endpoints, Proxy, is_loopback


def test_loopback_is_told_from_other_addresses() -> None:
    assert is_loopback("127.0.0.1") and is_loopback("127.3.2.1") and is_loopback("localhost")
    assert not is_loopback("10.0.0.1") and not is_loopback("0.0.0.0")
    assert not is_loopback("robot.local") and not is_loopback("*")


@pytest.mark.parametrize("host", ["10.213.9.9", "0.0.0.0"])
def test_binding_off_loopback_without_keys_is_refused_unless_insecure(
        host: str, context: zmq.Context[Any]) -> None:
    with pytest.raises(KeysError, match="not on loopback.*--insecure"):
        Proxy(Endpoints.for_domain(900, host), context=context).start()
    if host == "0.0.0.0":  # insecure: bound (every interface), plain text
        proxy = Proxy(Endpoints(f"tcp://{host}:*", f"tcp://{host}:*", insecure=True),
                      context=context)
        assert proxy.start().pub.startswith("tcp://0.0.0.0:")
        proxy.stop()
    else:  # insecure: past the rule, then the address is not this host's
        with pytest.raises(zmq.ZMQError) as info:
            Proxy(Endpoints(f"tcp://{host}:7400", f"tcp://{host}:7401", insecure=True),
                  context=context).start()
        assert not isinstance(info.value, KeysError)


def test_a_subscriber_follows_announced_endpoints_on_other_hosts_only_in_a_graph_off_loopback(
        ) -> None:
    local = Endpoints.for_domain(3)
    assert local.allows_direct("tcp://127.0.0.1:40000")
    assert not local.allows_direct("tcp://10.0.0.2:40000")  # a forged status's
    spanning = Endpoints.for_domain(3, "10.0.0.1")
    assert spanning.allows_direct("tcp://10.0.0.1:40000")
    assert spanning.allows_direct("tcp://10.0.0.2:40000")  # the other host's direct publisher
    for bad in ("tcp://10.0.0.2:x", "tcp://0.0.0.0:40000", "tcp://*:40000", "ipc:///tmp/a",
                "tcp://:40000"):
        assert not spanning.allows_direct(bad), bad


def test_the_direct_host_and_insecure_travel_to_the_nodes_in_the_environment() -> None:
    endpoints = Endpoints("tcp://10.0.0.1:7410", "tcp://10.0.0.1:7411", direct_host="10.0.0.2",
                          insecure=True)
    back = Endpoints.from_env(endpoints.to_env())
    assert back == endpoints
    assert back.direct_bind(1) == "tcp://10.0.0.2:*"
    assert Endpoints.from_env({}).direct_bind(1) == "tcp://127.0.0.1:*"
    with pytest.raises(ValueError, match="both"):
        Endpoints.from_env({"VIBRISSA_PUB_ENDPOINT": "tcp://127.0.0.1:1"})


def test_graph_flag_takes_host_and_domain() -> None:
    assert graph_address("10.0.0.1") == ("10.0.0.1", None)
    assert graph_address("robot.local:12") == ("robot.local", 12)
    for bad in ("10.0.0.1:", "[fd00::1]:2", "a b", "h:x", "h:99999"):
        with pytest.raises(argparse.ArgumentTypeError):
            graph_address(bad)


def _transport(tmp_path: Path, body: str, *overrides: str) -> TransportSpec | None:
    path = tmp_path / "two.yaml"
    path.write_text(textwrap.dedent(f"""\
        launch:
          - arg: {{name: host, default: ""}}
          - transport: {body}
          - node: {{cmd: [x], name: n}}
        """))
    return load_launch_file(path, dict(o.split(":=") for o in overrides)).transport


def test_launch_file_host_keys(tmp_path: Path) -> None:
    spec = _transport(tmp_path, "{bind: 10.0.0.1, on_peer_lost: continue, peer_timeout_s: 3}")
    assert spec == TransportSpec(bind="10.0.0.1", on_peer_lost="continue", peer_timeout_s=3.0)
    # an empty argument leaves the host unset: the same file runs on one host
    assert _transport(tmp_path, "{proxy_host: '$(var host)'}") == TransportSpec()
    assert _transport(tmp_path, "{proxy_host: '$(var host)'}", "host:=10.0.0.1") == \
        TransportSpec(proxy_host="10.0.0.1")
    assert _transport(tmp_path, "{bind: 0.0.0.0, direct_host: 10.0.0.1}") == \
        TransportSpec(bind="0.0.0.0", direct_host="10.0.0.1")
    for body, message in (("{bind: 10.0.0.1, proxy_host: 10.0.0.2}", "not both"),
                          ("{bind: 'tcp://10.0.0.1'}", "host name or IPv4"),
                          ("{proxy_host: h, pub_endpoint: 'tcp://h:1', sub_endpoint: 'tcp://h:2'}",
                           "not both"),
                          ("{on_peer_lost: later}", "shutdown or continue"),
                          ("{bind: 0.0.0.0}", "give direct_host"),
                          ("{proxy_host: h, direct_host: 0.0.0.0}", "give direct_host"),
                          ("{peer_timeout_s: 0.1}", ">= 0.5")):
        with pytest.raises(LaunchFileError, match=message):
            _transport(tmp_path, body)
