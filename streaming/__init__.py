"""Streaming Step 2: whisker wrenches and robot poses in, contact points out, without sockets.

A `Step2Stream`, built from `StreamSettings`, takes ticks (``WhiskerWrenchArray``: the base
wrenches f0 N, m0 N m of a sensor array, each row in its clamp frame C, with or without the
clamp poses X_PC) and robot poses (``RobotPose``), both in arrival order, and gives one
``ContactPointArray`` per tick (same ``stamp`` and ``seq``, in the poses' frame when the tick
carried them, else in ``map_frame``) with the rows that have a consistent contact (status OK or
AXIAL_LOAD) and, in ``free_ids``, the whiskers found free (a zero wrench, or below the noise
threshold), in the order the ticks came::

    stream = Step2Stream(StreamSettings(whiskers=robot.whiskers))
    stream.add_poses(poses)
    stream.add_wrenches(ticks)
    for outcome in stream.take():
        use(outcome.contacts)

Placing: a tick without clamp poses is placed through the robot description's mounts
(``whiskers``: each whisker's clamp frame at X_RC on ``robot_frame``) and the robot's poses,
interpolated at the tick's stamp in a frame buffer (`vibrissa.frame_buffer`, no extrapolation).
A tick waits until the poses cover its stamp (`PoseWait`), or ``pose_timeout_s`` while the
ticks go on (`Step2Stream.end_wrenches` when they have ended); poses are held until a tick
needs them or `Step2Stream.apply_poses`, so a tick is not late by a pose it does not need.

Step 2 in SI, with the clamp pose and each row's ``vibrissa.units.RodScale`` (its whisker's
from ``whiskers``, else ``rod``), is the core's ``vibrissa.reconstruct.reconstruct_si``; the
ticks let through together go through one call (`reconstruct_messages`), and a row's point
does not depend on the batch it came in.

Noisy sensors: with the free-rod noise (``noise_force_n``, ``noise_moment_nm``: std per axis) a
whisker is in contact only between a wrench threshold and its release, with hysteresis
(``vibrissa.contact_detection``: enter at ``contact_on_sigmas``, leave below
``contact_off_sigmas``, in units of the noise), so that a free rod's noise never becomes points
on the map; every point then carries its covariance (m^2, from the noise through Step 2,
``vibrissa.uncertainty``), and a contact found past the tip within ``tip_sigmas`` std of s1 is
the tip (status TIP_WITHIN_NOISE). Without a noise model every wrench with a force is a contact
and points carry no covariance.

Rows without a consistent contact are counted, not returned: a point-less reconstruction
carries NaN, and a point with finite placeholder zeros would be a point on the map.
`Step2Stream.counts`, in rows: ``contacts`` (points returned), ``free`` (below the contact
threshold: the rod is free), ``tip_within_noise`` (points that are the tip within the noise),
``no_covariance`` (points whose covariance is not defined, an axial load: they carry L^2 I, the
rod's reach), ``no_contact`` (valid wrench, no consistent contact, or a result that overflows to
inf near the float limit), ``multi_contact`` (of those, wrenches no single contact gives:
two contacts on the rod, beyond the noise), ``ambiguous`` (points of a tapered or pre-curved
rod chosen among several that fit, `ContactMemory` not deciding), ``bad_pose`` (clamp
quaternion of zero or non-finite length), ``no_pose`` (no clamp pose at the tick's stamp
within ``pose_timeout_s``), ``unknown_whisker`` (not in the robot description),
``wrong_frame`` (measured, by its ``frame_ids``, in another frame than its whisker's clamp
frame: placed there it would get another whisker's mount); and
``robot_poses``, ``bad_robot_pose`` (poses put in the frame buffer, refused),
``pose_time_jumps``, ``pose_reparents`` (histories dropped: a new timeline, a new parent frame;
`vibrissa.frame_buffer`), ``batches`` and ``max_batch`` (Step 2 calls and the most ticks in
one).

`warm_up` compiles (or loads from numba's cache) every kernel the stream calls, before the
first tick.
"""

from vibrissa.streaming.pose_wait import BACKLOG_TIMEOUTS, MAX_HELD_POSES, PoseWait
from vibrissa.streaming.step2 import Reconstructed, Rods, RodTable, reconstruct_messages, robot_frames
from vibrissa.streaming.stream import (
    COUNTS,
    Step2Stream,
    StreamSettings,
    Warnings,
    pose_handler,
    warm_up,
)

__all__ = [
    "BACKLOG_TIMEOUTS",
    "COUNTS",
    "MAX_HELD_POSES",
    "PoseWait",
    "Reconstructed",
    "RodTable",
    "Rods",
    "Step2Stream",
    "StreamSettings",
    "Warnings",
    "pose_handler",
    "reconstruct_messages",
    "robot_frames",
    "warm_up",
]
