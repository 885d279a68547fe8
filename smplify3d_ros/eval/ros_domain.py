"""A ROS domain no other process on this host uses, for the benchmarks and tests that run a ROS graph.

Two processes in one domain hear each other: a second `smplify3d bench-live` (or a second test run)
started beside the first receives the first's bag as well, and its frame synchronizer sees stamps jump
back and forth. A DDS participant of domain `d` binds well-known UDP ports on the host (the RTPS
defaults, as Fast DDS, ROS 2 Jazzy's default middleware, binds them): 7410 + 250 d + 2 p for its
metatraffic, p the participant's index in the domain. A domain is taken when one of its first
participants' ports is bound, or when another process holds the domain's reservation port,
7405 + 250 d, which no participant binds. Reserving holds that port for the life of this process, so a
process that has not started its participants yet (or is between them) keeps its domain.
"""

from __future__ import annotations

import random
import socket
from collections.abc import Iterable

PORT_BASE, DOMAIN_GAIN, PARTICIPANT_GAIN = 7400, 250, 2  # the RTPS well-known port parameters (PB, DG, PG)
METATRAFFIC_UNICAST, RESERVATION = 10, 5  # offsets d1 and an offset no RTPS port uses (d0 0, d2 1, d3 11)
PARTICIPANTS_PROBED = 8  # participants per domain whose ports say the domain is in use
MAX_DOMAIN = 101  # higher domains' ports fall in Linux's ephemeral range (32768-60999)

_held: dict[int, socket.socket] = {}  # domain -> the reservation socket this process holds


def _bound(port: int) -> socket.socket | None:
    """A UDP socket bound to `port` on every interface, or None when something holds it."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(("", port))
    except OSError:
        sock.close()
        return None
    return sock


def domain_in_use(domain: int) -> bool:
    """Whether a participant of `domain` runs on this host (one of its first participants' ports is bound)."""
    base = PORT_BASE + DOMAIN_GAIN * domain + METATRAFFIC_UNICAST
    for p in range(PARTICIPANTS_PROBED):
        sock = _bound(base + PARTICIPANT_GAIN * p)
        if sock is None:
            return True
        sock.close()
    return False


def domain_taken(domain: int) -> bool:
    """Whether another process on this host uses `domain` or holds its reservation (this process's own
    reservation counts as taken too)."""
    sock = _bound(PORT_BASE + DOMAIN_GAIN * domain + RESERVATION)
    if sock is None:
        return True
    sock.close()
    return domain_in_use(domain)


def reserve_domain(candidates: Iterable[int]) -> int | None:
    """The first of `candidates` that no process on this host uses or holds, reserved for this process's
    lifetime (a domain this process already holds is returned again); None when all are taken."""
    for domain in candidates:
        if domain in _held:
            return domain
        if not 0 <= domain <= MAX_DOMAIN:
            continue
        sock = _bound(PORT_BASE + DOMAIN_GAIN * domain + RESERVATION)
        if sock is None:
            continue
        if domain_in_use(domain):
            sock.close()
            continue
        _held[domain] = sock
        return domain
    return None


def random_free_domain(low: int = 20, high: int = MAX_DOMAIN, step: int = 1, offset: int = 0) -> int:
    """A reserved domain in [low, high] congruent to `offset` modulo `step`, tried in random order (the
    last of them, unreserved, when every one is taken)."""
    domains = list(range(low + offset % step, high + 1, step))
    random.shuffle(domains)
    chosen = reserve_domain(domains)
    return domains[-1] if chosen is None else chosen
