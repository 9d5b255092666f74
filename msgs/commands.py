"""Commands to a node (one type so far: a sensor's bias request).

Registered in ``MESSAGE_TYPES`` with the other types when ``vibrissa.msgs`` is imported, so
that the one codec encodes and decodes it like any message.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from vibrissa.msgs.messages import MESSAGE_TYPES, Message, _stamp, _text

SENSOR_COMMANDS = ("bias",)


@dataclass(frozen=True, eq=False)
class SensorCommand(Message):
    """A request to a sensor driver on its command topic (``vibrissa sensor bias NAME``)."""

    TYPE_NAME: ClassVar[str] = "vibrissa/SensorCommand"
    VERSION: ClassVar[int] = 1

    stamp: float = _stamp()
    command: str = _text("'bias': tare the sensor, if its rod is free", choices=SENSOR_COMMANDS)
    sender: str = _text("who asks (a node or a tool), for the driver's log")


MESSAGE_TYPES[SensorCommand.TYPE_NAME] = SensorCommand
