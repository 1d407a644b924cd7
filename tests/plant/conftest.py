"""Shared fixtures of the plant tests: scenarios built once, runs cached per module."""
from __future__ import annotations

from pathlib import Path

import pytest

from ropemon.lab.plant.run import simulate
from ropemon.lab.plant.scenario import load_scenario

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"


@pytest.fixture(scope="session")
def scenarios_dir() -> Path:
    return SCENARIOS


@pytest.fixture(scope="session")
def field_trip():
    return simulate(load_scenario(SCENARIOS / "paper-field-trip.toml"))


@pytest.fixture(scope="session")
def connection_device():
    return simulate(load_scenario(SCENARIOS / "paper-connection-device.toml"))


@pytest.fixture(scope="session")
def single_cylinder():
    return simulate(load_scenario(SCENARIOS / "paper-single-cylinder.toml"))


@pytest.fixture(scope="session")
def short_test():
    return simulate(load_scenario(SCENARIOS / "short-test.toml"))
