"""A stand-in for a node, driven by flags: records its pid and the signals it gets in --state-dir."""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--name", required=True)
    ap.add_argument("--state-dir", required=True, type=Path)
    ap.add_argument("--ignore-sigint", action="store_true", help="log SIGINT, keep running")
    ap.add_argument("--ignore-sigterm", action="store_true", help="log SIGTERM, keep running")
    ap.add_argument("--ready-delay", type=float, default=0.0, help="print the ready line after this many s")
    ap.add_argument("--exit-after", type=float, default=None, help="exit by itself after this many s")
    ap.add_argument("--code", type=int, default=0, help="exit code for --exit-after")
    ap.add_argument("--lines", type=int, default=1, help="lines printed at start")
    ap.add_argument("--grandchild", action="store_true", help="start a sleeping process of our own")
    ap.add_argument("--dump-stacks", action="store_true", help="arm stud_common.stacks, as our nodes do")
    args = ap.parse_args()
    if args.dump_stacks:
        sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "src" / "stud_common"))
        from stud_common.stacks import dump_stacks_on_signal
        dump_stacks_on_signal()
    state = args.state_dir
    with open(state / f"{args.name}.pids", "a") as f:  # one line per instance (respawns)
        f.write(f"{os.getpid()}\n")

    def on_signal(signum, _frame):
        with open(state / f"{args.name}.signals", "a") as f:
            f.write(f"{os.getpid()} {signal.Signals(signum).name}\n")
        ignored = (signum == signal.SIGINT and args.ignore_sigint) or (signum == signal.SIGTERM and args.ignore_sigterm)
        if not ignored:
            sys.exit(0)

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    if args.grandchild:
        grand = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
        (state / f"{args.name}.grandchild").write_text(f"{grand.pid}\n")
    for i in range(args.lines):
        print(f"{args.name} line {i + 1} of {args.lines}")
    sys.stdout.flush()
    time.sleep(args.ready_delay)
    print(f"{args.name} ready", flush=True)
    t0 = time.monotonic()
    while args.exit_after is None or time.monotonic() - t0 < args.exit_after:
        time.sleep(0.02)
    print(f"{args.name} exiting with {args.code}", flush=True)
    return args.code


if __name__ == "__main__":
    sys.exit(main())
