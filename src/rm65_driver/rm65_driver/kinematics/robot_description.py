"""The RM-65-B robot model (URDF) written from our modified-DH kinematics, with the weld gun and camera.

The URDF's joints are the DH table (:class:`rm65_driver.kinematics.rm65.DHModel`) in URDF form. A
modified-DH link transform is ``RotX(alpha_{i-1}) · TransX(a_{i-1}) · RotZ(q_i + offset_i) ·
TransZ(d_i)``; since ``RotZ(q)`` commutes with ``TransZ(d)`` it equals ``F_i · RotZ(q_i)`` with the
fixed ``F_i = RotX(alpha_{i-1}) · TransX(a_{i-1}) · RotZ(offset_i) · TransZ(d_i)``: ``F_i`` is joint
i's ``<origin>``, its axis is z, and link i's frame is DH frame i. The flange distance d6 is moved
out of joint 6 into a fixed joint ``link6 -> rm65_flange`` (same product, and the variant's d6 is
one number in one place). Then ``rm65_flange -> weld_tool`` (the tool offset along flange z, as the
driver's ``tool_offset_m``), and ``weld_tool -> camera_color_optical_frame`` (the hand-eye).

On a rail (``rail_length_m`` > 0) ``world`` is the rail's frame and the arm rides it: a prismatic
``rail_joint`` ``world -> carriage`` along x (0 .. ``rail_length_m``, metres) and a fixed
``rail_mount_joint`` ``carriage -> base_link`` (``rail_mount_xyz_m``) replace the fixed
``world_joint``; a ``rail`` link fixed to ``world`` shows the rail. Without a rail the fixed
``world_joint`` places ``base_link`` in ``world``.

The shapes are plain cylinders and spheres along the links, enough to see the arm's pose in a
viewer; no meshes, no inertia (RealMan publishes masses, not inertia tensors we could check).
``urdf/rm65.urdf`` in this package is :func:`rm65_urdf` at its defaults (a test keeps them equal).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

import numpy as np

from rm65_driver.kinematics.rm65 import D6_BY_VARIANT, JOINT_LIMITS_DEG, JOINT_MAX_SPEED_DEG_S, DHModel
from stud_common import frames
from stud_common.rotations import matrix_to_rpy, rpy_to_matrix

JOINT_NAMES = tuple(f"joint{i}" for i in range(1, 7))
LINK_NAMES = tuple(f"link{i}" for i in range(1, 7))
_ARM_RADIUS_M = 0.04
_GUN_RADIUS_M = 0.02


@dataclass(frozen=True)
class RM65Description:
    """What varies between cells: the arm variant (its d6), the tool offset (m, along flange z) and
    the hand-eye (camera optical frame in ``weld_tool``: xyz in m, roll-pitch-yaw in deg)."""

    variant: str = "RM65-B"
    tool_offset_m: float = 0.15
    hand_eye_xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    hand_eye_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    include_camera: bool = True
    dh: DHModel = field(default=None)  # type: ignore[assignment]
    rail_length_m: float = 0.0  # 0: no rail (world = the arm's base)
    rail_mount_xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # carriage -> base_link
    rail_max_speed_m_s: float = 0.5  # rail_joint's velocity limit

    def __post_init__(self) -> None:
        if self.variant not in D6_BY_VARIANT:
            raise ValueError(f"arm variant '{self.variant}' is not one of {list(D6_BY_VARIANT)}")
        if self.dh is None:
            object.__setattr__(self, "dh", DHModel.rm65(D6_BY_VARIANT[self.variant]))
        if not (math.isfinite(self.rail_length_m) and self.rail_length_m >= 0):
            raise ValueError(f"rail_length_m={self.rail_length_m}: expected a finite number >= 0")

    @property
    def hand_eye(self) -> np.ndarray:
        """``weld_tool`` -> ``camera_color_optical_frame`` (4, 4)."""
        T = np.eye(4)
        T[:3, :3] = rpy_to_matrix(*np.radians(self.hand_eye_rpy_deg))
        T[:3, 3] = self.hand_eye_xyz_m
        return T


def dh_joint_origin(dh: DHModel, i: int, include_d: bool = True) -> np.ndarray:
    """``F_i`` (4, 4) of joint ``i`` (0-based): the fixed part of the modified-DH link transform."""
    ca, sa = math.cos(dh.alpha[i]), math.sin(dh.alpha[i])
    co, so = math.cos(dh.offset[i]), math.sin(dh.offset[i])
    rot_x = np.array([[1, 0, 0, 0], [0, ca, -sa, 0], [0, sa, ca, 0], [0, 0, 0, 1.0]])
    trans_x = np.eye(4)
    trans_x[0, 3] = dh.a[i]
    rot_z = np.array([[co, -so, 0, 0], [so, co, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    trans_z = np.eye(4)
    trans_z[2, 3] = dh.d[i] if include_d else 0.0
    return rot_x @ trans_x @ rot_z @ trans_z


def _clean(v: float) -> float:
    """Round to 1e-12 (no ``6.1e-17`` from cos(90°) in the file) and drop a negative zero."""
    r = round(float(v), 12)
    return 0.0 if r == 0.0 else r


def _fmt(values) -> str:
    return " ".join(f"{_clean(v):.12g}" for v in values)


def _origin(T: np.ndarray) -> str:
    return f'<origin xyz="{_fmt(T[:3, 3])}" rpy="{_fmt(matrix_to_rpy(T[:3, :3]))}"/>'


def _cylinder_between(vector: np.ndarray, radius: float, material: str) -> str:
    """A visual cylinder from the link's origin to ``vector`` (m, link frame)."""
    length = float(np.linalg.norm(vector))
    z = vector / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = vector / 2.0
    return (f"    <visual>\n      {_origin(T)}\n      <geometry><cylinder radius=\"{radius:g}\" "
            f"length=\"{_clean(length):.12g}\"/></geometry>\n      <material name=\"{material}\"/>\n    </visual>\n")


