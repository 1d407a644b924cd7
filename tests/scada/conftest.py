"""Fixtures of the SCADA tests: a Mosquitto broker of the test's own on a free port."""
from __future__ import annotations

import pytest

from ropemon.lab.localnet import Broker, available


@pytest.fixture
def broker(tmp_path):
    if not available():
        pytest.fail("mosquitto is missing: `make test` installs it (apt-get install mosquitto, as root)")
    b = Broker(tmp_path)
    yield b
    b.close()
