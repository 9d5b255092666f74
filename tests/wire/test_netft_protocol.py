"""The RDT protocol without sockets: requests, records, and the stream's bookkeeping (loss,
reordering, 32-bit rollover, stalls, status words), fuzzed with malformed datagrams."""

from __future__ import annotations

import http.server
import threading

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vibrissa.wire.netft import (
    RECORD,
    Command,
    StreamTracker,
    pack_records,
    pack_request,
    parse_config,
    parse_datagram,
    parse_request,
    read_config,
    to_si,
)

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def records(first: int, n: int, *, ft_step: int = 1, status: int = 0, per: int = 1) -> list[bytes]:
    """Datagrams of ``per`` records each, rdt_sequence from ``first`` (wrapping at 2^32)."""
    seq = np.arange(first, first + n)
    counts = np.column_stack([seq % 1000 + k for k in range(6)])
    return [pack_records(seq[i:i + per], seq[i:i + per] * ft_step, np.full(len(seq[i:i + per]), status),
                         counts[i:i + per]) for i in range(0, n, per)]


def invariant(tracker: StreamTracker, span: int) -> None:
    c = tracker.counters
    assert c["received"] + c["status_faults"] + c["lost"] + c["reordered"] == span


def test_request_layout_is_atis() -> None:
    assert pack_request(Command.REALTIME, 0) == bytes.fromhex("1234 0002 00000000")
    assert pack_request(Command.BIAS) == bytes.fromhex("1234 0042 00000000")
    assert parse_request(pack_request(Command.BUFFERED, 7)) == (Command.BUFFERED, 7)
    assert parse_request(bytes.fromhex("4321 0002 00000000")) is None  # wrong header
    assert parse_request(bytes.fromhex("1234 0009 00000000")) is None  # unknown command
    assert parse_request(b"\x12\x34\x00\x02") is None  # short


def test_record_layout_and_units() -> None:
    data = pack_records([1], [2], [0], [[1_000_000, -2_000_000, 3, 4_000, -5, 6]])
    assert len(data) == RECORD.size == 36
    assert RECORD.unpack(data) == (1, 2, 0, 1_000_000, -2_000_000, 3, 4_000, -5, 6)
    rec = parse_datagram(data)
    assert rec is not None
    f, m = to_si(rec["counts"], counts_per_force=1e6, counts_per_torque=1e3)
    np.testing.assert_array_equal(f, [[1.0, -2.0, 3e-6]])
    np.testing.assert_array_equal(m, [[4.0, -5e-3, 6e-3]])


@pytest.mark.parametrize("per", [1, 5])
def test_in_order_stream_counts_nothing_but_records(per: int) -> None:
    tracker = StreamTracker()
    out = [tracker.feed(d, 0.1 * i) for i, d in enumerate(records(1, 50, per=per))]
    rdt = np.concatenate([r.rdt for r in out])
    np.testing.assert_array_equal(rdt, np.arange(1, 51))
    assert tracker.counters["received"] == 50
    assert sum(tracker.counters[k] for k in ("lost", "reordered", "duplicates", "malformed")) == 0


def test_loss_reordering_and_duplicates_across_the_rollover() -> None:
    first = (1 << 32) - 5
    data = records(first, 12)  # rdt wraps from 2^32 - 1 to 0 in the middle
    order = [0, 1, 3, 2, 4, 6, 7, 7, 9, 10, 11]  # 2 late, 5 and 8 lost, 7 twice
    tracker = StreamTracker()
    got = []
    for k in order:
        got += tracker.feed(data[k], 0.0).rdt.tolist()
    assert got == [(first + k) % (1 << 32) for k in (0, 1, 3, 4, 6, 7, 9, 10, 11)]
    c = tracker.counters
    assert (c["lost"], c["reordered"], c["duplicates"], c["malformed"]) == (2, 1, 1, 0)
    invariant(tracker, 12)


