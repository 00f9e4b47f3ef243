"""Device interfaces and typed errors shared by every driver (docs/architecture.md, rule 1).

Simulated and real devices implement the same small interface; the server never
asks which one it holds (docs/architecture.md, rule 14: what it needs is on the
interface). Units are SI: metres, radians, seconds.

Every driver class is built the same way: ``from_settings(settings, context)`` reads
its own keys from the server's settings (a plain mapping: drivers never import the
server) through a small config class beside it, and takes what the server makes once
and shares from the ``DeviceContext``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import IntEnum, StrEnum
from typing import TYPE_CHECKING, Any, Protocol, Self, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from telerobot.drivers.clock import Clock
from telerobot.drivers.events import Event

if TYPE_CHECKING:  # both import this module
    from telerobot.drivers.robot.kinematics import ArmKinematics
    from telerobot.drivers.robot.models import RobotModel
    from telerobot.drivers.sim.workcell import Workcell

FloatArray = NDArray[np.float64]


# ---------------------------------------------------------------- errors
class TelerobotError(Exception):
    """Base of every error a person may see. Each class says once what it is:
    ``code`` (stable, in problem+json and, mapped by ``messages.ERROR_CODES``, on the
    wire). Drivers know no HTTP: the server maps their errors to statuses
    (``telerobot.server.errors``)."""

    code = "telerobot_error"

    @classmethod
    def with_code(cls, code: str) -> type[TelerobotError] | None:
        """The most specific class of this family with ``code`` (an error that crossed
        a process boundary by its code, e.g. from the media worker)."""
        own = cls is TelerobotError or "code" in vars(cls)  # not one that inherits its code
        found: type[TelerobotError] | None = cls if own and cls.code == code else None
        for sub in cls.__subclasses__():
            deeper = sub.with_code(code)
            if deeper is not None:
                found = deeper
        return found


class InvalidCommand(TelerobotError, ValueError):
    """The command itself is wrong (NaN, wrong size, not a rotation …); nothing moved."""

    code = "invalid_command"


class UnreachablePose(InvalidCommand):
    """No joint configuration reaches the pose; nothing moved."""

    code = "unreachable_pose"


class JointLimitError(InvalidCommand):
    """The target is past a joint limit; nothing moved."""

    code = "joint_limit"


class NotReady(TelerobotError):
    """The device is not in a state that accepts this command; nothing moved."""

    code = "not_ready"


class DeviceError(TelerobotError):
    """The device or its link failed (timeout, garbled reply, port gone)."""

    code = "device_error"


class DriverUnavailable(TelerobotError):
    """The chosen driver is unknown or its SDK is not installed."""

    code = "driver_unavailable"


# ---------------------------------------------------------------- robot
@dataclass(frozen=True)
class SerialSettings:
    """RS-232 link settings (the thesis's Communication Settings property)."""

    port: str = "/dev/ttyS0"  # or a pty path, socket://host:port, loop://
    baudrate: int = 9600
    bytesize: int = 8
    parity: str = "N"
    stopbits: float = 1
    reply_timeout: float = 1.0  # seconds to wait for any reply
    move_margin: float = 2.0  # seconds past the controller's own estimate before a move is late


class RobotStatus(StrEnum):
    NOT_CONNECTED = "NOT_CONNECTED"
    CONNECTED = "CONNECTED"
    WAITING = "WAITING"  # initialising
    READY = "READY"
    MOVING = "MOVING"
    ERROR = "ERROR"


class WorkingFrame(StrEnum):
    """Frame in which Cartesian increments are expressed (thesis §4.3.1)."""

    BASE = "base"  # translate along and rotate about the base axes, pivoting at the tool point
    WRIST = "wrist"  # increments in the wrist (flange) frame, pivoting at the wrist centre
    TOOL = "tool"  # increments in the tool frame, pivoting at the tool point


@dataclass(frozen=True)
class Pose:
    position: FloatArray  # (3,) metres, base frame
    rotation: FloatArray  # (3, 3) orientation matrix, base frame

    @classmethod
    def from_matrix(cls, T: FloatArray) -> Pose:
        return cls(position=T[:3, 3].copy(), rotation=T[:3, :3].copy())

    def matrix(self) -> FloatArray:
        T = np.eye(4)
        T[:3, :3] = self.rotation
        T[:3, 3] = self.position
        return T


@dataclass(frozen=True)
class RobotMoved:
    joints: FloatArray  # corrected joint angles, radians
    pose: Pose
    time: float  # clock seconds


@dataclass(frozen=True)
class StatusChanged:
    old: RobotStatus
    new: RobotStatus
    message: str = ""


@dataclass(frozen=True)
class RobotFault:
    code: str
    message: str


@dataclass
class RobotEvents:
    """The thesis's PUMADataReceived, PUMAErrorOccured, PUMARobotMoved, PUMAStatusChanged."""

    data_received: Event[str] = field(default_factory=lambda: Event("data_received"))
    error: Event[RobotFault] = field(default_factory=lambda: Event("error"))
    moved: Event[RobotMoved] = field(default_factory=lambda: Event("moved"))
    status_changed: Event[StatusChanged] = field(default_factory=lambda: Event("status_changed"))


@dataclass(frozen=True)
class ArmSnapshot:
    """The arm's state at one instant, handed to other threads (the simulated force
    sensor) by swapping one reference: readers never see a half-updated state."""

    time: float
    joints: FloatArray  # corrected, radians
    velocities: FloatArray  # rad/s


class Kinematics(Protocol):
    """The arm's kinematic model, as far as the server reads it from a robot."""

    @property
    def tool(self) -> FloatArray:
        """The tool's 4×4 transform in the flange frame."""
        ...

    def fk(self, q: FloatArray) -> FloatArray:
        """The tool's 4×4 pose in the base frame at joint angles ``q``."""
        ...


class StopCategory(IntEnum):
    """Stop categories of IEC 60204-1 §9.2.2 (ISO 10218-1 asks a robot to state which
    stop it makes)."""

    UNCONTROLLED = 0  # power to the drives cut at once; the brakes stop the arm
    CONTROLLED_THEN_UNPOWERED = 1  # the drives brake the arm, power is cut at rest
    CONTROLLED_HOLDING = 2  # the drives brake the arm, then hold it at rest, powered


@dataclass(frozen=True)
class StopSpec:
    """How ``Robot.stop()`` brings the arm to rest: the server states it (GET
    /api/v1/safety) and computes stopping times and distances from it."""

    category: StopCategory
    decel: FloatArray  # rad/s² per joint: a stop's deceleration, the slowest joint's limit
    vmax: FloatArray  # rad/s per joint: the fastest each joint moves
    reaction_s: float  # worst time from stop() to the deceleration starting
    summary: str  # how this driver stops the arm, in a sentence


@runtime_checkable
class Robot(Protocol):
    """An arm of some model (the PUMA 560's six joints, the SO-101's five and a
    gripper). Every move is validated before anything is sent; a refused command raises
    a typed ``TelerobotError`` and the arm does not move."""

    name: str
    events: RobotEvents
    model: RobotModel  # what arm it is: joint names, limits, URDF (drivers/robot/models)

    @property
    def status(self) -> RobotStatus: ...
    @property
    def status_message(self) -> str: ...
    @property
    def joints(self) -> FloatArray: ...
    @property
    def pose(self) -> Pose: ...
    @property
    def target_joints(self) -> FloatArray: ...
    @property
    def stop_spec(self) -> StopSpec:
        """How ``stop()`` brings the arm to rest (a controlled stop at the drives' limit)."""
        ...

    frame: WorkingFrame
    joint_offsets: FloatArray

    async def connect(self) -> None: ...
    async def disconnect(self) -> None: ...
    async def initialize(self, joints: FloatArray | None = None) -> None: ...
    async def move_joints(self, q: FloatArray, *, relative: bool) -> FloatArray: ...
    async def move_cartesian(
        self,
        position: FloatArray,
        rotation: FloatArray,
        *,
        relative: bool,
        frame: WorkingFrame | None = None,
    ) -> FloatArray: ...
    async def stop(self) -> None:
        """Bring the arm to rest now, decelerating at the drives' limit (``stop_spec``)
        with power kept on; the target becomes where it comes to rest. Returns at once:
        the arm is at rest ``stop_spec``'s time later."""
        ...

    async def wait_idle(self, timeout: float | None = None) -> None: ...

    @property
    def kinematics(self) -> Kinematics:
        """The model the arm moves by (its tool included)."""
        ...

    def snapshot(self) -> ArmSnapshot:
        """The arm's state, safe to call from any thread (one reference swapped);
        velocities are zero where the arm does not report them."""
        ...

    def diagnostics(self) -> dict[str, Any]:
        """What the driver knows of the hardware's health, as JSON (a bus arm: each
        servo's temperature, voltage, load and errors; its read rate); {} if nothing."""
        ...

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], context: DeviceContext) -> Self: ...
    @classmethod
    def describe(cls, settings: Mapping[str, Any]) -> str:
        """What this driver drives, for a person ("the simulation")."""
        ...


