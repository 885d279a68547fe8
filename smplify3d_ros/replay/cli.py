"""`smplify3d replay`: the command line of the replay (light to import: `--help` loads no torch)."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys

from smplify3d_ros.cli import at_least


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", metavar="IN", help="rosbag2 recording: a bag directory, or a .mcap / .db3 file")
    parser.add_argument("-o", "--output", metavar="OUT.mcap",
                        help="output bag: a .mcap file, or a directory name for a rosbag2 bag directory")
    parser.add_argument("--params", metavar="PROFILE", default=None,
                        help="params profile name (e.g. ouster64) or YAML path; default: jackal_vlp16")
    parser.add_argument("--png", metavar="FILE", help="write a picture of the fit of one representative frame")
    parser.add_argument("--max-frames", type=at_least(1), default=None, help="stop after this many synchronized frames")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing output file or bag directory (never an input)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


_STDERR: int | None = None  # the terminal's stderr, kept while a replay runs (see `_terminated`)


def _terminated(signum: int, frame: object) -> None:
    """SIGTERM (systemd, docker stop): the partial outputs are removed and the command exits 130 at once,
    wherever it was. Unwinding from inside a library's initialization (the body model's, whose output is
    then redirected) did not reliably end the process with 130, so nothing is unwound."""
    from smplify3d_ros.replay.output import discard_all

    discard_all()
    if _STDERR is not None:
        os.write(_STDERR, b"smplify3d replay: interrupted\n")
    os._exit(130)


def run(args: argparse.Namespace) -> int:
    """0 on success, 1 when nothing could be fitted, 2 for an unusable bag, output or params (one line on
    stderr; `smplify3d` reports anything else)."""
    from smplify3d_ros.replay.reader import ReplayError
    from smplify3d_ros.replay.run import replay_bag
    from smplify3d_ros.settings import ConfigError

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    global _STDERR
    try:
        _STDERR = os.dup(2)
        previous = signal.signal(signal.SIGTERM, _terminated)
    except ValueError:  # not the main thread: leave signals alone
        previous = None
    try:
        summary = replay_bag(args.bag, args.output, args.params, args.png, progress=not args.no_progress,
                             max_frames=args.max_frames, overwrite=args.overwrite)
    except (ReplayError, ConfigError) as e:
        print(f"smplify3d replay: {e}", file=sys.stderr)
        return 2
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if _STDERR is not None:
            os.close(_STDERR)
            _STDERR = None
    print(summary.text())
    return 0 if summary.frames_published > 0 else 1


def main(argv: list[str] | None = None) -> int:
    from smplify3d_ros.cli import run_command

    parser = argparse.ArgumentParser(prog="smplify3d replay", description="fit every frame of a rosbag2")
    add_arguments(parser)
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error")
    args = parser.parse_args(argv)
    return run_command("replay", run, args, args.debug)


if __name__ == "__main__":
    sys.exit(main())
