"""The weld cell in one command: ``ros2 run stud_planner cell --mode sim|replay|hardware``.

Reads the cell description (``config/cell.yaml``: which processes each mode runs, their parameters),
merges the command line's overrides, writes one ROS 2 parameter file per node into the run's output
folder (``--ros-args --params-file FILE``, types kept), and hands the processes to
:mod:`stud_bringup.launcher`, which prefixes and logs their output, respawns what should be respawned
and stops everything on Ctrl-C. The node list is data: a new node is a new section in the YAML;
one marked ``optional`` is skipped with a note while it is not installed.

Usage::

    ros2 run stud_planner cell --mode sim [--drawing FILE.dxf] [--no-hmi] [--respawn-driver]
    ros2 run stud_planner cell --mode replay --bag DIR
    ros2 run stud_planner cell --mode hardware --set arm_driver.arm_ip=192.168.1.18
    ros2 run stud_planner cell --mode sim --dry-run        # print the commands and parameters only

Exit codes: 0 a clean stop (Ctrl-C) or completion (the sequencer finished the job); 1 a node failed
(the launcher's report says which, with its exit code and last lines); 2 a usage or configuration
error (one line on stderr).
"""
from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn, Sequence

import yaml

from stud_bringup.launcher import ChildSpec, Launcher, LaunchError
from stud_common.stacks import STACK_DUMP_SIGNAL

TOP_KEYS = {"launch", "vars", "nodes", "modes"}
LAUNCH_KEYS = {"sigint_timeout_s": float, "sigterm_timeout_s": float, "report_lines": int}
NODE_KEYS = {"package", "executable", "cmd", "args", "params", "remaps", "env", "required", "optional", "respawn",
             "max_respawns", "respawn_delay_s", "exit_on", "ready", "start_after", "start_timeout_s"}
MODE_KEYS = {"nodes", "needs", "vars", "params", "remaps"}
#: vars with a command-line option of their own (named in "needs" errors)
VAR_OPTIONS = {"bag": "--bag DIR", "drawing": "--drawing FILE", "out": "--out DIR"}
DRIVER_NODE = "arm_driver"   # --respawn-driver
HMI_NODE = "hmi"             # --no-hmi
#: Packages whose executables arm ``stud_common.stacks`` (a stuck one is asked for its stacks).
OUR_PACKAGES = frozenset({"stud_planner", "stud_perception", "rm65_driver", "stud_inspection", "stud_cell",
                          "stud_hmi", "stud_bringup", "rm65_sim"})
_SUBST_RE = re.compile(r"\$\{([^}]*)\}")
_PARAM_SCALARS = (bool, int, float, str)


class CellConfigError(Exception):
    """A problem with cell.yaml or the command line: one line on stderr, exit code 2."""


