"""The simulated workcell that every simulated device reads.

One scene: the PUMA 560 on its pedestal at the world origin (the robot's base
frame *is* the world frame), a table in front of it, a stiff block on the table to
push against, fiducial points near the work area (the thesis's four non-coplanar
ones, §5.3.1, the rest of the 0.2 m cube they span and four markers near the
table's corners, for perspective fits), and
a stereo pair of pinhole cameras 1.5–2 m away with a configurable baseline. The
cameras' ground-truth projections are exact, so
calibration and AR can be checked against them.

Camera convention: OpenCV's (x right, y down, z forward); pixels (u, v) with the
origin at the top-left corner of the image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from telerobot.drivers.base import FloatArray, InvalidCommand


@dataclass(frozen=True)
class Box:
    """An axis-aligned solid that the gripper can push into."""

    name: str
    centre: FloatArray  # (3,) metres
    size: FloatArray  # (3,) full extents, metres
    colour: tuple[int, int, int]  # RGB for rendering
    stiffness: float  # N/m, contact spring
    damping: float  # N·s/m, contact damper

    @property
    def lower(self) -> FloatArray:
        return self.centre - self.size / 2

    @property
    def upper(self) -> FloatArray:
        return self.centre + self.size / 2

    def corners(self) -> FloatArray:
        lo, hi = self.lower, self.upper
        return np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )

    def penetration(self, point: FloatArray) -> tuple[float, FloatArray]:
        """How deep ``point`` is inside the box and the outward normal of the nearest
        face; (0, zero vector) when it is outside."""
        p = np.asarray(point, dtype=float)
        below = p - self.lower
        above = self.upper - p
        if np.any(below < 0) or np.any(above < 0):
            return 0.0, np.zeros(3)
        depths = np.concatenate([below, above])
        k = int(np.argmin(depths))
        normal = np.zeros(3)
        normal[k % 3] = -1.0 if k < 3 else 1.0
        return float(depths[k]), normal


@dataclass(frozen=True)
class PinholeCamera:
    """A ground-truth pinhole camera: pixel = K (R X + t), no distortion."""

    name: str
    width: int
    height: int
    K: FloatArray  # (3, 3) intrinsics
    R: FloatArray  # (3, 3) world → camera rotation
    t: FloatArray  # (3,) world → camera translation

    @classmethod
    def look_at(
        cls,
        name: str,
        position: FloatArray,
        target: FloatArray,
        *,
        up: FloatArray | None = None,
        width: int = 1280,
        height: int = 720,
        hfov_deg: float = 60.0,
    ) -> PinholeCamera:
        position = np.asarray(position, dtype=float)
        forward = np.asarray(target, dtype=float) - position
        if np.linalg.norm(forward) < 1e-9:
            raise InvalidCommand("camera position and target coincide")
        z = forward / np.linalg.norm(forward)
        world_up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=float)
        x = np.cross(z, world_up)  # image right
        if np.linalg.norm(x) < 1e-9:
            raise InvalidCommand("camera looks straight along its up vector")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)  # image down
        R = np.vstack([x, y, z])
        f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
        K = np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
        return cls(name, width, height, K, R, -R @ position)

    @property
    def position(self) -> FloatArray:
        """Optical centre in the world frame."""
        result: FloatArray = -self.R.T @ self.t
        return result

    @property
    def P(self) -> FloatArray:
        """3×4 projection matrix K [R | t]."""
        result: FloatArray = self.K @ np.hstack([self.R, self.t[:, None]])
        return result

    def to_camera(self, points: FloatArray) -> FloatArray:
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        result: FloatArray = pts @ self.R.T + self.t
        return result

    def project(self, points: FloatArray) -> FloatArray:
        """World points (N×3) to pixels (N×2); NaN for points behind the camera."""
        pc = self.to_camera(points)
        uvw = pc @ self.K.T
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = uvw[:, :2] / uvw[:, 2:3]
        uv[pc[:, 2] <= 1e-9] = np.nan
        return uv

    def in_view(self, points: FloatArray) -> np.ndarray:
        uv = self.project(points)
        with np.errstate(invalid="ignore"):
            return (
                (uv[:, 0] >= 0)
                & (uv[:, 0] < self.width)
                & (uv[:, 1] >= 0)
                & (uv[:, 1] < self.height)
            )


@dataclass(frozen=True)
class StereoRig:
    left: PinholeCamera
    right: PinholeCamera

    @property
    def baseline(self) -> float:
        return float(np.linalg.norm(self.right.position - self.left.position))


@dataclass(frozen=True)
class Workcell:
    table: Box
    block: Box
    fiducials: FloatArray  # (12, 3): origin, 0.2 m along x, y, z; the cube; table corners
    rig: StereoRig
    work_centre: FloatArray  # (3,) where the cameras look
    obstacles: tuple[Box, ...] = field(default=())
    scale: float = 1.0  # of the PUMA-sized scene: what is drawn is sized with it
    pedestal_m: float = 0.6  # the arm's pedestal, from the floor to its base (0: none)
    # Each arm's base in this scene's frame (4×4), in the server's arm order; the first
    # arm's base is the scene's frame, so one arm needs none.
    mounts: tuple[FloatArray, ...] = field(default=())

    def seen_from(self, base: FloatArray) -> Workcell:
        """This scene in the frame of an arm based at ``base`` (4×4 in this scene's
        frame): what that arm's force sensor feels is computed in its own frame. Boxes
        stay axis-aligned: exact for a base turned by a multiple of 90°, their bounding
        box otherwise."""
        R, t = base[:3, :3], base[:3, 3]
        if np.allclose(R, np.eye(3)) and np.allclose(t, 0.0):
            return self

        def moved(box: Box) -> Box:
            return replace(box, centre=R.T @ (box.centre - t), size=np.abs(R.T) @ box.size)

        table, block = moved(self.table), moved(self.block)
        others = tuple(moved(b) for b in self.obstacles if b not in (self.table, self.block))
        return replace(self, table=table, block=block, obstacles=(table, block, *others))

    def contact(self, point: FloatArray) -> tuple[Box | None, float, FloatArray]:
        """The obstacle ``point`` is deepest in, its penetration depth and outward normal."""
        best: tuple[Box | None, float, FloatArray] = (None, 0.0, np.zeros(3))
        for box in self.obstacles:
            depth, normal = box.penetration(point)
            if depth > best[1]:
                best = (box, depth, normal)
        return best


def mount_transform(mount: tuple[float, float, float, float] | None) -> FloatArray:
    """x, y, z (m) and a turn about z (°) as a 4×4 transform; None: the identity."""
    T = np.eye(4)
    if mount is None:
        return T
    x, y, z, yaw = mount
    c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = [x, y, z]
    return T


def facing_mounts(
    scale: float, offset: tuple[float, float, float]
) -> tuple[FloatArray, FloatArray]:
    """Two arms facing each other across the table (as LeRobot's bimanual setups and
    ALOHA stand): the first at the origin, looking along +x, the second at the far side
    of the table, turned 180°. The table's centre is where one arm's scene has it."""
    return mount_transform(None), mount_transform((2 * bimanual_centre(scale, offset), 0, 0, 180))


def bimanual_centre(scale: float, offset: tuple[float, float, float]) -> float:
    """x of the two-arm table's centre: where the one-arm scene has its table."""
    return 0.70 * scale + offset[0]