def test_status_words_warnings_are_published_faults_not() -> None:
    tracker = StreamTracker(fault_mask=0x80000000)
    assert len(tracker.feed(records(1, 1, status=0x00010000)[0], 0.0)) == 1
    assert len(tracker.feed(records(2, 1, status=0x80000001)[0], 0.0)) == 0
    assert len(tracker.feed(records(3, 1)[0], 0.0)) == 1
    c = tracker.counters
    assert (c["status_warnings"], c["status_faults"], c["received"]) == (1, 1, 2)
    invariant(tracker, 3)


def test_stall_from_frozen_ft_sequence_and_from_silence() -> None:
    tracker = StreamTracker(stall_s=0.2)
    tracker.restart(0.0)
    assert not tracker.check_stall(0.19)
    assert tracker.check_stall(0.2)  # nothing ever came
    assert tracker.counters["stalls"] == 1
    tracker.feed(records(1, 1)[0], 0.3)
    assert not tracker.check_stall(0.31)  # a moving record ends the stall
    frozen = pack_records(np.arange(2, 10), np.full(8, 1), np.zeros(8), np.zeros((8, 6)))
    for i in range(8):  # records keep coming, ft_sequence does not move
        tracker.feed(frozen[36 * i:36 * i + 36], 0.3 + 0.05 * (i + 1))
        tracker.check_stall(0.3 + 0.05 * (i + 1))
    assert tracker.stalled and tracker.counters["stalls"] == 2


def test_the_old_streams_records_after_a_restart_are_not_the_new_ones_duplicates() -> None:
    """A stream requested again (after a stall): records the sensor sent before the request
    arrived follow the old stream and are published; the new stream (rdt_sequence from 1, the
    sensor's ft_sequence running on) begins at its first record, none taken for a duplicate."""
    seq = np.arange(1, 301)
    old = [pack_records(seq[i:i + 1], seq[i:i + 1], [0], np.zeros((1, 6))) for i in range(300)]
    new = [pack_records(seq[i:i + 1], seq[i:i + 1] + 300, [0], np.zeros((1, 6)))
           for i in range(300)]
    tracker = StreamTracker(ft_rate_hz=1000.0)
    got = [tracker.feed(d, 100.0 + 1e-3 * i).rdt.tolist() for i, d in enumerate(old[:200])]
    tracker.restart(100.3)
    got += [tracker.feed(d, 100.3).rdt.tolist() for d in old[200:]]  # sent before the request
    got += [tracker.feed(d, 100.3 + 1e-3 * i).rdt.tolist() for i, d in enumerate(new)]
    assert sum(got, []) == list(range(1, 301)) * 2
    c = tracker.counters
    assert (c["received"], c["duplicates"], c["lost"], c["sequence_anomalies"]) == (600, 0, 0, 0)


def test_sensor_time_follows_ft_sequence_on_the_host_clock() -> None:
    tracker = StreamTracker(ft_rate_hz=1000.0)
    delays = [0.001, 0.003, 0.002, 0.004, 0.0005]  # network jitter: the least sets the offset
    t, received = [], []
    for i, d in enumerate(records(1, 5, ft_step=10)):
        received.append(0.01 * (i + 1) + 100.0 + delays[i])
        t += tracker.feed(d, received[-1]).t_sensor.tolist()
    # ft = 10, 20, 30, ... at 1 kHz: 10 ms apart while the least delay holds, never after
    # the receive time; a lower delay (the last) moves the offset down
    assert np.diff(t[:4]) == pytest.approx([0.01] * 3, abs=1e-9)
    assert all(ts <= tr for ts, tr in zip(t, received, strict=True))
    assert t[4] == pytest.approx(received[4], abs=1e-9)


def test_malformed_datagrams_are_counted() -> None:
    tracker = StreamTracker()
    good = records(1, 3)
    assert len(tracker.feed(good[0], 0.0)) == 1
    for bad in (b"", good[1][:35], good[1] + b"\0", b"\x12\x34" * 100, bytes(36 * 41)):
        assert len(tracker.feed(bad, 0.0)) == 0
    far = records(1 + (1 << 21), 1)[0]  # a plausible size, an implausible sequence
    assert len(tracker.feed(far, 0.0)) == 0
    assert tracker.counters["malformed"] == 5 and tracker.counters["sequence_anomalies"] == 1
    assert tracker.feed(good[1], 0.0).rdt.tolist() == [2]  # the stream goes on


