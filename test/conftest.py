"""Shared fixtures: the body model and configuration, built once per test session; an rclpy context per test."""

from __future__ import annotations

import os

# One thread per process for the numeric libraries (OpenMP, OpenBLAS, MKL), in the test workers and in
# the processes they start: the suite runs two workers on two cores, and more threads only contend.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402 - after the thread settings, which the libraries read when they load
import pytest  # noqa: E402


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


@pytest.fixture()
def ros():
    """rclpy initialised in a ROS domain of this test run's own (loopback only), shut down after."""
    import node_support
    import rclpy

    node_support.isolate_ros_graph()
    rclpy.init()
    yield
    rclpy.try_shutdown()
