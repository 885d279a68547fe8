"""Bag in -> fits -> bag out, without a ROS runtime: `smplify3d replay IN [-o OUT.mcap] [--params FILE]`.

`reader.BagReader` turns a rosbag2 recording into synchronized sets of input messages (`sources` reads
the storage: no bad chunk, cut file or corrupt row stops it, each is counted), the node's
`runtime.processor.MessageProcessor` turns each into fits and output messages, `writer.BagWriter` writes
an MCAP bag (zstd chunks with CRCs) holding the input topics and every output topic
(`/smplify3d/markers`, ... and `/diagnostics`), each output at the recording time of the message that
completed its frame, and `scoring.TruthScorer` scores the fits against `/ground_truth/bodies` when the
bag has it. `output` decides where outputs may go and puts them there only when complete. `run.replay_bag`
drives them and returns a summary; `cli` is the command line. See docs/replay.md.
"""

from __future__ import annotations

import importlib
from typing import Any

_LAZY = {"replay_bag": "run", "ReplaySummary": "run", "ReplayError": "reader", "OutputError": "output",
         "add_arguments": "cli", "run": "cli", "main": "cli"}


def __getattr__(name: str) -> Any:
    """The package's API, imported on first use (the command line's --help must not load torch)."""
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
