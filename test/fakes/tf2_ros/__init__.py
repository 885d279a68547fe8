"""A small stand-in for tf2_ros (tf2_ros_py is not installable here): a Buffer that answers from transforms
a test sets, records every lookup (frames, time, timeout) and raises tf2's exception types; a
TransformListener that does nothing. Tests put this directory on sys.path."""

from __future__ import annotations

from typing import Any

FAKE = True


class TransformException(Exception):
    pass


class LookupException(TransformException):
    pass


class ConnectivityException(TransformException):
    pass


class ExtrapolationException(TransformException):
    pass


class Buffer:
    instances: list[Buffer] = []

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.transforms: dict[tuple[str, str], Any] = {}  # (target, source) -> TransformStamped
        self.failures: dict[str, Exception] = {}  # target frame -> exception to raise
        self.calls: list[tuple] = []
        self.frames_yaml = ""
        Buffer.instances.append(self)

    def _answer(self, target: str, source: str) -> Any:
        if target in self.failures:
            raise self.failures[target]
        if (target, source) not in self.transforms:
            raise LookupException(f'"{target}" passed to lookupTransform argument target_frame does not exist')
        return self.transforms[(target, source)]

    def lookup_transform(self, target: str, source: str, time: Any, timeout: Any = None) -> Any:
        self.calls.append(("lookup_transform", target, source, time, timeout))
        return self._answer(target, source)

    def lookup_transform_full(self, target: str, target_time: Any, source: str, source_time: Any, fixed_frame: str,
                              timeout: Any = None) -> Any:
        self.calls.append(("lookup_transform_full", target, source, target_time, source_time, fixed_frame, timeout))
        return self._answer(target, source)

    def all_frames_as_yaml(self) -> str:
        return self.frames_yaml


class TransformListener:
    def __init__(self, buffer: Buffer, node: Any, *args: Any, **kwargs: Any) -> None:
        self.buffer = buffer
