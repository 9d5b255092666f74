"""Wire messages of vibrissa: one dataclass per message type (``messages``), with units and
frames in the field docs. Their one codec is ``vibrissa.msgs.codec`` (``encode``/``decode``),
imported by name, so that a library using the types loads no msgpack."""

from vibrissa.msgs.messages import (
    MESSAGE_TYPES,
    ContactCloud,
    ContactPhase,
    ContactPointArray,
    ContactStatus,
    EndOfStream,
    Message,
    NodeStatus,
    PathSegment,
    Ping,
    RobotPose,
    SensorCommand,
    SnapEvent,
    SurfaceMesh,
    SweepProposal,
    WhiskerWrenchArray,
)

__all__ = [
    "MESSAGE_TYPES",
    "ContactCloud",
    "ContactPhase",
    "ContactPointArray",
    "ContactStatus",
    "EndOfStream",
    "Message",
    "NodeStatus",
    "PathSegment",
    "Ping",
    "RobotPose",
    "SensorCommand",
    "SnapEvent",
    "SurfaceMesh",
    "SweepProposal",
    "WhiskerWrenchArray",
]
