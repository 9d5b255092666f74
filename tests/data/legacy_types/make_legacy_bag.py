"""Write ``legacy.mcap``: a bag of the single-whisker message types ``vibrissa/WhiskerWrench``
(versions 1 and 2) and ``vibrissa/ContactPoint`` (versions 1 and 2, with and without a
covariance) beside arrays, a pose and an EndOfStream, each payload encoded by hand as those
types went on the wire (msgpack maps, arrays as ``{dtype, shape, data}``).

``ros2/`` beside it is ``vibrissa bag export legacy.mcap --format ros2`` as written when those
types were live types, kept so that an export of the bag today can be held to it message for
message. Run from the repository root: ``.venv/bin/python tests/data/legacy_types/make_legacy_bag.py``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from vibrissa.wire.bag import BagWriter

HERE = Path(__file__).parent
T0_NS = 1_700_000_000_000_000_000
Q_ID = [0.0, 0.0, 0.0, 1.0]


def array(values: Any, dtype: str = "<f8") -> dict[str, Any]:
    a = np.asarray(values, dtype=dtype)
    return {"dtype": a.dtype.str, "shape": list(a.shape), "data": a.tobytes()}


def pack(type_name: str, version: int, **fields: Any) -> bytes:
    return msgpack.packb({"_type": type_name, "_v": version, **fields})  # type: ignore[no-any-return]


def wrench_v2(i: int, whisker: str, pose: bool) -> bytes:
    rng = np.random.default_rng(i)
    fields: dict[str, Any] = dict(
        stamp=10.0 + 0.002 * i, seq=i, whisker_id=whisker, frame_id=f"{whisker}/clamp",
        f0=array(rng.normal(size=3)), m0=array(rng.normal(size=3) * 1e-3))
    if pose:
        fields.update(pose_frame_id="world", clamp_position=array(rng.normal(size=3)),
                      clamp_orientation=array(Q_ID))
    return pack("vibrissa/WhiskerWrench", 2, **fields)


def wrench_v1(i: int, whisker: str) -> bytes:
    rng = np.random.default_rng(100 + i)
    return pack("vibrissa/WhiskerWrench", 1, stamp=20.0 + 0.002 * i, seq=i, whisker_id=whisker,
                frame_id="world", f0=array(rng.normal(size=3)),
                m0=array(rng.normal(size=3) * 1e-3), clamp_position=array(rng.normal(size=3)),
                clamp_orientation=array(Q_ID))


def wrench_array(i: int, n: int) -> bytes:
    rng = np.random.default_rng(200 + i)
    ids = [f"a{k}" for k in range(n)]
    return pack("vibrissa/WhiskerWrenchArray", 2, stamp=30.0 + 0.002 * i, seq=i, whisker_ids=ids,
                frame_ids=[f"{w}/clamp" for w in ids], f0=array(rng.normal(size=(n, 3))),
                m0=array(rng.normal(size=(n, 3)) * 1e-3))


def contact(i: int, whisker: str, version: int, covariance: bool) -> bytes:
    rng = np.random.default_rng(300 + i)
    fields: dict[str, Any] = dict(
        stamp=40.0 + 0.002 * i, seq=i, whisker_id=whisker, frame_id="world",
        point=array(rng.normal(size=3)), s1=float(rng.random()), phase=1 + i % 2,
        force=array(rng.normal(size=3)), status=(0, 2, 5)[i % 3])
    if covariance:
        fields["covariance"] = array(np.diag(rng.random(3)) * 1e-6)
    return pack("vibrissa/ContactPoint", version, **fields)


def contact_array(i: int, n: int) -> bytes:
    rng = np.random.default_rng(400 + i)
    return pack("vibrissa/ContactPointArray", 2, stamp=50.0 + 0.002 * i, seq=i, frame_id="world",
                whisker_ids=[f"a{k}" for k in range(n)], point=array(rng.normal(size=(n, 3))),
                s1=array(rng.random(n)), phase=array(np.ones(n), "<i4"),
                force=array(rng.normal(size=(n, 3))), status=array(np.zeros(n), "<i4"))


def records() -> list[tuple[str, bytes]]:
    """(topic, payload) in log order."""
    out = [("/w0/wrench", wrench_v2(i, "w0", pose=i % 2 == 0)) for i in range(6)]
    out += [("/w1/wrench", wrench_v1(i, "w1")) for i in range(3)]
    out += [("/robot/wrench", wrench_array(i, 1 + i)) for i in range(3)]
    out += [("/w0/contact", contact(i, "w0", 2, covariance=i < 3)) for i in range(5)]
    out += [("/w1/contact", contact(10 + i, "w1", 1, covariance=False)) for i in range(2)]
    out += [("/robot/contact", contact_array(i, 2)) for i in range(2)]
    out.append(("/robot/pose", pack("vibrissa/RobotPose", 1, stamp=60.0, frame_id="map",
                                    child_frame_id="robot", position=array([1.0, 2.0, 3.0]),
                                    orientation=array(Q_ID))))
    out.append(("/w0/wrench", pack("vibrissa/EndOfStream", 1, stamp=70.0, source="/w0/netft",
                                   count=6)))
    return out


def main() -> None:
    with BagWriter(HERE / "legacy.mcap") as bag:
        for k, (topic, payload) in enumerate(records()):
            bag.write(topic, payload, T0_NS + k * 1_000_000)


if __name__ == "__main__":
    main()
