"""`ros2 bag info|record|play` and the bag library against rosbag2's on-disk layout.

Bags recorded by the real rosbag2 (shared corpus) check what we read; bags we write are checked with
independent readers (`mcap`, `mcap-ros2-support`, `rosbags`); record and play run as separate processes
over real DDS.
"""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from bag_nodes import content_digest
from rosproc import Proc, python_proc, wait_for
from stud_bag import BagError, BagReader, BagWriter, Qos, open_bag
from stud_bag.msgdef import message_definition

NODES = str(Path(__file__).resolve().parent / "bag_nodes.py")
TEXT, DEPTH, LAYOUT = "/bag_test/text", "/bag_test/depth", "/drawing/layout"


def ros2(*args: str, timeout: float = 60, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(["ros2", *args], capture_output=True, text=True, timeout=timeout, cwd=cwd)


def field(stdout: str, name: str) -> str:
    return next(line for line in stdout.splitlines() if line.startswith(name)).split(":", 1)[1].strip()


# -- info on bags rosbag2 wrote -------------------------------------------------------------------------
def test_info_prints_what_rosbag2_prints_for_a_version_7_bag_with_unknown_types(shared_bag):
    done = ros2("bag", "info", str(shared_bag("rosbag2_cdr_test")))
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""  # metadata and MCAP agree
    lines = done.stdout.splitlines()
    assert lines[0] == ""
    assert lines[1] == "Files:             cdr_test_0.mcap"
    assert lines[3] == "Storage id:        mcap"
    assert lines[4] == "ROS Distro:        unknown"  # version 7 has no ros_distro
    assert lines[5] == "Duration:          0.151137181s"
    assert lines[6].endswith("(1586406456.763032325)") and lines[7].endswith("(1586406456.914169506)")
    assert lines[8] == "Messages:          7"
    assert lines[9] == ("Topic information: Topic: /array_topic | Type: test_msgs/msg/Arrays | Count: 4 | "
                        "Serialization Format: cdr")
    assert lines[10] == ("                   Topic: /test_topic | Type: test_msgs/msg/BasicTypes | Count: 3 | "
                         "Serialization Format: cdr")
    assert lines[11:] == ["Service:           0", "Service information: "]


def test_info_on_the_split_bag_counts_all_files_and_reports_the_wrong_metadata_times(shared_bag):
    bag = shared_bag("rosbag2_wbag_split")
    done = ros2("bag", "info", str(bag))
    assert done.returncode == 0, done.stderr
    out = done.stdout
    files = [line.strip() for line in out.split("Bag size:")[0].split("Files:")[1].splitlines()]
    assert files == [f"wbag_{i}.mcap" for i in range(5)]
    assert field(out, "Messages") == "6074"
    topics = {line.split("Topic: ")[1].split(" |")[0]: line for line in out.splitlines() if "Topic: " in line}
    assert sorted(topics) == ["AAA", "BBB", "CCC", "DDD", "EEE", "FFF", "GGG", "HHH"]
    assert all("Type: std_msgs/msg/String" in line for line in topics.values())
    assert sum(int(line.split("Count: ")[1].split(" |")[0]) for line in topics.values()) == 6074
    # metadata.yaml says start 2623 ns, duration 411 ns: the messages span 1000..2998 ns
    assert field(out, "Start").endswith("(0.000001000)") and field(out, "End").endswith("(0.000002998)")
    assert field(out, "Duration") == "0.000001998s"
    assert "metadata.yaml disagrees with the MCAP files" in done.stderr and "starting_time 2623" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


def test_info_on_one_mcap_file_and_topic_names_only(shared_bag):
    one = shared_bag("rosbag2_wbag_split") / "wbag_1.mcap"
    done = ros2("bag", "info", str(one))
    assert done.returncode == 0, done.stderr
    assert field(done.stdout, "Files") == str(one) and field(done.stdout, "Messages") == "1240"
    names = ros2("bag", "info", "-t", str(shared_bag("rosbag2_cdr_test")))
    assert names.stdout.split() == ["/array_topic", "/test_topic"]


def test_open_bag_merges_split_files_in_log_time_order_and_deserialises(shared_bag):
    with open_bag(shared_bag("rosbag2_wbag_split")) as bag:
        messages = list(bag)
        assert bag.message_count == 6074 and len(bag.relative_file_paths) == 5
    assert len(messages) == 6074
    times = [m.log_time_ns for m in messages]
    assert times == sorted(times) and (times[0], times[-1]) == (1000, 2998)
    topic, type_name, _t, data = messages[0]
    assert type_name == "std_msgs/msg/String" and isinstance(data, bytes)
    assert isinstance(messages[0].message().data, str)
    only = list(open_bag(shared_bag("rosbag2_wbag_split"), topics=["AAA"]))
    assert len(only) == 804 and {m.topic for m in only} == {"AAA"}


def test_unknown_types_are_read_as_bytes_with_their_recorded_schema(shared_bag):
    with BagReader(shared_bag("rosbag2_cdr_test")) as bag:
        messages = list(bag)
        encoding, text = bag.message_definition("test_msgs/msg/Arrays")
    assert [m.type_name for m in messages].count("test_msgs/msg/Arrays") == 4
    assert encoding == "ros2msg" and "MSG: test_msgs/BasicTypes" in text
    with pytest.raises(LookupError, match="test_msgs/msg/Arrays"):
        messages[0].message() if messages[0].type_name.endswith("Arrays") else messages[-1].message()


def test_message_definitions_are_built_as_rosbag2_builds_them(shared_bag):
    with BagReader(shared_bag("rosbag2_wbag_split")) as bag:
        assert message_definition("std_msgs/msg/String") == bag.message_definition("std_msgs/msg/String")
    encoding, text = message_definition("stud_welding_msgs/msg/StudLayout")
    delimiters = [line for line in text.splitlines() if line.startswith("MSG: ")]
    # dependencies sorted, each once, nested ones after their parent (rosbag2's depth-first order)
    assert delimiters == ["MSG: geometry_msgs/Point", "MSG: std_msgs/Header", "MSG: builtin_interfaces/Time",
                          "MSG: stud_welding_msgs/Stud"]
    assert encoding == "ros2msg" and "\n" + "=" * 80 + "\nMSG: std_msgs/Header\n" in text
    assert message_definition("no_such_msgs/msg/Thing") == ("unknown", "")


# -- the library writer ---------------------------------------------------------------------------------
def _sample_messages():
    from sensor_msgs.msg import Image
    from std_msgs.msg import String
    from stud_welding_msgs.msg import Stud, StudLayout

    layout = StudLayout(source_file="a.dxf", studs=[Stud(id="S0001", x=0.1, y=0.2, diameter=0.016)])
    layout.header.frame_id = "drawing"
    image = Image(height=48, width=64, encoding="16UC1", step=128, data=np.arange(64 * 48, dtype="<u2").tobytes())
    image.header.stamp.sec = 77
    return layout, image, String(data="hello")


@pytest.mark.parametrize("mode", ["none", "file", "message"])
def test_bag_writer_output_opens_in_mcap_and_rosbags_readers(tmp_path, mode):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    layout, image, text = _sample_messages()
    bag_dir = tmp_path / "sensor_bag"
    t0 = 1_700_000_000_000_000_000
    with BagWriter(bag_dir, compression_mode=mode) as bag:
        bag.add_topic(LAYOUT, "stud_welding_msgs/msg/StudLayout",
                      offered_qos_profiles=[Qos(durability="transient_local", depth=1)])
        bag.write(LAYOUT, layout, t0)
        for i in range(3):
            bag.write("/camera/depth/image_raw", image, t0 + (i + 1) * 100_000_000)
            bag.write("/note", text, t0 + (i + 1) * 100_000_000 + 1)

    meta = yaml.safe_load((bag_dir / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap" and meta["ros_distro"]
    assert meta["message_count"] == 7 and meta["duration"]["nanoseconds"] == 300_000_001
    assert meta["compression_mode"] == ("" if mode == "none" else mode.upper())
    name = "sensor_bag_0.mcap" + (".zstd" if mode == "file" else "")
    assert meta["relative_file_paths"] == [name] and meta["files"][0]["message_count"] == 7
    layout_meta = meta["topics_with_message_count"][0]
    assert layout_meta["topic_metadata"]["offered_qos_profiles"][0]["durability"] == "transient_local"

    if mode == "none":  # what Foxglove and rosbag2's MCAP plugin read
        with open(bag_dir / name, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            assert reader.get_header().profile == "ros2"
            assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
            assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
            assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
            assert "rosbag2" in [m.name for m in reader.iter_metadata()]
        from mcap_ros2.decoder import DecoderFactory

        with open(bag_dir / name, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            decoded = [msg for _s, _c, _m, msg in reader.iter_decoded_messages()]
        assert decoded[0].studs[0].id == "S0001" and decoded[1].header.stamp.sec == 77

    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag_dir) as reader:
        assert reader.message_count == 7
        for conn in reader.connections:
            store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        got = [(c.topic, store.deserialize_cdr(raw, c.msgtype)) for c, _t, raw in reader.messages()]
    assert got[0][1].studs[0].diameter == pytest.approx(0.016) and got[2][1].data == "hello"

    back = list(open_bag(bag_dir))
    assert [m.topic for m in back][:3] == [LAYOUT, "/camera/depth/image_raw", "/note"]
    assert back[1].message().data.tobytes() == bytes(image.data) and back[0].message().header.frame_id == "drawing"


@pytest.mark.parametrize("mode", ["none", "file"])
def test_bag_writer_splits_by_duration_and_reader_joins_the_files(tmp_path, mode):
    from rosbags.rosbag2 import Reader
    from std_msgs.msg import String

    with BagWriter(tmp_path / "split", max_bag_duration_s=0.25, compression_mode=mode) as bag:
        for i in range(20):
            bag.write("/s", String(data=str(i)), 10**18 + i * 50_000_000)
    suffix = ".zstd" if mode == "file" else ""
    assert sorted(p.name for p in (tmp_path / "split").iterdir()) == \
        ["metadata.yaml"] + [f"split_{i}.mcap{suffix}" for i in range(4)]
    with Reader(tmp_path / "split") as other:
        assert [len(raw) for _c, _t, raw in other.messages()] == [len(m.data) for m in open_bag(tmp_path / "split")]
    with BagReader(tmp_path / "split") as reader:
        assert reader.relative_file_paths == [f"split_{i}.mcap{suffix}" for i in range(4)]
        assert [m.message().data for m in reader] == [str(i) for i in range(20)] and reader.notes == []
        assert [f.message_count for f in reader.metadata.files] == [6, 6, 6, 2]


def test_split_files_whose_times_overlap_are_merged_by_log_time_not_concatenated(tmp_path):
    # Split files need not cover disjoint times (a recorder splitting by size while a late topic
    # arrives, files from two recorders joined): the reader merges them by log time.
    from std_msgs.msg import String

    t0 = 10**18
    for name, topic, times in (("a", "/a", range(0, 20, 2)), ("b", "/b", range(1, 20, 2))):
        with BagWriter(tmp_path / name) as bag:
            for k in times:
                bag.write(topic, String(data=str(k)), t0 + k * 1_000_000)
    joined = tmp_path / "joined"
    joined.mkdir()
    (tmp_path / "a" / "a_0.mcap").rename(joined / "joined_0.mcap")
    (tmp_path / "b" / "b_0.mcap").rename(joined / "joined_1.mcap")
    with BagReader(joined) as reader:
        got = [(m.topic, m.message().data, m.log_time_ns) for m in reader.messages()]
        assert [int(d) for _t, d, _n in got] == list(range(20))
        assert [n for _t, _d, n in got] == sorted(n for _t, _d, n in got)
        assert [t for t, _d, _n in got][:4] == ["/a", "/b", "/a", "/b"]
        assert [m.message().data for m in reader.messages(["/b"])] == [str(k) for k in range(1, 20, 2)]
        late = [int(m.message().data) for m in reader.messages(start_time_ns=t0 + 15_000_000)]
        assert late == [15, 16, 17, 18, 19]
        window = [int(m.message().data) for m in reader.messages(start_time_ns=t0 + 5_000_000,
                                                                 end_time_ns=t0 + 8_000_000)]
        assert window == [5, 6, 7, 8]   # both bounds inclusive


def test_a_recording_that_was_never_closed_is_read_up_to_its_last_message(tmp_path):
    from std_msgs.msg import String

    with BagWriter(tmp_path / "b", storage_preset_profile="fastwrite") as bag:
        for i in range(50):
            bag.write("/s", String(data="x" * 100), 10**18 + i)
    data = (tmp_path / "b" / "b_0.mcap").read_bytes()
    (tmp_path / "b" / "b_0.mcap").write_bytes(data[: len(data) * 2 // 3])  # killed mid-write
    (tmp_path / "b" / "metadata.yaml").unlink()
    with BagReader(tmp_path / "b") as reader:
        count = len(list(reader))
        assert 10 < count < 50 and reader.message_count == count
        assert any("no metadata.yaml" in n for n in reader.notes)
        assert any("last complete record" in n for n in reader.notes)


# -- errors ------------------------------------------------------------------------------------------
def _one_line_error(done: subprocess.CompletedProcess, code: int, *needles: str) -> None:
    assert done.returncode == code, (done.stdout, done.stderr)
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
    for needle in needles:
        assert needle in done.stderr, done.stderr


def test_missing_empty_and_corrupt_bags_are_one_line_errors_with_exit_1(tmp_path):
    _one_line_error(ros2("bag", "info", str(tmp_path / "nope")), 1, str(tmp_path / "nope"), "does not exist")
    (tmp_path / "empty").mkdir()
    _one_line_error(ros2("bag", "info", str(tmp_path / "empty")), 1, "no metadata.yaml and no .mcap files")
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "junk_0.mcap").write_bytes(b"not an mcap at all" * 100)
    _one_line_error(ros2("bag", "info", str(junk)), 1, "junk_0.mcap", "not an MCAP file")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "bad_0.mcap").write_bytes(b"\x89MCAP0\r\n" + os.urandom(5000))
    _one_line_error(ros2("bag", "play", str(bad)), 1, "bad_0.mcap", "corrupt MCAP")
    listed = tmp_path / "listed"
    listed.mkdir()
    (listed / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9}\n")
    _one_line_error(ros2("bag", "info", str(listed)), 1, "metadata.yaml", "missing field 'storage_identifier'")
    with pytest.raises(BagError, match="does not exist"):  # the library raises what the CLI prints
        open_bag(tmp_path / "nope")


def test_usage_errors_exit_2_and_refusals_exit_1(tmp_path, shared_bag):
    _one_line_error(ros2("bag"), 2, "verb")
    _one_line_error(ros2("bag", "info"), 2, "bag_path")
    _one_line_error(ros2("bag", "play", str(tmp_path), "--rate", "0"), 2, "--rate")
    _one_line_error(ros2("bag", "play", str(tmp_path), "--wait-for-subscribers", "/a=two"), 2,
                    "--wait-for-subscribers '/a=two': expected N or TOPIC=N")
    _one_line_error(ros2("bag", "record", "-o", str(tmp_path / "x")), 2, "--topics")
    _one_line_error(ros2("bag", "record", "-a", "--compression-format", "zstd", "-o", str(tmp_path / "y")), 2,
                    "compression format")
    _one_line_error(ros2("bag", "record", "-a", "-o", str(tmp_path)), 1, "already exists")
    # nothing of the bag can be published here: its types are not installed
    done = ros2("bag", "play", str(shared_bag("rosbag2_cdr_test")))
    assert done.returncode == 1 and "nothing to play" in done.stderr and "Traceback" not in done.stderr
    assert "test_msgs/msg/Arrays" in done.stderr  # each skipped type is named once


# -- record and play over DDS -----------------------------------------------------------------------
def _ros2_proc(args: list[str], log: Path) -> Proc:
    return Proc(["ros2", *args], log)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A publisher process (latched layout first, then text and 640x480 16UC1 images at 20 Hz) recorded by a
    `ros2 bag record` process until SIGINT. Returns (bag dir, what was published)."""
    tmp = tmp_path_factory.mktemp("record")
    bag_dir = tmp / "roundtrip"
    publisher = python_proc(NODES, ["publish", "--out", str(tmp / "sent.json"), "--strings", "20", "--images", "10",
                                    "--period", "0.05"], tmp / "publisher.log")
    recorder = None
    try:
        wait_for(lambda: "publisher up" in publisher.output(), 30, what="publisher")
        recorder = _ros2_proc(["bag", "record", "-o", str(bag_dir), "--topics", TEXT, DEPTH, LAYOUT],
                              tmp / "record.log")
        wait_for(lambda: "published" in publisher.output() or publisher.popen.poll() is not None, 40,
                 what="publisher done")
        assert "published 32" in publisher.output(), publisher.output() + recorder.output()
        assert recorder.stop() == 0, recorder.log_path.read_text()
    finally:
        if recorder is not None:
            recorder.stop()
        publisher.stop()
    return bag_dir, json.loads((tmp / "sent.json").read_text()), recorder.log_path.read_text()


def test_record_writes_a_rosbag2_bag_with_latched_and_image_topics(recorded):
    bag_dir, sent, log = recorded
    assert "Recording stopped: 32 messages on 3 topics" in log
    meta = yaml.safe_load((bag_dir / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["ros_distro"] == "jazzy" and meta["storage_identifier"] == "mcap"
    assert meta["relative_file_paths"] == ["roundtrip_0.mcap"] and meta["compression_mode"] == ""
    topics = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    assert {n: t["message_count"] for n, t in topics.items()} == {TEXT: 20, DEPTH: 10, LAYOUT: 2}
    assert topics[DEPTH]["topic_metadata"]["type"] == "sensor_msgs/msg/Image"
    offered = topics[LAYOUT]["topic_metadata"]["offered_qos_profiles"]
    assert [(q["reliability"], q["durability"]) for q in offered] == [("reliable", "transient_local")]
    assert topics[TEXT]["topic_metadata"]["type_description_hash"].startswith("RIHS01_")

    with open(bag_dir / "roundtrip_0.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    assert {s.name: s.encoding for s in summary.schemas.values()} == {
        "std_msgs/msg/String": "ros2msg", "sensor_msgs/msg/Image": "ros2msg",
        "stud_welding_msgs/msg/StudLayout": "ros2msg"}
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}

    from rosbags.rosbag2 import Reader

    with Reader(bag_dir) as reader:
        assert reader.message_count == 32 and reader.ros_distro == "jazzy"
        assert {c.topic: c.msgcount for c in reader.connections} == {TEXT: 20, DEPTH: 10, LAYOUT: 2}

    # content, order and receive-time stamping: the bag holds what was sent, log time = receive time
    with BagReader(bag_dir) as bag:
        messages = list(bag)
    for topic in (TEXT, DEPTH, LAYOUT):
        assert [content_digest(m.message()) for m in messages if m.topic == topic] == \
            [s["sha"] for s in sent if s["topic"] == topic]
    ticks = [m.log_time_ns / 1e9 for m in messages if m.topic == TEXT]
    sent_ticks = [s["t"] for s in sent if s["topic"] == TEXT]
    assert np.abs(np.diff(ticks) - np.diff(sent_ticks)).max() < 0.03


def _play_and_listen(bag_dir: Path, tmp: Path, *play_args: str) -> list[dict]:
    expected = 32
    listener = python_proc(NODES, ["listen", "--out", str(tmp / "received.json"), "--expect", str(expected),
                                   "--timeout", "30"], tmp / "listener.log")
    try:
        wait_for(lambda: "listening" in listener.output(), 30, what="listener")
        play = subprocess.run(["ros2", "bag", "play", str(bag_dir), "--wait-for-subscribers", "1", *play_args],
                              capture_output=True, text=True, timeout=60)
        assert play.returncode == 0, play.stderr
        assert f"Played {expected} messages on 3 topics" in play.stderr
        assert "Playing although" not in play.stderr, play.stderr  # every wanted subscriber was matched
        wait_for(lambda: "received" in listener.output(), 30, what="listener results")
    finally:
        listener.stop()
    return json.loads((tmp / "received.json").read_text())


def _assert_replayed(received: list[dict], bag_dir: Path, sent: list[dict], rate: float) -> float:
    with BagReader(bag_dir) as bag:
        messages = list(bag)
    assert len(received) == len(messages) == len(sent)
    for topic in (TEXT, DEPTH, LAYOUT):
        got = [r for r in received if r["topic"] == topic]
        # identical bytes to the recording, identical content and header stamps to what was published
        assert [r["raw_sha"] for r in got] == [hashlib.sha256(m.data).hexdigest() for m in messages if m.topic == topic]
        assert [r["sha"] for r in got] == [s["sha"] for s in sent if s["topic"] == topic]
        assert [r["stamp"] for r in got] == [s["stamp"] for s in sent if s["topic"] == topic]
    # timing: message i goes out at (log_i - log_0) / rate after the start; compare receive times with
    # that schedule, up to one common offset (start-up latency)
    schedule, arrival = [], []
    for topic in (TEXT, DEPTH, LAYOUT):
        schedule += [m.log_time_ns / 1e9 / rate for m in messages if m.topic == topic]
        arrival += [r["t"] for r in received if r["topic"] == topic]
    offsets = np.array(arrival) - np.array(schedule)
    jitter = np.abs(offsets - np.median(offsets))
    # typically a few ms; the bounds leave room for a loaded 2-core machine
    assert np.percentile(jitter, 90) < 0.03 and jitter.max() < 0.15, np.sort(jitter)[-5:]
    first_recv = min(arrival)
    return max(r["t"] for r in received) - first_recv


def test_play_republishes_the_recording_with_its_timing_and_stamps(recorded, tmp_path):
    bag_dir, sent, _ = recorded
    duration = _assert_replayed(_play_and_listen(bag_dir, tmp_path), bag_dir, sent, rate=1.0)
    with BagReader(bag_dir) as bag:
        assert duration == pytest.approx(bag.duration_ns / 1e9, abs=0.1)


def test_play_at_rate_2_takes_half_the_time(recorded, tmp_path):
    """Also: topic counts of --wait-for-subscribers beat the count for all (one listener, which a
    count of 3 for every topic alone would wait 10 s for in vain)."""
    bag_dir, sent, _ = recorded
    counts = ["--wait-for-subscribers", "3", f"{TEXT}=1", f"{DEPTH}=1", f"{LAYOUT}=1"]
    duration = _assert_replayed(_play_and_listen(bag_dir, tmp_path, "--rate", "2", *counts), bag_dir, sent, rate=2.0)
    with BagReader(bag_dir) as bag:
        assert duration == pytest.approx(bag.duration_ns / 2e9, abs=0.1)


def test_record_keeps_up_with_full_size_depth_images_at_10_hz(tmp_path):
    """1280x960 16UC1 (2.4 MB) at 10 Hz for 2 s: every frame reaches the bag, at its receive time."""
    bag_dir = tmp_path / "depth"
    publisher = python_proc(NODES, ["publish", "--out", str(tmp_path / "sent.json"), "--strings", "0",
                                    "--images", "20", "--image-every", "1", "--period", "0.1",
                                    "--image-size", "1280x960"], tmp_path / "publisher.log")
    recorder = None
    try:
        wait_for(lambda: "publisher up" in publisher.output(), 30, what="publisher")
        recorder = _ros2_proc(["bag", "record", "-o", str(bag_dir), "--topics", DEPTH, LAYOUT], tmp_path / "rec.log")
        wait_for(lambda: "published" in publisher.output() or publisher.popen.poll() is not None, 60,
                 what="publisher done")
        assert recorder.stop() == 0, recorder.log_path.read_text()
    finally:
        if recorder is not None:
            recorder.stop()
        publisher.stop()
    with BagReader(bag_dir) as bag:
        frames = [m for m in bag.messages([DEPTH])]
        size = bag.bag_size
    assert len(frames) == 20, recorder.log_path.read_text()
    assert all(len(f.data) > 1280 * 960 * 2 for f in frames)
    gaps = np.diff([f.log_time_ns for f in frames]) / 1e9
    assert gaps.mean() == pytest.approx(0.1, abs=0.01) and gaps.max() < 0.2
    raw = sum(len(f.data) for f in frames)
    print(f"recorded {len(frames)} frames of 2.4 MB at 10 Hz; "
          f"{raw / 2**20:.1f} MiB raw -> {size / 2**20:.1f} MiB on disk")


def test_play_topics_start_offset_and_loop_until_sigint(recorded, tmp_path):
    bag_dir, _sent, _ = recorded
    with BagReader(bag_dir) as bag:
        offset_s = (bag.duration_ns / 1e9) / 2
        cut = bag.start_time_ns + int(offset_s * 1e9)
        selected = [m for m in bag.messages([TEXT]) if m.log_time_ns >= cut]
    assert 3 < len(selected) < 20
    listener = python_proc(NODES, ["listen", "--out", str(tmp_path / "received.json"), "--expect",
                                   str(2 * len(selected)), "--timeout", "30"], tmp_path / "listener.log")
    player = None
    try:
        wait_for(lambda: "listening" in listener.output(), 30, what="listener")
        player = _ros2_proc(["bag", "play", str(bag_dir), "--topics", TEXT, "--start-offset", f"{offset_s:.6f}",
                             "--loop", "--wait-for-subscribers", "1"], tmp_path / "play.log")
        wait_for(lambda: "received" in listener.output(), 30, what="two loops")
        assert player.popen.poll() is None  # still looping
        assert player.stop() == 0  # SIGINT: clean exit
    finally:
        if player is not None:
            player.stop()
        listener.stop()
    received = json.loads((tmp_path / "received.json").read_text())
    assert {r["topic"] for r in received} == {TEXT}
    assert [r["raw_sha"] for r in received] == 2 * [hashlib.sha256(m.data).hexdigest() for m in selected]


@pytest.mark.parametrize("stop", ["max-duration", "SIGTERM"])
def test_record_stops_on_max_duration_or_sigterm_and_finishes_the_bag(tmp_path, stop):
    bag_dir = tmp_path / "short"
    args = ["bag", "record", "-a", "-o", str(bag_dir)] + (["--max-duration", "1"] if stop == "max-duration" else [])
    recorder = _ros2_proc(args, tmp_path / "rec.log")
    try:
        wait_for(lambda: "Recording..." in recorder.output(), 30, what="recorder")
        if stop == "SIGTERM":
            recorder.popen.terminate()
        assert recorder.popen.wait(timeout=30) == 0, recorder.output()
    finally:
        recorder.stop()
    assert "Recording stopped" in recorder.log_path.read_text()
    meta = yaml.safe_load((bag_dir / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["relative_file_paths"] == ["short_0.mcap"]
    with BagReader(bag_dir) as bag:
        assert bag.notes == []  # indexed MCAP, metadata in agreement