def _stream(tracker: StreamTracker, rdt: np.ndarray, ft: np.ndarray, t0: float = 100.0,
            period_s: float = 1e-3) -> tuple[list[int], list[float]]:
    """Feed records (rdt, ft) one a datagram, received ``period_s`` apart from ``t0`` (a
    measured latency of 0.5 ms); the rdt and stamps published."""
    rdt_out: list[int] = []
    stamps: list[float] = []
    for k, (r, f) in enumerate(zip(rdt.tolist(), ft.tolist(), strict=True)):
        out = tracker.feed(pack_records([r], [f], [0], np.zeros((1, 6))), t0 + k * period_s + 5e-4)
        rdt_out += out.rdt.tolist()
        stamps += out.t_sensor.tolist()
    return rdt_out, stamps


@pytest.mark.parametrize("what", ["ft+2^30", "ft-2^30", "rdt+2^20", "rdt-2^20"])
def test_one_wild_record_is_an_anomaly_and_the_stream_goes_on(what: str) -> None:
    # one record of 3000 (1 kHz) with a wild sequence, in place of the sensor's own: it is
    # counted as an anomaly and dropped (its place counts as lost), nothing else changes; the
    # stamps keep the sensor's 1 ms (before: 1000 identical stamps after ft+2^30, or
    # 1 048 575 records lost and every later one malformed after rdt+2^20)
    rdt, ft = np.arange(1, 3001), np.arange(5000, 8000)
    field, jump = what[:-5].rstrip("+-"), (1 if "+" in what else -1) << int(what[-2:])
    (rdt if field == "rdt" else ft)[1000] += jump
    tracker = StreamTracker(ft_rate_hz=1000.0)
    got, stamps = _stream(tracker, rdt % (1 << 32), ft % (1 << 32))
    c = tracker.counters
    assert (c["sequence_anomalies"], c["lost"], c["malformed"], c["received"]) == (1, 1, 0, 2999)
    assert got == [k for k in range(1, 3001) if k != 1001]
    steps = np.diff(stamps)
    assert np.all(steps > 0)
    assert np.abs(np.delete(steps, 999) - 1e-3).max() < 1e-9  # 2 ms across the dropped one


@pytest.mark.parametrize("jump", [-(1 << 30), -5000, 1 << 30, 5000])
def test_sequences_that_jump_for_good_resynchronise_at_once(jump: int) -> None:
    # the sensor's ft_sequence jumps and runs on from there (a counter reset, or garbage):
    # one anomaly, one record dropped, then the stream is back with stamps that follow the
    # sensor's 1 ms again, strictly increasing throughout (before: backwards jumps froze the
    # stamps until the host clock caught up, 5 s or 12 days here)
    rdt, ft = np.arange(1, 3001), np.arange(5000, 8000)
    ft[1000:] += jump
    tracker = StreamTracker(ft_rate_hz=1000.0)
    got, stamps = _stream(tracker, rdt, ft % (1 << 32))
    c = tracker.counters
    assert (c["sequence_anomalies"], c["lost"], c["received"]) == (1, 0, 2999)
    assert got == [k for k in range(1, 3001) if k != 1001]
    steps = np.diff(stamps)
    assert np.all(steps > 0)
    assert np.abs(steps[1000:] - 1e-3).max() < 1e-9  # on the sensor's clock again at once
    assert stamps[-1] <= 100.0 + 2999e-3 + 5e-4  # and never after a record's receipt


def test_stamps_strictly_increase_when_the_offset_moves_down() -> None:
    # a latency of 5 ms, then 0.5 ms: the offset moves down 4.5 ms; the stamps do not repeat,
    # they advance at half the sensor's pace (0.5 ms a record) until they meet it (before:
    # nine identical stamps)
    tracker = StreamTracker(ft_rate_hz=1000.0)
    stamps = []
    for k in range(40):
        latency = 5e-3 if k < 20 else 5e-4
        stamps += tracker.feed(records(k + 1, 1)[0], 10.0 + k * 1e-3 + latency).t_sensor.tolist()
    steps = np.diff(stamps)
    assert np.all(steps >= 0.5e-3 - 1e-12)
    np.testing.assert_allclose(steps[19:28], 0.5e-3, atol=1e-12)
    np.testing.assert_allclose(steps[28:], 1e-3, atol=1e-12)
    assert stamps[-1] == pytest.approx(10.0 + 39e-3 + 5e-4, abs=1e-12)


