"""Corrupted, cut and hostile bags, outputs that must not be written, parameters that cannot be read: the
replay goes on and counts each fault under its own name; the command line says what is wrong in one line,
with a non-zero exit code, and never shows a traceback (unless asked with --debug); nothing a user had is
deleted, and nothing incomplete looks complete.

Bag defects are replayed with the stub fitter (this is about the reading, not the fitting); the command
line cases that need a fit run the real one on one frame.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import struct
import subprocess
import sys
from collections import Counter
from collections.abc import Callable
from functools import cache
from pathlib import Path

import bag_fixture
import node_support
import numpy as np
import pytest

from smplify3d_ros import cli

N_FRAMES = 6
# the names faults are counted under (ReplaySummary.read_drops, /diagnostics drop.message.<name>)
UNDECODABLE = "undecodable"
BAD_TRUTH = "bad_ground_truth"
BAD_CHUNK = "bad_chunk"
CHUNK_CRC = "chunk_crc_mismatch"
STORAGE_CORRUPT = "storage_corrupt"
TRUNCATED = "truncated"

SYNC_TOPICS = ("/camera/color/image_raw", "/camera/color/camera_info", "/velodyne_points", "/keypoints")


# -- bags ---------------------------------------------------------------------------------------------------
@cache
def base_bag() -> bag_fixture.FixtureBag:
    """6 frames, one person: a bare .mcap with zstd chunks and their CRCs."""
    T = node_support.node_config().extrinsic.T_cam_lidar()
    model = node_support.fitter().model
    frames = bag_fixture.repeat_frames(bag_fixture.make_frames(model, T, 2, 1, seed=7), N_FRAMES)
    path = node_support.workdir() / "robust_base.mcap"
    return bag_fixture.write_fixture_bag(path, model, T, "mcap-crc", frames=frames)


def base_mcap() -> Path:
    return base_bag().path


def recorded(path: Path) -> list[tuple[str, str, int, bytes]]:
    """(topic, type, log time, raw) of every message, as rosbags reads them."""
    from rosbags.rosbag2 import Reader

    with Reader(path) as reader:
        return [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages()]


def write_messages(path: Path, messages: list[tuple[str, str, int, bytes]], storage: str = "mcap") -> Path:
    """A bag with these raw messages: a bare .mcap (zstd, CRCs) or a sqlite3 bag directory (rosbags)."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    if storage == "mcap":
        return bag_fixture.write_mcap(path, store, messages)
    from rosbags.rosbag2 import Writer

    with Writer(path, version=9) as writer:
        conns: dict[str, object] = {}
        for topic, msgtype, t, raw in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[topic], t, raw)
    return path


def edited(path: Path, edit: Callable[[list], list]) -> Path:
    return write_messages(path, edit(recorded(base_bag().path)))


def _nth(messages: list, topic: str, n: int) -> int:
    return [i for i, m in enumerate(messages) if m[0] == topic][n]


def foreign_cdr(path: Path) -> Path:
    """A PointCloud2 connection carrying a String's CDR bytes."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    other = bytes(store.serialize_cdr(store.types["std_msgs/msg/String"](data="not a cloud"), "std_msgs/msg/String"))

    def edit(messages):
        i = _nth(messages, "/velodyne_points", 2)
        messages[i] = (*messages[i][:3], other)
        return messages
    return edited(path, edit)


def half_image(path: Path) -> Path:
    def edit(messages):
        i = _nth(messages, "/camera/color/image_raw", 2)
        messages[i] = (*messages[i][:3], messages[i][3][: len(messages[i][3]) // 2])
        return messages
    return edited(path, edit)


def bad_truth(path: Path) -> Path:
    """Ground-truth documents: not JSON, nested 100,000 deep, bytes that are no String."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)

    def doc(text: str) -> bytes:
        return bytes(store.serialize_cdr(store.types["std_msgs/msg/String"](data=text), "std_msgs/msg/String"))

    def edit(messages):
        for n, raw in ((1, doc("{not json")), (2, doc("[" * 100_000)), (3, b"\x00\x01\x00\x00\xff\xff")):
            i = _nth(messages, "/ground_truth/bodies", n)
            messages[i] = (*messages[i][:3], raw)
        return messages
    return edited(path, edit)


