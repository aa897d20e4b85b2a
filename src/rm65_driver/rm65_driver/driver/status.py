"""The arm driver's state side: polling the controller, ``/arm/state``, ``/joint_states``,
``/camera/pose``, ``/arm/welds`` and ``/diagnostics``.

:class:`DriverStatus` is a member of :class:`~rm65_driver.driver.driver_node.DriverNode` (the client and
the journal it reads are the node's :class:`~rm65_driver.driver.shared_state.DriverState`; its publishers
are its own): a thread polls the arm state at ``state_rate_hz`` (Hz), with
a back-off of 0.2 s doubling to 5 s while the controller is not connected, and publishes each
reading -- joints in rad, the ``weld_tool`` pose in ``world`` (m) from the driver's own forward
kinematics, whatever the controller's tool frame; with a rail also the carriage (``expand_get_state``),
which places the base in ``world`` and is ``rail_joint`` (m) in ``/joint_states``.
"""
from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from stud_welding_msgs.msg import ArmState, WeldRecord

from rm65_driver.driver.shared_state import DriverState
from rm65_driver.journal.scan import JournalCorrupt
from rm65_driver.protocol.arm_client import ArmError
from stud_common import frames, names, ros_io
from stud_common.hand_eye_in_use import camera_in_world
from stud_common.vocabulary import WeldPhase

