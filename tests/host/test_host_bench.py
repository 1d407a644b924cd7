"""The host benchmark's decoders agree (what it times is real work); speed itself is in `make bench`."""
from __future__ import annotations

from ropemon.station.batch import decode_bytes
from ropemon.lab.bench import host


def test_benchmark_decoders_agree_on_its_capture():
    data = host.make_capture(3000)
    kept_naive: list = []
    kept_stream: list = []
    n = host.naive_decode(data, kept_naive)
    assert 2800 < n < 3000  # some frames damaged on purpose
    assert host.stream_decode(data, kept_stream) == n == len(decode_bytes(data))
    assert [d["seq"] for d in kept_naive] == [f.seq for f in kept_stream]
    assert kept_naive[5]["ropes"][2]["raw_kpa"] == kept_stream[5].ropes[2].raw_kpa

