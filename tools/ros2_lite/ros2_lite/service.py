"""``ros2 service list|call`` and ``ros2 action list|send_goal``: ros2service's and ros2action's output."""
from __future__ import annotations

import argparse
import time

from ros2_lite.graph import ProbeNode, add_spin_time, is_hidden_name
from ros2_lite.msg_yaml import InterfaceError, interface_class, message_to_yaml, parse_values, set_message_fields


class ServiceError(Exception):
    """One line on stderr, exit code 1."""


def _full(name: str) -> str:
    return name if name.startswith("/") else "/" + name


def _fill(request, values_text: str, what: str) -> None:
    try:
        set_message_fields(request, parse_values(values_text))
    except InterfaceError as exc:
        raise ServiceError(f"Failed to populate {what}: {exc}") from None


# -- service --------------------------------------------------------------------------------------------
def cmd_service_list(args: argparse.Namespace) -> int:
    with ProbeNode(args, "service_list") as probe:
        probe.settle()
        services = sorted((n, t) for n, t in probe.node.get_service_names_and_types()
                          if args.include_hidden_services or not is_hidden_name(n))
    if args.count_services:
        print(len(services))
        return 0
    for name, types in services:
        print(f"{name} [{', '.join(types)}]" if args.show_types else name)
    return 0


def cmd_service_call(args: argparse.Namespace) -> int:
    try:
        srv = interface_class(args.service_type, "srv")
        srv.Request, srv.Response  # noqa: B018 (a message type is not a service)
    except (InterfaceError, AttributeError):
        raise ServiceError("The passed service type is invalid") from None
    if args.rate is not None and args.rate <= 0:
        raise ServiceError("rate must be greater than zero")
    request = srv.Request()
    _fill(request, args.values, "field")
    with ProbeNode(args, "requester") as probe:
        client = probe.node.create_client(srv, _full(args.service_name))
        if not client.service_is_ready():
            print("waiting for service to become available...", flush=True)
            client.wait_for_service()
        while True:
            print(f"requester: making request: {request!r}\n", flush=True)
            started = time.monotonic()
            future = client.call_async(request)
            probe.spin_until_done(future)
            if future.result() is None:
                raise ServiceError(f"Exception while calling service: {future.exception()!r}")
            print(f"response:\n{future.result()!r}\n", flush=True)
            if args.rate is None:
                break
            probe.spin_for(max(0.0, started + 1.0 / args.rate - time.monotonic()))
    return 0


# -- action ---------------------------------------------------------------------------------------------
def cmd_action_list(args: argparse.Namespace) -> int:
    import rclpy.action

    with ProbeNode(args, "action_list") as probe:
        probe.settle()
        actions = sorted(rclpy.action.get_action_names_and_types(probe.node))
    if args.count_actions:
        print(len(actions))
        return 0
    for name, types in actions:
        print(f"{name} [{', '.join(types)}]" if args.show_types else name)
    return 0


_STATUS = {1: "ACCEPTED", 2: "EXECUTING", 3: "CANCELING", 4: "SUCCEEDED", 5: "CANCELED", 6: "ABORTED"}


def cmd_action_send_goal(args: argparse.Namespace) -> int:
    from rclpy.action import ActionClient

    try:
        action = interface_class(args.action_type, "action")
        goal = action.Goal()
    except (InterfaceError, AttributeError):
        raise ServiceError("The passed action type is invalid") from None
    try:
        set_message_fields(goal, parse_values(args.goal))
    except InterfaceError as exc:
        raise ServiceError(f"Failed to populate message fields: {exc}") from None

    def on_feedback(feedback) -> None:
        print(f"Feedback:\n    {message_to_yaml(feedback.feedback)}", flush=True)

    with ProbeNode(args, "send_goal") as probe:
        client = ActionClient(probe.node, action, _full(args.action_name))
        handle = None
        try:
            print("Waiting for an action server to become available...", flush=True)
            client.wait_for_server()
            print(f"Sending goal:\n     {message_to_yaml(goal)}", flush=True)
            future = client.send_goal_async(goal, on_feedback if args.feedback else None)
            probe.spin_until_done(future)
            handle = future.result()
            if handle is None:
                raise ServiceError(f"Exception while sending goal: {future.exception()!r}")
            if not handle.accepted:
                print("Goal was rejected.")
                handle = None
                return 0
            print(f"Goal accepted with ID: {bytes(handle.goal_id.uuid).hex()}\n", flush=True)
            result_future = handle.get_result_async()
            probe.spin_until_done(result_future)
            result = result_future.result()
            if result is None:
                raise ServiceError(f"Exception while getting result: {result_future.exception()!r}")
            handle = None
            print(f"Result:\n    {message_to_yaml(result.result)}")
            print(f"Goal finished with status: {_STATUS.get(result.status, 'UNKNOWN')}")
        finally:
            if handle is not None and handle.status in (1, 2):  # Ctrl-C while the goal runs: cancel it
                print("Canceling goal...")
                cancel = handle.cancel_goal_async()
                probe.spin_until_done(cancel, timeout_s=5.0)
                if cancel.done() and cancel.result() is not None and cancel.result().goals_canceling:
                    print("Goal canceled.")
            client.destroy()
    return 0


# -- parser ----------------------------------------------------------------------------------------------
def register(sub, parser_class) -> None:
    service = sub.add_parser("service", help="services: list, call")
    verbs = service.add_subparsers(dest="service_command", metavar="VERB", parser_class=parser_class)
    lst = verbs.add_parser("list", help="Output a list of available services")
    add_spin_time(lst)
    lst.add_argument("-t", "--show-types", action="store_true", help="Additionally show the service type")
    lst.add_argument("-c", "--count-services", action="store_true", help="Only display the number of services")
    lst.add_argument("--include-hidden-services", action="store_true", help="Consider hidden services as well")
    lst.set_defaults(func=cmd_service_list)
    call = verbs.add_parser("call", help="Call a service")
    call.add_argument("service_name", help="Name of the ROS service to call to (e.g. '/add_two_ints')")
    call.add_argument("service_type", help="Type of the ROS service (e.g. 'std_srvs/srv/Empty')")
    call.add_argument("values", nargs="?", default="{}", help="Values to fill the service request with in YAML format")
    call.add_argument("-r", "--rate", metavar="N", type=float, help="Repeat the call at a specific rate in Hz")
    call.set_defaults(func=cmd_service_call)

    action = sub.add_parser("action", help="actions: list, send_goal")
    verbs = action.add_subparsers(dest="action_command", metavar="VERB", parser_class=parser_class)
    lst = verbs.add_parser("list", help="Output a list of action names")
    add_spin_time(lst)
    lst.add_argument("-t", "--show-types", action="store_true", help="Additionally show the action type")
    lst.add_argument("-c", "--count-actions", action="store_true", help="Only display the number of actions")
    lst.set_defaults(func=cmd_action_list)
    send = verbs.add_parser("send_goal", help="Send an action goal")
    send.add_argument("action_name", help="Name of the ROS action (e.g. '/fibonacci')")
    send.add_argument("action_type", help="Type of the ROS action (e.g. 'example_interfaces/action/Fibonacci')")
    send.add_argument("goal", nargs="?", default="{}", help="Goal request values in YAML format")
    send.add_argument("-f", "--feedback", action="store_true", help="Echo feedback messages for the goal")
    send.set_defaults(func=cmd_action_send_goal)
