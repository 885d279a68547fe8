"""diagnostic_msgs/DiagnosticArray for `/diagnostics`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from msg_adapters.factory import MessageFactory, resolve_factory

# diagnostic_msgs/DiagnosticStatus levels.
LEVELS: dict[str, int] = {"OK": 0, "WARN": 1, "ERROR": 2, "STALE": 3}


def _level(level: int | str) -> int:
    if isinstance(level, str):
        if level.upper() not in LEVELS:
            raise ValueError(f"unknown diagnostic level {level!r}; known: {', '.join(LEVELS)}")
        return LEVELS[level.upper()]
    if int(level) not in LEVELS.values():
        raise ValueError(f"diagnostic level must be 0 (OK) to 3 (STALE), got {level}")
    return int(level)


def format_value(value: float | str | bool) -> str:
    """KeyValue text: floats with 6 significant digits, booleans as true/false, the rest via str()."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def diagnostic_status(
    name: str,
    level: int | str,
    message: str,
    values: Mapping[str, float | int | str],
    factory: MessageFactory | None = None,
    hardware_id: str = "",
) -> Any:
    """One DiagnosticStatus with `values` as its key/value pairs (in order); `level` 0..3 or a LEVELS name."""
    factory = resolve_factory(factory)
    return factory.make(
        "diagnostic_msgs/msg/DiagnosticStatus",
        level=_level(level),
        name=str(name),
        message=str(message),
        hardware_id=str(hardware_id),
        values=[
            factory.make("diagnostic_msgs/msg/KeyValue", key=str(k), value=format_value(v))
            for k, v in values.items()
        ],
    )


def diagnostics_message(stamp: Any, statuses: list[Any], factory: MessageFactory | None = None) -> Any:
    """A DiagnosticArray of several statuses (diagnostic_updater publishes one per task)."""
    factory = resolve_factory(factory)
    return factory.make("diagnostic_msgs/msg/DiagnosticArray", header=factory.header(stamp, ""), status=statuses)


def diagnostics_array(
    stamp: Any,
    name: str,
    level: int | str,
    message: str,
    values: Mapping[str, float | int | str],
    factory: MessageFactory | None = None,
    hardware_id: str = "",
) -> Any:
    """A DiagnosticArray holding one DiagnosticStatus with `values` as its key/value pairs (in order).

    `level` is 0..3 or "OK" / "WARN" / "ERROR" / "STALE".
    """
    status = diagnostic_status(name, level, message, values, factory, hardware_id)
    return diagnostics_message(stamp, [status], factory)
