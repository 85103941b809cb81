"""Shared fixtures: scenarios and host builds are made once per session."""
from __future__ import annotations

import functools

import pytest


@functools.cache
def scenario(name: str, seed: int = 0, **opts):
    from firmware_sim import scenarios
    return scenarios.make(name, seed=seed, **opts)


@functools.cache
def host_build(filter_name: str, precision: str = "float", sets: tuple = ()):
    from generator import config
    from firmware_sim import host
    return host.build(config.resolve(filter_name, sets=list(sets), precision=precision))


@functools.cache
def reference_run(filter_name: str, scenario_name: str, sets: tuple = (), seed: int = 0, **opts):
    from generator import config
    from firmware_sim import host
    cfg = config.resolve(filter_name, sets=list(sets))
    return host.run_reference(cfg.spec.reference(cfg.params), scenario(scenario_name, seed, **opts))


@pytest.fixture(scope="session")
def fixedwing():
    return scenario("fixedwing_gps")