def duplicated_frame(path: Path) -> Path:
    """Frame 2's synchronized messages recorded a second time, 5 ms after the first."""
    def edit(messages):
        stamp = bag_fixture.T0 + 2 * bag_fixture.PERIOD
        copies = [(topic, msgtype, t + 5_000_000, raw) for topic, msgtype, t, raw in messages
                  if topic in SYNC_TOPICS and 0 <= t * 1e-9 - stamp < 0.07]
        return sorted(messages + copies, key=lambda m: m[2])
    return edited(path, edit)


def _chunk_offsets(path: Path) -> list[tuple[int, object]]:
    """(chunk record offset, ChunkIndex) of an MCAP file, by offset."""
    from mcap.reader import make_reader

    with open(path, "rb") as handle:
        summary = make_reader(handle).get_summary()
    return sorted((c.chunk_start_offset, c) for c in summary.chunk_indexes)


def _chunk_data_offset(path: Path, offset: int) -> int:
    """Where a chunk record's (compressed) data starts."""
    data = path.read_bytes()
    compression_len = struct.unpack_from("<I", data, offset + 9 + 28)[0]
    return offset + 9 + 28 + 4 + compression_len + 8


def zstd_header(path: Path) -> Path:
    """8 bytes overwritten at the zstd frame header of the third chunk."""
    data = bytearray(base_mcap().read_bytes())
    start = _chunk_data_offset(base_mcap(), _chunk_offsets(base_mcap())[2][0])
    assert data[start:start + 4] == b"\x28\xb5\x2f\xfd", "a zstd frame starts here"
    data[start:start + 8] = b"\xff" * 8
    path.write_bytes(bytes(data))
    return path


def uncompressed_with_crc(path: Path) -> Path:
    """The base bag re-chunked uncompressed (CRCs on), as a recorder without compression writes it."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(base_mcap(), "rb") as src, open(path, "wb") as dst:
        reader = make_reader(src)
        summary = reader.get_summary()
        writer = Writer(dst, compression=CompressionType.NONE, enable_crcs=True)
        writer.start(profile="ros2", library="test")
        schemas = {s.id: writer.register_schema(s.name, s.encoding, s.data) for s in summary.schemas.values()}
        channels = {c.id: writer.register_channel(c.topic, c.message_encoding, schemas[c.schema_id], c.metadata)
                    for c in summary.channels.values()}
        for _, channel, message in reader.iter_messages():
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)
        writer.finish()
    return path


def chunk_crc(path: Path) -> Path:
    """8 bytes changed in the middle of an uncompressed chunk: it still parses, its CRC says it is wrong
    (without a CRC its garbage would be used without a word)."""
    uncompressed_with_crc(path)
    data = bytearray(path.read_bytes())
    offset, index = _chunk_offsets(path)[3]
    middle = _chunk_data_offset(path, offset) + index.uncompressed_size // 2
    data[middle:middle + 8] = bytes(b ^ 0x5A for b in data[middle:middle + 8])
    path.write_bytes(bytes(data))
    return path


def huge_chunk(path: Path) -> Path:
    """A chunk declaring 1 TiB uncompressed: refused without allocating it."""
    data = bytearray(base_mcap().read_bytes())
    offset = _chunk_offsets(base_mcap())[2][0]
    struct.pack_into("<Q", data, offset + 9 + 16, 1 << 40)
    path.write_bytes(bytes(data))
    return path


def corrupt_sqlite(path: Path) -> Path:
    """A sqlite3 bag whose page (an overflow page of a message) at half the file is overwritten."""
    write_messages(path, recorded(base_bag().path), "sqlite3")
    db3 = next(path.glob("*.db3"))
    data = bytearray(db3.read_bytes())
    page = len(data) // 2 // 4096 * 4096
    data[page:page + 8] = b"\xff" * 8
    db3.write_bytes(bytes(data))
    return path


# defect -> (bag maker, read fault it is counted as, frames the replay still synchronizes)
DEFECTS: dict[str, tuple[Callable[[Path], Path], str, int]] = {
    "foreign_cdr_cloud": (foreign_cdr, UNDECODABLE, N_FRAMES - 1),
    "half_image": (half_image, UNDECODABLE, N_FRAMES - 1),
    "bad_ground_truth": (bad_truth, BAD_TRUTH, N_FRAMES),
    "zstd_frame_header": (zstd_header, BAD_CHUNK, -1),
    "chunk_crc": (chunk_crc, CHUNK_CRC, -1),
    "huge_chunk": (huge_chunk, BAD_CHUNK, -1),
    "sqlite3_corrupt_page": (corrupt_sqlite, STORAGE_CORRUPT, -1),
}
SUFFIX = {"sqlite3_corrupt_page": ""}


def stream_counts(path: Path) -> Counter:
    """Messages per topic that the `mcap` package's own stream reader recovers before it stops."""
    from mcap.stream_reader import StreamReader

    counts: Counter = Counter()
    channels = {}
    try:
        for record in StreamReader(open(path, "rb")).records:  # noqa: SIM115 - read to the error
            if type(record).__name__ == "Channel":
                channels[record.id] = record.topic
            elif type(record).__name__ == "Message":
                counts[channels[record.channel_id]] += 1
    except Exception:  # noqa: BLE001 - the cut
        pass
    return counts