JOINT_NAMES = [f"joint{i}" for i in range(1, 7)]
RAIL_JOINT = frames.RAIL_JOINT  # prismatic world -> carriage, m (with a rail)
WELDS_QOS = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class DriverStatus:
    """State polling and publishing of :class:`~rm65_driver.driver.driver_node.DriverNode`: its publishers, the
    diagnostics and the polling thread (:meth:`start`, :meth:`stop`)."""

    def __init__(self, node: Node, state: DriverState, group: CallbackGroup) -> None:
        self._node = node
        self.state = state
        p = state.p
        self.pub_state = node.create_publisher(ArmState, names.ARM_STATE, ros_io.RESULT_QOS)
        self.pub_joints = node.create_publisher(JointState, names.JOINT_STATES, 10)
        # Every confirmed weld, for the QA record and the inspection: reliable, and transient local
        # with a deep history so a subscriber that (re)starts mid-job still gets this job's welds.
        self.pub_welds = node.create_publisher(WeldRecord, names.ARM_WELDS, WELDS_QOS)
        self.pub_camera = (node.create_publisher(PoseStamped, names.CAMERA_POSE, ros_io.CAMERA_PUB_QOS)
                           if p["publish_camera_pose"] else None)
        self.diag = ros_io.Diagnostics(node, hardware_id=f"RM65 {p['arm_ip']}:{p['tcp_port']}")
        node.create_timer(1.0, self.diag.publish, callback_group=group)
        self._running = True
        self._wake = threading.Event()
        self._connected_logged: bool | None = None
        self._poller = threading.Thread(target=self._poll_loop, name="rm65-state", daemon=True)

    def start(self) -> None:
        """Start polling (once the node is set up: the thread reads its state)."""
        self._poller.start()

    def stop(self) -> None:
        """Ask the polling thread to end (:meth:`join` waits for it)."""
        self._running = False
        self._wake.set()

    def join(self, timeout_s: float) -> None:
        self._poller.join(timeout=timeout_s)

    # -- state publishing -------------------------------------------------------------------------
    def _poll_loop(self) -> None:
        backoff = 0.2
        s = self.state
        while self._running:
            period = 1.0 / s.p["state_rate_hz"]
            t0 = time.monotonic()
            seq = s.sequence
            job_running = seq is not None and seq.running
            if not s.client.connected and not job_running:  # a running job reconnects by itself
                try:
                    s.client.connect()
                    backoff = 0.2
                except ArmError as exc:
                    self._log_connection(False, str(exc))
                    self._publish(None)
                    self._sleep(backoff)
                    backoff = min(backoff * 2, 5.0)
                    continue
            reading = None
            if s.client.connected:
                try:
                    reading = s.client.get_state()
                except ArmError as exc:
                    self._node.get_logger().warn(f"arm state not read: {exc}", throttle_duration_sec=5.0)
                if s.rail.present and s.client.connected:
                    self._read_rail()
            self._log_connection(s.client.connected, s.client.last_error)
            self._publish(reading)
            self._sleep(period - (time.monotonic() - t0))

    def _read_rail(self) -> None:
        try:
            rail = self.state.rail.read()
        except ArmError as exc:
            self._node.get_logger().warn(f"rail state not read: {exc}", throttle_duration_sec=5.0)
            return
        if rail is not None and not rail.enabled:
            self._node.get_logger().warn("rail_length_m is set but the controller's expansion joint is not enabled "
                                         "(expand_get_state en_flag 0)", throttle_duration_sec=30.0)

    def _sleep(self, seconds: float) -> None:
        self._wake.wait(max(0.0, seconds))  # set at shutdown

    def _log_connection(self, connected: bool, why: str) -> None:
        if connected != self._connected_logged:
            p = self.state.p
            if connected:
                self._node.get_logger().info(f"connected to the controller at {p['arm_ip']}:{p['tcp_port']}")
            else:
                self._node.get_logger().warn(f"controller {p['arm_ip']}:{p['tcp_port']} not connected: {why}")
            self._connected_logged = connected

    def _mode(self, reading) -> int:
        s = self.state
        seq = s.sequence
        if s.estop:
            return ArmState.MODE_ESTOP
        if s.journal_fault is not None:
            return ArmState.MODE_FAULT
        if not s.client.connected:
            return ArmState.MODE_DISCONNECTED
        if reading is not None and reading.error_codes:
            return ArmState.MODE_FAULT
        if s.client.paused:
            return ArmState.MODE_PAUSED
        if seq is not None and seq.running:
            return ArmState.MODE_WELDING if seq.phase in (WeldPhase.WELD, WeldPhase.DWELL) else ArmState.MODE_MOVING
        if s.rail.moving:
            return ArmState.MODE_MOVING
        return ArmState.MODE_IDLE

    def _publish(self, reading) -> None:
        s = self.state
        stamp = self._node.get_clock().now().to_msg()
        msg = ArmState()
        msg.header.stamp = stamp
        msg.header.frame_id = "world"
        msg.mode = self._mode(reading)
        msg.connected = s.client.connected
        seq = s.sequence
        if seq is not None and seq.running:
            msg.current_stud, msg.done, msg.total = seq.current_stud, seq.done, seq.total
        fault = s.journal_fault
        msg.message = s.fault_text(fault) if fault is not None else s.message
        msg.uncertain_studs = self.uncertain_studs()
        if s.rail.present:
            msg.rail_position_m, msg.rail_moving = s.rail.position_m, s.rail.moving
        if reading is not None:
            s.last_state = reading
            T_tool = s.kin.fk(reading.joints_rad) @ s.tool_T  # weld_tool in base, whatever the controller's tool frame
            if s.rail.present:
                T_tool = s.rail.world_T_base() @ T_tool  # ... in world
            msg.joints = [float(v) for v in reading.joints_rad]
            msg.tool_pose = ros_io.rt_to_pose(T_tool[:3, :3], T_tool[:3, 3])
            msg.error_codes = [int(c) & 0xFFFF for c in reading.error_codes]
            msg.errors = reading.errors_text
            js = JointState()
            js.header.stamp = stamp
            js.name = JOINT_NAMES + ([RAIL_JOINT] if s.rail.present else [])
            js.position = [float(v) for v in reading.joints_rad] + ([s.rail.position_m] if s.rail.present else [])
            self.pub_joints.publish(js)
            if self.pub_camera is not None:
                T_cam = camera_in_world(T_tool, s.hand_eye_T())
                cam = PoseStamped()
                cam.header.stamp = stamp
                cam.header.frame_id = "world"
                cam.pose = ros_io.rt_to_pose(T_cam[:3, :3], T_cam[:3, 3])
                self.pub_camera.publish(cam)
        self.pub_state.publish(msg)
        self._update_diagnostics(msg)

    def publish_weld(self, stud_id: str, joints_rad: np.ndarray, job_id: str, world_T_base: np.ndarray | None = None,
                     rail_m: float = 0.0) -> None:
        """A confirmed weld on /arm/welds: the tool pose in world, the base there where the job had it."""
        T_tool = self.state.kin.fk(joints_rad) @ self.state.tool_T
        if self.state.rail.present and world_T_base is not None:
            T_tool = world_T_base @ T_tool
        msg = WeldRecord(stud_id=stud_id, job_id=job_id, joints=[float(v) for v in joints_rad],
                         tool_pose=ros_io.rt_to_pose(T_tool[:3, :3], T_tool[:3, 3]), rail_position_m=float(rail_m))
        msg.header.stamp = self._node.get_clock().now().to_msg()
        msg.header.frame_id = "world"
        self.pub_welds.publish(msg)

    def uncertain_studs(self) -> list[str]:
        """The journal's uncertain studs that wait for an operator decision (/arm/resolve_stud):
        not the stud being welded now -- started and not yet confirmed is every weld's normal course."""
        journal = self.state.journal
        if journal is None:
            return []
        seq = self.state.sequence
        busy = seq.current_stud if seq is not None and seq.running else ""
        return sorted(s for s in journal.uncertain_ids if s != busy)

    def _update_diagnostics(self, msg: ArmState) -> None:
        d, s = self.diag, self.state
        journal, fault = s.journal, s.journal_fault
        values = dict(connected=msg.connected, mode=msg.mode, job=f"{msg.done}/{msg.total}",
                      current_stud=msg.current_stud, errors="; ".join(msg.errors) or "none",
                      uncertain_studs=len(msg.uncertain_studs) if journal is not None else "unknown",
                      journal_file=str(s.journal_path),
                      journal_damaged_lines=(", ".join(f"{Path(f).name}:{n}" for f, n in fault.report.lines[:20])
                                             if isinstance(fault, JournalCorrupt) else "none"))
        if s.estop:
            d.set(d.ERROR, "e-stop engaged (publish false on /arm/estop to release)", **values)
        elif fault is not None:
            d.set(d.ERROR, s.fault_text(fault), **values)
        elif not msg.connected:
            d.set(d.ERROR, f"controller not connected: {s.client.last_error}", **values)
        elif msg.errors:
            d.set(d.ERROR, "controller error: " + "; ".join(msg.errors), **values)
        elif msg.uncertain_studs:
            d.set(d.WARN, f"{len(msg.uncertain_studs)} uncertain stud(s) need an operator decision "
                          f"(/arm/resolve_stud): {', '.join(msg.uncertain_studs[:10])}", **values)
        else:
            d.set(d.OK, "connected", **values)