def _box(size, center, material: str) -> str:
    return (f"    <visual>\n      <origin xyz=\"{_fmt(center)}\" rpy=\"0 0 0\"/>\n"
            f"      <geometry><box size=\"{_fmt(size)}\"/></geometry>\n"
            f"      <material name=\"{material}\"/>\n    </visual>\n")


def _sphere(radius: float, material: str) -> str:
    return (f"    <visual>\n      <geometry><sphere radius=\"{radius:g}\"/></geometry>\n"
            f"      <material name=\"{material}\"/>\n    </visual>\n")


def _urdf_head(desc: RM65Description) -> list[str]:
    """The document's start: the XML declaration, the generator's comment, the robot element, the materials."""
    return [
        '<?xml version="1.0"?>\n',
        "<!-- RealMan RM-65 (variant " + desc.variant + ") with a stud-welding gun and an eye-in-hand RGB-D camera.\n"
        "     Generated by rm65_driver.kinematics.robot_description from the arm's modified-DH table"
        " (docs/FRAMES.md):\n"
        "     joint i's origin is RotX(alpha_{i-1}) TransX(a_{i-1}) RotZ(offset_i) TransZ(d_i), its axis z.\n"
        "     Metres and radians. Joint effort limits are not documented by RealMan: 0 here. -->\n",
        '<robot name="rm65">\n',
        '  <material name="arm_white"><color rgba="0.92 0.92 0.92 1"/></material>\n'
        '  <material name="joint_grey"><color rgba="0.35 0.35 0.38 1"/></material>\n'
        '  <material name="gun_copper"><color rgba="0.80 0.45 0.20 1"/></material>\n'
        '  <material name="camera_black"><color rgba="0.10 0.10 0.12 1"/></material>\n',
        '  <material name="rail_grey"><color rgba="0.55 0.57 0.60 1"/></material>\n' if desc.rail_length_m > 0 else "",
    ]


