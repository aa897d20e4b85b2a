"""URDF kinematics without ROS: parse a URDF's links and joints, and chain its joint origins.

What a robot state publisher needs and nothing more (no inertia, collision or meshes): each joint's
parent and child link, its fixed origin (``<origin xyz rpy>``, URDF's roll-pitch-yaw, i.e.
``Rz(yaw) · Ry(pitch) · Rx(roll)``), its axis and type. The transform parent -> child of a joint at
position ``q`` (rad or m) is ``origin · motion(q)``, motion a rotation about the axis for
``revolute``/``continuous`` and a translation along it for ``prismatic``; ``fixed`` joints have none.
Units: metres and radians. Transforms are 4x4 numpy arrays.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from stud_common.rotations import rpy_to_matrix

MOVING_TYPES = ("revolute", "continuous", "prismatic")
JOINT_TYPES = MOVING_TYPES + ("fixed",)


class UrdfError(ValueError):
    """A URDF this module cannot use: the message names the element and the value."""


@dataclass(frozen=True)
class Joint:
    """One URDF joint. ``origin`` (4, 4): parent link -> joint frame at q = 0; ``axis`` (3,): unit
    vector in the joint frame; ``lower``/``upper`` (rad or m) and ``velocity`` from ``<limit>``."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float = -math.inf
    upper: float = math.inf
    velocity: float = math.inf

    @property
    def moving(self) -> bool:
        return self.type in MOVING_TYPES

    def transform(self, q: float = 0.0) -> np.ndarray:
        """Parent link -> child link (4, 4) at joint position ``q``."""
        if not self.moving or q == 0.0:
            return self.origin.copy()
        motion = np.eye(4)
        if self.type == "prismatic":
            motion[:3, 3] = self.axis * q
        else:
            motion[:3, :3] = axis_angle_matrix(self.axis, q)
        return self.origin @ motion


@dataclass(frozen=True)
class RobotModel:
    """A URDF's name, links and joints (in file order), with the tree they form."""

    name: str
    links: tuple[str, ...]
    joints: tuple[Joint, ...]

    @property
    def root(self) -> str:
        children = {j.child for j in self.joints}
        roots = [link for link in self.links if link not in children]
        return roots[0]

    @property
    def moving_joints(self) -> tuple[Joint, ...]:
        return tuple(j for j in self.joints if j.moving)

    @property
    def fixed_joints(self) -> tuple[Joint, ...]:
        return tuple(j for j in self.joints if not j.moving)

    def joint(self, name: str) -> Joint:
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(name)

    def chain(self, root: str, tip: str) -> list[Joint]:
        """Joints from ``root`` down to ``tip`` (``tip`` must descend from ``root``)."""
        by_child = {j.child: j for j in self.joints}
        path: list[Joint] = []
        link = tip
        while link != root:
            if link not in by_child:
                raise UrdfError(f"link '{tip}' is not below '{root}' in robot '{self.name}'")
            joint = by_child[link]
            path.append(joint)
            link = joint.parent
        return path[::-1]

    def frame_transform(self, root: str, tip: str, positions: Mapping[str, float]) -> np.ndarray:
        """``root`` -> ``tip`` (4, 4) for joint ``positions`` (name -> rad or m; missing ones at 0)."""
        T = np.eye(4)
        for joint in self.chain(root, tip):
            T = T @ joint.transform(float(positions.get(joint.name, 0.0)))
        return T


