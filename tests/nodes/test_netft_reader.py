"""The Net F/T driver's records without sockets (``NetFTReader``): ``max_latency_s`` leaves out
records too far behind the newest, whether they came late in one drain or waited too long to
be taken, and counts each once as ``stale``."""

from __future__ import annotations

import numpy as np

from vibrissa.nodes.netft import NetFTParams, NetFTReader, health
from vibrissa.wire.netft import NetFTConfig, StreamTracker, pack_records

RATE_HZ = 1000.0  # ft_sequence rate: record k is measured at k ms
CPF = 1000.0  # counts per N and per N m


def reader(max_latency_s: float = 0.05) -> NetFTReader:
    params = NetFTParams(ft_rate_hz=RATE_HZ, max_latency_s=max_latency_s, stall_s=10.0,
                         counts_per_force=CPF, counts_per_torque=CPF)
    return NetFTReader(params, NetFTConfig(CPF, CPF))


def datagram(rdt: list[int], ft: list[int]) -> bytes:
    """Records whose sensor force x is ft_sequence counts (ft / CPF N): a row says which it was."""
    counts = np.zeros((len(rdt), 6), dtype=np.int64)
    counts[:, 0] = ft
    return pack_records(rdt, ft, [0] * len(rdt), counts)


def measured_at_ms(f0: np.ndarray) -> list[int]:
    """The ft_sequence of each row: the clamp's reaction is minus the sensor's load (X_CS = I)."""
    return [round(-x * CPF) for x in f0[:, 0]]


def test_records_that_come_behind_newer_ones_in_one_drain_are_stale() -> None:
    r = reader()
    r.read(datagram([0], [0]), t_receive=10.0)  # the stream starts: sensor time 0 is 10.0 s
    assert measured_at_ms(r.take()[1]) == [0]
    # one drain: records measured at 100..104 ms and 300..304 ms (rdt in order: nothing lost)
    r.read_many([datagram([1, 2, 3, 4, 5], [100, 101, 102, 103, 104]),
                 datagram([6, 7, 8, 9, 10], [300, 301, 302, 303, 304])], t_receive=10.305)
    stamp, f0, _ = r.take()
    assert measured_at_ms(f0) == [300, 301, 302, 303, 304]  # within 50 ms of 304 ms
    assert r.counters["stale"] == 5
    assert r.counters["received"] == 11 and r.counters["lost"] == 0
    np.testing.assert_allclose(stamp, 10.0 + np.arange(300, 305) * 1e-3, rtol=0, atol=1e-12)


def test_a_backlog_that_waited_past_max_latency_is_stale_when_newer_records_come() -> None:
    r = reader()
    r.read(datagram(list(range(10)), list(range(10))), t_receive=1.009)
    _, f0, _ = r.take(limit=3)
    assert measured_at_ms(f0) == [0, 1, 2]
    assert len(r) == 7  # 3..9 wait
    # 60 ms later the next records arrive: 3..9 ms are now more than 50 ms behind 69 ms
    r.read(datagram(list(range(10, 20)), list(range(60, 70))), t_receive=1.069)
    _, f0, _ = r.take()
    assert measured_at_ms(f0) == list(range(60, 70))
    assert r.counters["stale"] == 7
    assert len(r) == 0


def test_every_record_received_is_taken_or_stale_exactly_once() -> None:
    rng = np.random.default_rng(7)
    r = reader(max_latency_s=0.02)
    taken = 0
    ft = 0
    for k in range(200):
        ft += int(rng.integers(1, 30))  # the sensor's counter moves on by 1-29 ms per datagram
        n = int(rng.integers(1, 5))
        r.read(datagram(list(range(4 * k, 4 * k + n)), list(range(ft, ft + n))),
               t_receive=100.0 + (ft + n) * 1e-3)
        ft += n
        if rng.random() < 0.3:
            stamp, f0, m0 = r.take(limit=int(rng.integers(1, 8)))
            taken += len(stamp)
            assert len(f0) == len(m0) == len(stamp)
    taken += len(r.take()[0])
    received = r.counters["received"]
    assert received > 0 and r.counters["stale"] > 0
    assert taken + r.counters["stale"] == received


def test_records_that_convert_to_a_non_finite_wrench_are_counted_not_taken() -> None:
    # a calibration the driver refuses (1e-300 counts per N) makes a full-scale count inf N:
    # such a record is counted non_finite and left out, the others are taken
    params = NetFTParams(ft_rate_hz=RATE_HZ, max_latency_s=1.0, stall_s=10.0)
    r = NetFTReader(params, NetFTConfig(1e-300, CPF))
    counts = np.zeros((3, 6), dtype=np.int64)
    counts[1, 0] = (1 << 31) - 1
    r.read(pack_records([1, 2, 3], [1, 2, 3], [0] * 3, counts), t_receive=1.0)
    stamp, f0, m0 = r.take()
    assert len(stamp) == 2 and np.isfinite(f0).all() and np.isfinite(m0).all()
    assert r.counters["non_finite"] == 1 and r.counters["received"] == 3


def test_the_health_line_says_normal_or_names_what_is_not() -> None:
    clean = dict.fromkeys(StreamTracker.COUNTERS, 0) | {"received": 1700, "stale": 0,
                                                      "restarts": 0, "foreign": 0}
    line = health(clean, 1.7, loopback=True)
    assert line.startswith("health: normal (1700 records in 1.7 s (1000 per s)")
    busy = clean | {"stale": 21, "lost": 3, "received": 1697}
    line = health(busy, 1.7, loopback=True)
    assert line.startswith("health: ABNORMAL: 3 of 1700 records lost (gaps in rdt_sequence), "
                           "0.18%: loopback loses and reorders nothing")
    assert "21 records dropped as stale" in line
    assert line.count("this machine is too busy") == 2
    # on a network a little loss is normal; duplicates and restarts never are
    assert health(clean | {"lost": 1, "received": 1699}, 1.7, loopback=False).startswith(
        "health: normal")
    line = health(clean | {"duplicates": 5, "restarts": 2}, 1.7, loopback=False)
    assert "5 records that came twice" in line and "2 stream requests after the first" in line