# ---------------------------------------------------------------- force sensor
FORCE_CHANNELS = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")


@dataclass(frozen=True)
class ForceSample:
    """One 6-axis reading in the sensor frame: N and N·m."""

    seq: int  # counts every sample taken; gaps mean samples withheld by the threshold
    time: float  # sensor timestamp, seconds on the monotonic clock
    values: tuple[float, float, float, float, float, float]


@runtime_checkable
class ForceSensor(Protocol):
    """A 6-axis force/torque sensor sampled off the event loop.

    Subscribers are called from the sampling thread: they must be quick and
    thread-safe (hand the sample over, e.g. with ``loop.call_soon_threadsafe``).
    """

    name: str

    @property
    def running(self) -> bool: ...
    @property
    def latest(self) -> ForceSample | None: ...

    rate_hz: float
    threshold: float  # report only changes larger than this on some channel; 0 = every sample
    filter_cutoff_hz: float | None  # first-order low-pass; None = off

    @property
    def counters(self) -> Mapping[str, int]:
        """The driver's counters (received, lost, bad packets …); empty if it keeps none."""
        ...

    @property
    def error(self) -> str | None:
        """What is wrong with the sensor now, if anything (None for a simulated one)."""
        ...

    def subscribe(
        self, callback: Callable[[ForceSample], None], *, first: bool = False
    ) -> Callable[[], None]:
        """Call ``callback`` with every sample, on the sensor's thread; ``first``: ahead of
        the subscribers so far (the priority channel: its datagram leaves before any
        subscriber wakes the event loop)."""
        ...

    def start(self) -> None: ...
    def stop(self) -> None: ...
    def tare(self) -> None: ...

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], context: DeviceContext) -> Self: ...