def assert_output_bag_ok(path: Path) -> dict[str, str]:
    """The output opens with rosbags and with mcap (CRCs checked); its last /diagnostics values."""
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    with open(path, "rb") as handle:
        assert sum(1 for _ in make_reader(handle, validate_crcs=True).iter_messages()) > 0
    store = get_typestore(Stores.ROS2_JAZZY)
    diagnostics = [m for m in recorded(path) if m[0] == "/diagnostics"]
    assert diagnostics, "diagnostics written"
    last = store.deserialize_cdr(diagnostics[-1][3], diagnostics[-1][1])
    return {kv.key: kv.value for kv in last.status[0].values}


# -- the replay: every fault counted and skipped --------------------------------------------------------
@pytest.mark.parametrize("defect", sorted(DEFECTS))
def test_a_bad_message_or_chunk_is_a_counted_drop(defect, tmp_path, capfd):
    make, reason, frames = DEFECTS[defect]
    bag = make(tmp_path / f"{defect}{SUFFIX.get(defect, '.mcap')}")
    out = tmp_path / "out.mcap"
    summary = node_support.stub_replay(bag, out)
    assert summary.read_drops.get(reason, 0) >= 1, (summary.read_drops, summary.read_problems)
    assert reason in summary.text()
    if frames >= 0:
        assert summary.frames_synced == frames
    else:  # what a skipped chunk or row held is lost (a frame or two), nothing more
        assert N_FRAMES - 2 <= summary.frames_synced <= N_FRAMES, summary.text()
    assert summary.frames_published == summary.frames_synced >= N_FRAMES - 2
    values = assert_output_bag_ok(out)
    assert int(values[f"drop.message.{reason}"]) >= 1
    assert "Traceback" not in "".join(capfd.readouterr())


def test_sqlite3_corruption_names_the_message_index(tmp_path):
    summary = node_support.stub_replay(corrupt_sqlite(tmp_path / "bag"))
    assert any("message index" in line for line in summary.read_problems), summary.read_problems
    assert summary.messages_read == summary.messages_in_bag - summary.read_drops[STORAGE_CORRUPT]


@pytest.mark.parametrize("fraction", [0.3, 0.6, 0.95])
def test_a_cut_mcap_is_replayed_up_to_the_cut(fraction, tmp_path):
    data = base_mcap().read_bytes()
    bag = tmp_path / "cut.mcap"
    bag.write_bytes(data[: int(len(data) * fraction)])
    counts = stream_counts(bag)
    summary = node_support.stub_replay(bag)
    assert summary.frames_synced == min(counts[t] for t in SYNC_TOPICS), (counts, summary.text())
    assert summary.read_drops[TRUNCATED] == 1
    assert summary.messages_read == sum(counts.values()) > 0
    assert summary.truncated and f"{summary.messages_read} messages recovered" in summary.truncated
    assert "truncated" in summary.text()


