"""`smplify3d smpl-to-npz MODEL.pkl [-o MODEL.npz]`: convert an SMPL (or GMM prior, or regressor) pickle
to an .npz with the same keys, once, so that later runs load plain arrays and no pickle at all.

The .pkl is read through the package's restricted loader (smpl_model.load_arrays: an exact allowlist,
nothing in the file runs); entries that are not numeric arrays (`bs_style`, `pose_training_info`...) are
left out and listed. The .npz is written with allow_pickle off and read back before it replaces anything.
See docs/smpl.md.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

PICKLE_SUFFIXES = (".pkl", ".pickle")
_SAVEZ_ARGUMENTS = ("file", "allow_pickle")  # np.savez's own parameter names cannot be array keys


class ConvertError(RuntimeError):
    """The conversion cannot be done; the message says why, in one line."""


def convert(source: str | Path, output: str | Path | None = None, force: bool = False) -> tuple[Path, list[str]]:
    """Write `source`'s arrays to `output` (default: next to it, .npz); returns (output, skipped keys)."""
    source = Path(source)
    if source.suffix not in PICKLE_SUFFIXES:
        raise ConvertError(f"{source}: expected a .pkl file")
    target = Path(output) if output else source.with_suffix(".npz")
    if target.suffix != ".npz":
        raise ConvertError(f"{target}: the output must be a .npz file")
    if target.exists() and not force:
        raise ConvertError(f"{target} exists (--force replaces it)")
    if not target.parent.is_dir():
        raise ConvertError(f"{target.parent}: no such directory")
    from smplify3d_ros.body.smpl_model import load_arrays  # torch with it: not at import (fast --help)

    skipped: list[str] = []
    arrays = load_arrays(source, skipped)
    clash = sorted(set(arrays) & set(_SAVEZ_ARGUMENTS))
    if clash:
        raise ConvertError(f"{source}: key {clash[0]!r} cannot be stored by np.savez")
    _write_npz(target, arrays)
    return target, skipped


def _write_npz(target: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write next to the target, check it reads back equal without pickle, then replace: a failed
    conversion never leaves a half-written model where the config points."""
    partial = target.with_name(f".{target.name}.partial")
    try:
        with open(partial, "wb") as handle:
            np.savez(handle, allow_pickle=False, **arrays)
        with np.load(partial, allow_pickle=False) as back:
            same = set(back.files) == set(arrays) and all(np.array_equal(back[k], v) for k, v in arrays.items())
        if not same:
            raise ConvertError(f"{target}: the written file does not read back equal")
        os.replace(partial, target)
    except OSError as exc:
        raise ConvertError(f"{target}: cannot write ({exc.strerror or exc})") from exc
    finally:
        partial.unlink(missing_ok=True)


# -- command line -----------------------------------------------------------------------------------------
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("pkl", metavar="MODEL.pkl", help="SMPL model, SMPLify GMM prior or regressor pickle")
    parser.add_argument("-o", "--output", metavar="OUT.npz", help="output file (default: MODEL.npz next to it)")
    parser.add_argument("--force", action="store_true", help="replace the output if it exists")


def run(args: argparse.Namespace) -> int:
    """0 on success, 2 for an unusable input or output (one line on stderr)."""
    from smplify3d_ros.body.smpl_model import SmplFileError

    try:
        target, skipped = convert(args.pkl, args.output, args.force)
    except (ConvertError, SmplFileError) as exc:
        print(f"smplify3d smpl-to-npz: {exc}", file=sys.stderr)
        return 2
    note = f"; left out (not numeric arrays): {', '.join(k[:40] for k in skipped[:10])}" if skipped else ""
    print(f"wrote {target}{note}")
    return 0
