"""A launch and the graph tools meet without flags, as ROS 2 nodes do in a domain; two
launches at once never share a graph; a tool that hears nothing says where it looked."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

DOMAIN = 6600 + os.getpid() % 90 * 16  # this test's own range (+0..+14), away from a user's graphs
# and its ports (7400 + 2 domain) below the ephemeral ports (32768-60999) that connections and
# random binds of tests running beside it take


def env_for(domain: int) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("VIBRISSA_")}
    env["VIBRISSA_DOMAIN_ID"] = str(domain)
    return env


class Launch:
    """``vibrissa launch FILE`` in the background, its stderr collected by a thread."""

    def __init__(self, path: Path, env: dict[str, str], *words: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "vibrissa.cli.main", "launch", "--grace", "3", str(path),
             *words], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
        self.err: list[str] = []
        self._reader = threading.Thread(target=lambda: self.err.extend(self.proc.stderr or ()),
                                        daemon=True)
        self._reader.start()

    def wait_line(self, pattern: str, timeout: float = 30.0) -> re.Match[str]:
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in list(self.err):
                if match := rx.search(line):
                    return match
            if self.proc.poll() is not None:
                self._reader.join(5)
                break
            time.sleep(0.05)
        pytest.fail(f"no line matching {pattern!r} in:\n{''.join(self.err)}")

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


def graph_file(tmp_path: Path, namespace: str) -> Path:
    """A graph of one real node: a reconstructor in ``namespace`` (it runs until stopped)."""
    path = tmp_path / f"{namespace.strip('/')}.launch.yaml"
    path.write_text(yaml.safe_dump({"launch": [{"node": {
        "pkg": "vibrissa", "exec": "reconstructor", "name": "reconstructor",
        "namespace": namespace}}]}))
    return path


def tool(env: dict[str, str], *words: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "vibrissa.cli.main", *words], env=env,
                          capture_output=True, text=True, timeout=60)


def test_tools_find_the_launch_without_flags_and_two_launches_do_not_mix(tmp_path: Path) -> None:
    env = env_for(DOMAIN)
    first = Launch(graph_file(tmp_path, "/graph_a"), env)
    second = None
    try:
        first.wait_line(rf"proxy: .*\(domain {DOMAIN};")
        first.wait_line(r"started 'reconstructor'")
        second = Launch(graph_file(tmp_path, "/graph_b"), env)
        second.wait_line(rf"domain {DOMAIN} is in use by another graph; this graph runs on "
                         rf"domain {DOMAIN + 1}")
        second.wait_line(rf"tools: --domain {DOMAIN + 1} or VIBRISSA_DOMAIN_ID={DOMAIN + 1}")
        listed = tool(env, "topic", "list", "--listen", "2")  # no flags: the environment's domain
        assert listed.returncode == 0, listed.stderr
        assert "/graph_a/wrench" in listed.stdout and "/graph_a/reconstructor" in listed.stdout
        assert "/graph_b" not in listed.stdout
        other = tool(env, "topic", "list", "--listen", "2", "--domain", str(DOMAIN + 1))
        assert other.returncode == 0, other.stderr
        assert "/graph_b/wrench" in other.stdout and "/graph_a" not in other.stdout
    finally:
        codes = [launch.stop() for launch in (second, first) if launch is not None]
    assert codes == [128 + signal.SIGINT] * 2


def test_a_domain_asked_for_must_be_free(tmp_path: Path) -> None:
    env = env_for(DOMAIN + 7)
    first = Launch(graph_file(tmp_path, "/graph_a"), env)
    try:
        first.wait_line(rf"\(domain {DOMAIN + 7};")
        second = tool(env, "launch", str(graph_file(tmp_path, "/graph_b")), "--domain",
                      str(DOMAIN + 7))
        assert second.returncode == 1
        assert f"cannot start the proxy: domain {DOMAIN + 7} is in use" in second.stderr
        assert "choose a free one with --domain N" in second.stderr
    finally:
        first.stop()


def test_a_tool_that_hears_nothing_says_where_it_looked_and_where_graphs_run(
    tmp_path: Path,
) -> None:
    quiet = tool(env_for(DOMAIN + 12), "topic", "list", "--listen", "0.3")
    assert quiet.returncode == 1
    assert f"no running graph heard on domain {DOMAIN + 12}" in quiet.stderr
    # what it suggests depends on graphs elsewhere (tests in parallel run some on domain 0..)
    assert ("start one (`vibrissa launch demo`)" in quiet.stderr
            or "graphs are running on domain" in quiet.stderr)
    running = Launch(graph_file(tmp_path, "/graph_a"), env_for(DOMAIN + 14))
    try:
        running.wait_line(rf"\(domain {DOMAIN + 14};")
        hint = tool(env_for(DOMAIN + 12), "topic", "list", "--listen", "0.3")
        assert hint.returncode == 1
        # (among graphs other tests run beside it: "domain 6694, 8456: pass ...")
        assert re.search(rf"graphs are running on domain [\d, ]*\b{DOMAIN + 14}\b[\d, ]*: pass "
                         "--domain N",
                         hint.stderr), hint.stderr
        echo = tool(env_for(DOMAIN + 12), "topic", "echo", "/x", "--timeout", "0.5")
        assert echo.returncode == 1
        assert "no message on /x for 0.5 s (0 printed)" in echo.stderr
    finally:
        running.stop()
