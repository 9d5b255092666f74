"""What a graph's nodes say they moved, from their statuses on ``/vibrissa/status``: per node
its counters over all its starts, the topics it publishes and takes, and what reached a node
from the nodes upstream of it. The launcher's summary and the mapper's report read it."""

from __future__ import annotations

from dataclasses import dataclass

from vibrissa.msgs import NodeStatus


@dataclass(frozen=True)
class Upstream:
    """One node upstream of another, as its statuses tell: what it received, lost and refused
    of its own input (all its starts), and what its producers published when every topic
    they publish is one it takes (``sent_to_it``; None otherwise: their messages went
    elsewhere too)."""

    node: str
    received: int
    lost: int
    rejected: int
    sent_to_it: int | None


class Traffic:
    """What the nodes' statuses say they moved: per node, the last counters of each of its
    starts, summed (a respawned node counts from 0 again)."""

    KEYS = ("published", "received", "lost", "rejected", "anomalies", "refused_peers")

    def __init__(self) -> None:
        self._banked: dict[str, dict[str, int]] = {}
        self._current: dict[str, dict[str, int]] = {}
        self._topics: dict[str, tuple[set[str], set[str]]] = {}  # fqn -> published, taken

    def add(self, status: NodeStatus) -> None:
        """Take a node's status."""
        published, taken = self._topics.setdefault(status.node, (set(), set()))
        published.update(status.publishes)
        taken.update(status.subscribes)
        counts = {key: int(status.counters.get(key, 0)) for key in self.KEYS}
        current = self._current.get(status.node)
        if current is not None and (counts["published"] < current["published"]
                                    or counts["received"] < current["received"]):
            banked = self._banked.setdefault(status.node, dict.fromkeys(self.KEYS, 0))
            for key in self.KEYS:  # a new start: what the last one moved stays counted
                banked[key] += current[key]
        self._current[status.node] = counts

    def publishes(self, fqn: str) -> set[str]:
        """The topics the node said it publishes, in any of its starts."""
        return self._topics.get(fqn, (set(), set()))[0]

    def subscribes(self, fqn: str) -> set[str]:
        """The topics the node said it takes, in any of its starts."""
        return self._topics.get(fqn, (set(), set()))[1]

    def of(self, fqn: str) -> dict[str, int] | None:
        """The node's totals, or None if it never reported."""
        if fqn not in self._current:
            return None
        banked = self._banked.get(fqn, dict.fromkeys(self.KEYS, 0))
        return {key: banked[key] + self._current[fqn][key] for key in self.KEYS}

    def upstream_of(self, fqn: str) -> list[Upstream]:
        """The nodes whose messages reach ``fqn`` (through any chain of topics), nearest
        first, each with what reached it."""
        found: list[str] = []
        frontier = [fqn]
        while frontier:
            node = frontier.pop(0)
            for other in sorted(self._topics):
                if other != fqn and other not in found and self.publishes(other) & self.subscribes(node):
                    found.append(other)
                    frontier.append(other)
        result = []
        for node in found:
            totals = self.of(node) or dict.fromkeys(self.KEYS, 0)
            producers = [p for p in self._topics if p != node and self.publishes(p) & self.subscribes(node)]
            whole = producers and all(self.publishes(p) <= self.subscribes(node) for p in producers)
            sent = sum((self.of(p) or {}).get("published", 0) for p in producers) if whole else None
            result.append(Upstream(node, totals["received"], totals["lost"], totals["rejected"], sent))
        return result
