"""Ticks waiting for the robot pose at their stamp, and the robot poses held until a tick
needs them."""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Sequence

from vibrissa.frame_buffer import FrameBuffer
from vibrissa.msgs import RobotPose, WhiskerWrenchArray

BACKLOG_TIMEOUTS = 10.0
"""Under a backlog that never drains, a wrench waits this many ``pose_timeout_s`` for its pose."""

MAX_HELD_POSES = 20_000
"""The most robot poses `PoseWait` holds (200 s at 100 Hz, about 12 MB)."""


class PoseWait:
    """Ticks (wrenches) waiting for the robot pose at their stamp, in arrival order.

    A wrench is ready when it carries its clamp pose, or when every frame it was measured in
    can be looked up in the map frame at its stamp (the pose stream has passed it; a frame the
    robot description does not have is left out: its rows count as ``unknown_whisker``); one that
    has waited ``timeout_s`` is let through too, and its rows then count as ``no_pose``, but
    only if the input queue was seen empty after that (``take(drained_at=...)``, the clock's
    time the queue was last seen empty): under a backlog, or a process that was not scheduled
    between reading its input and handling it, the pose it waits for may be queued behind, and
    a pose that was sent is not missing. Likewise the wrench stream must have gone on: a wrench
    arrived ``timeout_s`` after it, or the input ended (`end`); a sensor that stopped sending
    between a wrench and its pose (its process not scheduled, on a loaded machine) has not
    lost the pose. A permanent backlog, or a sensor silent for good, still ends the wait,
    after ``BACKLOG_TIMEOUTS`` x ``timeout_s``. The order of the wrenches is kept: one that
    waits holds back those behind it.

    Robot poses given to `hold` go to ``on_pose`` (into ``frames``) in arrival order: as many
    as the front wrench needs when it is not ready without them (in `take`, before any wrench
    times out), the others at `apply_poses`, which the caller calls once the points of what `take`
    let through are out. So a tick that arrives with the next pose (a pose stream ahead of the
    wrenches) is not late by that pose's handling (a tenth of a millisecond live, on one tick in
    ten at 1 kHz ticks and 100 Hz poses). `apply_poses` also keeps back a pose stamped more
    than ``lead_s`` past the newest wrench until it has been held for ``timeout_s`` with no
    wrench coming meanwhile: poses that arrive far ahead of their wrenches (a recording played
    as fast as possible, its poses and wrenches on separate sockets) would push the poses the
    wrenches behind them need out of the frames' history. At most `MAX_HELD_POSES` are held
    (then the oldest goes in). A lookup between two kept poses does not depend on newer ones
    (`vibrissa.frame_buffer`), so the points are the same bits whenever a pose goes in.
    """

    def __init__(self, frames: FrameBuffer | None, map_frame: str, timeout_s: float,
                 clock: Callable[[], float] = time.monotonic,
                 on_pose: Callable[[RobotPose], None] = lambda pose: None,
                 lead_s: float = math.inf) -> None:
        self.frames = frames
        self.map_frame = map_frame
        self.timeout_s = timeout_s
        self.lead_s = lead_s
        self._clock = clock
        self._on_pose = on_pose
        self._queue: deque[tuple[float, WhiskerWrenchArray]] = deque()
        self._poses: deque[tuple[float, RobotPose]] = deque()  # held since, in arrival order
        self._newest = -math.inf  # the newest wrench's stamp
        self._last_wrench = -math.inf  # when the last wrench arrived
        self._ended = False  # the wrench input ended, and no wrench came since

    def __len__(self) -> int:
        return len(self._queue)

    def add(self, msgs: Sequence[WhiskerWrenchArray]) -> None:
        now = self._clock()
        self._queue.extend((now, msg) for msg in msgs)
        if msgs:
            self._newest = max([self._newest, *(msg.stamp for msg in msgs)])
            self._last_wrench = now
            self._ended = False

    def end(self) -> None:
        """The wrench input has ended (its EndOfStream): no wrench will come to show that the
        stream went on, so the waiting ones time out ``timeout_s`` after they arrived."""
        self._ended = True

    def hold(self, pose: RobotPose) -> None:
        """Keep a robot pose until a wrench needs it, or until `apply_poses`."""
        self._poses.append((self._clock(), pose))
        if len(self._poses) > MAX_HELD_POSES:
            self._on_pose(self._poses.popleft()[1])

    def apply_poses(self, drained_at: float | None = None) -> None:
        """Hand the held robot poses to ``on_pose``, in arrival order, up to the first stamped
        more than ``lead_s`` past the newest wrench that had not been held ``timeout_s``
        without a wrench coming when the input queue was last seen empty (``drained_at``, the
        clock's time; None: now). Under a backlog the wrenches are queued, not missing: poses
        let in for them ahead of time would move the history past the wrenches behind."""
        limit = self._newest + self.lead_s if self.lead_s < math.inf else math.inf
        quiet_since = (self._clock() if drained_at is None else drained_at) - self.timeout_s
        while self._poses:
            held_since, pose = self._poses[0]
            if pose.stamp > limit and max(held_since, self._last_wrench) > quiet_since:
                break
            self._poses.popleft()
            self._on_pose(pose)

    def take(self, drained_at: float | None = None) -> list[WhiskerWrenchArray]:
        """The wrenches from the front that are ready or have waited long enough: ``timeout_s``
        before the input queue was last seen empty (``drained_at``, the clock's time; None:
        now) with a wrench arriving ``timeout_s`` after it or the input ended, or
        ``BACKLOG_TIMEOUTS`` x ``timeout_s`` before now. While the front one is not ready and
        poses are held, they go in, oldest first."""
        out = self._take(drained_at, expire=not self._poses)
        while self._queue and self._poses:  # the front one's pose may be held
            self._on_pose(self._poses.popleft()[1])
            out += self._take(drained_at, expire=not self._poses)
        return out

    def _take(self, drained_at: float | None, expire: bool) -> list[WhiskerWrenchArray]:
        out: list[WhiskerWrenchArray] = []
        now = self._clock()
        went_on = now if drained_at is None else min(drained_at, now)
        if not self._ended:
            went_on = min(went_on, self._last_wrench)
        deadline = (max(went_on - self.timeout_s, now - self.timeout_s * BACKLOG_TIMEOUTS)
                    if expire else -math.inf)
        while self._queue:
            arrived, msg = self._queue[0]
            if arrived > deadline and not self._ready(msg):
                break
            out.append(self._queue.popleft()[1])
        return out

    def wait_s(self) -> float:
        """Seconds until the front wrench times out (inf with none waiting), unless a
        wrench comes first."""
        if not self._queue:
            return math.inf
        arrived = self._queue[0][0]
        went_on = self._ended or self._last_wrench >= arrived + self.timeout_s
        waits = self.timeout_s * (1.0 if went_on else BACKLOG_TIMEOUTS)
        return max(0.0, arrived + waits - self._clock())

    def _ready(self, msg: WhiskerWrenchArray) -> bool:
        if msg.has_pose or self.frames is None:
            return True
        return self.frames.covers_rows(self.map_frame, msg.frame_ids, msg.stamp)
