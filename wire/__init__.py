"""Wire transport of vibrissa: ZeroMQ proxy, publishers, subscribers and topic names."""

from vibrissa.wire.topics import STATUS_TOPIC, node_fqn, resolve_topic, validate_name
from vibrissa.wire.transport import (
    DEFAULT_HWM,
    Endpoints,
    Header,
    Proxy,
    Publisher,
    Received,
    Subscriber,
    TopicCounters,
)

__all__ = [
    "DEFAULT_HWM",
    "STATUS_TOPIC",
    "Endpoints",
    "Header",
    "Proxy",
    "Publisher",
    "Received",
    "Subscriber",
    "TopicCounters",
    "node_fqn",
    "resolve_topic",
    "validate_name",
]
