"""The arm driver's state side: polling the controller, ``/arm/state``, ``/joint_states``,
``/camera/pose``, ``/arm/welds`` and ``/diagnostics``.

:class:`DriverStatus` is a part of :class:`~rm65_driver.driver_node.DriverNode` (its publishers,
client and journal are made there): a thread polls the arm state at ``state_rate_hz`` (Hz), with
a back-off of 0.2 s doubling to 5 s while the controller is not connected, and publishes each
reading -- joints in rad, the ``weld_tool`` pose in ``world`` (m) from the driver's own forward
kinematics, whatever the controller's tool frame; with a rail also the carriage (``expand_get_state``),
which places the base in ``world`` and is ``rail_joint`` (m) in ``/joint_states``.
"""
from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.publisher import Publisher
from sensor_msgs.msg import JointState
from stud_welding_msgs.msg import ArmState, WeldRecord

from stud_common import ros_io
from stud_common.hand_eye_in_use import camera_in_world

from stud_common import frames

from .arm_client import ArmError
from .driver_base import DriverBase
from .journal_scan import JournalCorrupt

JOINT_NAMES = [f"joint{i}" for i in range(1, 7)]
RAIL_JOINT = frames.RAIL_JOINT  # prismatic world -> carriage, m (with a rail)


class DriverStatus(DriverBase):
    """State polling and publishing of :class:`~rm65_driver.driver_node.DriverNode` (state lives there)."""

    hand_eye: Any
    diag: ros_io.Diagnostics
    pub_state: Publisher
    pub_joints: Publisher
    pub_welds: Publisher
    pub_camera: Publisher | None
    _running: bool
    _wake: threading.Event
    _connected_logged: bool | None

    # -- state publishing -------------------------------------------------------------------------
    def _poll_loop(self) -> None:
        backoff = 0.2
        while self._running:
            period = 1.0 / self.p["state_rate_hz"]
            t0 = time.monotonic()
            seq = self.sequence
            job_running = seq is not None and seq.running
            if not self.client.connected and not job_running:  # a running job reconnects by itself
                try:
                    self.client.connect()
                    backoff = 0.2
                except ArmError as exc:
                    self._log_connection(False, str(exc))
                    self._publish(None)
                    self._sleep(backoff)
                    backoff = min(backoff * 2, 5.0)
                    continue
            reading = None
            if self.client.connected:
                try:
                    reading = self.client.get_state()
                except ArmError as exc:
                    self.get_logger().warn(f"arm state not read: {exc}", throttle_duration_sec=5.0)
                if self.rail.present and self.client.connected:
                    try:
                        rail = self.rail.read()
                        if rail is not None and not rail.enabled:
                            self.get_logger().warn("rail_length_m is set but the controller's expansion joint is not "
                                                   "enabled (expand_get_state en_flag 0)", throttle_duration_sec=30.0)
                    except ArmError as exc:
                        self.get_logger().warn(f"rail state not read: {exc}", throttle_duration_sec=5.0)
            self._log_connection(self.client.connected, self.client.last_error)
            self._publish(reading)
            self._sleep(period - (time.monotonic() - t0))

    def _sleep(self, seconds: float) -> None:
        self._wake.wait(max(0.0, seconds))  # set at shutdown

    def _log_connection(self, connected: bool, why: str) -> None:
        if connected != self._connected_logged:
            if connected:
                self.get_logger().info(f"connected to the controller at {self.p['arm_ip']}:{self.p['tcp_port']}")
            else:
                self.get_logger().warn(f"controller {self.p['arm_ip']}:{self.p['tcp_port']} not connected: {why}")
            self._connected_logged = connected

    def _mode(self, reading) -> int:
        seq = self.sequence
        if self._estop:
            return ArmState.MODE_ESTOP
        if self.journal_fault is not None:
            return ArmState.MODE_FAULT
        if not self.client.connected:
            return ArmState.MODE_DISCONNECTED
        if reading is not None and reading.error_codes:
            return ArmState.MODE_FAULT
        if self.client.paused:
            return ArmState.MODE_PAUSED
        if seq is not None and seq.running:
            return ArmState.MODE_WELDING if seq.phase in ("weld", "dwell") else ArmState.MODE_MOVING
        if self.rail.moving:
            return ArmState.MODE_MOVING
        return ArmState.MODE_IDLE

    def _publish(self, reading) -> None:
        stamp = self.get_clock().now().to_msg()
        msg = ArmState()
        msg.header.stamp = stamp
        msg.header.frame_id = "world"
        msg.mode = self._mode(reading)
        msg.connected = self.client.connected
        seq = self.sequence
        if seq is not None and seq.running:
            msg.current_stud, msg.done, msg.total = seq.current_stud, seq.done, seq.total
        fault = self.journal_fault
        msg.message = self._fault_text(fault) if fault is not None else self._message
        msg.uncertain_studs = self.uncertain_studs()
        if self.rail.present:
            msg.rail_position_m, msg.rail_moving = self.rail.position_m, self.rail.moving
        if reading is not None:
            self._last_state = reading
            T_tool = self.kin.fk(reading.joints_rad) @ self.tool_T  # weld_tool in base, whatever the controller's tool frame
            if self.rail.present:
                T_tool = self.rail.world_T_base() @ T_tool  # ... in world
            msg.joints = [float(v) for v in reading.joints_rad]
            msg.tool_pose = ros_io.rt_to_pose(T_tool[:3, :3], T_tool[:3, 3])
            msg.error_codes = [int(c) & 0xFFFF for c in reading.error_codes]
            msg.errors = reading.errors_text
            js = JointState()
            js.header.stamp = stamp
            js.name = JOINT_NAMES + ([RAIL_JOINT] if self.rail.present else [])
            js.position = [float(v) for v in reading.joints_rad] + ([self.rail.position_m] if self.rail.present else [])
            self.pub_joints.publish(js)
            if self.pub_camera is not None:
                T_cam = camera_in_world(T_tool, self._hand_eye())
                cam = PoseStamped()
                cam.header.stamp = stamp
                cam.header.frame_id = "world"
                cam.pose = ros_io.rt_to_pose(T_cam[:3, :3], T_cam[:3, 3])
                self.pub_camera.publish(cam)
        self.pub_state.publish(msg)
        self._update_diagnostics(msg)

    def _publish_weld(self, stud_id: str, joints_rad: np.ndarray, job_id: str, world_T_base: np.ndarray | None = None,
                      rail_m: float = 0.0) -> None:
        """A confirmed weld on /arm/welds: the tool pose in world, the base there where the job had it."""
        T_tool = self.kin.fk(joints_rad) @ self.tool_T
        if self.rail.present and world_T_base is not None:
            T_tool = world_T_base @ T_tool
        msg = WeldRecord(stud_id=stud_id, job_id=job_id, joints=[float(v) for v in joints_rad],
                         tool_pose=ros_io.rt_to_pose(T_tool[:3, :3], T_tool[:3, 3]), rail_position_m=float(rail_m))
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = "world"
        self.pub_welds.publish(msg)

    def _hand_eye(self) -> np.ndarray:
        return self.hand_eye.T_tool_cam

    def uncertain_studs(self) -> list[str]:
        """The journal's uncertain studs that wait for an operator decision (/arm/resolve_stud):
        not the stud being welded now -- started and not yet confirmed is every weld's normal course."""
        journal = self.journal
        if journal is None:
            return []
        seq = self.sequence
        busy = seq.current_stud if seq is not None and seq.running else ""
        return sorted(s for s in journal.uncertain_ids if s != busy)

    def _update_diagnostics(self, msg: ArmState) -> None:
        d = self.diag
        journal, fault = self.journal, self.journal_fault
        values = dict(connected=msg.connected, mode=msg.mode, job=f"{msg.done}/{msg.total}",
                      current_stud=msg.current_stud, errors="; ".join(msg.errors) or "none",
                      uncertain_studs=len(msg.uncertain_studs) if journal is not None else "unknown",
                      journal_file=str(self.journal_path),
                      journal_damaged_lines=(", ".join(f"{Path(f).name}:{n}" for f, n in fault.report.lines[:20])
                                             if isinstance(fault, JournalCorrupt) else "none"))
        if self._estop:
            d.set(d.ERROR, "e-stop engaged (publish false on /arm/estop to release)", **values)
        elif fault is not None:
            d.set(d.ERROR, self._fault_text(fault), **values)
        elif not msg.connected:
            d.set(d.ERROR, f"controller not connected: {self.client.last_error}", **values)
        elif msg.errors:
            d.set(d.ERROR, "controller error: " + "; ".join(msg.errors), **values)
        elif msg.uncertain_studs:
            d.set(d.WARN, f"{len(msg.uncertain_studs)} uncertain stud(s) need an operator decision "
                          f"(/arm/resolve_stud): {', '.join(msg.uncertain_studs[:10])}", **values)
        else:
            d.set(d.OK, "connected", **values)