def stereo_rig(
    target: FloatArray,
    *,
    distance: float = 1.8,
    baseline: float = 0.12,
    azimuth_deg: float = 20.0,
    elevation_deg: float = 25.0,
    width: int = 1280,
    height: int = 720,
    hfov_deg: float = 60.0,
) -> StereoRig:
    """Two parallel cameras ``distance`` metres from ``target``, seen from in front of
    the robot (+x), ``azimuth_deg`` to the side and ``elevation_deg`` above it."""
    if not 0.1 <= distance <= 20 or not 0.0 < baseline < 2.0:
        raise InvalidCommand("camera distance must be 0.1–20 m and baseline 0–2 m")
    target = np.asarray(target, dtype=float)
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    direction = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    centre = target + distance * direction
    forward = -direction
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    half = right * baseline / 2
    # Parallel optical axes (a rectified rig, like a stereo camera), both aimed along `forward`.
    cams = [
        PinholeCamera.look_at(
            name,
            centre + s * half,
            centre + s * half + forward,
            width=width,
            height=height,
            hfov_deg=hfov_deg,
        )
        for name, s in (("left", -1.0), ("right", 1.0))
    ]
    return StereoRig(cams[0], cams[1])


# The two-arm scene's cameras stand this much further back than the one-arm scene's,
# aimed this high (PUMA-sized metres): both arms are seen whole, reaching up or out.
TWO_ARM_DISTANCE = 1.3
TWO_ARM_TARGET_Z = 0.6


