"""Node logic without sockets: the wrench source, normals, fit, accumulation, full disks."""

from __future__ import annotations

import resource
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from vibrissa.msgs import WhiskerWrenchArray
from vibrissa.nodes.mapper import MapperParams
from vibrissa.nodes.reconstructor import ReconstructorParams
from vibrissa.nodes.wrench_source import WrenchSourceParams, tick_messages
from vibrissa.surfaces import parse_surface
from vibrissa.sweep import SweepRun, Trail, simulate_sweeps
from vibrissa.ticks import sequential_ticks
from vibrissa.units import RodScale
from vibrissa.wire.bag import BagReader

UNIT_ROD = RodScale()


def sweep_wrenches(run: SweepRun, whisker_id: str, frame_id: str, rod: RodScale
                   ) -> Iterator[WhiskerWrenchArray]:
    """The wrench source's one path, one whisker sweeping one sweep after the other."""
    return tick_messages(sequential_ticks(run, rod), [whisker_id] * len(run.trails), frame_id)


def test_sweep_wrenches_are_si_with_running_seq() -> None:
    surface = parse_surface("paraboloid:a=0.5,b=1,h=0.4")
    trails = [Trail(0.0, 0.1), Trail(0.3, 0.0)]
    sweeps = simulate_sweeps(surface, trails, 0.02)
    length, ei = 0.05, 2e-4
    msgs = list(sweep_wrenches(SweepRun(surface, trails, 0.02), "w7", "world",
                               RodScale(length, ei)))
    n0, n1 = sweeps[0].n_steps, sweeps[1].n_steps
    assert n0 > 3 and n1 > 3
    assert [m.seq for m in msgs] == list(range(n0 + n1))
    assert all(m.whisker_ids == ["w7"] for m in msgs)  # a batch of one row each
    last = msgs[n0 + 2]  # the third equilibrium of the second sweep
    np.testing.assert_array_equal(last.clamp_orientation, [[0, 0, 0, 1]])
    np.testing.assert_allclose(last.clamp_position[0], sweeps[1].p0[2] * length, rtol=1e-15)
    np.testing.assert_allclose(last.f0[0], sweeps[1].f0[2] * ei / length**2, rtol=1e-15)
    np.testing.assert_allclose(last.m0[0], sweeps[1].m0[2] * ei / length, rtol=1e-15)


@pytest.mark.parametrize("cls", [WrenchSourceParams, ReconstructorParams, MapperParams])
def test_params_give_the_rod_scale_and_refuse_a_rod_without_length(cls: Any) -> None:
    assert cls(rod_length_m=0.05).rod == RodScale(0.05, getattr(cls(), "rod_ei_nm2", 1.0))
    with pytest.raises(ValueError, match="length_m"):
        cls(rod_length_m=0.0)


def test_array_names_default_per_whisker_and_must_match_the_trails() -> None:
    params = WrenchSourceParams(y0=(0.1, 0.2, 0.3), array=True)
    assert params.array_whisker_ids == ["whisker0", "whisker1", "whisker2"]
    assert WrenchSourceParams(y0=(0.1,), whisker_ids=("left",)).array_whisker_ids == ["left"]
    with pytest.raises(ValueError, match=r"parameter 'whisker_ids' must be one name per y0 \(2\)"):
        WrenchSourceParams(y0=(0.1, 0.2), whisker_ids=("left",))




def run_with_file_size_limit(script: str, limit_bytes: int) -> subprocess.CompletedProcess[str]:
    """``script`` in a Python whose files cannot grow past ``limit_bytes``: writes beyond it
    fail as on a full disk (EFBIG instead of ENOSPC; SIGXFSZ is ignored)."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120, preexec_fn=limit)  # noqa: PLW1509 - the test's own child


def test_a_full_disk_stops_the_recorder_with_one_error_and_a_readable_bag(
    tmp_path: Path,
) -> None:
    bag = tmp_path / "rec.mcap"
    script = f"""
import numpy as np
from vibrissa.msgs import WhiskerWrenchArray
from vibrissa.msgs.codec import encode
from vibrissa.nodes.recorder import RecorderParams, record
from vibrissa.wire.bag import BagReader
from vibrissa.wire.transport import Header, Received

class Endless:
    seq = 0
    def receive(self, timeout_s):
        self.seq += 1
        msg = WhiskerWrenchArray(stamp=0.0, seq=self.seq, whisker_ids=["w"], frame_ids=["w/clamp"],
                                 pose_frame_id="world", clamp_position=np.random.rand(1, 3),
                                 clamp_orientation=[[0, 0, 0, 1]], f0=np.random.rand(1, 3),
                                 m0=np.random.rand(1, 3))
        return Received("/w/wrench", msg, encode(msg), Header(1, self.seq), 0.0)
    def totals(self):
        return {{"lost": 0, "rejected": 0}}

try:
    record(RecorderParams(output={str(bag)!r}, chunk_size=4096), Endless())
except OSError as exc:
    print("error:", exc.errno, "chained:", exc.__context__ is not None)
"""
    result = run_with_file_size_limit(script, 200_000)
    # the write's own error, not a second one from closing the bag on the same full disk
    assert result.stdout.strip() == "error: 27 chained: False", result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    got = list(BagReader(bag))
    assert len(got) > 100 and all(r.topic == "/w/wrench" for r in got)
