"""`smplify3d`: the command line, a thin shell over the package's pipelines.

    smplify3d setup                 build the body model's cache once (about a minute on first use)
    smplify3d replay IN [-o OUT]    fit every frame of a bag, write an output bag (no ROS runtime needed)
    smplify3d make-bags             regenerate the synthetic bags in bags/
    smplify3d bench                 accuracy benchmark on simulated scenes
    smplify3d bench-speed           fit time and accuracy of the optimizer profiles
    smplify3d bench-extract         precision/recall of the LiDAR person extraction
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import time

# subcommand -> (module, help); each module has add_arguments(parser) and run(args) -> int
COMMANDS = {
    "replay": ("smplify3d_ros.replay.cli", "fit every frame of a rosbag2 (MCAP or sqlite3) and write the results"),
    "make-bags": ("smplify3d_ros.sim.bags", "regenerate the synthetic Jackal/VLP-16 bags with ground truth"),
    "bench": ("smplify3d_ros.eval.bench.cli", "accuracy benchmark on simulated scenes (Markdown + JSON)"),
    "bench-speed": ("smplify3d_ros.eval.bench_speed", "per-person fit time and MPJPE of the profiles"),
    "bench-extract": ("smplify3d_ros.eval.extraction", "precision/recall of person point extraction"),
    "tune": ("smplify3d_ros.eval.tune", "tune a profile's weights and iterations on the tuning seeds"),
    "smpl-to-npz": ("smplify3d_ros.body.smpl_convert", "convert an SMPL .pkl to .npz (safe to load, no pickle)"),
}


def _setup(args: argparse.Namespace) -> int:
    """Build what first use would otherwise build inside a latency-critical path."""
    from smplify3d_ros.body import load_body_model
    from smplify3d_ros.config import load_config

    start = time.perf_counter()
    config = load_config(args.params)
    model = load_body_model(config.fitting.body.model, config.fitting.body)
    print(f"body model {model.name!r} ready ({len(model.faces)} faces) in {time.perf_counter() - start:.1f} s")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="smplify3d", description=__doc__.split("\n\n")[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)
    setup = sub.add_parser("setup", help="build the body model cache once (run at install time)")
    setup.add_argument("--params", help="params profile or YAML file (default: jackal_vlp16)")
    setup.set_defaults(func=_setup)
    for name, (module_name, help_text) in COMMANDS.items():
        command = sub.add_parser(name, help=help_text)
        command.set_defaults(module=module_name)
        try:
            importlib.import_module(module_name).add_arguments(command)
        except ImportError as exc:  # keep the other commands usable, say what is missing
            command.set_defaults(missing=str(exc))
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    if hasattr(args, "func"):
        return args.func(args)
    if getattr(args, "missing", None):
        print(f"smplify3d {args.command}: unavailable ({args.missing})", file=sys.stderr)
        return 2
    try:
        return int(importlib.import_module(args.module).run(args) or 0)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
