"""Driver name → implementation, imported only when chosen (docs/architecture.md, rule 2).

A driver whose SDK is missing fails when, and only when, it is selected, with one
message that says what to install. The names here are the names the settings accept
(``robot``, ``force``, ``camera``): adding a device is its folder, its class (built by
its ``from_settings``) and one line below.
"""

from __future__ import annotations

import importlib
from typing import Final, Literal, overload

from telerobot.drivers.base import DriverUnavailable, ForceSensor, JointLeader, Robot, StereoCamera

# kind → name → (module, class)
DRIVERS: Final[dict[str, dict[str, tuple[str, str]]]] = {
    "robot": {
        "sim": ("telerobot.drivers.robot.sim", "SimArm"),
        "val": ("telerobot.drivers.robot.puma560.val_serial", "ValSerialPuma"),
        "so101": ("telerobot.drivers.robot.so101.arm", "So101Arm"),
    },
    "force": {
        "sim": ("telerobot.drivers.force.sim", "SimForceSensor"),
        "netft": ("telerobot.drivers.force.netft", "NetFtSensor"),
    },
    "camera": {
        "sim": ("telerobot.drivers.camera.sim", "SimStereoCamera"),
        "opencv": ("telerobot.drivers.camera.opencv", "OpenCVStereoCamera"),
        "opencv-sbs": ("telerobot.drivers.camera.opencv", "OpenCVSideBySideCamera"),
    },
    "master": {
        "sim": ("telerobot.drivers.master.sim", "SimMaster"),
        "touch": ("telerobot.drivers.master.touch", "TouchMaster"),
    },
    # Leader arms, joint for joint (``telerobot master --device <name>-leader``)
    "leader": {
        "sim": ("telerobot.drivers.master.sim_leader", "SimLeader"),
        "so101": ("telerobot.drivers.robot.so101.leader", "So101Leader"),
    },
}


def driver_names(kind: str) -> list[str]:
    return sorted(DRIVERS.get(kind, {}))


@overload
def load_driver(kind: Literal["robot"], name: str) -> type[Robot]: ...
@overload
def load_driver(kind: Literal["force"], name: str) -> type[ForceSensor]: ...
@overload
def load_driver(kind: Literal["camera"], name: str) -> type[StereoCamera]: ...
@overload
def load_driver(kind: Literal["leader"], name: str) -> type[JointLeader]: ...
@overload
def load_driver(kind: str, name: str) -> type: ...
def load_driver(kind: str, name: str) -> type:
    """The class implementing driver ``name`` of ``kind`` (robot, force, camera …)."""
    try:
        module_name, class_name = DRIVERS[kind][name]
    except KeyError:
        known = ", ".join(driver_names(kind)) or "none"
        raise DriverUnavailable(f"unknown {kind} driver {name!r} (known: {known})") from None
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        missing = exc.name or "a package"
        raise DriverUnavailable(
            f"the {kind} driver {name!r} needs {missing} that is not installed: {exc}"
        ) from None
    cls: type = getattr(module, class_name)
    return cls
