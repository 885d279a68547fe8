"""A ROS domain of our own: one another process on this host uses or holds is never chosen."""

from __future__ import annotations

import random
import subprocess
import sys

import pytest

from smplify3d_ros.eval import ros_domain


def _free_domains() -> list[int]:
    """Domains nothing on this host uses or holds now (another test run beside this one holds its own), in
    random order: tests in other workers pick from the same range."""
    free = [d for d in range(20, ros_domain.MAX_DOMAIN + 1) if not ros_domain.domain_taken(d)]
    random.shuffle(free)
    return free


def test_a_domain_whose_participant_port_is_bound_is_in_use_and_not_reserved():
    busy, *others = _free_domains()
    port = ros_domain.PORT_BASE + ros_domain.DOMAIN_GAIN * busy + ros_domain.METATRAFFIC_UNICAST + 2  # participant 1
    sock = ros_domain._bound(port)
    assert sock is not None
    try:
        assert ros_domain.domain_in_use(busy) and ros_domain.domain_taken(busy)
        got = ros_domain.reserve_domain([busy, *others])
        assert got is not None and got != busy
        assert ros_domain.reserve_domain([got]) == got  # held by this process: its own again
    finally:
        sock.close()
    assert not ros_domain.domain_in_use(busy)


def test_a_domain_another_process_reserved_is_skipped_before_it_starts_a_participant():
    free = _free_domains()
    child = subprocess.Popen([sys.executable, "-c", "import sys; from smplify3d_ros.eval.ros_domain import "
                              f"reserve_domain; print(reserve_domain({free}), flush=True); sys.stdin.readline()"],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        held = int(child.stdout.readline())
        assert not ros_domain.domain_in_use(held) and ros_domain.domain_taken(held)  # only the reservation
        got = ros_domain.reserve_domain([held, *free])
        assert got is not None and got != held
    finally:
        child.communicate("\n", timeout=30)


def test_a_domain_with_a_running_ros_node_is_in_use():
    pytest.importorskip("rclpy")
    domain = _free_domains()[0]
    code = ("import os, sys; os.environ['ROS_DOMAIN_ID'] = sys.argv[1]; "
            "os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'; import rclpy; rclpy.init(); "
            "node = rclpy.create_node('domain_probe'); print('up', flush=True); sys.stdin.readline(); "
            "node.destroy_node(); rclpy.shutdown()")
    child = subprocess.Popen([sys.executable, "-c", code, str(domain)], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "up"
        assert ros_domain.domain_in_use(domain) and ros_domain.domain_taken(domain)
        assert ros_domain.reserve_domain([domain]) is None
    finally:
        child.communicate("\n", timeout=30)
    assert child.returncode == 0
