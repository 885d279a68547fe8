"""The replay's memory does not grow with the bag's length: a 600-frame bag with ground truth (every
frame's true mesh, 13,718 vertices) peaks within 5 % of a 60-frame one.

Each replay runs in its own process (peak RSS, VmHWM, is per process), with the stub fitter: the fitting's
memory is the fitter's business and does not depend on the bag's length. The bags repeat two posed
frames with new stamps (`bag_fixture.repeat_frames`), without images.

As a benchmark (prints both peaks):  .venv/bin/python test/test_replay_memory.py [--frames 60 600]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import bag_fixture
import node_support

N_SHORT, N_LONG = 60, 600
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


def replay_in_subprocess(bag: Path, out: Path) -> dict:
    """Peak RSS (KiB) and the summary's counts of one replay in a fresh process."""
    proc = subprocess.run([sys.executable, __file__, "--replay", str(bag), str(out)], capture_output=True,
                          text=True, timeout=1200, cwd=Path(__file__).parent)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _replay(bag: str, out: str) -> None:
    summary = node_support.stub_replay(bag, out)
    print(json.dumps({"peak_kib": peak_rss_kib(), "frames": summary.frames_published,
                      "scored": summary.ground_truth_frames, "records": len(summary.frames),
                      "output_bytes": Path(out).stat().st_size}))


def test_peak_memory_does_not_grow_with_the_bag(tmp_path):
    runs = {}
    for n in (N_SHORT, N_LONG):
        runs[n] = replay_in_subprocess(write_bag(tmp_path / f"bag{n}.mcap", n), tmp_path / f"out{n}.mcap")
        assert runs[n]["frames"] == runs[n]["scored"] == n, runs[n]
    short, long = runs[N_SHORT]["peak_kib"], runs[N_LONG]["peak_kib"]
    print(f"peak RSS: {N_SHORT} frames {short / 1024:.1f} MiB, {N_LONG} frames {long / 1024:.1f} MiB")
    assert long <= short * (1 + TOLERANCE), runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--replay", nargs=2, metavar=("BAG", "OUT"), help=argparse.SUPPRESS)
    parser.add_argument("--frames", nargs="+", type=int, default=[N_SHORT, N_LONG])
    args = parser.parse_args()
    if args.replay:
        _replay(*args.replay)
        return
    work = node_support.workdir()
    for n in args.frames:
        run = replay_in_subprocess(write_bag(work / f"bag{n}.mcap", n), work / f"out{n}.mcap")
        print(f"{n} frames: peak RSS {run['peak_kib'] / 1024:.1f} MiB, {run['frames']} published, "
              f"{run['scored']} scored, {run['records']} frame records kept, output {run['output_bytes']} B")


if __name__ == "__main__":
    main()
