"""``ros2 bag info|record|play`` on rosbag2's on-disk layout (metadata.yaml + MCAP); the bag library
is the ``stud_bag`` package (src/stud_bag).

Command line: rosbag2's verbs and flag names (``ros2 bag info BAG``, ``ros2 bag record -o DIR --topics
...|-a``, ``ros2 bag play BAG --rate R --loop --topics ... --start-offset S --clock [HZ]``), with
``record --max-duration S`` and ``play --wait-for-subscribers N`` added. Errors are one line on stderr:
exit code 1 for a bag that is missing, unreadable or cannot be written, 2 for a bad command line.
"""
from __future__ import annotations

import argparse
import datetime
import os
import sys
import time

from stud_bag import BagError, BagReader, BagWriter
from stud_bag.core import PRESET_PROFILES

__all__ = ["format_info", "main", "run"]


class _UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:
        raise _UsageError(f"{self.prog}: error: {message}")


# -- info -----------------------------------------------------------------------------------------
def _format_duration(ns: int) -> dict[str, str]:
    """rosbag2_py format_duration: local date/time and seconds with nanoseconds."""
    seconds, frac = divmod(ns, 1_000_000_000)
    tm = time.localtime(seconds)
    return {"date": time.strftime("%b %e %Y", tm), "time": time.strftime("%H:%M:%S", tm) + f".{frac:09d}",
            "time_in_sec": f"{seconds}.{frac:09d}"}


def _format_time_point(ns: int) -> str:
    d = _format_duration(ns)
    return f"{d['date']} {d['time']} ({d['time_in_sec']})"


def _format_file_size(size_bytes: int) -> str:
    size, units, index = float(size_bytes), ["B", "KiB", "MiB", "GiB", "TiB"], 0
    while size >= 1024 and index < 4:
        size /= 1024
        index += 1
    return f"{size:.{0 if index == 0 else 1}f} {units[index]}"


def _is_service_event(name: str, type_name: str) -> bool:
    return "/srv/" in type_name and type_name.endswith("_Event") and name.endswith("/_service_event")


def format_info(reader: BagReader) -> str:
    """The text ``ros2 bag info`` (rosbag2 Jazzy, ``format_bag_meta_data``) prints for the bag."""
    indent = " " * 19
    topics = [t for t in reader.topics.values() if not _is_service_event(t.name, t.type)]
    services = [t for t in reader.topics.values() if _is_service_event(t.name, t.type)]
    lines = ["", "Files:             " + ("\n" + indent).join(reader.relative_file_paths),
             f"Bag size:          {_format_file_size(reader.bag_size)}",
             f"Storage id:        {reader.storage_identifier}",
             f"ROS Distro:        {reader.ros_distro or 'unknown'}",
             f"Duration:          {_format_duration(reader.duration_ns)['time_in_sec']}s",
             f"Start:             {_format_time_point(reader.start_time_ns)}",
             f"End:               {_format_time_point(reader.end_time_ns)}",
             f"Messages:          {reader.message_count - sum(s.message_count for s in services)}"]
    topic_lines = [f"Topic: {t.name} | Type: {t.type} | Count: {t.message_count} | "
                   f"Serialization Format: {t.serialization_format}" for t in topics]
    lines.append("Topic information: " + ("\n" + indent).join(topic_lines))
    lines.append(f"Service:           {len(services)}")
    service_lines = [
        f"Service: {s.name[: -len('/_service_event')]} | Type: {s.type[: -len('_Event')]} | "
        f"Event Count: {s.message_count} | Serialization Format: {s.serialization_format}" for s in services]
    lines.append("Service information: " + ("\n" + indent + "  ").join(service_lines))
    return "\n".join(lines)


def cmd_info(argv: list[str]) -> int:
    parser = _Parser(prog="ros2 bag info", description="Print information about a bag to the screen.")
    parser.add_argument("bag_path", help="bag directory or .mcap file")
    parser.add_argument("-s", "--storage", default="", choices=["", "mcap"], help="storage (only mcap)")
    parser.add_argument("-t", "--topic-name", action="store_true", help="only display topic names")
    parser.add_argument("-v", "--verbose", action="store_true", help="accepted for compatibility")
    args = parser.parse_args(argv)
    with BagReader(args.bag_path) as reader:
        for note in reader.notes:
            print(f"[WARN] [ros2bag]: {note}", file=sys.stderr)
        if args.topic_name:
            for topic in reader.topics.values():
                if not _is_service_event(topic.name, topic.type):
                    print(topic.name)
        else:
            print(format_info(reader))
    return 0


# -- record -----------------------------------------------------------------------------------------
def _non_negative_float(text: str) -> float:
    value = float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text} is negative")
    return value


def _positive_float(text: str) -> float:
    value = float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text} is not positive")
    return value