@pytest.mark.parametrize(("fraction", "frames"), [(0.3, 7), (0.6, 14), (0.95, 23)])
def test_the_bundled_walk_bag_cut_while_recording(fraction, frames, tmp_path):
    """bags/walk cut at 30, 60, 95 % of its bytes: as many frames as the mcap stream reader recovers."""
    walk = node_support.REPO / "bags" / "walk" / "walk.mcap"
    if not walk.exists():
        pytest.skip("bags/ not generated (smplify3d make-bags)")
    data = walk.read_bytes()
    bag = tmp_path / "walk_cut.mcap"
    bag.write_bytes(data[: int(len(data) * fraction)])
    assert min(stream_counts(bag)[t] for t in SYNC_TOPICS) == frames
    summary = node_support.stub_replay(bag)
    assert summary.frames_synced == summary.frames_published == frames
    assert summary.read_drops == {TRUNCATED: 1}


def test_a_duplicated_frame_is_in_the_summary(tmp_path):
    summary = node_support.stub_replay(duplicated_frame(tmp_path / "dup.mcap"))
    assert summary.frames_synced == N_FRAMES
    assert summary.sync["sync.dropped_duplicate"] == len(SYNC_TOPICS)
    assert f"duplicate {len(SYNC_TOPICS)}" in summary.text()


def test_bad_init_bodies_documents_are_counted(tmp_path):
    """A document with an unreadable stamp goes to the parser, which counts it; bytes that are no String
    are an undecodable message."""
    from rosbags.typesys import Stores, get_typestore

    from smplify3d_ros.runtime.config import load_node_config

    store = get_typestore(Stores.ROS2_JAZZY)

    def doc(text: str) -> bytes:
        return bytes(store.serialize_cdr(store.types["std_msgs/msg/String"](data=text), "std_msgs/msg/String"))

    def edit(messages):
        t = messages[-1][2]
        body = {"schema": "smplify3d_ros/bodies", "version": 1, "stamp": "garbage", "frame_id": "", "bodies": []}
        return messages + [("/hmr/bodies", "std_msgs/msg/String", t + 1, doc(json.dumps(body))),
                           ("/hmr/bodies", "std_msgs/msg/String", t + 2, b"\x00\x01\x00\x00\xff\xff\xff\x7f")]

    node = load_node_config(overrides={"node": {"topics": {"init_bodies": "/hmr/bodies"}}})
    summary = node_support.stub_replay(edited(tmp_path / "init.mcap", edit), node_config=node)
    assert summary.init_bodies_dropped == {"bad_document": 1}
    assert summary.read_drops == {UNDECODABLE: 1}
    assert "bad_document 1" in summary.text()


def test_output_is_compressed_with_chunk_crcs(tmp_path):
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    out = tmp_path / "out.mcap"
    node_support.stub_replay(base_bag().path, out)
    chunks = [r for r in StreamReader(open(out, "rb"), emit_chunks=True).records  # noqa: SIM115
              if isinstance(r, Chunk)]
    assert chunks and all(c.compression == "zstd" and c.uncompressed_crc != 0 for c in chunks)
    raw = sum(len(m[3]) for m in recorded(out))
    assert out.stat().st_size < raw / 2, "zstd chunks"
    umask = os.umask(0o022)
    os.umask(umask)
    assert out.stat().st_mode & 0o777 == 0o666 & ~umask, "the usual permissions, not a temporary file's 0600"


# -- outputs: nothing of the user's is deleted --------------------------------------------------------------
def digest(path: Path) -> str:
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    return hashlib.sha256(b"".join(p.name.encode() + p.read_bytes() for p in files)).hexdigest()


def leftovers(folder: Path) -> list[str]:
    return sorted(str(p) for p in folder.rglob("*") if ".partial-" in p.name or ".replaced-" in p.name)


def run_cli(argv: list[str], capfd) -> tuple[int, str, str]:
    code = cli.main(argv)
    out, err = capfd.readouterr()
    return code, out, err


def assert_one_line_error(code: int, out: str, err: str, expected: str, exit_code: int = 2) -> None:
    assert code == exit_code, (code, out, err)
    assert "Traceback" not in out + err
    lines = [line for line in err.splitlines() if line.startswith("smplify3d ")]
    assert len(lines) == 1 and expected in lines[0], err


@pytest.fixture()
def user_bag(tmp_path) -> Path:
    """The base bag's messages as a sqlite3 bag directory in the test's own folder (to check it is left
    untouched)."""
    return write_messages(tmp_path / "recording", recorded(base_bag().path), "sqlite3")