# -- the description ----------------------------------------------------------------------------
def default_config_path() -> Path:
    """The installed ``share/stud_bringup/config/cell.yaml``; from a source tree, the file beside this package."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

        try:
            installed = Path(get_package_share_directory("stud_bringup")) / "config" / "cell.yaml"
            if installed.is_file():
                return installed
        except PackageNotFoundError:
            pass
    except ImportError:
        pass
    return Path(__file__).resolve().parents[1] / "config" / "cell.yaml"  # the source tree


def load_config(path: str | os.PathLike) -> dict:
    """Read and validate a cell description; :class:`CellConfigError` names the file and the key."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise CellConfigError(f"cannot read {path}: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise CellConfigError(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from None
    validate_config(data, str(path))
    return data


def validate_config(cfg: Any, source: str = "cell.yaml") -> None:
    """Check the structure of a cell description (types, known keys, node references)."""
    check = _ConfigChecker(source)
    check.mapping(cfg, "top level", TOP_KEYS)
    check.launch(cfg.get("launch"))
    check.mapping(cfg.get("vars"), "vars")
    nodes = check.mapping(cfg.get("nodes"), "nodes")
    if not nodes:
        check.fail("nodes", "no nodes defined")
    for name, node in nodes.items():
        check.node(name, node, nodes)
    modes = check.mapping(cfg.get("modes"), "modes")
    if not modes:
        check.fail("modes", "no modes defined")
    for mode, spec in modes.items():
        check.mode(mode, spec, nodes)


class _ConfigChecker:
    """The checks of :func:`validate_config`; each failure is a :class:`CellConfigError` naming the key."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, where: str, what: str) -> None:
        raise CellConfigError(f"{self.source}: {where}: {what}")

    def mapping(self, value: Any, where: str, keys: set[str] | None = None) -> dict:
        if value is None:
            return {}
        if not isinstance(value, dict):
            self.fail(where, f"must be a mapping, got {type(value).__name__}")
        unknown = sorted(set(map(str, value)) - keys) if keys is not None else []
        if unknown and keys is not None:
            self.fail(where, f"unknown key '{unknown[0]}' (known: {', '.join(sorted(keys))})")
        return value

    def str_list(self, value: Any, where: str) -> list:
        if not isinstance(value, list) or not all(isinstance(v, (str, int, float)) for v in value):
            self.fail(where, "must be a list of strings")
        return value

    def launch(self, section: Any) -> None:
        for key, kind in LAUNCH_KEYS.items():
            value = self.mapping(section, "launch", set(LAUNCH_KEYS)).get(key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0
                                      or (kind is int and not isinstance(value, int))):
                self.fail(f"launch.{key}", f"must be a non-negative {kind.__name__}, got {value!r}")

    def node(self, name: Any, node: Any, nodes: dict) -> None:
        where = f"nodes.{name}"
        if not re.match(r"^[A-Za-z0-9_][A-Za-z0-9_-]*$", str(name)):
            self.fail(where, "a node name uses letters, digits, '_' and '-'")
        node = self.mapping(node, where, NODE_KEYS)
        has_pkg = "package" in node or "executable" in node
        if has_pkg == ("cmd" in node):
            self.fail(where, "give either package + executable or cmd")
        if has_pkg and not (isinstance(node.get("package"), str) and isinstance(node.get("executable"), str)):
            self.fail(where, "package and executable must both be strings")
        if "cmd" in node and not self.str_list(node["cmd"], f"{where}.cmd"):
            self.fail(f"{where}.cmd", "is empty")
        self.str_list(node.get("args", []), f"{where}.args")
        self.mapping(node.get("params"), f"{where}.params")
        self.mapping(node.get("remaps"), f"{where}.remaps")
        self.mapping(node.get("env"), f"{where}.env")
        for flag in ("required", "optional", "respawn", "exit_on"):
            if not isinstance(node.get(flag, False), bool):
                self.fail(f"{where}.{flag}", f"must be true or false, got {node[flag]!r}")
        for num in ("max_respawns", "respawn_delay_s", "start_timeout_s"):
            value = node.get(num, 0)
            least = -1 if num == "max_respawns" else 0
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value < least:
                self.fail(f"{where}.{num}", f"must be a number >= {least}, got {value!r}")
        if "ready" in node:
            try:
                re.compile(str(node["ready"]))
            except re.error as exc:
                self.fail(f"{where}.ready", f"not a regular expression: {exc}")
        after = node.get("start_after", [])
        for dep in [after] if isinstance(after, str) else self.str_list(after, f"{where}.start_after"):
            if dep not in nodes:
                self.fail(f"{where}.start_after", f"unknown node '{dep}'")
            if dep == name:
                self.fail(f"{where}.start_after", "a node cannot wait for itself")

    def mode(self, mode: Any, spec: Any, nodes: dict) -> None:
        where = f"modes.{mode}"
        spec = self.mapping(spec, where, MODE_KEYS)
        listed = spec.get("nodes")
        if not isinstance(listed, list) or not listed:
            self.fail(f"{where}.nodes", "must be a non-empty list of node names")
        for n in listed:
            if n not in nodes:
                self.fail(f"{where}.nodes", f"unknown node '{n}' (defined: {', '.join(nodes)})")
        self.str_list(spec.get("needs", []), f"{where}.needs")
        self.mapping(spec.get("vars"), f"{where}.vars")
        for section in ("params", "remaps"):
            for n, value in self.mapping(spec.get(section), f"{where}.{section}").items():
                if n not in nodes:
                    self.fail(f"{where}.{section}", f"unknown node '{n}'")
                self.mapping(value, f"{where}.{section}.{n}")


# -- substitutions --------------------------------------------------------------------------------
class _Substituter:
    """``${var}``, ``${share:PKG}``, ``${env:NAME}``; a string that is exactly one ``${var}`` keeps the type."""

    def __init__(self, variables: dict[str, Any]):
        self.vars = variables

    def __call__(self, value: Any, where: str, depth: int = 0) -> Any:
        if depth > 10:
            raise CellConfigError(f"{where}: substitutions nest too deep (a var that refers to itself?)")
        if isinstance(value, dict):
            return {k: self(v, f"{where}.{k}", depth) for k, v in value.items()}
        if isinstance(value, list):
            return [self(v, where, depth) for v in value]
        if not isinstance(value, str):
            return value
        whole = _SUBST_RE.fullmatch(value)
        if whole:
            return self._lookup(whole.group(1), where, depth)
        return _SUBST_RE.sub(lambda m: self._text(self._lookup(m.group(1), where, depth)), value)

    @staticmethod
    def _text(value: Any) -> str:
        if isinstance(value, bool):
            return "true" if value else "false"
        return str(value)

    def _lookup(self, key: str, where: str, depth: int) -> Any:
        kind, _, arg = key.partition(":")
        if kind == "share" and arg:
            return share_directory(arg, where)
        if kind == "env" and arg:
            if arg not in os.environ:
                raise CellConfigError(f"{where}: ${{env:{arg}}}: environment variable {arg} is not set")
            return os.environ[arg]
        if key not in self.vars or self.vars[key] is None:
            option = VAR_OPTIONS.get(key, f"--var {key}=VALUE")
            raise CellConfigError(f"{where}: ${{{key}}} has no value (give {option})")
        return self(self.vars[key], f"vars.{key}", depth + 1)


def share_directory(package: str, where: str = "") -> str:
    """``package``'s installed share directory (ament index); :class:`CellConfigError` naming ``where`` if none."""
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    try:
        return get_package_share_directory(package)
    except PackageNotFoundError:
        raise CellConfigError(f"{where}: ${{share:{package}}}: package '{package}' is not installed") from None


def find_executable(package: str, executable: str) -> str | None:
    """``<prefix>/lib/<package>/<executable>`` from the ament index, as ``ros2 run`` finds it."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        path = Path(get_package_prefix(package)) / "lib" / package / executable
    except PackageNotFoundError:
        return None
    return str(path) if path.is_file() and os.access(path, os.X_OK) else None


# -- the plan -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlannedNode:
    """One process of the launch, all substitutions done. ``skip``: why it will not run."""

    name: str
    argv: list[str]
    params: dict = field(default_factory=dict)
    remaps: dict = field(default_factory=dict)
    env: dict = field(default_factory=dict)
    required: bool = False
    respawn: bool = False
    max_respawns: int = 3
    respawn_delay_s: float = 1.0
    exit_on: bool = False
    ready: str | None = None
    start_after: tuple[str, ...] = ()
    start_timeout_s: float = 30.0
    skip: str | None = None
    package: str | None = None  # None: a ``cmd`` node

    def command(self, params_file: str | None) -> list[str]:
        """The full command; the ROS arguments only when there are parameters or remappings."""
        ros = (["--params-file", params_file] if self.params and params_file else []) + \
              [a for src, dst in self.remaps.items() for a in ("-r", f"{src}:={dst}")]
        return self.argv + (["--ros-args", *ros] if ros else [])


def parse_assignment(text: str, option: str) -> tuple[str, Any]:
    """``KEY=VALUE`` with the value read as YAML (``1.5`` a float, ``true`` a bool, ``[1, 2]`` a list)."""
    key, sep, raw = text.partition("=")
    if not sep or not key:
        raise CellConfigError(f"{option} {text!r}: expected KEY=VALUE")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    return key.strip(), value


def _check_param(value: Any, where: str) -> Any:
    """ROS 2 parameter types: bool, int, float, str, homogeneous lists of those, nested namespaces."""
    if isinstance(value, dict):
        # An empty namespace holds no parameters, and rcl's parser refuses a file with one before other keys.
        return {str(k): _check_param(v, f"{where}.{k}") for k, v in value.items() if v != {}}
    if isinstance(value, _PARAM_SCALARS):
        return value
    if isinstance(value, list):
        if not value:  # no ROS type: the node reads it as [] (ros_io.declare_params), which its check accepts or not
            return value
        kinds = {type(v) for v in value}
        if kinds <= {int, float}:
            return [float(v) for v in value] if len(kinds) == 2 else value  # [1, 0.5] -> doubles
        if len(kinds) == 1 and kinds <= set(_PARAM_SCALARS):
            return value
        raise CellConfigError(f"{where}: list elements must be all numbers, all strings or all booleans: {value}")
    raise CellConfigError(f"{where}: {value!r} is not a ROS parameter value (bool, int, float, string or a list)")


def _deep_merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def plan_cell(cfg: dict, mode: str, *, out_dir: str, cli_vars: dict | None = None, sets: Sequence[str] = (),
              with_nodes: Sequence[str] = (), without_nodes: Sequence[str] = (), respawn_driver: bool = False,
              check_installed: bool = True) -> tuple[list[PlannedNode], list[str]]:
    """The processes of ``mode`` with their commands and parameters, and notes for the user
    (skipped nodes, ignored options). Raises :class:`CellConfigError` for anything that would not run."""
    modes, nodes = cfg["modes"], cfg["nodes"]
    if mode not in modes:
        raise CellConfigError(f"unknown mode '{mode}' (this cell has: {', '.join(modes)})")
    mspec = modes[mode] or {}
    notes: list[str] = []
    for n in [*with_nodes, *without_nodes]:
        if n not in nodes:
            raise CellConfigError(f"unknown node '{n}' (defined: {', '.join(nodes)})")
    names = [n for n in [*mspec["nodes"], *(w for w in with_nodes if w not in mspec["nodes"])]
             if n not in without_nodes]
    variables = {**(cfg.get("vars") or {}), **(mspec.get("vars") or {}), **(cli_vars or {}), "out": out_dir,
                 "mode": mode}
    for need in mspec.get("needs", []):
        if variables.get(need) in (None, ""):
            raise CellConfigError(f"--mode {mode} needs {VAR_OPTIONS.get(need, f'--var {need}=VALUE')}")
    subst = _Substituter(variables)

    overrides: dict[str, dict] = {}
    for text in sets:
        key, value = parse_assignment(text, "--set")
        node, dot, param = key.partition(".")
        if not dot or not param:
            raise CellConfigError(f"--set {text!r}: expected NODE.PARAM=VALUE")
        if node not in nodes:
            raise CellConfigError(f"--set {text!r}: unknown node '{node}' (defined: {', '.join(nodes)})")
        if node not in names:
            raise CellConfigError(f"--set {text!r}: node '{node}' is not part of mode {mode} "
                                  f"(add it with --with {node})")
        overrides.setdefault(node, {})[param] = value

    if respawn_driver and DRIVER_NODE not in names:
        notes.append(f"--respawn-driver ignored: {DRIVER_NODE} is not part of mode {mode}")

    planned: list[PlannedNode] = []
    for name in names:
        node = nodes[name]
        where = f"nodes.{name}"
        params = _deep_merge(node.get("params") or {}, (mspec.get("params") or {}).get(name) or {})
        params = _check_param(_deep_merge(subst(params, f"{where}.params"), overrides.get(name, {})), f"{where}.params")
        remaps = {str(subst(k, f"{where}.remaps")): str(subst(v, f"{where}.remaps"))
                  for k, v in {**(node.get("remaps") or {}), **((mspec.get("remaps") or {}).get(name) or {})}.items()}
        env = {str(k): (None if v is None else subst._text(subst(v, f"{where}.env")))
               for k, v in (node.get("env") or {}).items()}
        args = [subst._text(a) for a in subst([str(a) if not isinstance(a, str) else a
                                               for a in node.get("args", [])], f"{where}.args")]
        skip = None
        if "cmd" in node:
            cmd = [subst._text(a) for a in subst(list(node["cmd"]), f"{where}.cmd")]
            exe = shutil.which(cmd[0]) if check_installed else cmd[0]
            what = f"command '{cmd[0]}'"
            argv = [exe or cmd[0], *cmd[1:], *args]
        else:
            exe = find_executable(node["package"], node["executable"]) if check_installed else \
                f"{node['package']}/{node['executable']}"
            what = f"{node['package']}/{node['executable']}"
            argv = [exe or what, *args]
        if exe is None:
            if node.get("optional", False):
                skip = f"{what} is not installed"
                notes.append(f"skipping {name}: {skip}")
            else:
                raise CellConfigError(f"cannot launch {name}: {what} is not installed "
                                      "(build with: bash tools/setup.sh)")
        planned.append(PlannedNode(
            name=name, argv=argv, params=params, remaps=remaps, env=env, required=node.get("required", False),
            respawn=node.get("respawn", False) or (respawn_driver and name == DRIVER_NODE),
            max_respawns=int(node.get("max_respawns", 3)), respawn_delay_s=float(node.get("respawn_delay_s", 1.0)),
            exit_on=node.get("exit_on", False), ready=node.get("ready"), start_after=_names(node.get("start_after")),
            start_timeout_s=float(node.get("start_timeout_s", 30.0)), skip=skip,
            package=None if "cmd" in node else node["package"]))
    running = {p.name for p in planned if p.skip is None}  # wait only for nodes of this launch
    return [PlannedNode(**{**p.__dict__, "start_after": tuple(n for n in p.start_after if n in running)})
            for p in planned], notes


def _names(value: str | list | None) -> tuple[str, ...]:
    return () if value is None else (value,) if isinstance(value, str) else tuple(value)


def write_params_file(node: PlannedNode, folder: Path) -> Path | None:
    """``<folder>/<node>.yaml`` in the ROS 2 format, for every node name (``/**``): the file is the
    node's by construction, and the node's name in code may change without breaking the launch."""
    if not node.params:
        return None
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{node.name}.yaml"
    path.write_text(f"# written by `cell` for {node.name}; edit config/cell.yaml instead\n" +
                    yaml.safe_dump({"/**": {"ros__parameters": node.params}}, sort_keys=False,
                                   default_flow_style=None))
    return path


def child_specs(plan: Sequence[PlannedNode], out_dir: Path) -> list[ChildSpec]:
    """Launcher specs for the nodes that run; writes their parameter files under ``<out_dir>/params``."""
    env_all = {} if "ROS_LOG_DIR" in os.environ else {"ROS_LOG_DIR": str(out_dir / "ros_log")}
    specs = []
    for node in plan:
        if node.skip is not None:
            continue
        params_file = write_params_file(node, out_dir / "params")
        specs.append(ChildSpec(
            name=node.name, argv=node.command(str(params_file) if params_file else None),
            env={**env_all, **node.env}, required=node.required, respawn=node.respawn,
            max_respawns=node.max_respawns, respawn_delay_s=node.respawn_delay_s, exit_on=node.exit_on,
            ready_pattern=node.ready, start_after=node.start_after or None, start_timeout_s=node.start_timeout_s,
            stack_dump_signal=STACK_DUMP_SIGNAL if node.package in OUR_PACKAGES else None))
    return specs


# -- command line -----------------------------------------------------------------------------------
class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise CellConfigError(f"{self.prog}: {message}")


def build_parser() -> argparse.ArgumentParser:
    """The ``cell`` command line; a bad option raises :class:`CellConfigError` instead of exiting."""
    p = _Parser(prog="cell", description="Start the weld cell's nodes as one supervised group (Ctrl-C stops all).")
    p.add_argument("--mode", required=True, help="a mode of the cell description: sim, replay or hardware")
    p.add_argument("--bag", help="bag directory to play (replay mode)")
    p.add_argument("--params", help="cell description YAML (default: stud_bringup's config/cell.yaml)")
    p.add_argument("--drawing", help="DXF drawing (sets ${drawing})")
    p.add_argument("--out", help="output folder for logs, parameter files, the weld journal "
                                 "(default: $ROS_HOME/stud_welding/cell/<mode>-<time>)")
    p.add_argument("--no-hmi", action="store_true", help=f"do not start the {HMI_NODE} node")
    p.add_argument("--respawn-driver", action="store_true", help=f"restart {DRIVER_NODE} when it dies")
    p.add_argument("--with", dest="with_nodes", action="append", default=[], metavar="NODE",
                   help="also run this node of the description (repeatable)")
    p.add_argument("--without", dest="without_nodes", action="append", default=[], metavar="NODE",
                   help="do not run this node (repeatable)")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="NODE.PARAM=VALUE",
                   help="override a node parameter; VALUE is read as YAML (repeatable)")
    p.add_argument("--var", dest="vars", action="append", default=[], metavar="NAME=VALUE",
                   help="set a ${NAME} of the description (repeatable)")
    p.add_argument("--dry-run", action="store_true", help="print the commands and parameters, start nothing")
    return p


def _default_out(mode: str) -> Path:
    home = os.environ.get("ROS_HOME") or os.path.join(os.path.expanduser("~"), ".ros")
    return Path(home) / "stud_welding" / "cell" / f"{mode}-{time.strftime('%Y%m%d-%H%M%S')}"


def _print_plan(plan: Sequence[PlannedNode], out_dir: Path) -> None:
    for node in plan:
        if node.skip:
            print(f"# {node.name}: skipped ({node.skip})")
            continue
        flags = [f for f, on in (("required", node.required), ("exit_on", node.exit_on),
                                 (f"respawn<={node.max_respawns}", node.respawn)) if on]
        after = [f"after {', '.join(node.start_after)}"] if node.start_after else []
        print(f"# {node.name}{' (' + ', '.join(flags + after) + ')' if flags or after else ''}")
        params_file = out_dir / "params" / f"{node.name}.yaml" if node.params else None
        print(shlex.join(node.command(str(params_file) if params_file else None)))
        if node.params:
            for line in yaml.safe_dump(node.params, sort_keys=False, default_flow_style=None).splitlines():
                print(f"#   {line}")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``cell`` command: the mode's nodes as one supervised group (--dry-run: print them); returns the
    exit code."""
    args_in = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(args_in)
        cfg = load_config(args.params or default_config_path())
        cli_vars = dict(parse_assignment(v, "--var") for v in args.vars)
        if args.bag is not None:
            bag = Path(args.bag).expanduser()
            if not bag.exists():
                raise CellConfigError(f"--bag {args.bag}: no such bag directory or file")
            cli_vars["bag"] = str(bag.resolve())
        if args.drawing is not None:
            drawing = Path(args.drawing).expanduser()
            if not drawing.is_file():
                raise CellConfigError(f"--drawing {args.drawing}: no such file")
            cli_vars["drawing"] = str(drawing.resolve())
        out_dir = (Path(args.out).expanduser() if args.out else _default_out(args.mode)).resolve()
        without = [*args.without_nodes, *([HMI_NODE] if args.no_hmi else [])]
        plan, notes = plan_cell(cfg, args.mode, out_dir=str(out_dir), cli_vars=cli_vars, sets=args.sets,
                                with_nodes=args.with_nodes, without_nodes=without,
                                respawn_driver=args.respawn_driver)
        for note in notes:
            print(f"[cell] {note}", file=sys.stderr)
        if args.dry_run:
            _print_plan(plan, out_dir)
            return 0
        if not any(p.skip is None for p in plan):
            raise CellConfigError(f"--mode {args.mode}: nothing to run")
        launch = cfg.get("launch") or {}
        specs = child_specs(plan, out_dir)
        launcher = Launcher(specs, out_dir, sigint_timeout_s=float(launch.get("sigint_timeout_s", 10.0)),
                            sigterm_timeout_s=float(launch.get("sigterm_timeout_s", 5.0)),
                            report_lines=int(launch.get("report_lines", 20)))
    except (CellConfigError, LaunchError) as exc:
        print(f"cell: {exc}" if not str(exc).startswith("cell") else str(exc), file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"cell: {exc}", file=sys.stderr)
        return 2
    print(f"[cell] mode {args.mode}: {', '.join(s.name for s in specs)}; output in {out_dir}", flush=True)
    return launcher.run()


if __name__ == "__main__":
    sys.exit(main())