def cmd_record(argv: list[str]) -> int:
    from ros2_lite.bag_record import Recorder, RecordOptions

    parser = _Parser(prog="ros2 bag record", description="Record ROS data to a bag.")
    parser.add_argument("-o", "--output", help="bag directory to create (default: rosbag2_<date>-<time>)")
    parser.add_argument("-s", "--storage", default="mcap", choices=["mcap"], help="storage (only mcap)")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("topics_positional", nargs="*", default=[], metavar="[Topic ...]",
                       help="topics to record (deprecated, use --topics)")
    group.add_argument("--topics", nargs="+", default=[], metavar="Topic", help="topics to record")
    parser.add_argument("-a", "--all", action="store_true", help="record all topics (not hidden ones)")
    parser.add_argument("--all-topics", action="store_true", help="record all topics (not hidden ones)")
    parser.add_argument("-e", "--regex", default="", help="record topics matching this regular expression")
    parser.add_argument("--exclude-regex", default="", help="do not record topics matching this expression")
    parser.add_argument("--exclude-topics", nargs="+", default=[], metavar="Topic", help="topics not to record")
    parser.add_argument("--include-hidden-topics", action="store_true")
    parser.add_argument("--include-unpublished-topics", action="store_true")
    parser.add_argument("--no-discovery", action="store_true", help="only topics present at start-up")
    parser.add_argument("-p", "--polling-interval", type=int, default=100, help="topic discovery period, ms")
    parser.add_argument("-b", "--max-bag-size", type=int, default=0, help="split files at this size, bytes")
    parser.add_argument("-d", "--max-bag-duration", type=int, default=0, help="split files after this many s")
    parser.add_argument("--max-cache-size", type=int, default=100 * 1024 * 1024,
                        help="bytes of messages waiting for the disk before dropping (x2)")
    parser.add_argument("--storage-preset-profile", default="zstd_fast", choices=PRESET_PROFILES,
                        help="MCAP chunk compression: zstd_fast (default), zstd_small, none, fastwrite")
    parser.add_argument("--compression-mode", default="none", choices=["none", "file", "message"])
    parser.add_argument("--compression-format", default="", choices=["", "zstd"])
    parser.add_argument("--node-name", default="rosbag2_recorder")
    parser.add_argument("--custom-data", nargs="*", default=[], metavar="KEY=VALUE")
    parser.add_argument("--max-duration", type=_non_negative_float, default=0.0,
                        help="stop recording after this many seconds (not in rosbag2)")
    args = parser.parse_args(argv)
    topics = args.topics or args.topics_positional
    if not (args.all or args.all_topics or topics or args.regex):
        parser.error("Need to specify at least one option out of --all, --all-topics, --topics or --regex")
    if args.exclude_regex and not (args.all or args.all_topics or args.regex):
        parser.error("--exclude-regex argument requires either --all, --all-topics or --regex")
    if args.compression_format and args.compression_mode == "none":
        parser.error("Invalid choice: Cannot specify compression format without a compression mode.")
    if any("=" not in kv for kv in args.custom_data):
        parser.error("--custom-data expects KEY=VALUE pairs")
    uri = args.output or datetime.datetime.now().strftime("rosbag2_%Y_%m_%d-%H_%M_%S")
    if os.path.isdir(uri):
        raise BagError(f"Output folder '{uri}' already exists.")
    writer = BagWriter(uri, storage_preset_profile=args.storage_preset_profile,
                       compression_mode=args.compression_mode, compression_format=args.compression_format,
                       max_bag_size=args.max_bag_size, max_bag_duration_s=args.max_bag_duration,
                       custom_data=dict(kv.split("=", 1) for kv in args.custom_data))
    options = RecordOptions(
        topics=topics, all_topics=args.all or args.all_topics, regex=args.regex,
        exclude_regex=args.exclude_regex, exclude_topics=args.exclude_topics,
        include_hidden_topics=args.include_hidden_topics,
        include_unpublished_topics=args.include_unpublished_topics, polling_interval_ms=args.polling_interval,
        no_discovery=args.no_discovery, max_duration_s=args.max_duration, max_cache_size=args.max_cache_size,
        node_name=args.node_name)
    return Recorder(writer, options).run()