OUTPUT_CASES: dict[str, tuple[Callable[[Path, Path], tuple[list[str], Path]], str]] = {
    # case -> (argv after `-o`, path that must be left as it was), expected text
    "the input directory": (lambda bag, tmp: ([str(bag)], bag), "the input"),
    "the input .db3": (lambda bag, tmp: ([str(next(bag.glob("*.db3")))], bag), "the input"),
    "inside the input": (lambda bag, tmp: ([str(bag / "fits.mcap")], bag), "the input"),
    "holding the input": (lambda bag, tmp: ([str(tmp), "--overwrite"], bag), "holds the input"),
    "a folder of results": (lambda bag, tmp: ([str(_results(tmp))], tmp / "results"), "not empty"),
    "a folder of results, --overwrite": (lambda bag, tmp: ([str(_results(tmp)), "--overwrite"], tmp / "results"),
                                         "other than a bag's"),
    "an existing file": (lambda bag, tmp: ([str(_file(tmp, "fits.mcap"))], tmp / "fits.mcap"), "exists"),
    "under a regular file": (lambda bag, tmp: ([str(_file(tmp, "notes.txt") / "fits.mcap")], tmp / "notes.txt"),
                             "cannot write"),
    "an unwritable place": (lambda bag, tmp: (["/proc/fits.mcap"], bag), "cannot write"),
    "a directory named .mcap": (lambda bag, tmp: ([str(_results(tmp, "old.mcap"))], tmp / "old.mcap"),
                                "is a directory"),
    "the picture's name": (lambda bag, tmp: ([str(tmp / "fit.png"), "--png", str(tmp / "fit.png")], bag),
                           "different names"),
}


def _results(tmp: Path, name: str = "results") -> Path:
    folder = tmp / name
    folder.mkdir(exist_ok=True)
    (folder / "thesis.tex").write_text("months of work")
    return folder


def _file(tmp: Path, name: str) -> Path:
    (tmp / name).write_bytes(b"a file of the user's")
    return tmp / name


@pytest.mark.parametrize("case", sorted(OUTPUT_CASES))
def test_refused_outputs_leave_everything_as_it_was(case, user_bag, tmp_path, capfd, stub_fitted_cli):
    make, expected = OUTPUT_CASES[case]
    argv, kept = make(user_bag, tmp_path)
    before_bag, before_kept = digest(user_bag), digest(kept)
    code, out, err = run_cli(["replay", str(user_bag), "-o", *argv, "--no-progress"], capfd)
    assert_one_line_error(code, out, err, expected)
    assert digest(user_bag) == before_bag and digest(kept) == before_kept
    assert leftovers(tmp_path) == []


def test_overwrite_replaces_a_file_only_when_the_run_succeeded(user_bag, tmp_path):
    from smplify3d_ros.replay.output import OutputError

    target = _file(tmp_path, "fits.mcap")
    with pytest.raises(OutputError, match="exists"):
        node_support.stub_replay(user_bag, target)

    class Interrupted(node_support.StubFitter):
        def fit(self, people, K, origin, options=None):
            if len(self.calls) == 2:
                raise KeyboardInterrupt
            return super().fit(people, K, origin, options)

    with pytest.raises(KeyboardInterrupt):
        node_support.stub_replay(user_bag, target, overwrite=True, fitter=Interrupted())
    assert target.read_bytes() == b"a file of the user's", "an interrupted run replaces nothing"
    assert leftovers(tmp_path) == []
    summary = node_support.stub_replay(user_bag, target, overwrite=True)
    assert summary.output == str(target) and assert_output_bag_ok(target)
    # a bag directory written by the replay may be replaced too
    node_support.stub_replay(user_bag, tmp_path / "fits_dir")
    node_support.stub_replay(user_bag, tmp_path / "fits_dir", overwrite=True)
    assert sorted(p.name for p in (tmp_path / "fits_dir").iterdir()) == ["fits_dir.mcap", "metadata.yaml"]
    assert leftovers(tmp_path) == [] and recorded(user_bag) == recorded(base_bag().path)


