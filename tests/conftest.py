"""Shared fixtures: tiny scenarios and worlds."""

from __future__ import annotations

import dataclasses

import pytest

from scenarios import Scenario, load_scenario
from sim import PushWorld


@pytest.fixture(scope="session")
def tiny() -> Scenario:
    return load_scenario("tiny")


@pytest.fixture
def tiny_world(tiny: Scenario) -> PushWorld:
    return PushWorld(tiny)


def with_fields(scenario: Scenario, section: str, **changes) -> Scenario:
    """A copy of ``scenario`` with fields of one section replaced."""
    return dataclasses.replace(
        scenario, **{section: dataclasses.replace(getattr(scenario, section), **changes)}
    )


@pytest.fixture(scope="session")
def tiny_data(tmp_path_factory):
    """A small tiny-scenario dataset (21 episodes of 8 steps: train, val and test splits)."""
    from sim.dataset import DataConfig, generate

    root = tmp_path_factory.mktemp("tiny_data")
    generate(
        DataConfig("tiny", episodes=21, steps_per_episode=8, episodes_per_shard=7),
        root,
        progress=False,
    )
    return root


@pytest.fixture(scope="session")
def ray_local():
    """A local Ray instance of 2 worker CPUs, shared by the tests (skipped without the scale
    extra). The code under test finds it started and leaves it running."""
    ray = pytest.importorskip("ray", reason='the scale extra: pip install -e ".[scale]"')
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()