# -- play -------------------------------------------------------------------------------------------
def cmd_play(argv: list[str]) -> int:
    from ros2_lite.bag_play import Player, PlayOptions

    parser = _Parser(prog="ros2 bag play", description="Play back ROS data from a bag.")
    parser.add_argument("bag_path", help="bag directory or .mcap file")
    parser.add_argument("-s", "--storage", default="", choices=["", "mcap"], help="storage (only mcap)")
    parser.add_argument("--read-ahead-queue-size", type=int, default=1000, help="accepted for compatibility")
    parser.add_argument("-r", "--rate", type=_positive_float, default=1.0, help="playback rate (> 0)")
    parser.add_argument("--topics", nargs="+", default=[], metavar="topic", help="topics to play")
    parser.add_argument("-e", "--regex", default="", help="play only topics matching this expression")
    parser.add_argument("-x", "--exclude-regex", default="", help="do not play topics matching this expression")
    parser.add_argument("--exclude-topics", nargs="+", default=[], metavar="topic", help="topics not to play")
    parser.add_argument("-l", "--loop", action="store_true", help="play again and again")
    parser.add_argument("--clock", type=_positive_float, nargs="?", const=40.0, default=0.0,
                        help="publish /clock at this frequency (Hz, default 40 when given)")
    parser.add_argument("-d", "--delay", type=_non_negative_float, default=0.0, help="sleep before play, s")
    parser.add_argument("--start-offset", type=_non_negative_float, default=0.0,
                        help="start this many seconds into the bag")
    parser.add_argument("--wait-for-subscribers", nargs="+", default=[], metavar="N|TOPIC=N",
                        help="before playing, wait (up to 10 s) until every topic has N matched subscribers; "
                             "TOPIC=N sets one topic's own count, e.g. 2 /camera/color/image_raw=1 (not in rosbag2)")
    parser.add_argument("-m", "--remap", nargs="+", default=[], metavar="REMAP",
                        help='topics to be remapped: in the form "old_topic1:=new_topic1 old_topic2:=new_topic2"')
    args = parser.parse_args(argv)
    remap = {}
    for rule in args.remap:
        old, sep, new = rule.partition(":=")
        if not sep or not old or not new:
            raise _UsageError(f"ros2 bag play: error: --remap '{rule}': expected old_topic:=new_topic")
        remap["/" + old.lstrip("/")] = "/" + new.lstrip("/")
    wait_all, wait_topics = _subscriber_counts(args.wait_for_subscribers)
    reader = BagReader(args.bag_path)
    try:
        for note in reader.notes:
            print(f"[WARN] [ros2bag]: {note}", file=sys.stderr)
        options = PlayOptions(rate=args.rate, loop=args.loop, topics=args.topics, exclude_topics=args.exclude_topics,
                              regex=args.regex, exclude_regex=args.exclude_regex, start_offset_s=args.start_offset,
                              delay_s=args.delay, clock_hz=args.clock, wait_for_subscribers=wait_all,
                              wait_for_topic=wait_topics, remap=remap)
        return Player(reader, options).run()
    finally:
        reader.close()


# -- entry --------------------------------------------------------------------------------------------
VERBS = {"info": cmd_info, "record": cmd_record, "play": cmd_play}


def _subscriber_counts(values: list[str]) -> tuple[int, dict[str, int]]:
    """``--wait-for-subscribers`` values: ``N`` for every topic, ``TOPIC=N`` for one."""
    every, per_topic = 0, {}
    for value in values:
        topic, sep, count = value.rpartition("=")
        try:
            n = int(count)
        except ValueError:
            n = -1
        if n < 0 or (sep and not topic):
            raise _UsageError(f"ros2 bag play: error: --wait-for-subscribers '{value}': expected N or TOPIC=N "
                              "(N a whole number >= 0)")
        if sep:
            per_topic["/" + topic.lstrip("/")] = n
        else:
            every = n
    return every, per_topic


def main(argv: list[str]) -> int:
    """``ros2 bag <verb> ...`` with ``argv`` after ``bag``. Returns the exit code."""
    try:
        if not argv or argv[0] in ("-h", "--help"):
            usage = "usage: ros2 bag {info,record,play} ...\n  info    print information about a bag\n" \
                    "  record  record topics to a bag\n  play    play back a bag"
            if argv:
                print(usage)
                return 0
            raise _UsageError("ros2 bag: error: a verb is required: info, record or play")
        verb = VERBS.get(argv[0])
        if verb is None:
            raise _UsageError(f"ros2 bag: error: unknown verb '{argv[0]}' (expected info, record or play)")
        return verb(argv[1:])
    except _UsageError as exc:
        print(_one_line(exc), file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help
        return exc.code if isinstance(exc.code, int) else 0
    except BagError as exc:
        print(f"[ERROR] [ros2bag]: {_one_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # one line, not a traceback; ROS2_LITE_DEBUG=1 shows it
        if os.environ.get("ROS2_LITE_DEBUG") == "1":
            raise
        print(f"[ERROR] [ros2bag]: {type(exc).__name__}: {_one_line(exc)}", file=sys.stderr)
        return 1


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def run(args: argparse.Namespace) -> int:
    """Entry from ``ros2_lite.cli`` (``args.bag_argv``: the words after ``ros2 bag``)."""
    return main(list(args.bag_argv))
