"""`ropemon bench fleet` in small: the product's MQTT faces (2 edge nodes x 5 hoists at 10
frames/s) through a real Mosquitto, killed and restarted in the middle, into the fleet
consumer: every rope of every frame handed over is in the historian. No speed is asserted
(figures live in docs/benchmarks.md)."""
from __future__ import annotations

import pytest

pytest.importorskip("paho.mqtt")

from ropemon.lab.bench import fleet  # noqa: E402
from ropemon.lab.localnet import available  # noqa: E402


def test_fleet_bench_loses_no_frame_across_a_broker_kill():
    if not available():
        pytest.fail("mosquitto is missing: `make test` installs it (apt-get install mosquitto, as root)")
    r = fleet.run("product", edges=2, per_edge=5, procs=1, seconds=6.0, warmup_s=1.0, outage=(2.0, 1.5),
                  drain_s=30.0)
    assert r["frames"] == 2 * 5 * 60
    assert r["lost_rows"] == 0 and r["lost"] == 0
    assert r["historical_rows"] > 0                # the outage's frames came from the outboxes
    assert r["sessions"] == 2 * 2                  # each edge node born again after the restart
    assert r["outbox_left"] == 0 and r["outbox_dropped"] == 0
    assert r["backlog_frames"] > 0 and r["catch_up_s"] >= 0
