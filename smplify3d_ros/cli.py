"""`smplify3d`: the command line, a thin shell over the package's pipelines.

    smplify3d setup                 build the body model's cache once (about a minute on first use)
    smplify3d replay IN [-o OUT]    fit every frame of a bag, write an output bag (no ROS runtime needed)
    smplify3d make-bags             regenerate the synthetic bags in bags/
    smplify3d bench                 accuracy benchmark on simulated scenes (--sequences: tracking)
    smplify3d bench-speed           fit time and accuracy of the optimizer profiles
    smplify3d bench-extract         precision/recall of the LiDAR person extraction
    smplify3d bench-live BAG        the node live on a bag at its recorded rate: output rate, latency
    smplify3d tune                  tune a profile on the tuning seeds
    smplify3d smpl-to-npz MODEL     convert an SMPL .pkl to .npz

Errors are one line on stderr naming the file, key or topic at fault, with exit code 2 when the input,
parameters or output are unusable and 3 for anything unexpected (a bug); `smplify3d --debug CMD ...`
also prints the traceback. Ctrl-C (and SIGTERM in `replay`) exits with 130.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import time
import traceback
from collections.abc import Callable

EXIT_USER_ERROR = 2  # unusable input, parameters or output: the message says what to change
EXIT_INTERNAL_ERROR = 3  # a bug: --debug shows the traceback
EXIT_INTERRUPTED = 130

# subcommand -> (module, help); each module has add_arguments(parser) and run(args) -> int
COMMANDS = {
    "replay": ("smplify3d_ros.replay.cli", "fit every frame of a rosbag2 (MCAP or sqlite3) and write the results"),
    "make-bags": ("smplify3d_ros.sim.bags", "regenerate the synthetic Jackal/VLP-16 bags with ground truth"),
    "bench": ("smplify3d_ros.eval.bench.cli", "accuracy benchmark on simulated scenes (Markdown + JSON)"),
    "bench-speed": ("smplify3d_ros.eval.bench_speed", "per-person fit time and MPJPE of the profiles"),
    "bench-extract": ("smplify3d_ros.eval.extraction", "precision/recall of person point extraction"),
    "bench-live": ("smplify3d_ros.eval.live", "the node live on a bag at its recorded rate: output rate, latency"),
    "tune": ("smplify3d_ros.eval.tune", "tune a profile's weights and iterations on the tuning seeds"),
    "smpl-to-npz": ("smplify3d_ros.body.smpl_convert", "convert an SMPL .pkl to .npz (safe to load, no pickle)"),
}


def at_least(low: float, cast: Callable[[str], float] = int, strict: bool = False) -> Callable[[str], float]:
    """An argparse `type`: `cast` of the text, at least `low` (`strict`: above it); anything else is
    argparse's one-line usage error, not a failure deep in the run."""
    def parse(text: str) -> float:
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {'an integer' if cast is int else 'a number'}, got {text!r}") from None
        if not (value > low if strict else value >= low):  # NaN fails too
            raise argparse.ArgumentTypeError(f"must be {'>' if strict else '>='} {low:g}, got {text!r}")
        return value

    return parse


def _setup(args: argparse.Namespace) -> int:
    """Build what first use would otherwise build inside a latency-critical path."""
    from smplify3d_ros.body import load_body_model
    from smplify3d_ros.config import load_config

    start = time.perf_counter()
    config = load_config(args.params)
    model = load_body_model(config.fitting.body.model, config.fitting.body)
    print(f"body model {model.name!r} ready ({len(model.faces)} faces) in {time.perf_counter() - start:.1f} s")
    return 0


def _user_error_types() -> tuple[type[BaseException], ...]:
    """Errors that are the input's fault (imported when needed: --help must stay light)."""
    from smplify3d_ros.settings import ConfigError

    types: list[type[BaseException]] = [ConfigError, OSError]
    for module, name in (("smplify3d_ros.replay.reader", "ReplayError"),
                         ("smplify3d_ros.body.smpl_model", "SmplFileError")):
        try:
            types.append(getattr(importlib.import_module(module), name))
        except ImportError:
            pass
    return tuple(types)


def _one_line(error: BaseException) -> str:
    """An error as one line: an OSError names its file, others their first line (bounded)."""
    if isinstance(error, OSError) and error.filename is not None:
        text = f"{error.filename}: {error.strerror or error}"
    else:
        lines = str(error).strip().splitlines()
        text = lines[0] if lines else type(error).__name__
    return text if len(text) <= 500 else text[:500] + "..."


def run_command(name: str, func: Callable[[argparse.Namespace], int | None], args: argparse.Namespace,
                debug: bool = False) -> int:
    """Run one subcommand: any error becomes one line on stderr and a non-zero exit code (2: the input's
    fault, 3: a bug), its traceback only with `debug`."""
    try:
        return int(func(args) or 0)
    except KeyboardInterrupt:
        print(f"smplify3d {name}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as error:  # noqa: BLE001 - the one place every error of a command ends up
        if debug:
            traceback.print_exc()
        if isinstance(error, _user_error_types()):
            print(f"smplify3d {name}: {_one_line(error)}", file=sys.stderr)
            return EXIT_USER_ERROR
        hint = "" if debug else " (run `smplify3d --debug ...` for the traceback)"
        print(f"smplify3d {name}: internal error: {type(error).__name__}: {_one_line(error)}{hint}",
              file=sys.stderr)
        return EXIT_INTERNAL_ERROR


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser; only `command`'s module is imported, to add its arguments (so that `--help` of the
    command line, or of one subcommand, never imports the others: some load torch)."""
    parser = argparse.ArgumentParser(prog="smplify3d", description=__doc__.split("\n\n")[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error")
    sub = parser.add_subparsers(dest="command", required=True)
    setup = sub.add_parser("setup", help="build the body model cache once (run at install time)")
    setup.add_argument("--params", metavar="PROFILE", help="params profile or YAML file (default: jackal_vlp16)")
    setup.set_defaults(func=_setup)
    for name, (module_name, help_text) in COMMANDS.items():
        subcommand = sub.add_parser(name, help=help_text)
        subcommand.set_defaults(module=module_name)
        if name != command:
            continue
        try:
            importlib.import_module(module_name).add_arguments(subcommand)
        except ImportError as exc:  # keep the other commands usable, say what is missing
            subcommand.set_defaults(missing=str(exc))
    return parser


def _command(argv: list[str]) -> str | None:
    """The subcommand named on the command line (the first word that is one)."""
    return next((word for word in argv if word in COMMANDS), None)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(_command(argv)).parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    if hasattr(args, "func"):
        return run_command(args.command, args.func, args, args.debug)
    if getattr(args, "missing", None):
        print(f"smplify3d {args.command}: unavailable ({args.missing})", file=sys.stderr)
        return EXIT_USER_ERROR
    return run_command(args.command, lambda a: importlib.import_module(a.module).run(a), args, args.debug)


if __name__ == "__main__":
    sys.exit(main())
