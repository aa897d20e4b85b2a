"""``ros2 node list|info`` and ``ros2 param list|get|set|dump``: ros2node's and ros2param's output, on rclpy.

Parameters go through the node's rcl_interfaces services (rclpy's AsyncParameterClient), as ros2param.
``--timeout`` (how long to wait for the node to be discovered) defaults to 5 s here, not 1 s:
without a daemon, discovery starts from nothing. A refused ``param set`` prints ros2cli's
"Setting parameter failed: ..." and exits 1 (ros2cli exits 0), so a script can tell.
"""
from __future__ import annotations

import argparse
import re
import sys

import yaml

from ros2_lite.graph import ProbeNode, absolute_name, add_spin_time, is_hidden_name, split_node_name

NODE_TIMEOUT_S = 5
SERVICE_TIMEOUT_S = 5.0


class NodeError(Exception):
    """One line on stderr, exit code 1."""


# -- node ----------------------------------------------------------------------------------------------
def cmd_node_list(args: argparse.Namespace) -> int:
    with ProbeNode(args, "node_list") as probe:
        probe.settle()
        names = probe.node_names(include_hidden=args.all)
    if args.count_nodes:
        print(len(names))
    elif names:
        names = sorted(names)
        if len(set(names)) < len(names):
            print("WARNING: Be aware that there are nodes in the graph that share an exact name, which can have "
                  "unintended side effects.", file=sys.stderr)
        print(*names, sep="\n")
    return 0


def _print_section(title: str, names_and_types, include_hidden: bool) -> None:
    print(f"  {title}:")
    print(*[f"    {name}: {', '.join(types)}" for name, types in names_and_types
            if include_hidden or not is_hidden_name(name)], sep="\n")


def cmd_node_info(args: argparse.Namespace) -> int:
    import rclpy.action

    full = absolute_name(args.node_name)
    with ProbeNode(args, "node_info") as probe:
        if not probe.wait_for_node(full, NODE_TIMEOUT_S, args.include_hidden):
            raise NodeError(f"Unable to find node '{args.node_name}'")
        probe.settle()  # the node's endpoints are discovered after the node itself
        count = probe.node_names(True).count(full)
        if count > 1:
            print(f'There are {count} nodes in the graph with the exact name "{full}". You are seeing information '
                  "about only one of them.", file=sys.stderr)
        name, namespace = split_node_name(full)
        n = probe.node
        print(full)
        _print_section("Subscribers", n.get_subscriber_names_and_types_by_node(name, namespace), args.include_hidden)
        _print_section("Publishers", n.get_publisher_names_and_types_by_node(name, namespace), args.include_hidden)
        _print_section("Service Servers", n.get_service_names_and_types_by_node(name, namespace), args.include_hidden)
        _print_section("Service Clients", n.get_client_names_and_types_by_node(name, namespace), args.include_hidden)
        _print_section("Action Servers", rclpy.action.get_action_server_names_and_types_by_node(n, name, namespace),
                       args.include_hidden)
        _print_section("Action Clients", rclpy.action.get_action_client_names_and_types_by_node(n, name, namespace),
                       args.include_hidden)
    return 0


# -- param ----------------------------------------------------------------------------------------------
def _client(probe: ProbeNode, node_name: str):
    from rclpy.parameter_client import AsyncParameterClient

    client = AsyncParameterClient(probe.node, node_name)
    if not client.wait_for_services(timeout_sec=SERVICE_TIMEOUT_S):
        raise NodeError(f"Wait for service timed out waiting for parameter services for node {node_name}")
    return client


def _call(probe: ProbeNode, future, node_name: str):
    probe.spin_until_done(future)
    if future.result() is None:
        raise NodeError(f"Exception while calling service of node {node_name}: {future.exception()}")
    return future.result()


def _find_node(probe: ProbeNode, args: argparse.Namespace) -> str:
    full = absolute_name(args.node_name)
    if not probe.wait_for_node(full, args.timeout, args.include_hidden_nodes):
        raise NodeError("Node not found")
    return full


def parameter_type_word(ptype: int) -> str:
    from rcl_interfaces.msg import ParameterType as T

    return {T.PARAMETER_BOOL: "boolean", T.PARAMETER_INTEGER: "integer", T.PARAMETER_DOUBLE: "double",
            T.PARAMETER_STRING: "string", T.PARAMETER_BYTE_ARRAY: "byte array",
            T.PARAMETER_BOOL_ARRAY: "boolean array", T.PARAMETER_INTEGER_ARRAY: "integer array",
            T.PARAMETER_DOUBLE_ARRAY: "double array", T.PARAMETER_STRING_ARRAY: "string array",
            T.PARAMETER_NOT_SET: "not set"}[ptype]


def cmd_param_list(args: argparse.Namespace) -> int:
    with ProbeNode(args, "param_list") as probe:
        if args.node_name:
            nodes = [_find_node(probe, args)]
        else:
            probe.settle()
            nodes = sorted(probe.node_names(args.include_hidden_nodes))
        regex = re.compile(args.filter) if args.filter else None
        for full in nodes:
            try:
                client = _client(probe, full)
            except NodeError:
                print(f"Wait for service timed out waiting for parameter services for node {full}")
                continue
            names = sorted(_call(probe, client.list_parameters(prefixes=args.param_prefixes), full).result.names)
            if regex is not None:
                names = [n for n in names if regex.match(n)]
            if not args.node_name and names:
                print(f"{full}:")
            types = {}
            if args.param_type and names:
                described = _call(probe, client.describe_parameters(names), full)
                types = {d.name: parameter_type_word(d.type) for d in described.descriptors}
            for name in names:
                print(f"  {name} (type: {types[name]})" if args.param_type else f"  {name}")
    return 0


