"""Write ``live_tick.msgpack``: ticks as a reconstructor receives them (encoded
WhiskerWrenchArray and RobotPose payloads, in arrival order) and the ContactPointArray bytes it
published for each, with its counts, so that a faster Step 2 can be held to the same bytes.

Run once from the repository root: ``.venv/bin/python tests/data/live_tick/make_live_tick.py``.
Three streams: clamp poses on the wire (a rod of its own, rows without contact and a zero
quaternion among them, then a tick whose every row is a contact), a robot description with its
poses (an unknown whisker and a row in the wrong frame among them), and a noise model (free
rows, an axial load without covariance). Random wrenches are made one contact's
(`single_contact`), but for one twisted row of two contacts.
"""

from __future__ import annotations

from pathlib import Path

import msgpack
import numpy as np
from scipy.spatial.transform import Rotation

from vibrissa.frames import Transform, clamp_frame
from vibrissa.msgs import RobotPose, WhiskerWrenchArray
from vibrissa.msgs.codec import decode, encode
from vibrissa.scene import Whisker
from vibrissa.streaming import Step2Stream, StreamSettings
from vibrissa.units import RodScale

OUT = Path(__file__).with_name("live_tick.msgpack")
ROD = RodScale(0.05, 2e-5)


def single_contact(f0: np.ndarray, m0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows (N, 3) of (f0, m0) made wrenches one contact can give: m0z = 0 and f0 normal to
    m0 (the rod bent in the plane of its force and its axis; Step 2 flags any other
    MULTI_CONTACT)."""
    f0, m0 = np.array(f0, dtype=float), np.array(m0, dtype=float)
    m0[:, 2] = 0.0
    norm2 = np.sum(m0 * m0, axis=1)
    bent = norm2 > 0
    f0[bent] -= m0[bent] * (np.sum(f0[bent] * m0[bent], axis=1) / norm2[bent])[:, None]
    return f0, m0


def _poses_ticks(rng: np.random.Generator) -> list[bytes]:
    ticks = []
    for k in range(3):
        n = 32
        f0 = rng.normal(size=(n, 3)) * ROD.force_n * 0.1
        m0 = rng.normal(size=(n, 3)) * ROD.moment_nm * 0.1
        f0, m0 = single_contact(f0, m0)
        m0[7] = [0.0, 0.05 * ROD.moment_nm, 0.02 * ROD.moment_nm]  # twisted: two contacts
        f0[3] = m0[3] = 0.0  # no force: no contact
        q = Rotation.random(n, random_state=10 + k).as_quat()
        q[5] = 0.0  # a zero quaternion: bad pose
        ticks.append(encode(WhiskerWrenchArray(
            stamp=0.001 * k, seq=k, whisker_ids=[f"w{j}" for j in range(n)],
            frame_ids=[f"w{j}/clamp" for j in range(n)], f0=f0, m0=m0, pose_frame_id="world",
            clamp_position=rng.uniform(-0.1, 0.1, (n, 3)), clamp_orientation=q)))
    n = 32  # every row a contact
    scale = rng.uniform(0.5, 1.5, (n, 1))
    ticks.append(encode(WhiskerWrenchArray(
        stamp=0.003, seq=3, whisker_ids=[f"w{j}" for j in range(n)],
        frame_ids=[f"w{j}/clamp" for j in range(n)],
        f0=scale * [0.1 * ROD.force_n, 0.0, 0.0], m0=scale * [0.0, 0.05 * ROD.moment_nm, 0.0],
        pose_frame_id="world", clamp_position=rng.uniform(-0.1, 0.1, (n, 3)),
        clamp_orientation=Rotation.random(n, random_state=20).as_quat())))
    return ticks


def _robot() -> list[Whisker]:
    return [Whisker(f"r{j}", 0.03 + 0.01 * j, 1e-4 * (1 + j),
                    Transform.from_xyz_rpy([0.01 * j, -0.02, 0.0], [np.pi / 2, 0.1 * j, 0.0]))
            for j in range(4)]


def _robot_stream(rng: np.random.Generator) -> list[bytes]:
    out = []
    for j in range(4):
        t = 0.01 * j
        out.append(encode(RobotPose(stamp=t, frame_id="world", child_frame_id="base_link",
                                    position=[0.1 * t, 0.0, 0.0],
                                    orientation=[0.0, 0.0, np.sin(0.15 * t), np.cos(0.15 * t)])))
    names = ["r0", "r1", "r2", "r3", "ghost"]
    frames = [clamp_frame(w) for w in names]
    frames[2] = "r1/clamp"  # measured in another whisker's frame
    for k in range(3):
        rods = [w.scale for w in _robot()] + [ROD]
        f0 = np.array([rng.normal(size=3) * r.force_n * 0.1 for r in rods])
        m0 = np.array([rng.normal(size=3) * r.moment_nm * 0.1 for r in rods])
        f0, m0 = single_contact(f0, m0)
        out.append(encode(WhiskerWrenchArray(
            stamp=0.005 + 0.007 * k, seq=k, whisker_ids=names, frame_ids=frames, f0=f0, m0=m0)))
    rods = [w.scale for w in _robot()]  # the robot's whiskers, every row a contact
    out.append(encode(WhiskerWrenchArray(
        stamp=0.025, seq=3, whisker_ids=names[:4], frame_ids=[clamp_frame(w) for w in names[:4]],
        f0=[[0.1 * r.force_n, 0.0, 0.0] for r in rods],
        m0=[[0.0, 0.05 * r.moment_nm, 0.0] for r in rods])))
    return out


def _noise_ticks(rng: np.random.Generator) -> list[bytes]:
    sigma = np.r_[[1e-6] * 3, [1e-8] * 3]
    out = []
    for k in range(3):
        n = 8
        wrench = rng.normal(size=(n, 6)) * sigma
        if k == 1:
            f0, m0 = single_contact(rng.normal(size=(4, 3)) * 0.1 * ROD.force_n,
                                    rng.normal(size=(4, 3)) * 0.05 * ROD.moment_nm)
            wrench[:4, :3] += f0
            wrench[:4, 3:] += m0
            wrench[4] = [0.0, 0.0, 0.1 * ROD.force_n, 0.0, 0.0, 0.0]  # axial: no covariance
        out.append(encode(WhiskerWrenchArray(
            stamp=0.001 * k, seq=k, whisker_ids=[f"n{j}" for j in range(n)],
            frame_ids=[f"n{j}/clamp" for j in range(n)], f0=wrench[:, :3], m0=wrench[:, 3:],
            pose_frame_id="world", clamp_position=np.zeros((n, 3)),
            clamp_orientation=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)))))
    return out


def settings(name: str) -> StreamSettings:
    """The stream settings of scenario ``name``."""
    if name == "robot":
        return StreamSettings(whiskers=tuple(_robot()), pose_timeout_s=0.0)
    if name == "noise":
        return StreamSettings(rod=ROD, noise_force_n=1e-6, noise_moment_nm=1e-8)
    return StreamSettings(rod=ROD)


def run(name: str, payloads: list[bytes]) -> list[tuple[bytes, dict[str, int]]]:
    """Each published ContactPointArray's bytes and the stream's counts after it."""
    stream = Step2Stream(settings(name), lambda text: None, clock=lambda: 0.0)
    out = []
    for payload in payloads:
        msg = decode(payload, (WhiskerWrenchArray, RobotPose))
        if isinstance(msg, RobotPose):
            stream.add_pose(msg)
            continue
        stream.add_wrenches([msg])
        for outcome in stream.take():
            out.append((encode(outcome.contacts), dict(stream.counts)))
        stream.apply_poses()
    return out


def main() -> None:
    rng = np.random.default_rng(7)
    scenarios = {"poses": _poses_ticks(rng), "robot": _robot_stream(rng),
                 "noise": _noise_ticks(rng)}
    record = {name: {"input": payloads, "output": run(name, payloads)}
              for name, payloads in scenarios.items()}
    OUT.write_bytes(msgpack.packb(record))
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
