"""`ros2` for machines without ros2cli: `run`, `pkg`, `interface`, `bag`, and the introspection verbs
`topic`, `node`, `param`, `service`, `action` (on rclpy; ros2cli's arguments and output).

ROS 2 Jazzy comes from PyPI wheels here and those do not include ros2cli, so this
covers what our users run. Lookups follow ros2cli exactly: a package's prefix comes
from the ament index (``AMENT_PREFIX_PATH``), its executables are the executable files
under ``<prefix>/lib/<package>/`` (ros2run's ``get_executable_paths``). When a real
ros2cli is importable we hand over to it and do nothing ourselves.

Exit codes: 0 success, 1 a lookup or runtime failure (the message ros2cli prints),
2 a usage error, 130 Ctrl-C. A child started by ``ros2 run`` returns its own exit code. Output
into a closed pipe (``ros2 topic list | head -1``) ends the command quietly with 141, as a tool killed
by SIGPIPE.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import shlex
import signal
import subprocess
import sys

from ros2_lite import ament, node, service, topic
from ros2_lite.msg_yaml import InterfaceError

#: A verb's failure, printed as one line on stderr with exit code 1.
_VERB_ERRORS = (topic.TopicError, node.NodeError, service.ServiceError, InterfaceError)


class UsageError(Exception):
    """Bad command line: printed as one line, exit code 2."""


class CommandError(Exception):
    """A lookup or runtime failure: printed as one line, exit code 1."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # argparse would print usage and exit 2 itself
        raise UsageError(f"{self.prog}: {message}")


def _hand_over_to_ros2cli(argv: list[str]) -> int | None:
    if os.environ.get("ROS2_LITE_NO_HANDOVER") == "1":
        return None
    if importlib.util.find_spec("ros2cli") is None:
        return None
    from ros2cli.cli import main as ros2cli_main  # type: ignore[import-not-found]

    sys.argv = ["ros2", *argv]
    return ros2cli_main()


# -- ros2 run -------------------------------------------------------------------------------
def cmd_run(args: argparse.Namespace) -> int:
    prefix = ament.package_prefix(args.package_name)
    if prefix is None:
        raise CommandError(f"Package '{args.package_name}' not found")
    matches = [p for p in ament.executables(args.package_name, prefix) if p.name == args.executable_name]
    if not matches:
        raise CommandError("No executable found")
    if len(matches) > 1:
        raise CommandError("Multiple executables found:\n" + "\n".join(f"- {p}" for p in matches))
    cmd = [str(matches[0]), *args.argv]
    if args.prefix:
        cmd = shlex.split(args.prefix) + cmd
    return _run_forwarding_signals(cmd)


def _run_forwarding_signals(cmd: list[str]) -> int:
    """Run the child in the foreground; Ctrl-C reaches it (same process group) and we
    wait for it to shut down instead of dying first, as ros2run does. SIGTERM is passed on."""
    process = subprocess.Popen(cmd)

    def _forward(signum, _frame):
        process.send_signal(signum)

    previous = signal.signal(signal.SIGTERM, _forward)
    try:
        while True:
            try:
                return process.wait()
            except KeyboardInterrupt:
                continue  # the child got the same SIGINT and is shutting down
    finally:
        signal.signal(signal.SIGTERM, previous)


# -- ros2 pkg ---------------------------------------------------------------------------------
def cmd_pkg_list(_args: argparse.Namespace) -> int:
    for name in sorted(ament.packages()):
        print(name)
    return 0


def cmd_pkg_prefix(args: argparse.Namespace) -> int:
    prefix = ament.package_prefix(args.package_name)
    if prefix is None:
        raise CommandError("Package not found")
    print(prefix)
    return 0


def cmd_pkg_executables(args: argparse.Namespace) -> int:
    names = [args.package_name] if args.package_name else sorted(ament.packages())
    for name in names:
        prefix = ament.package_prefix(name)
        if prefix is None:
            raise CommandError("Package not found")
        for path in ament.executables(name, prefix):
            print(path if args.full_path else f"{name} {path.name}")
    return 0