@pytest.fixture()
def stub_fitted_cli(monkeypatch):
    """`smplify3d replay` with the stub fitter (for command line cases that are not about fitting)."""
    import functools
    import importlib

    replay_run = importlib.import_module("smplify3d_ros.replay.run")
    monkeypatch.setattr(replay_run, "replay_bag", functools.partial(
        replay_run.replay_bag, fitter=node_support.StubFitter(), config=node_support.config(),
        node_config=node_support.node_config()))


def test_a_failing_writer_leaves_no_output(user_bag, tmp_path, monkeypatch, capfd, stub_fitted_cli):
    """Disk full half-way: one line, exit 2, no file that looks complete."""
    from smplify3d_ros.replay import writer as replay_writer

    calls = {"n": 0}
    original = replay_writer.BagWriter.write_raw

    def full(self, conn, timestamp, raw):
        calls["n"] += 1
        if calls["n"] == 8:
            raise OSError(28, "No space left on device")
        original(self, conn, timestamp, raw)

    monkeypatch.setattr(replay_writer.BagWriter, "write_raw", full)
    target = tmp_path / "fits.mcap"
    code, out, err = run_cli(["replay", str(user_bag), "-o", str(target), "--no-progress", "--max-frames", "3"],
                             capfd)
    assert_one_line_error(code, out, err, "No space left on device")
    assert not target.exists() and leftovers(tmp_path) == []


# -- the command line: one line per error, everywhere -----------------------------------------------------
BAD_YAML = {
    "parse error": "fitting: {body: [unclosed\n",
    "tab indentation": "fitting:\n\tbody:\n\t\tmodel: anny\n",
    "python tag": "fitting: !!python/object/apply:os.system ['touch {marker}']\n",
}


def _commands(tmp: Path) -> dict[str, list[str]]:
    bag = str(base_bag().path)
    return {
        "setup": ["setup"],
        "replay": ["replay", bag, "--no-progress"],
        "make-bags": ["make-bags", "--out", str(tmp / "bags"), "--only", "walk", "--no-progress"],
        "bench": ["bench", "--scenes", "1", "--no-plot", "--no-progress"],
        "bench-speed": ["bench-speed", "--repeats", "1"],
        "bench-extract": ["bench-extract"],
    }


@pytest.mark.parametrize("kind", sorted(BAD_YAML))
@pytest.mark.parametrize("command", ["setup", "replay", "make-bags", "bench", "bench-speed", "bench-extract"])
def test_malformed_params_are_one_line_on_every_command(command, kind, tmp_path, capfd):
    marker = tmp_path / "ran"
    params = tmp_path / "mine.yaml"
    params.write_text(BAD_YAML[kind].replace("{marker}", str(marker)))
    code, out, err = run_cli([*_commands(tmp_path)[command], "--params", str(params)], capfd)
    assert_one_line_error(code, out, err, str(params))
    assert not marker.exists()


def _smpl_params(tmp: Path, model_file: Path) -> Path:
    params = tmp / "smpl.yaml"
    params.write_text(f"fitting:\n  body:\n    model: smpl\n    smpl_model_path: {json.dumps(str(model_file))}\n")
    return params


SMPL_FILES: dict[str, Callable[[Path, Path], Path]] = {
    "missing": lambda tmp, marker: tmp / "SMPL_NEUTRAL.pkl",
    "truncated": lambda tmp, marker: _write(tmp / "SMPL_NEUTRAL.pkl", _pickled_model()[:100]),
    "hostile": lambda tmp, marker: _write(tmp / "SMPL_NEUTRAL.pkl",
                                          f"cos\nsystem\n(S{str(f'touch {marker}')!r}\ntR.".encode()),
}


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _pickled_model() -> bytes:
    import pickle

    buf = io.BytesIO()
    pickle.dump({"v_template": np.zeros((10, 3)), "f": np.zeros((2, 3), np.int64)}, buf, protocol=2)
    return buf.getvalue()


@pytest.mark.parametrize("kind", sorted(SMPL_FILES))
@pytest.mark.parametrize("command", ["setup", "replay"])
def test_an_unusable_smpl_file_is_one_line(command, kind, tmp_path, capfd):
    marker = tmp_path / "ran"
    model_file = SMPL_FILES[kind](tmp_path, marker)
    argv = {"setup": ["setup"], "replay": ["replay", str(base_bag().path), "-o", str(tmp_path / "o.mcap"),
                                           "--no-progress"]}[command]
    code, out, err = run_cli([*argv, "--params", str(_smpl_params(tmp_path, model_file))], capfd)
    assert_one_line_error(code, out, err, str(model_file))
    assert not marker.exists() and leftovers(tmp_path) == []


