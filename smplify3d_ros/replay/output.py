"""Where the replay writes, without ever losing a user's file: checked before the replay starts, written
under a temporary name beside the target, renamed into place only when complete.

- An output equal to an input, inside an input bag directory, or holding an input is refused.
- An existing file, or a non-empty directory, is replaced only with `overwrite`; a directory only if it
  is a bag directory (metadata.yaml and storage files, nothing else): `-o ~/results --overwrite` does not
  erase a folder of results.
- Until it is complete the output is `<name>.partial-XXXXXX` (a file, or a directory holding no
  metadata.yaml); a failed or interrupted run removes it, a killed one leaves it under that name.
"""

from __future__ import annotations

import os
import secrets
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from smplify3d_ros.replay.reader import ReplayError

BAG_FILE_SUFFIXES = (".mcap", ".db3", ".zstd", ".yaml")  # what a bag directory may hold


class OutputError(ReplayError):
    """The output cannot be written where asked (or would replace something it must not)."""


def _is_within(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _check_inputs(target: Path, inputs: list[Path]) -> None:
    target = target.parent.resolve() / target.name  # a symlinked folder may lead into an input
    for given in inputs:
        inp = given.resolve()
        if _is_within(target, inp) or (target.exists() and inp.exists() and os.path.samefile(target, inp)):
            where = "is" if target == inp or inp.is_file() else "is inside"
            raise OutputError(f"{target} {where} the input {given}: choose another output")
        if _is_within(inp, target):
            raise OutputError(f"{target} holds the input {given}: choose another output")


def _is_bag_directory(path: Path) -> bool:
    entries = list(path.iterdir())
    return any(e.name == "metadata.yaml" for e in entries) and all(
        e.is_file() and not e.is_symlink() and e.suffix in BAG_FILE_SUFFIXES for e in entries)


def _check_existing(target: Path, directory: bool, overwrite: bool) -> None:
    if not target.exists() and not target.is_symlink():
        return
    if target.is_dir() and not target.is_symlink():
        if not directory:
            raise OutputError(f"{target} is a directory; give a file name")
        if not any(target.iterdir()):
            return  # an empty directory is replaced by the bag directory
        if not overwrite:
            raise OutputError(f"{target} exists and is not empty (--overwrite replaces a bag directory)")
        if not _is_bag_directory(target):
            raise OutputError(f"{target} holds files other than a bag's; not replaced, even with --overwrite")
        return
    if directory:
        raise OutputError(f"{target} is a file; give a directory name (or a .mcap file name)")
    if not overwrite:
        raise OutputError(f"{target} exists (--overwrite replaces it)")


@dataclass
class Output:
    """One output in the making: `temp` (a file, or a directory for a bag directory) until `commit`."""

    target: Path
    temp: Path
    directory: bool

    @property
    def file(self) -> Path:
        """Where the data goes: the temporary file, or the storage file in the temporary directory."""
        return self.temp / f"{self.target.name}.mcap" if self.directory else self.temp

    def commit(self) -> None:
        """Put the complete output in place (replacing what `prepare_output` allowed to replace)."""
        _IN_THE_MAKING.pop(id(self), None)
        old = None
        if self.target.is_dir() and not self.target.is_symlink() and any(self.target.iterdir()):
            old = Path(tempfile.mkdtemp(prefix=f"{self.target.name}.replaced-", dir=self.target.parent))
            os.replace(self.target, old)  # a non-empty directory cannot be replaced in one rename
        os.replace(self.temp, self.target)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)

    def discard(self) -> None:
        """Remove the incomplete output (created by this run; after `commit` there is none)."""
        _IN_THE_MAKING.pop(id(self), None)
        if self.temp.is_dir() and not self.temp.is_symlink():
            shutil.rmtree(self.temp, ignore_errors=True)
        else:
            self.temp.unlink(missing_ok=True)


_IN_THE_MAKING: dict[int, Output] = {}  # the outputs `prepare_output` created and nobody committed yet


def discard_all() -> None:
    """Remove every output still in the making (a terminating signal, `replay.cli`)."""
    for made in list(_IN_THE_MAKING.values()):
        made.discard()


def _create_temp(parent: Path, prefix: str, directory: bool) -> Path:
    """A new file or directory `prefix`XXXXXX with the usual permissions (tempfile's are private: 0600)."""
    for _ in range(100):
        temp = parent / f"{prefix}{secrets.token_hex(3)}"
        try:
            if directory:
                temp.mkdir(0o777)
            else:
                os.close(os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return temp
        except FileExistsError:
            continue
    raise FileExistsError(f"no free temporary name {prefix}XXXXXX in {parent}")


def check_output(target: str | Path, inputs: list[Path], overwrite: bool = False,
                 directory: bool = False) -> Path:
    """The absolute `target` if it may be written (module docstring), else OutputError naming the path;
    creates nothing."""
    target = Path(os.path.abspath(Path(target).expanduser()))
    _check_inputs(target, inputs)
    _check_existing(target, directory, overwrite)
    return target


def prepare_output(target: str | Path, inputs: list[Path], overwrite: bool = False,
                   directory: bool = False) -> Output:
    """Check `target` (`check_output`) and create its temporary; OutputError naming the path if not."""
    target = check_output(target, inputs, overwrite, directory)
    parent = target.parent
    blocking = next((p for p in (parent, *parent.parents) if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise OutputError(f"cannot write {target}: {blocking} is a file, not a directory")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        temp = _create_temp(parent, f"{target.name}.partial-", directory)
    except OSError as e:
        where = f" ({e.filename})" if e.filename and Path(e.filename) in target.parents else ""
        raise OutputError(f"cannot write {target}: {e.strerror or e}{where}") from None
    made = Output(target, temp, directory)
    _IN_THE_MAKING[id(made)] = made
    return made