# ---------------------------------------------------------------- stereo camera
class CameraStatus(StrEnum):
    STOPPED = "STOPPED"
    RUNNING = "RUNNING"
    FAILED = "FAILED"  # capture failed; the driver keeps retrying


@dataclass(frozen=True)
class StereoFrame:
    """Left and right images taken together, side by side in one RGB array
    (H × 2W × 3): one capture time, one sequence number, never mixed with another
    frame's partner. ``left``/``right`` are views, not copies."""

    seq: int
    time: float  # capture time, seconds on the monotonic clock
    sbs: np.ndarray  # uint8, H × 2W × 3, RGB
    skew: float = 0.0  # seconds between the two sensors' exposures, where known

    @property
    def left(self) -> np.ndarray:
        return self.sbs[:, : self.sbs.shape[1] // 2]

    @property
    def right(self) -> np.ndarray:
        return self.sbs[:, self.sbs.shape[1] // 2 :]


@runtime_checkable
class StereoCamera(Protocol):
    """Captures in its own thread into a newest-wins slot: capture never waits for
    the network, and a reader never gets the same frame twice."""

    name: str
    width: int  # of one eye
    height: int
    fps: float

    @property
    def status(self) -> CameraStatus: ...
    @property
    def status_message(self) -> str: ...

    def start(self) -> None: ...
    def stop(self) -> None: ...
    def next_frame(self, after_seq: int, timeout: float, every: bool = False) -> StereoFrame | None:
        """The newest frame newer than ``after_seq``, waiting up to ``timeout`` s;
        ``every``: the oldest one still kept (a reader that must miss none)."""
        ...

    def show_board(self, view: int | None) -> None:
        """Show the ChArUco calibration board at the ``view``-th calibration pose (None
        puts it away); a camera that cannot raises ``TelerobotError`` saying what to do."""
        ...

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], context: DeviceContext) -> Self: ...
    @classmethod
    def default_rig(cls, settings: Mapping[str, Any]) -> str:
        """The rig's name when the settings give none (each rig keeps its calibration)."""
        ...


