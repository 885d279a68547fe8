"""The replay's memory does not grow with the bag's length: a 60-frame bag with ground truth (every
frame's true mesh, 13,718 vertices) peaks within 5 % of a 10-frame one. A reader that kept every
parsed ground-truth frame peaked 22 MiB higher after the 60 (408 vs 385 MiB), above the 5 % (19 MiB).

One process (peak RSS, VmHWM, is per process) replays the first 10 frames of the bag, then the whole
60, with the stub fitter (the fitting's memory is the fitter's business and does not depend on the
bag's length): the peak after the 60 must stay within 5 % of the peak after the 10. The bag repeats two
posed frames with new stamps (`bag_fixture.repeat_frames`), without images.

As a benchmark (prints both peaks):  .venv/bin/python test/test_replay_memory.py [--frames 10 100]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import bag_fixture
import node_support

N_SHORT, N_LONG = 10, 60
TOLERANCE = 0.05


def write_bag(path: Path, n_frames: int) -> Path:
    T = node_support.node_config().extrinsic.T_cam_lidar()
    model = node_support.fitter().model
    frames = bag_fixture.repeat_frames(bag_fixture.make_frames(model, T, 2, 1, seed=11), n_frames)
    bag_fixture.write_fixture_bag(path, model, T, "mcap-crc", frames=frames, with_image=False)
    return path


def peak_rss_kib() -> int:
    with open("/proc/self/status", encoding="ascii") as handle:
        return next(int(line.split()[1]) for line in handle if line.startswith("VmHWM:"))


def replays_in_subprocess(bag: Path, out: Path, frames: list[int]) -> list[dict]:
    """Peak RSS (KiB) and the summary's counts after each replay of the first `frames[k]` frames, in
    one fresh process."""
    proc = subprocess.run([sys.executable, __file__, "--replay", str(bag), str(out),
                           *[str(n) for n in frames]], capture_output=True, text=True, timeout=1200,
                          cwd=Path(__file__).parent)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return [json.loads(line) for line in proc.stdout.strip().splitlines()[-len(frames):]]


def _replays(bag: str, out: str, frames: list[int]) -> None:
    for n in frames:
        summary = node_support.stub_replay(bag, f"{out}.{n}.mcap", max_frames=n)
        print(json.dumps({"peak_kib": peak_rss_kib(), "frames": summary.frames_published,
                          "scored": summary.ground_truth_frames, "records": len(summary.frames),
                          "output_bytes": Path(f"{out}.{n}.mcap").stat().st_size}), flush=True)


def test_peak_memory_does_not_grow_with_the_bag(tmp_path):
    bag = write_bag(tmp_path / "bag.mcap", N_LONG)
    short, long = replays_in_subprocess(bag, tmp_path / "out.mcap", [N_SHORT, N_LONG])
    assert short["frames"] == short["scored"] == N_SHORT and long["frames"] == long["scored"] == N_LONG
    print(f"peak RSS: {N_SHORT} frames {short['peak_kib'] / 1024:.1f} MiB, {N_LONG} frames "
          f"{long['peak_kib'] / 1024:.1f} MiB")
    assert long["peak_kib"] <= short["peak_kib"] * (1 + TOLERANCE), (short, long)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--replay", nargs="+", metavar="ARG", help=argparse.SUPPRESS)  # BAG OUT N...
    parser.add_argument("--frames", nargs="+", type=int, default=[N_SHORT, N_LONG])
    args = parser.parse_args()
    if args.replay:
        _replays(args.replay[0], args.replay[1], [int(n) for n in args.replay[2:]])
        return
    work = node_support.workdir()
    bag = write_bag(work / "bag.mcap", max(args.frames))
    for n, run in zip(args.frames, replays_in_subprocess(bag, work / "out.mcap", args.frames), strict=True):
        print(f"{n} frames: peak RSS {run['peak_kib'] / 1024:.1f} MiB, {run['frames']} published, "
              f"{run['scored']} scored, {run['records']} frame records kept, output {run['output_bytes']} B")


if __name__ == "__main__":
    main()