def test_records_of_a_frozen_ft_sequence_are_counted_not_published() -> None:
    tracker = StreamTracker(ft_rate_hz=1000.0)
    frozen = pack_records(np.arange(1, 6), [7, 8, 8, 8, 9], np.zeros(5), np.zeros((5, 6)))
    out = tracker.feed(frozen, 1.0)
    assert out.ft.tolist() == [7, 8, 9] and np.all(np.diff(out.t_sensor) > 0)
    assert tracker.counters["ft_frozen"] == 2 and tracker.counters["lost"] == 0


@FUZZ
@given(st.lists(st.one_of(
    st.binary(max_size=2000),  # garbage of any length
    st.integers(1, 200).map(lambda n: records(n, 1)[0]),  # records, any order
    st.integers(0, 35).map(lambda k: records(7, 1)[0][:k]),  # short
    st.binary(min_size=36, max_size=36),  # a record's size, random content
), max_size=60), st.integers(0, 5))
def test_any_datagrams_never_raise_and_keep_the_books(datagrams: list[bytes], _: int) -> None:
    tracker = StreamTracker()
    published: list[int] = []
    stamps: list[float] = []
    for i, data in enumerate(datagrams):
        out = tracker.feed(data, float(i))
        published += out.rdt.tolist()
        stamps += out.t_sensor.tolist()
        tracker.check_stall(float(i))
    c = tracker.counters
    assert c["datagrams"] == len(datagrams)
    assert all(v >= 0 for v in c.values())
    # what is published is strictly increasing (modulo 2^32 near the start), in sensor time
    # always, in rdt_sequence unless the stream resynchronised to a jump
    assert np.all(np.diff(stamps) > 0)
    if not c["sequence_anomalies"]:
        assert all(0 < (b - a) % (1 << 32) < (1 << 31)
                   for a, b in zip(published, published[1:], strict=False))
    assert len(published) == len(stamps) == c["received"]


@FUZZ
@given(st.integers(0, (1 << 32) - 1), st.permutations(list(range(30))), st.sets(st.integers(0, 29)))
def test_counts_are_exact_for_any_order_and_loss(first: int, order: list[int], dropped: set[int]) -> None:
    data = records(first, 30)
    tracker = StreamTracker()
    sent = [k for k in order if k not in dropped]
    published = []
    for k in sent:
        published += tracker.feed(data[k], 0.0).rdt.tolist()
    if not sent:
        return
    # what the driver must find: a record that came after a newer one is reordered (one
    # older than the stream's first a duplicate: it is outside the stream's books), a gap
    # between the first and the newest never filled is lost
    start, newest, late, early = sent[0], sent[0], 0, 0
    for k in sent[1:]:
        if k < start:
            early += 1
        elif k < newest:
            late += 1
        newest = max(newest, k)
    c = tracker.counters
    assert (c["reordered"], c["duplicates"]) == (late, early)
    assert c["lost"] == (newest - start + 1) - len([k for k in sent if k >= start])
    assert c["received"] == len(published) == len(sent) - late - early
    invariant(tracker, newest - start + 1)


XML = """<?xml version="1.0" encoding="utf-8"?>
<netft><setuserfilter>0</setuserfilter><comrdtrate>7000</comrdtrate>
<scfgfu>N</scfgfu><scfgtu>Nmm</scfgtu><cfgcpf>1000000</cfgcpf><cfgcpt>1000</cfgcpt></netft>"""


def test_config_from_netftapi2_xml() -> None:
    config = parse_config(XML)
    assert config.counts_per_force == 1e6
    assert config.counts_per_torque == 1e6  # 1000 counts per N mm
    assert config.rdt_rate_hz == 7000
    for bad in ("<netft>", "<netft><cfgcpf>0</cfgcpf><cfgcpt>1</cfgcpt></netft>",
                "<netft><cfgcpf>1</cfgcpf></netft>",
                "<netft><cfgcpf>1</cfgcpf><cfgcpt>1</cfgcpt><scfgfu>lbf</scfgfu></netft>"):
        with pytest.raises(ValueError, match="netftapi2.xml"):
            parse_config(bad)