def default_workcell(
    *,
    camera_distance: float = 1.8,
    baseline: float = 0.12,
    width: int = 1280,
    height: int = 720,
    block_stiffness: float = 5.0e4,
    block_damping: float = 80.0,
    scale: float = 1.0,
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    pedestal_m: float = 0.6,
    mounts: tuple[FloatArray, ...] = (),
) -> Workcell:
    """The scene sized for the PUMA 560; another arm gets it ``scale``d about the base
    and moved by ``offset`` (its model's ``scene``): the same table, block, fiducials and
    camera view, in reach of a smaller arm. ``camera_distance`` and ``baseline`` are the
    PUMA-sized ones, scaled with the rest.

    With two ``mounts`` or more it is the two-arm workcell: the table between the arms
    (``facing_mounts``), the block in its middle where both reach it, the fiducials moved
    with the table, and the cameras looking across from the first arm's right (its
    ``-y``) and further back (``TWO_ARM_DISTANCE``), so the first arm is on the left of
    the picture and both are seen whole."""
    if not 0.05 <= scale <= 5.0:
        raise InvalidCommand(f"the scene's scale must be 0.05–5, not {scale}")
    shift = np.asarray(offset, dtype=float)

    def at(*xyz: float) -> FloatArray:
        result: FloatArray = scale * np.array(xyz, dtype=float) + shift
        return result

    table_top = 0.40
    table = Box(
        "table",
        centre=at(0.70, -0.10, table_top - 0.025),
        size=scale * np.array([0.70, 1.00, 0.05]),
        colour=(150, 111, 74),
        stiffness=2.0e4,
        damping=50.0,
    )
    two = len(mounts) > 1
    if two:  # the table between the arms, centred on the line between their bases
        table = replace(table, centre=at(0.70, 0.0, table_top - 0.025))
    block = Box(
        "block",
        centre=at(0.70, 0.0, table_top + 0.05) if two else at(0.65, -0.30, table_top + 0.05),
        size=scale * np.array([0.10, 0.10, 0.10]),
        colour=(200, 60, 50),
        stiffness=block_stiffness,
        damping=block_damping,
    )
    origin = np.array([0.55, 0.05, table_top])
    # The thesis's affine basis first (origin, then 0.2 m along x, y, z), then the other
    # corners of that 0.2 m cube (balls on posts), then four markers near the table's
    # corners: a perspective fit extrapolates badly beyond the points it was given, so
    # they span the whole work area (bench.ar_registration: DLT p95 2–5 px → ≤ 1.6 px).
    cube = origin + 0.2 * np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, 0, 1], [0, 1, 1], [1, 1, 1]],
        dtype=float,
    )
    corners = np.array(
        [[0.42, -0.55, table_top], [0.98, -0.55, table_top], [0.42, 0.35, table_top],
         [0.98, 0.35, table_top]]
    )  # fmt: skip
    if two:  # on the table as it moved: its corner markers stay on its corners
        cube, corners = cube + [0.0, 0.10, 0.0], corners + [0.0, 0.10, 0.0]
    fiducials = scale * np.vstack([cube, corners]) + shift
    centre = at(0.70, 0.0, TWO_ARM_TARGET_Z) if two else at(0.65, -0.15, 0.55)
    rig = stereo_rig(
        centre,
        distance=scale * camera_distance * (TWO_ARM_DISTANCE if two else 1.0),
        baseline=scale * baseline,
        azimuth_deg=-70.0 if two else 20.0,
        width=width,
        height=height,
    )
    return Workcell(
        table,
        block,
        fiducials,
        rig,
        centre,
        obstacles=(table, block),
        scale=scale,
        pedestal_m=pedestal_m,
        mounts=tuple(mounts),
    )