def test_an_unexpected_error_is_one_line_and_debug_shows_it(monkeypatch, capfd):
    import importlib

    replay_run = importlib.import_module("smplify3d_ros.replay.run")

    def broken(*args, **kwargs):
        raise RuntimeError("a bug\nwith a second line")

    monkeypatch.setattr(replay_run, "replay_bag", broken)
    argv = ["replay", str(base_bag().path), "--no-progress"]
    code, out, err = run_cli(argv, capfd)
    assert_one_line_error(code, out, err, "internal error: RuntimeError: a bug", exit_code=3)
    assert "--debug" in err
    code, out, err = run_cli(["--debug", *argv], capfd)
    assert code == 3 and "Traceback" in err and "a bug" in err


def test_the_installed_command_on_a_cut_bag(tmp_path):
    """End to end, the real fitter, a bag cut after its first frames: a summary that says so, no traceback."""
    data = base_mcap().read_bytes()
    bag = tmp_path / "cut.mcap"
    bag.write_bytes(data[: int(len(data) * 0.3)])
    frames = min(stream_counts(bag)[t] for t in SYNC_TOPICS)
    out = tmp_path / "fits.mcap"
    proc = subprocess.run([sys.executable, "-m", "smplify3d_ros.cli", "replay", str(bag), "-o", str(out),
                           "--no-progress"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stdout + proc.stderr
    assert "truncated bag" in proc.stdout and f"{frames} synchronized frames, {frames} published" in proc.stdout
    assert_output_bag_ok(out)
    refused = subprocess.run([sys.executable, "-m", "smplify3d_ros.cli", "replay", str(bag), "-o", str(bag)],
                             capture_output=True, text=True, timeout=600)
    assert refused.returncode == 2 and "Traceback" not in refused.stdout + refused.stderr
    assert refused.stderr.strip().splitlines()[-1].startswith("smplify3d replay: ")
    assert bag.read_bytes() == data[: int(len(data) * 0.3)]


def test_sigterm_removes_the_partial_output(tmp_path):
    """A replay stopped by SIGTERM (systemd, docker stop) exits 130 and leaves no partial file."""
    import signal
    import time

    out = tmp_path / "fits.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "smplify3d_ros.cli", "replay", str(base_bag().path), "-o",
                             str(out), "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not leftovers(tmp_path) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert leftovers(tmp_path), "the partial output appears while the replay runs"
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stdout + stderr and "interrupted" in stderr
    assert leftovers(tmp_path) == [] and not out.exists()


@pytest.mark.parametrize("argv, expected", [
    (["bench", "--scenes", "0"], "--scenes: must be >= 1"),
    (["bench", "--sequences", "--frames", "0"], "--frames: must be >= 1"),
    (["replay", "in.mcap", "--max-frames", "-1"], "--max-frames: must be >= 1"),
    (["bench-live", "in.mcap", "--speed", "0"], "--speed: must be > 0"),
    (["bench-live", "in.mcap", "--settle", "nan"], "--settle: must be >= 0"),
    (["bench-speed", "--batches", "1", "0"], "--batches: must be >= 1"),
    (["bench-extract", "--scenes", "x"], "--scenes: expected an integer"),
    (["tune", "--trials", "0"], "--trials: must be >= 1"),
    (["bench", "--seed", "-5"], "--seed: must be >= 0"),
    (["bench", "--distance=-1,5"], "--distance: distances must be > 0 m"),
])
def test_counts_out_of_range_are_a_usage_line_before_anything_runs(argv, expected, capfd):
    """Zero scenes, frames, repeats or trials, a negative frame limit or a playback speed of 0 stopped deep
    in a run with an internal error (an empty range indexed, a division by zero in the player process)."""
    with pytest.raises(SystemExit) as stop:
        cli.main(argv)
    out, err = capfd.readouterr()
    assert stop.value.code == 2 and "Traceback" not in out + err
    assert expected in err.strip().splitlines()[-1], err