@pytest.mark.live  # an HTTP server on loopback
def test_config_read_over_http() -> None:
    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 - the http.server API
            body = XML.encode() if self.path == "/netftapi2.xml" else b""
            self.send_response(200 if body else 404)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    server = http.server.HTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        config = read_config("127.0.0.1", timeout_s=5.0, port=server.server_address[1])
        assert (config.counts_per_force, config.counts_per_torque) == (1e6, 1e6)
    finally:
        server.shutdown()
        server.server_close()


@FUZZ
@given(st.permutations(list(range(40))), st.sets(st.integers(0, 39)), st.integers(1, 5),
       st.lists(st.integers(1, 12), min_size=1, max_size=20))
def test_a_drain_fed_at_once_is_the_datagrams_fed_in_turn(order: list[int], dropped: set[int],
                                                           per: int, cuts: list[int]) -> None:
    data = records(3, 40 * per, per=per, ft_step=3)
    sent = [data[k] for k in order if k not in dropped] + [b"\x00" * 35]  # and a malformed one
    one, many = StreamTracker(ft_rate_hz=1000.0), StreamTracker(ft_rate_hz=1000.0)
    singly: list[tuple[int, float]] = []
    batched: list[tuple[int, float]] = []
    i = 0
    for n, t in zip(cuts * 40, np.arange(1.0, 100.0, 0.01), strict=False):  # drains of n at t
        if i >= len(sent):
            break
        for d in sent[i:i + n]:
            r = one.feed(d, t)
            singly += zip(r.rdt.tolist(), r.t_sensor.tolist(), strict=True)
        r = many.feed_many(sent[i:i + n], t)
        batched += zip(r.rdt.tolist(), r.t_sensor.tolist(), strict=True)
        i += n
    assert one.counters == many.counters
    assert [k for k, _ in batched] == [k for k, _ in singly]
    # and the same stamps: each datagram of a drain moves the offset as it would alone
    np.testing.assert_allclose([t for _, t in batched], [t for _, t in singly], atol=1e-12)


@pytest.mark.live  # UDP sockets
def test_a_second_device_on_a_taken_port_is_refused() -> None:
    # two simulated sensors on one port would split the driver's stream between them
    from vibrissa.wire.netft_device import NetFTDevice

    first = NetFTDevice(np.zeros((1, 6)))
    try:
        with pytest.raises(OSError):
            NetFTDevice(np.zeros((1, 6)), port=first.address[1])
    finally:
        first.close()


def test_the_devices_ft_sequence_runs_on_between_two_streams() -> None:
    """A sensor's internal counter runs whether it streams or not: a stream requested again
    after 0.3 s begins with rdt_sequence 1 and an ft_sequence 0.3 s on (the driver's sensor
    time, and the simulated robot's poses stamped from it, stay on the host's clock)."""
    import socket
    import time

    from vibrissa.wire.netft_device import NetFTDevice

    def receive(sock: socket.socket, until: float) -> list[tuple[int, int]]:
        """(rdt, ft) of every record until ``until`` (monotonic)."""
        got = []
        while time.monotonic() < until:
            try:
                data = sock.recv(65536)
            except TimeoutError:
                continue
            got += [(int(r["rdt"]), int(r["ft"])) for r in parse_datagram(data)]
        return got

    with NetFTDevice(np.zeros((1, 6)), rate_hz=1000) as device, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(0.01)
        sock.sendto(pack_request(Command.REALTIME), device.address)
        first = receive(sock, time.monotonic() + 0.2)
        sock.sendto(pack_request(Command.STOP), device.address)
        first += receive(sock, time.monotonic() + 0.3)  # in flight; then the sensor idles
        sock.sendto(pack_request(Command.REALTIME), device.address)
        again = receive(sock, time.monotonic() + 0.1)
        assert again[0][0] == 1 and again[0][1] - first[-1][1] >= 250