def rm65_urdf(desc: RM65Description = RM65Description()) -> str:
    """The URDF document of the arm, gun and camera for ``desc``."""
    dh = desc.dh
    origins = [dh_joint_origin(dh, i, include_d=i < 5) for i in range(6)]
    flange = np.eye(4)
    flange[2, 3] = dh.d[5]
    tool = np.eye(4)
    tool[2, 3] = desc.tool_offset_m
    limits = np.radians(JOINT_LIMITS_DEG)
    speeds = np.radians(JOINT_MAX_SPEED_DEG_S)

    # Each link's visual: a sphere at its joint and a cylinder to the next joint's origin.
    child_offset = {frames.BASE_LINK: origins[0][:3, 3]}
    for i in range(5):
        child_offset[LINK_NAMES[i]] = origins[i + 1][:3, 3]
    child_offset[LINK_NAMES[5]] = flange[:3, 3]

    def link(name: str, body: str = "") -> str:
        return f"  <link name={quoteattr(name)}>\n{body}  </link>\n" if body else f"  <link name={quoteattr(name)}/>\n"

    def arm_body(name: str) -> str:
        body = _sphere(_ARM_RADIUS_M * 1.15, "joint_grey") if name != frames.BASE_LINK else ""
        offset = child_offset[name]
        if np.linalg.norm(offset) > 1e-9:
            body += _cylinder_between(offset, _ARM_RADIUS_M, "arm_white")
        return body

    def joint(name: str, jtype: str, parent: str, child: str, T: np.ndarray, extra: str = "") -> str:
        return (f"  <joint name={quoteattr(name)} type=\"{jtype}\">\n    <parent link={quoteattr(parent)}/>\n"
                f"    <child link={quoteattr(child)}/>\n    {_origin(T)}\n{extra}  </joint>\n")

    out = [*_urdf_head(desc), link(frames.WORLD)]
    if desc.rail_length_m > 0:
        L = desc.rail_length_m
        mount = np.eye(4)
        mount[:3, 3] = desc.rail_mount_xyz_m
        out += [
            joint("rail_base_joint", "fixed", frames.WORLD, "rail", np.eye(4)),
            link("rail", _box((L + 0.3, 0.12, 0.04), (L / 2, 0.0, -0.06), "rail_grey")),
            joint(frames.RAIL_JOINT, "prismatic", frames.WORLD, frames.CARRIAGE, np.eye(4),
                  f"    <axis xyz=\"1 0 0\"/>\n    <limit lower=\"0\" upper=\"{_clean(L):.12g}\" effort=\"0\" "
                  f"velocity=\"{_clean(desc.rail_max_speed_m_s):.12g}\"/>\n"),
            link(frames.CARRIAGE, _box((0.30, 0.25, 0.04), (0.0, 0.0, -0.02), "joint_grey")),
            joint("rail_mount_joint", "fixed", frames.CARRIAGE, frames.BASE_LINK, mount),
        ]
    else:
        out.append(joint("world_joint", "fixed", frames.WORLD, frames.BASE_LINK, np.eye(4)))
    out.append(link(frames.BASE_LINK, arm_body(frames.BASE_LINK)))
    parent = frames.BASE_LINK
    for i in range(6):
        extra = (f"    <axis xyz=\"0 0 1\"/>\n    <limit lower=\"{_clean(limits[i, 0]):.12g}\" "
                 f"upper=\"{_clean(limits[i, 1]):.12g}\" effort=\"0\" velocity=\"{_clean(speeds[i]):.12g}\"/>\n")
        out.append(joint(JOINT_NAMES[i], "revolute", parent, LINK_NAMES[i], origins[i], extra))
        out.append(link(LINK_NAMES[i], arm_body(LINK_NAMES[i])))
        parent = LINK_NAMES[i]
    out.append(joint("flange_joint", "fixed", LINK_NAMES[5], frames.FLANGE, flange))
    out.append(link(frames.FLANGE))
    # The gun: a body on the flange (its own link, for viewers) and its tip frame weld_tool.
    out.append(joint("weld_gun_joint", "fixed", frames.FLANGE, "weld_gun", np.eye(4)))
    gun_body = _cylinder_between(tool[:3, 3], _GUN_RADIUS_M, "gun_copper") if desc.tool_offset_m > 1e-9 else ""
    out.append(link("weld_gun", gun_body))
    out.append(joint("weld_tool_joint", "fixed", frames.FLANGE, frames.WELD_TOOL, tool))
    out.append(link(frames.WELD_TOOL))
    if desc.include_camera:
        out.append(joint("camera_joint", "fixed", frames.WELD_TOOL, frames.CAMERA_OPTICAL, desc.hand_eye))
        out.append(link(frames.CAMERA_OPTICAL,
                        "    <visual>\n      <origin xyz=\"0 0 -0.015\" rpy=\"0 0 0\"/>\n"
                        "      <geometry><box size=\"0.09 0.025 0.03\"/></geometry>\n"
                        "      <material name=\"camera_black\"/>\n    </visual>\n"))
    out.append("</robot>\n")
    return "".join(out)
