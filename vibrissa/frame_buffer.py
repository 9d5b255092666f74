"""Frames over time, with tf2's semantics: a tree of named frames, each child with one parent,
joined by static transforms (a whisker's mount) or by stamped poses (the robot in ``world`` or
``odom``, from a pose stream).

A frame with stamped poses moves to a new parent when a pose names one (tf2 lets a frame's
parent change over time): its history under the old parent is dropped, so that one stray pose
in another frame costs a few lookups, not the stream. A static frame keeps its parent.

A lookup at a stamp composes the transforms along the tree, each stamped one interpolated
between the two poses around the stamp (position linear, orientation slerp, the rule of
`vibrissa.frames.PoseSamples`, with the compiled quaternion kernels of `vibrissa.frames`: a
sensor tick cannot spend scipy's per-call cost); `lookup_many` does it for many stamps at once
and `lookup_rows` for the rows of a sensor array. It never extrapolates: a stamp newer than
the last pose or older than the kept history is an `ExtrapolationError` naming the frames and
the times.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from vibrissa.frames import (
    Transform,
    mounted_poses,
    mounted_poses_between,
    pose_between,
    quaternion_products,
    quaternion_rotate,
    quaternion_slerp,
)

__all__ = ["MAX_DEPTH", "MAX_FRAMES", "MAX_POSES", "ConnectivityError", "ExtrapolationError",
           "FrameBuffer", "FrameError", "RowPoses"]

DEFAULT_HISTORY_S = 10.0
MAX_FRAMES = 1024
"""The most frames a buffer holds: a pose naming a new frame beyond it is refused (ValueError),
so that a stream of invented frame names cannot grow it without end."""
MAX_DEPTH = 32
"""The most frames from a frame up to its root (a robot's tree is a few deep): with
`MAX_POSES` per stamped edge it bounds what one chain of invented parents can hold."""
MAX_POSES = 100_000
"""The most stamped poses kept per edge (10 s at 10 kHz); beyond it the oldest are forgotten,
so that a flood of poses shortens the history instead of growing the memory."""
TIME_JUMP_POSES = 3
"""A pose older than its edge's kept history is refused; this many in a row, each newer than the
one before, are a new timeline (a simulation or a bag started again, a clock set back, or one
stray pose stamped far ahead of the stream): the edge forgets its history and keeps the last
of them. So one bad stamp costs a few poses, not the stream."""

FloatArray = NDArray[np.float64]

_SHOWN = 8  # frame names an error lists at most


def _short(name: str) -> str:
    """A frame name as an error shows it: at most 40 characters (names come off the wire)."""
    return name if len(name) <= 40 else name[:37] + "..."


def _known(frames: set[str]) -> str:
    """The first `_SHOWN` of ``frames``, sorted and shortened, and how many there are."""
    if not frames:
        return "none yet"
    names = sorted(frames)
    shown = ", ".join(_short(name) for name in names[:_SHOWN])
    return shown if len(names) <= _SHOWN else f"{shown}, ... ({len(names)} in all)"


class FrameError(LookupError):
    """A transform that cannot be looked up; the message names the frames and times."""


class ExtrapolationError(FrameError):
    """The stamp lies outside the poses kept for an edge of the chain (never extrapolated)."""


class ConnectivityError(FrameError):
    """No chain of transforms joins the two frames."""


@dataclass
class _Edge:
    """X_parent_child: static (``stamps`` empty) or stamped poses in increasing time."""

    parent: str
    static: Transform | None = None
    stamps: list[float] = field(default_factory=list)
    poses: list[FloatArray] = field(default_factory=list)  # (x, y, z, qx, qy, qz, qw) each
    arrays: tuple[FloatArray, FloatArray, FloatArray] | None = None  # of stamps and poses
    refused: list[float] = field(default_factory=list)  # stamps of the too old poses in a row

    def kept(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Stamps (n,), positions (n, 3) and quaternions (n, 4) of the kept poses (made at
        the first lookup after a change)."""
        if self.arrays is None:
            poses = np.array(self.poses)
            self.arrays = (np.array(self.stamps), poses[:, :3], poses[:, 3:])
        return self.arrays

    def _around(self, stamp: float) -> tuple[int, float | None]:
        """The kept pose at or before ``stamp`` (within the kept ones) and the fraction of the
        way to the next; None at the newest stamp (or the only pose): that pose, bit for bit."""
        i = bisect.bisect_right(self.stamps, stamp) - 1
        if i == len(self.stamps) - 1:
            return i, None
        return i, (stamp - self.stamps[i]) / (self.stamps[i + 1] - self.stamps[i])

    def gap_around(self, stamp: float, max_gap_s: float) -> tuple[float, float] | None:
        """The stamps of the kept poses around ``stamp`` (on neither) when they are more than
        ``max_gap_s`` apart, else None."""
        stamps = self.stamps
        k = bisect.bisect_right(stamps, stamp) - 1
        if (0 <= k < len(stamps) - 1 and stamp != stamps[k]
                and stamps[k + 1] - stamps[k] > max_gap_s):
            return stamps[k], stamps[k + 1]
        return None

    def covers(self, stamp: float, max_gap_s: float) -> bool:
        """Whether a lookup at ``stamp`` reads a static edge or interpolates between kept
        poses at most ``max_gap_s`` apart."""
        return self.static is not None or (self.stamps[0] <= stamp <= self.stamps[-1]
                                           and self.gap_around(stamp, max_gap_s) is None)

    def mounted_at(self, stamp: float, p_AC: FloatArray, q_AC_xyzw: FloatArray
                   ) -> tuple[FloatArray, FloatArray]:
        """Frames mounted at (p_AC (N, 3), q_AC (N, 4)) on this stamped edge's child, in its
        parent at ``stamp`` (within the kept poses): `at` of a tick composed with every mount
        (`vibrissa.frames.mounted_poses`), in one compiled call."""
        i, fraction = self._around(stamp)
        pose = self.poses[i]
        if fraction is None:
            return mounted_poses(pose[:3], pose[3:], p_AC, q_AC_xyzw)
        return mounted_poses_between(pose, self.poses[i + 1], fraction, p_AC, q_AC_xyzw)

    def at(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Positions (n, 3) and quaternions (n, 4) at stamps ``t`` (n,) within the kept ones:
        position linear, orientation slerp between the two poses around each stamp; at a kept
        stamp, that pose bit for bit (whether newer poses have arrived or not), so that a
        lookup does not depend on when it is made."""
        if self.static is not None:
            return (np.tile(self.static.translation, (len(t), 1)),
                    np.tile(self.static.quaternion_xyzw, (len(t), 1)))
        if len(t) == 1:  # a tick: the two poses around it, without the arrays of all kept
            i, fraction = self._around(float(t[0]))
            if fraction is None:
                return self.poses[i][None, :3].copy(), self.poses[i][None, 3:].copy()
            return pose_between(self.poses[i], self.poses[i + 1], fraction)
        stamps, p, q = self.kept()
        if len(stamps) == 1:  # one pose, and every stamp is its stamp
            return np.tile(p[0], (len(t), 1)), np.tile(q[0], (len(t), 1))
        k = np.clip(np.searchsorted(stamps, t, side="right") - 1, 0, len(stamps) - 2)
        frac = (t - stamps[k]) / (stamps[k + 1] - stamps[k])
        p_t = p[k] + frac[:, None] * (p[k + 1] - p[k])  # exact at frac 0, not always at 1
        q_t = quaternion_slerp(q[k], q[k + 1], frac)
        newest = frac == 1.0  # t is the newest stamp
        if newest.any():
            p_t[newest], q_t[newest] = p[-1], q[-1]
        return p_t, q_t


@dataclass
class RowPoses:
    """Poses of rows (n) from `FrameBuffer.lookup_rows`: whether each was found, its position
    (n, 3) and quaternion (x, y, z, w) (n, 4) (NaN and identity where not), and the errors of
    the rows not found (each distinct message once)."""

    ok: NDArray[np.bool_]
    p: NDArray[np.float64]
    q_xyzw: NDArray[np.float64]
    errors: list[str]

    @classmethod
    def none_found(cls, n: int, error: str | None = None) -> RowPoses:
        """``n`` rows none of which was found (and the error why, when given)."""
        identity = np.zeros((n, 4))
        identity[:, 3] = 1.0
        return cls(np.zeros(n, bool), np.full((n, 3), np.nan), identity,
                   [] if error is None else [error])

    def note(self, error: str) -> None:
        if error not in self.errors:
            self.errors.append(error)


_RowPlan = tuple[dict[str, NDArray[np.int64]], FloatArray, FloatArray, list[str], NDArray[np.bool_]]
_MAX_PLANS = 64


class FrameBuffer:
    """Static and stamped transforms between named frames; `lookup` at any stamp the kept
    poses cover. Poses older than ``history_s`` behind the newest of their edge are forgotten,
    and so are the oldest beyond `MAX_POSES` an edge; at most `MAX_FRAMES` frames. Two kept
    poses more than ``max_gap_s`` apart are not interpolated between (a pose stream that
    stopped, or one pose stamped far ahead of it): a stamp between them is an
    `ExtrapolationError` too."""

    def __init__(self, history_s: float = DEFAULT_HISTORY_S, max_gap_s: float = math.inf,
                 gap_name: str = "max_gap_s") -> None:
        if not history_s > 0:
            raise ValueError(f"history_s must be > 0, got {history_s}")
        if not max_gap_s > 0:
            raise ValueError(f"max_gap_s must be > 0, got {max_gap_s}")
        self.history_s = history_s
        self.max_gap_s = max_gap_s
        self.gap_name = gap_name  # how errors name max_gap_s (a node's parameter)
        self._edges: dict[str, _Edge] = {}  # by child frame
        self._frames: set[str] = set()
        self._anchors: dict[str, tuple[str, FloatArray, FloatArray]] = {}  # lookup_rows'
        self._plans: dict[tuple[str, ...], _RowPlan] = {}  # lookup_rows' of frame lists
        self._newest: dict[tuple[str, str], float | None] = {}  # newest's, by (target, anchor)
        self._splits: dict[tuple[str, str], tuple[list[str], list[str]]] = {}  # _lookup's
        self._stamped: dict[tuple[str, str], list[_Edge]] = {}  # has_gap_rows', by (target, anchor)

    @property
    def frames(self) -> set[str]:
        """Every frame named so far."""
        return set(self._frames)

    def set_static(self, parent: str, child: str, X_parent_child: Transform) -> None:
        """A transform that does not change (a mount); replaces an earlier static one."""
        edge = self._edge(parent, child, static=True)
        edge.static = X_parent_child
        self._forget_tree()  # the mounts composed into anchors and plans

    def add(self, parent: str, child: str, stamp: float, X_parent_child: Transform
            ) -> float | None:
        """The pose of ``child`` in ``parent`` at ``stamp`` (s); a different pose at a stamp
        already kept is refused (ValueError; tf2 keeps the first too), the same one ignored.
        A pose naming another parent than the kept ones' moves ``child`` there (its history
        goes; a static frame is refused). One older than the kept history is refused
        (ValueError), unless it is the `TIME_JUMP_POSES`-th such in a row: then the edge starts
        again from it, and the newest stamp of the history it forgot is returned (else
        None)."""
        return self.add_pose(parent, child, stamp, X_parent_child.translation,
                             X_parent_child.quaternion_xyzw)

    def add_pose(self, parent: str, child: str, stamp: float, position: ArrayLike,
                 quaternion_xyzw: ArrayLike) -> float | None:
        """`add` from a position (3,) and a quaternion (x, y, z, w) (normalised here) as a pose
        message has them, without building a `Transform`; ValueError names what is wrong (a
        stamp, position or quaternion that is not finite, a zero quaternion, a stamp older
        than the kept history)."""
        if not math.isfinite(stamp):
            raise ValueError(f"stamp of {child} in {parent} must be finite, got {stamp}")
        p = np.asarray(position, dtype=float).reshape(3)
        q = np.asarray(quaternion_xyzw, dtype=float).reshape(4)
        scale = float(np.max(np.abs(q)))  # scaled first: |q|^2 of (0, 0, 1e300, 1e300) overflows
        norm = scale * math.sqrt(float((q / scale) @ (q / scale))) if scale > 0 else 0.0
        if not (np.isfinite(p).all() and 0.0 < norm < math.inf):
            raise ValueError(f"pose of {child} in {parent} at t={stamp!r}: position {p.tolist()} "
                             f"and quaternion {q.tolist()} must be finite, the quaternion "
                             "non-zero")
        edge = self._edge(parent, child, static=False)
        forgotten = None
        if edge.stamps and stamp < edge.stamps[-1] - self.history_s:
            if edge.refused and stamp <= edge.refused[-1]:
                edge.refused.clear()
            edge.refused.append(stamp)
            if len(edge.refused) < TIME_JUMP_POSES:
                raise ValueError(
                    f"pose of {child} in {parent} at t={stamp!r}: older than the kept history "
                    f"(the newest pose is at t={edge.stamps[-1]!r}, {self.history_s:g} s are "
                    f"kept); {TIME_JUMP_POSES - len(edge.refused)} more such, each newer, "
                    "start the history again")
            forgotten = edge.stamps[-1]
            edge.stamps.clear()
            edge.poses.clear()
        edge.refused.clear()
        edge.arrays = None
        self._newest.clear()
        pose = np.concatenate([p, q / norm])
        k = bisect.bisect_left(edge.stamps, stamp)
        if k < len(edge.stamps) and edge.stamps[k] == stamp:
            if not np.array_equal(edge.poses[k], pose):  # as tf2: the first pose of a stamp
                raise ValueError(f"pose of {_short(child)} in {_short(parent)} at t={stamp!r}: "
                                 "another pose has this stamp already (kept)")
            return forgotten
        edge.stamps.insert(k, stamp)
        edge.poses.insert(k, pose)
        old = max(bisect.bisect_left(edge.stamps, edge.stamps[-1] - self.history_s),
                  len(edge.stamps) - MAX_POSES)
        if old:
            del edge.stamps[:old], edge.poses[:old]
        return forgotten

    def newest(self, target: str, source: str) -> float | None:
        """The newest stamp at which ``source`` can be looked up in ``target``: the oldest of
        the newest poses of the stamped edges between them (inf when all are static); None
        when a frame is unknown or the two are not joined (yet). Kept until the next change:
        the clamps of a robot share one answer (their anchor's)."""
        anchored = self._anchor(source)
        return None if anchored is None else self._newest_at(target, anchored[0])

    def newest_rows(self, target: str, sources: Sequence[str]) -> float | None:
        """`newest` of the known ``sources`` (the rows of a sensor array): the oldest of
        theirs (inf with none known), None when a known one is not joined to ``target``. An
        unknown frame is left out: waiting for poses does not make it known."""
        return self._newest_of(target, self._row_plan(sources))

    def covers_rows(self, target: str, sources: Sequence[str], stamp: float) -> bool:
        """Whether the known ``sources`` can be looked up in ``target`` at ``stamp`` without
        waiting for more poses: `newest_rows` >= ``stamp`` and no `has_gap_rows` (one look
        at the rows' plan for both: a tick asks it before its lookup)."""
        plan = self._row_plan(sources)
        newest = self._newest_of(target, plan)
        return newest is not None and newest >= stamp and not self._gap_in(target, plan, stamp)

    def _row_plan(self, sources: Sequence[str]) -> _RowPlan:
        """The plan of a list of frames (`_plan`), kept while it has no unknown frame."""
        key = tuple(sources)
        plan = self._plans.get(key)
        return self._plan(key) if plan is None else plan

    def _newest_of(self, target: str, plan: _RowPlan) -> float | None:
        newest = math.inf
        for anchor in plan[0]:
            at_anchor = self._newest_at(target, anchor)
            if at_anchor is None:
                return None
            newest = min(newest, at_anchor)
        return newest

    def _newest_at(self, target: str, anchor: str) -> float | None:
        """`newest` of a frame whose edge to its parent is stamped (the static edges below an
        anchor limit nothing), kept until the next change."""
        key = (target, anchor)
        if key in self._newest:
            return self._newest[key]
        try:
            up_source, root_source = self._chain(anchor)
            up_target, root_target = self._chain(target)
        except ConnectivityError:
            return None
        if root_source != root_target:
            newest = None
        else:
            while up_source and up_target and up_source[-1] == up_target[-1]:  # the common part
                up_source.pop()
                up_target.pop()
            newest = min((self._edges[f].stamps[-1] for f in up_source + up_target
                          if self._edges[f].stamps), default=math.inf)
        self._newest[key] = newest
        return newest

    def lookup_rows(self, target: str, sources: Sequence[str], stamps: ArrayLike | float
                    ) -> RowPoses:
        """X_target_source of each row (n): frame ``sources[i]`` at ``stamps[i]`` (or every
        row at ``stamps`` when it is one number: a sensor tick), for the rows of a sensor array
        (frames under one moving frame, stamps shared).

        Each source is split into its static part up to its first stamped ancestor A (a
        mount, composed once) and A at the row's stamps; rows are looked up per A and per
        distinct stamp, so a tick of 32 clamps on one robot costs one interpolation. A row that
        cannot be looked up has ``ok`` False and its error in ``errors``; nothing raises.
        """
        n = len(sources)
        # one stamp (a sensor tick): no array of it unless the rows need more than one pose
        t = (None if isinstance(stamps, float) or np.ndim(stamps) == 0
             else np.asarray(stamps, dtype=float).reshape(-1))
        if t is not None and len(t) != n:
            raise ValueError(f"{n} sources for {len(t)} stamps")
        by_anchor, mount_p, mount_q, unknown, all_ok = self._row_plan(sources)
        if not unknown and len(by_anchor) == 1 and n and (t is None or (t == t[0]).all()):
            # a tick of frames under one moving frame: one pose, composed with every mount
            stamp = float(cast(float, stamps) if t is None else t[0])
            (anchor,) = by_anchor
            edge = self._edges.get(anchor)
            try:
                if edge is not None and edge.parent == target:  # a robot's pose in the map
                    if not edge.covers(stamp, self.max_gap_s):
                        self._check_covered(edge, anchor, np.array([stamp]), target, anchor)
                    p, q = edge.mounted_at(stamp, mount_p, mount_q)
                else:
                    p_TA, q_TA = self._lookup(target, anchor, np.array([stamp]))
                    p, q = mounted_poses(p_TA[0], q_TA[0], mount_p, mount_q)
            except FrameError as exc:
                return RowPoses.none_found(n, str(exc))
            return RowPoses(all_ok.copy(), p, q, [])
        if t is None:
            t = np.full(n, float(cast(float, stamps)))
        out = RowPoses.none_found(n)
        for error in unknown:
            out.note(error)
        for anchor, rows in by_anchor.items():
            t_rows = t[rows]
            if t_rows[0] == t_rows[-1] and (t_rows == t_rows[0]).all():  # a tick: one stamp
                unique, inverse = t_rows[:1], np.zeros(len(rows), dtype=np.int64)
            else:
                unique, inverse = np.unique(t_rows, return_inverse=True)
            found = np.ones(len(unique), bool)
            try:
                p_TA, q_TA = self._lookup(target, anchor, unique)
            except FrameError:  # some stamps only: find which, one by one
                p_TA, q_TA = np.zeros((len(unique), 3)), np.tile([0.0, 0, 0, 1], (len(unique), 1))
                for k in range(len(unique)):
                    try:
                        p_TA[k], q_TA[k] = (a[0] for a in self._lookup(target, anchor, unique[k:k + 1]))
                    except FrameError as exc:
                        found[k] = False
                        out.note(str(exc))
            rows_a = rows
            if not found.all():
                rows_a, inverse = rows[found[inverse]], inverse[found[inverse]]
                if len(rows_a) == 0:
                    continue
            q_rows = q_TA[inverse]
            out.p[rows_a] = p_TA[inverse] + quaternion_rotate(q_rows, mount_p[rows_a])
            out.q_xyzw[rows_a] = quaternion_products(q_rows, mount_q[rows_a])
            out.ok[rows_a] = True
        return out

    def _plan(self, sources: tuple[str, ...]) -> _RowPlan:
        """Rows grouped by the anchor of their frame (`_anchor`), the static poses of the
        frames in their anchors (positions, quaternions), the errors of unknown frames, and
        ``ok`` of every row found (read-only: a lookup returns a copy)."""
        n = len(sources)
        by_anchor: dict[str, list[int]] = {}
        mount_p, mount_q = np.zeros((n, 3)), np.tile([0.0, 0, 0, 1], (n, 1))
        unknown: list[str] = []
        for i, source in enumerate(sources):
            anchored = self._anchor(source)
            if anchored is None:
                error = f"unknown frame {_short(source)!r} (known: {_known(self._frames)})"
                if error not in unknown:
                    unknown.append(error)
                continue
            anchor, mount_p[i], mount_q[i] = anchored
            by_anchor.setdefault(anchor, []).append(i)
        all_ok = np.ones(n, bool)
        all_ok.flags.writeable = False
        plan = ({anchor: np.array(rows) for anchor, rows in by_anchor.items()}, mount_p, mount_q,
                unknown, all_ok)
        if len(self._plans) >= _MAX_PLANS:
            self._plans.clear()
        if not unknown:  # a frame may become known: plans with unknown frames are not kept
            self._plans[sources] = plan
        return plan

    def _anchor(self, frame: str) -> tuple[str, FloatArray, FloatArray] | None:
        """The first frame from ``frame`` up whose edge to its parent is stamped (or the root),
        and the static pose of ``frame`` in it (position, quaternion); None for an unknown
        frame."""
        cached = self._anchors.get(frame)
        if cached is not None:
            return cached
        if frame not in self._frames:
            return None
        X: Transform | None = None  # a mount alone is not composed (scipy: 40 us a product)
        anchor = frame
        while anchor in self._edges and (static := self._edges[anchor].static) is not None:
            X = static if X is None else static @ X
            anchor = self._edges[anchor].parent
        X = X if X is not None else Transform()
        self._anchors[frame] = (anchor, X.translation, X.quaternion_xyzw)
        return self._anchors[frame]

    def lookup(self, target: str, source: str, stamp: float) -> Transform:
        """X_target_source at ``stamp``: the pose of ``source`` in ``target``.

        Raises
        ------
        ConnectivityError
            A frame is unknown, or the two are in different trees.
        ExtrapolationError
            A stamped edge of the chain has no poses around ``stamp``.
        """
        p, rotations = self.lookup_many(target, source, [stamp])
        return Transform(rotations[0], p[0])

    def lookup_many(self, target: str, source: str, stamps: ArrayLike
                    ) -> tuple[NDArray[np.float64], Rotation]:
        """`lookup` at each of ``stamps`` (n,): positions of ``source`` in ``target`` (n, 3) and
        R_target_source; one error for the first stamp that cannot be looked up."""
        p, q = self._lookup(target, source, np.asarray(stamps, dtype=float).reshape(-1))
        return p, Rotation.from_quat(q)

    def _lookup(self, target: str, source: str, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """`lookup_many` as positions (n, 3) and quaternions (n, 4)."""
        split = self._splits.get((target, source))
        if split is None:
            split = self._splits[(target, source)] = self._split(target, source)
        up_source, up_target = split
        p_s, q_s = self._compose(up_source, t, target, source)
        if not up_target:
            return p_s, q_s
        p_t, q_t = self._compose(up_target, t, target, source)
        q_t_inv = q_t * np.array([-1.0, -1.0, -1.0, 1.0])  # the conjugate: R_top_target^-1
        return quaternion_rotate(q_t_inv, p_s - p_t), quaternion_products(q_t_inv, q_s)

    def _split(self, target: str, source: str) -> tuple[list[str], list[str]]:
        """The frames from ``source`` and from ``target`` up to (not including) the frame where
        their chains meet."""
        up_source, root_source = self._chain(source)
        up_target, root_target = self._chain(target)
        if root_source != root_target:
            raise ConnectivityError(f"cannot look up {source} in {target}: {source} is under "
                                    f"{root_source}, {target} under {root_target}; no "
                                    "transform joins them")
        # drop the common part of the two chains to the root
        while up_source and up_target and up_source[-1] == up_target[-1]:
            up_source.pop()
            up_target.pop()
        if len(self._splits) >= _MAX_PLANS:
            self._splits.clear()
        return up_source, up_target

    def _compose(self, chain: list[str], t: FloatArray, target: str, source: str
                 ) -> tuple[FloatArray, FloatArray]:
        """X_top_first at each of ``t`` for ``chain`` (child first): positions, quaternions."""
        if not chain:
            q = np.zeros((len(t), 4))
            q[:, 3] = 1.0
            return np.zeros((len(t), 3)), q
        for k, child in enumerate(chain):
            edge = self._edges[child]
            self._check_covered(edge, child, t, target, source)
            p_edge, q_edge = edge.at(t)
            if k == 0:
                p, q = p_edge, q_edge
            else:
                p, q = p_edge + quaternion_rotate(q_edge, p), quaternion_products(q_edge, q)
        return p, q

    def _check_covered(self, edge: _Edge, child: str, t: FloatArray, target: str, source: str
                       ) -> None:
        stamps = edge.stamps
        if edge.static is not None:
            return
        if len(t) == 1 and stamps[0] <= t[0] <= stamps[-1]:  # a tick: one stamp
            if self.max_gap_s < math.inf and edge.gap_around(float(t[0]), self.max_gap_s) is not None:
                self._check_gaps(edge, child, t, target, source)
            return
        outside = ~((t >= stamps[0]) & (t <= stamps[-1]))
        if outside.any():
            stamp = float(t[np.flatnonzero(outside)[0]])
            newer = stamp > stamps[-1]
            raise ExtrapolationError(
                f"cannot look up {source} in {target} at t={stamp!r}: the pose of {child} in "
                f"{edge.parent} is known from t={stamps[0]!r} to t={stamps[-1]!r} ("
                + (f"{stamp - stamps[-1]:.6g} s newer than the last pose" if newer
                   else f"{stamps[0] - stamp:.6g} s older than the kept history")
                + "; no extrapolation)")
        if self.max_gap_s < math.inf:
            self._check_gaps(edge, child, t, target, source)

    def _check_gaps(self, edge: _Edge, child: str, t: FloatArray, target: str, source: str
                    ) -> None:
        """ExtrapolationError for a stamp of ``t`` (within the kept poses) between two poses
        more than ``max_gap_s`` apart."""
        gap_at = self._gap_at(edge, t)
        if gap_at is not None:
            stamp, before, after = gap_at
            raise ExtrapolationError(
                f"cannot look up {_short(source)} in {_short(target)} at t={stamp!r}: the poses "
                f"of {_short(child)} in {_short(edge.parent)} around it, at t={before!r} and "
                f"t={after!r}, are {after - before:.6g} s apart, more than {self.gap_name} "
                f"({self.max_gap_s:g} s); no interpolation across the gap")

    def _gap_at(self, edge: _Edge, t: FloatArray) -> tuple[float, float, float] | None:
        """The first stamp of ``t`` within ``edge``'s poses that falls between two of them more
        than ``max_gap_s`` apart (not on either), with their stamps; None when there is none."""
        for stamp in dict.fromkeys(t.tolist()):  # each distinct stamp once, in order
            around = edge.gap_around(stamp, self.max_gap_s)
            if around is not None:
                return stamp, *around
        return None

    def has_gap_rows(self, target: str, sources: Sequence[str], stamp: float) -> bool:
        """Whether a stamped edge between ``target`` and a known frame of ``sources`` has two
        poses more than ``max_gap_s`` apart around ``stamp`` (then more poses may yet fill
        the gap: a wrench waits for them)."""
        return self._gap_in(target, self._row_plan(sources), stamp)

    def _gap_in(self, target: str, plan: _RowPlan, stamp: float) -> bool:
        if self.max_gap_s == math.inf:
            return False
        for anchor in plan[0]:
            for edge in self._stamped_between(target, anchor):
                if edge.gap_around(stamp, self.max_gap_s) is not None:
                    return True
        return False

    def _stamped_between(self, target: str, anchor: str) -> list[_Edge]:
        """The stamped edges from ``anchor`` and from ``target`` up to their roots (none when
        either is unknown), kept until the tree changes."""
        key = (target, anchor)
        edges = self._stamped.get(key)
        if edges is None:
            try:
                chain = self._chain(anchor)[0] + self._chain(target)[0]
            except ConnectivityError:
                chain = []
            edges = [self._edges[f] for f in chain if self._edges[f].static is None]
            if len(self._stamped) >= _MAX_PLANS:
                self._stamped.clear()
            self._stamped[key] = edges
        return edges

    def _edge(self, parent: str, child: str, static: bool) -> _Edge:
        for name in (parent, child):
            if not isinstance(name, str) or not name:
                raise ValueError(f"frame names must be non-empty strings, got {name!r}")
        if parent == child:
            raise ValueError(f"frame {child} cannot be its own parent")
        edge = self._edges.get(child)
        if edge is not None and edge.parent != parent and edge.static is None and not static:
            self._move(child, parent)  # a stamped frame under a new parent, as tf2 allows
            edge = None
        if edge is None:
            new = {parent, child} - self._frames
            if len(self._frames) + len(new) > MAX_FRAMES:
                raise ValueError(f"{child} in {parent}: the buffer holds {MAX_FRAMES} frames "
                                 "already, the most it takes")
            if self._chain_has(parent, child):
                raise ValueError(f"{child} in {parent} would close a loop: {parent} is already "
                                 f"under {child}")
            if self._depth(parent) + self._height(child) >= MAX_DEPTH:
                raise ValueError(f"{_short(child)} in {_short(parent)}: a chain of frames deeper "
                                 f"than {MAX_DEPTH}, the most the buffer takes")
            edge = self._edges[child] = _Edge(parent)
            self._frames.update((parent, child))
            self._forget_tree()
        elif edge.parent != parent:
            raise ValueError(f"frame {_short(child)} already has the parent "
                             f"{_short(edge.parent)}; a static frame keeps it (got "
                             f"{_short(parent)})")
        elif static != (edge.static is not None or not edge.stamps):
            kind = "static" if edge.static is not None else "stamped"
            raise ValueError(f"{child} in {parent} is {kind} already")
        return edge

    def __contains__(self, frame: object) -> bool:
        """Whether ``frame`` is named in the buffer."""
        return frame in self._frames

    def parent(self, frame: str) -> str | None:
        """The parent of ``frame`` (None: a root, or not a frame)."""
        edge = self._edges.get(frame)
        return None if edge is None else edge.parent

    def _move(self, child: str, parent: str) -> None:
        """Drop ``child``'s stamped edge to its parent, so that ``_edge`` makes one to ``parent``
        (after its checks: a loop, the frame limit); the old parent goes too when nothing else
        names it."""
        if self._chain_has(parent, child):
            raise ValueError(f"{_short(child)} in {_short(parent)} would close a loop: "
                             f"{_short(parent)} is already under {_short(child)}")
        old = self._edges.pop(child).parent
        if old not in self._edges and all(e.parent != old for e in self._edges.values()):
            self._frames.discard(old)
        self._forget_tree()

    def _forget_tree(self) -> None:
        """Drop what was derived from the tree (chains, anchors and their static poses, plans,
        newest stamps): an edge came, went or changed its static transform."""
        for cache in (self._splits, self._anchors, self._plans, self._newest, self._stamped):
            cache.clear()

    def _depth(self, frame: str) -> int:
        """Frames above ``frame`` up to its root."""
        depth = 0
        while frame in self._edges:
            frame = self._edges[frame].parent
            depth += 1
        return depth

    def _height(self, frame: str) -> int:
        """Frames below ``frame`` down to its deepest descendant."""
        children: dict[str, list[str]] = {}
        for child, edge in self._edges.items():
            children.setdefault(edge.parent, []).append(child)
        height, level = 0, [frame]
        while True:
            level = [c for f in level for c in children.get(f, ())]
            if not level:
                return height
            height += 1

    def _chain_has(self, frame: str, ancestor: str) -> bool:
        while frame in self._edges:
            frame = self._edges[frame].parent
            if frame == ancestor:
                return True
        return False

    def _chain(self, frame: str) -> tuple[list[str], str]:
        """The frames from ``frame`` up to (not including) its root, and the root."""
        if frame not in self._frames:
            raise ConnectivityError(f"unknown frame {_short(frame)!r} (known: "
                                    f"{_known(self._frames)})")
        chain = []
        while frame in self._edges:
            chain.append(frame)
            frame = self._edges[frame].parent
        return chain, frame
