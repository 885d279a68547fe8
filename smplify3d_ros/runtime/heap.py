"""The garbage collector and a long-running fitter: startup objects moved out of its way.

Loading the body model, torch and the message types leaves some 400 000 objects that live as long as
the process. CPython's cyclic collector walks all of them at every full (generation 2) collection, and
the per-frame work (a mesh marker alone is 18 000 `geometry_msgs/Point` objects per person) triggers
one every few frames: measured on `bags/walk`, a pause of about 210 ms every 5 frames, on top of a
50 ms frame. `gc.freeze()` moves everything alive at that point into a permanent generation that the
collector no longer walks (the objects stay valid; they are simply never collected, which they would
not be anyway); the full collections that follow walk the frame's own objects and take a few ms.
The drivers call `freeze_startup_heap()` after building their fitter and before the first frame
(bench-speed once per profile's fitter).
"""

from __future__ import annotations

import gc


def freeze_startup_heap() -> int:
    """Collect once, then exempt every surviving object from later collections; returns how many objects
    are frozen now."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()