def axis_angle_matrix(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation (3, 3) by ``angle`` (rad) about the unit vector ``axis`` (Rodrigues)."""
    x, y, z = axis
    c, s = math.cos(angle), math.sin(angle)
    C = 1.0 - c
    return np.array([
        [c + x * x * C, x * y * C - z * s, x * z * C + y * s],
        [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
        [z * x * C - y * s, z * y * C + x * s, c + z * z * C],
    ])


def origin_matrix(xyz, rpy) -> np.ndarray:
    """URDF ``<origin xyz rpy>`` -> 4x4."""
    T = np.eye(4)
    T[:3, :3] = rpy_to_matrix(*[float(v) for v in rpy])
    T[:3, 3] = [float(v) for v in xyz]
    return T


def _floats(text: str | None, count: int, where: str, default: tuple[float, ...]) -> tuple[float, ...]:
    if text is None:
        return default
    try:
        values = tuple(float(v) for v in text.split())
    except ValueError:
        raise UrdfError(f"{where}: '{text}' is not {count} numbers") from None
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise UrdfError(f"{where}: '{text}' is not {count} finite numbers")
    return values


def parse_urdf(text: str) -> RobotModel:
    """A URDF document -> :class:`RobotModel`. Raises :class:`UrdfError` for a document that is not
    a tree of known joint types over declared links."""
    try:
        robot = ET.fromstring(text)
    except ET.ParseError as exc:
        raise UrdfError(f"not valid XML: {exc}") from None
    if robot.tag != "robot":
        raise UrdfError(f"the root element is <{robot.tag}>, expected <robot>")
    links = tuple(link.get("name", "") for link in robot.findall("link"))
    if not links or "" in links:
        raise UrdfError("every <link> needs a name, and a robot needs at least one")
    joints = []
    for el in robot.findall("joint"):
        name = el.get("name", "")
        jtype = el.get("type", "")
        where = f"joint '{name}'"
        if jtype not in JOINT_TYPES:
            raise UrdfError(f"{where}: type '{jtype}' is not one of {list(JOINT_TYPES)}")
        parent, child = el.find("parent"), el.find("child")
        if parent is None or child is None:
            raise UrdfError(f"{where}: needs <parent link> and <child link>")
        origin = el.find("origin")
        xyz = _floats(origin.get("xyz") if origin is not None else None, 3, f"{where} origin xyz", (0.0,) * 3)
        rpy = _floats(origin.get("rpy") if origin is not None else None, 3, f"{where} origin rpy", (0.0,) * 3)
        axis_el = el.find("axis")
        axis = np.array(_floats(axis_el.get("xyz") if axis_el is not None else None, 3, f"{where} axis",
                                (1.0, 0.0, 0.0)))
        if jtype in MOVING_TYPES:
            norm = float(np.linalg.norm(axis))
            if norm < 1e-12:
                raise UrdfError(f"{where}: the axis is zero")
            axis = axis / norm
        limit = el.find("limit")
        lower = upper = velocity = None
        if limit is not None:
            lower = float(limit.get("lower", "0"))
            upper = float(limit.get("upper", "0"))
            velocity = float(limit.get("velocity", "inf"))
        if jtype in ("revolute", "prismatic") and limit is None:
            raise UrdfError(f"{where}: a {jtype} joint needs <limit>")
        joints.append(Joint(
            name=name, type=jtype, parent=parent.get("link", ""), child=child.get("link", ""),
            origin=origin_matrix(xyz, rpy), axis=axis,
            lower=lower if lower is not None and jtype != "continuous" else -math.inf,
            upper=upper if upper is not None and jtype != "continuous" else math.inf,
            velocity=velocity if velocity is not None else math.inf))
    model = RobotModel(name=robot.get("name", ""), links=links, joints=tuple(joints))
    _check_tree(model)
    return model


def _check_tree(model: RobotModel) -> None:
    known = set(model.links)
    seen_children: set[str] = set()
    for j in model.joints:
        for role, link in (("parent", j.parent), ("child", j.child)):
            if link not in known:
                raise UrdfError(f"joint '{j.name}': {role} link '{link}' is not declared")
        if j.child in seen_children:
            raise UrdfError(f"link '{j.child}' has two parents (joint '{j.name}')")
        seen_children.add(j.child)
    roots = [link for link in model.links if link not in seen_children]
    if len(roots) != 1:
        raise UrdfError(f"the links form {len(roots)} trees (roots {roots}), a URDF is one tree")