# -- ros2 interface -------------------------------------------------------------------------
def cmd_interface_show(args: argparse.Namespace) -> int:
    try:
        text = ament.interface_text(args.type, comments=not args.no_comments, expand=True)
    except LookupError as exc:
        raise CommandError(str(exc)) from None
    print(text)
    return 0


def cmd_interface_list(args: argparse.Namespace) -> int:
    kinds = {"msg": args.only_msgs, "srv": args.only_srvs, "action": args.only_actions}
    wanted = [k for k, on in kinds.items() if on] or list(kinds)
    for name in sorted(ament.interfaces()):
        if name.split("/")[1] in wanted:
            print(f"    {name}")
    return 0


# -- ros2 bag -----------------------------------------------------------------------------------
def cmd_bag(args: argparse.Namespace) -> int:
    from ros2_lite import bag  # heavy imports (rosbags, mcap, rclpy) only for bag commands

    return bag.run(args)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="ros2", description="ros2 commands (run, pkg, interface, bag, topic, node, param, "
                                              "service, action) without ros2cli")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    run = sub.add_parser("run", help="run a package's executable")
    run.add_argument("--prefix", help="prefix command, e.g. 'gdb -ex run --args'")
    run.add_argument("package_name")
    run.add_argument("executable_name")
    run.add_argument("argv", nargs=argparse.REMAINDER, help="arguments for the executable (incl. --ros-args ...)")
    run.set_defaults(func=cmd_run)

    pkg = sub.add_parser("pkg", help="packages in the ament index")
    pkg_sub = pkg.add_subparsers(dest="pkg_command", metavar="VERB", parser_class=_Parser)
    pkg_sub.add_parser("list", help="list packages").set_defaults(func=cmd_pkg_list)
    prefix = pkg_sub.add_parser("prefix", help="prefix of a package")
    prefix.add_argument("package_name")
    prefix.set_defaults(func=cmd_pkg_prefix)
    exe = pkg_sub.add_parser("executables", help="executables of a package (or all)")
    exe.add_argument("package_name", nargs="?")
    exe.add_argument("--full-path", action="store_true")
    exe.set_defaults(func=cmd_pkg_executables)

    iface = sub.add_parser("interface", help="message, service and action definitions")
    iface_sub = iface.add_subparsers(dest="interface_command", metavar="VERB", parser_class=_Parser)
    show = iface_sub.add_parser("show", help="show a definition, e.g. stud_welding_msgs/msg/WeldTarget")
    show.add_argument("type")
    show.add_argument("--no-comments", action="store_true")
    show.set_defaults(func=cmd_interface_show)
    lst = iface_sub.add_parser("list", help="list interfaces")
    lst.add_argument("-m", "--only-msgs", action="store_true")
    lst.add_argument("-s", "--only-srvs", action="store_true")
    lst.add_argument("-a", "--only-actions", action="store_true")
    lst.set_defaults(func=cmd_interface_list)

    bag = sub.add_parser("bag", help="record, play and inspect rosbag2 MCAP bags")
    bag.add_argument("bag_argv", nargs=argparse.REMAINDER)
    bag.set_defaults(func=cmd_bag)

    topic.register(sub, _Parser)
    node.register(sub, _Parser)
    service.register(sub, _Parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    handed = _hand_over_to_ros2cli(argv)
    if handed is not None:
        return handed
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if not hasattr(args, "func"):
            verb = getattr(args, "command", None)
            raise UsageError(f"ros2{' ' + verb if verb else ''}: a command is required (see 'ros2 --help')")
        return int(args.func(args) or 0)
    except UsageError as exc:
        print(f"{exc}", file=sys.stderr)
        return 2
    except (CommandError, *_VERB_ERRORS) as exc:
        print(f"{exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:
        # The reader went away (`| head`): stop quietly, and keep the interpreter's final flush of
        # stdout from failing again on the closed pipe.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # rclpy raises this when Ctrl-C shut its context down mid-spin
        if type(exc).__name__ == "ExternalShutdownException":
            return 130
        raise


if __name__ == "__main__":
    sys.exit(main())
