"""Shared fixtures: the body model and configuration are built once per test session."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="session")
def config():
    from smplify3d_ros.config import load_config

    return load_config()


@pytest.fixture(scope="session")
def anny_model(config):
    from smplify3d_ros.body import load_body_model

    return load_body_model("anny", config.fitting.body)


@pytest.fixture()
def rng():
    return np.random.default_rng(1234)