_GET_LABELS = {  # ParameterType -> (label, ParameterValue field)
    1: ("Boolean value is:", "bool_value"), 2: ("Integer value is:", "integer_value"),
    3: ("Double value is:", "double_value"), 4: ("String value is:", "string_value"),
    5: ("Byte values are:", "byte_array_value"), 6: ("Boolean values are:", "bool_array_value"),
    7: ("Integer values are:", "integer_array_value"), 8: ("Double values are:", "double_array_value"),
    9: ("String values are:", "string_array_value"),
}


def cmd_param_get(args: argparse.Namespace) -> int:
    with ProbeNode(args, "param_get") as probe:
        full = _find_node(probe, args)
        client = _client(probe, full)
        response = _call(probe, client.get_parameters([args.parameter_name]), full)
    if not response.values:
        raise NodeError("Parameter not set")
    value = response.values[0]
    if value.type == 0:
        print("Parameter not set.")
        return 0
    if value.type not in _GET_LABELS:
        raise NodeError(f"Unknown parameter type '{value.type}'")
    label, attr = _GET_LABELS[value.type]
    shown = getattr(value, attr)
    if hasattr(shown, "tolist"):
        shown = shown.tolist()
    elif not isinstance(shown, (str, bool, int, float)):
        shown = list(shown)
    print(shown if args.hide_type else f"{label} {shown}")
    return 0


def cmd_param_set(args: argparse.Namespace) -> int:
    from rcl_interfaces.msg import Parameter
    from rclpy.parameter import get_parameter_value

    with ProbeNode(args, "param_set") as probe:
        full = _find_node(probe, args)
        client = _client(probe, full)
        parameter = Parameter(name=args.parameter_name, value=get_parameter_value(string_value=args.value))
        result = _call(probe, client.set_parameters([parameter]), full).results[0]
    if result.successful:
        print("Set parameter successful" + (f": {result.reason}" if result.reason else ""))
        return 0
    print("Setting parameter failed" + (f": {result.reason}" if result.reason else ""), file=sys.stderr)
    return 1


def cmd_param_dump(args: argparse.Namespace) -> int:
    from rclpy.parameter import parameter_value_to_python

    with ProbeNode(args, "param_dump") as probe:
        full = _find_node(probe, args)
        client = _client(probe, full)
        names = sorted(_call(probe, client.list_parameters(), full).result.names)
        values = _call(probe, client.get_parameters(names), full).values if names else []
    params: dict = {}
    for name, value in zip(names, values):
        python = parameter_value_to_python(value)
        if hasattr(python, "tolist"):
            python = python.tolist()
        elif isinstance(python, (list, tuple)) or type(python).__name__ == "array":
            python = list(python)
        _insert(params, name, python)
    print(yaml.dump({full: {"ros__parameters": params}}, default_flow_style=False))
    return 0


def _insert(tree: dict, dotted: str, value) -> None:
    """``a.b.c`` -> nested mappings, as ros2param dump writes them."""
    head, _, rest = dotted.partition(".")
    if rest:
        _insert(tree.setdefault(head, {}), rest, value)
    else:
        tree[head] = value


# -- parser ----------------------------------------------------------------------------------------------
def register(sub, parser_class) -> None:
    node = sub.add_parser("node", help="nodes: list, info")
    verbs = node.add_subparsers(dest="node_command", metavar="VERB", parser_class=parser_class)
    lst = verbs.add_parser("list", help="Output a list of available nodes")
    add_spin_time(lst)
    lst.add_argument("-a", "--all", action="store_true", help="Display all nodes even hidden ones")
    lst.add_argument("-c", "--count-nodes", action="store_true", help="Only display the number of nodes discovered")
    lst.set_defaults(func=cmd_node_list)
    info = verbs.add_parser("info", help="Output information about a node")
    add_spin_time(info)
    info.add_argument("node_name", help="Node name to request information")
    info.add_argument("--include-hidden", action="store_true", help="Display hidden topics, services, and actions")
    info.set_defaults(func=cmd_node_info)

    param = sub.add_parser("param", help="parameters: list, get, set, dump")
    verbs = param.add_subparsers(dest="param_command", metavar="VERB", parser_class=parser_class)

    def common(p, node_required: bool = True) -> None:
        add_spin_time(p)
        p.add_argument("node_name", nargs=None if node_required else "?", help="Name of the ROS node")
        p.add_argument("--include-hidden-nodes", action="store_true", help="Consider hidden nodes as well")
        p.add_argument("--timeout", metavar="N", type=int, default=NODE_TIMEOUT_S,
                       help=f"Wait for N seconds until the node is found (default: {NODE_TIMEOUT_S})")

    lst = verbs.add_parser("list", help="Output a list of available parameters")
    common(lst, node_required=False)
    lst.add_argument("--filter", help="Only parameters matching the regex expression")
    lst.add_argument("--param-prefixes", nargs="+", default=[], help="Only list parameters with these prefixes")
    lst.add_argument("--param-type", action="store_true", help="Print the parameter types")
    lst.set_defaults(func=cmd_param_list)
    get = verbs.add_parser("get", help="Get parameter")
    common(get)
    get.add_argument("parameter_name", help="Name of the parameter")
    get.add_argument("--hide-type", action="store_true", help="Hide the type information")
    get.set_defaults(func=cmd_param_get)
    set_ = verbs.add_parser("set", help="Set parameter")
    common(set_)
    set_.add_argument("parameter_name", help="Name of the parameter")
    set_.add_argument("value", help="Value of the parameter (YAML: true, 3, 0.5, [1, 2], text)")
    set_.set_defaults(func=cmd_param_set)
    dump = verbs.add_parser("dump", help="Show all of the parameters of a node in a YAML file format")
    common(dump)
    dump.set_defaults(func=cmd_param_dump)
