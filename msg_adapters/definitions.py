"""Message definitions the package carries: hri_msgs (REP-155) types, registered in rosbags typestores so
that bags hold them without the hri_msgs package (`register_hri_types`). No other msg_adapters import."""

from __future__ import annotations

from pathlib import Path
from typing import Any

MSG_DIR = Path(__file__).resolve().parent / "msg"
HRI_TYPES = ("hri_msgs/msg/NormalizedPointOfInterest2D", "hri_msgs/msg/Skeleton2D", "hri_msgs/msg/IdsList")


def register_hri_types(typestore: Any) -> Any:
    """Add the hri_msgs definitions of msg_adapters/msg to a rosbags typestore (once; returns it)."""
    from rosbags.typesys import get_types_from_msg

    missing = [name for name in HRI_TYPES if name not in typestore.types]
    if missing:
        types: dict[str, Any] = {}
        for name in HRI_TYPES:
            package, _, type_name = name.split("/")
            types.update(get_types_from_msg((MSG_DIR / package / f"{type_name}.msg").read_text(), name))
        typestore.register(types)
    return typestore