# ---------------------------------------------------------------- master arm
@dataclass(frozen=True)
class MasterState:
    """One reading of a master device, in the device's own frame."""

    time: float  # seconds on the monotonic clock
    position: FloatArray  # metres
    rotation: FloatArray  # 3×3
    clutch: bool  # held: the arm follows (it is also the dead-man)


@runtime_checkable
class MasterArm(Protocol):
    """A haptic master device read at 1 kHz by the master-arm bridge.

    ``to_base`` turns the device's axes into the robot base's (a rotation), so the
    same bridge drives any device; ``max_force_n`` is what the device can render."""

    name: str
    to_base: FloatArray
    max_force_n: float

    def open(self) -> None: ...
    def close(self) -> None: ...
    def read(self) -> MasterState: ...
    def set_force(self, force: FloatArray) -> None:
        """Render ``force`` (N, device frame) until the next call."""
        ...


@runtime_checkable
class JointLeader(Protocol):
    """A leader arm: a copy of the follower's joints that the operator moves by hand
    (the SO-101 leader: the same servos with their torque off), read joint for joint by
    the joint-mirror bridge. ``read`` gives the model's angles (calibrated, radians)."""

    name: str
    joint_names: tuple[str, ...]  # must be the follower's, in its order

    def open(self) -> None: ...
    def close(self) -> None: ...
    def read(self) -> FloatArray: ...
    @classmethod
    def from_options(
        cls, model: RobotModel, *, port: str, baudrate: int, calibration: str | None
    ) -> Self:
        """The leader for the follower's ``model`` on ``port`` (a serial URL), with its
        joint calibration file (None: where the driver keeps it)."""
        ...


# ---------------------------------------------------------------- construction
def _no_arm() -> ArmSnapshot:
    raise DriverUnavailable("this driver follows the arm, but it was built without one")


@dataclass(frozen=True)
class OtherArm:
    """Another arm of the same server, for a device that sees every arm (the simulated
    cameras draw them all): its state, its kinematics (a new model at each call), its
    model's settings name and where its base stands in the workcell (4×4)."""

    probe: Callable[[], ArmSnapshot]
    kinematics: Callable[[], ArmKinematics]
    model: str
    mount: FloatArray


@dataclass(frozen=True)
class DeviceContext:
    """What the server hands a driver's ``from_settings`` besides the settings: what it
    makes once and shares, or makes one way for every device."""

    # A new model of the arm with the configured tool at each call (Pinocchio's data is
    # per instance: each user, each thread, gets its own).
    kinematics: Callable[[], ArmKinematics]
    workcell: Callable[[], Workcell]  # the simulated workcell every sim device reads
    arm_probe: Callable[[], ArmSnapshot] = _no_arm  # the arm's state, from any thread
    clock: Clock | None = None  # None: the driver's own monotonic clock
    # The server's other arms (docs/arms.md), for a device that sees them all.
    other_arms: tuple[OtherArm, ...] = ()
    # Where in its period a sensor that sets its own schedule takes its samples, as a
    # share of the period (arm i of N: i/N): several arms' sensors then never wake at
    # the same instant to queue behind one another for the interpreter (bench.
    # force_under_video --arms 2: the second stream's p99 was twice the first's).
    sample_phase: float = 0.0
