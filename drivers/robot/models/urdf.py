"""A small URDF writer: links drawn with primitives, revolute and fixed joints.

Models are written as data (``Joint`` rows) and turned into URDF text here, so one
description serves Pinocchio (kinematics), the simulated cameras (link segments) and
the page (three.js draws the same URDF). Geometry is primitives only: cylinders from
one joint to the next, as a schematic arm; no meshes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import numpy as np

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Joint:
    """One joint: ``origin`` places it in its parent link's frame (xyz, then roll-pitch-
    yaw as URDF applies them); ``limits`` None makes it fixed."""

    name: str
    parent: str
    child: str
    xyz: Vec3
    rpy: Vec3 = (0.0, 0.0, 0.0)
    axis: Vec3 = (0.0, 0.0, 1.0)
    limits: tuple[float, float] | None = None  # radians; None: a fixed joint
    effort: float = 100.0
    velocity: float = 2.0


@dataclass(frozen=True)
class Segment:
    """A cylinder drawn in ``link`` from ``start`` to ``end`` (link frame, metres)."""

    link: str
    start: Vec3
    end: Vec3
    radius: float


def _fmt(v: Sequence[float]) -> str:
    return " ".join(repr(float(x)) for x in v)  # exact: the shortest round trip


def _along(direction: np.ndarray) -> Vec3:
    """Roll-pitch-yaw turning a cylinder's z axis onto ``direction``."""
    x, y, z = direction / np.linalg.norm(direction)
    pitch = math.acos(max(-1.0, min(1.0, z)))  # about y, then yaw about z
    yaw = math.atan2(y, x) if math.hypot(x, y) > 1e-12 else 0.0
    return (0.0, pitch, yaw)


def _visual(segment: Segment) -> str:
    a, b = np.array(segment.start, float), np.array(segment.end, float)
    length = float(np.linalg.norm(b - a))
    if length < 1e-6:
        return ""
    rpy = _along(b - a)
    return (
        f'    <visual><origin xyz="{_fmt((a + b) / 2)}" rpy="{_fmt(rpy)}"/>'
        f'<geometry><cylinder radius="{segment.radius:.6g}" length="{length:.6g}"/></geometry>'
        '<material name="arm"/></visual>\n'
    )


def write_urdf(name: str, joints: Sequence[Joint], segments: Sequence[Segment] = ()) -> str:
    """URDF text for a serial chain: the links are the joints' parents and children."""
    links: list[str] = []
    for joint in joints:
        for link in (joint.parent, joint.child):
            if link not in links:
                links.append(link)
    out = [f'<?xml version="1.0"?>\n<robot name={quoteattr(name)}>\n']
    out.append('  <material name="arm"><color rgba="0.85 0.55 0.15 1"/></material>\n')
    for link in links:
        visuals = "".join(_visual(s) for s in segments if s.link == link)
        # A small inertia on every link: Pinocchio and viewers expect one; the
        # kinematics does not use it.
        out.append(
            f"  <link name={quoteattr(link)}>\n{visuals}"
            '    <inertial><mass value="0.1"/>'
            '<inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial>\n'
            "  </link>\n"
        )
    for j in joints:
        kind = "fixed" if j.limits is None else "revolute"
        out.append(
            f"  <joint name={quoteattr(j.name)} type={quoteattr(kind)}>\n"
            f"    <parent link={quoteattr(j.parent)}/><child link={quoteattr(j.child)}/>\n"
            f'    <origin xyz="{_fmt(j.xyz)}" rpy="{_fmt(j.rpy)}"/>\n'
        )
        if j.limits is not None:
            out.append(
                f'    <axis xyz="{_fmt(j.axis)}"/>\n'
                f'    <limit lower="{j.limits[0]:.9g}" upper="{j.limits[1]:.9g}" '
                f'effort="{j.effort:g}" velocity="{j.velocity:g}"/>\n'
            )
        out.append("  </joint>\n")
    out.append("</robot>\n")
    return "".join(out)


def dh_chain(
    dh: Sequence[tuple[float, float, float]],
    qlim: np.ndarray,
    *,
    radius: float = 0.04,
) -> tuple[list[Joint], list[Segment]]:
    """Joints and drawing segments for a standard-DH arm (joint i: Rz(q) Tz(d) Tx(a)
    Rx(alpha)): joint i sits at the previous row's Tz(d) Tx(a) Rx(alpha), and the
    last row places the flange."""
    joints: list[Joint] = []
    segments: list[Segment] = []
    placement: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the previous row's d, a, alpha
    for i, row in enumerate(dh):
        d, a, alpha = placement
        parent = f"link{i}"
        joints.append(
            Joint(
                f"joint{i + 1}",
                parent,
                f"link{i + 1}",
                (a, 0.0, d),
                (alpha, 0.0, 0.0),
                limits=(float(qlim[i, 0]), float(qlim[i, 1])),
            )
        )
        # Drawn along z by d, then along x by a, as the DH row moves.
        segments.append(Segment(parent, (0.0, 0.0, 0.0), (0.0, 0.0, d), radius))
        segments.append(Segment(parent, (0.0, 0.0, d), (a, 0.0, d), radius))
        placement = row
    d, a, alpha = placement
    joints.append(Joint("flange_joint", f"link{len(dh)}", "flange", (a, 0.0, d), (alpha, 0, 0)))
    return joints, segments


def origin_matrix(xyz: Vec3, rpy: Vec3) -> np.ndarray:
    """The 4×4 transform of a URDF origin (rotation Rz(yaw) Ry(pitch) Rx(roll))."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    T = np.eye(4)
    T[:3, :3] = np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )
    T[:3, 3] = xyz
    return T


def chain_segments(joints: Sequence[Joint], radius: float) -> list[Segment]:
    """A cylinder in each link from its origin to each joint it carries: the arm drawn
    as the straight lines between its joints."""
    return [Segment(j.parent, (0.0, 0.0, 0.0), j.xyz, radius) for j in joints]
