"""Driver name → implementation, imported only when chosen (docs/architecture.md, rule 2).

A driver whose SDK is missing fails when, and only when, it is selected, with one
message that says what to install. The names here are the names the settings accept
(``robot``, ``force``, ``camera``): adding a device is its folder, its class (built by
its ``from_settings``), its settings' class if it has settings, and one entry below.
"""

from __future__ import annotations

import importlib
from typing import Final, Literal, NamedTuple, overload

from telerobot.drivers.base import DriverUnavailable, ForceSensor, JointLeader, Robot, StereoCamera
from telerobot.drivers.settings import DriverSettings


class Entry(NamedTuple):
    """One driver: its class (``module``, ``cls``), imported when chosen, and its own
    settings' class, if it has settings (``"module:Class"``, a light module imported by
    the server at start: ``telerobot.drivers.settings``)."""

    module: str
    cls: str
    settings: str | None = None


# kind → name → entry
DRIVERS: Final[dict[str, dict[str, Entry]]] = {
    "robot": {
        "sim": Entry("telerobot.drivers.robot.sim", "SimArm"),
        "val": Entry(
            "telerobot.drivers.robot.puma560.val_serial",
            "ValSerialPuma",
            "telerobot.drivers.robot.puma560.settings:ValSerialSettings",
        ),
        "so101": Entry(
            "telerobot.drivers.robot.so101.arm",
            "So101Arm",
            "telerobot.drivers.robot.so101.settings:So101Settings",
        ),
    },
    "force": {
        "sim": Entry("telerobot.drivers.force.sim", "SimForceSensor"),
        "netft": Entry(
            "telerobot.drivers.force.netft",
            "NetFtSensor",
            "telerobot.drivers.force.netft_settings:NetFtSettings",
        ),
    },
    "camera": {
        "sim": Entry("telerobot.drivers.camera.sim", "SimStereoCamera"),
        "opencv": Entry(
            "telerobot.drivers.camera.opencv",
            "OpenCVStereoCamera",
            "telerobot.drivers.camera.opencv_settings:OpenCVSettings",
        ),
        "opencv-sbs": Entry(
            "telerobot.drivers.camera.opencv",
            "OpenCVSideBySideCamera",
            "telerobot.drivers.camera.opencv_settings:OpenCVSettings",
        ),
    },
    "master": {
        "sim": Entry("telerobot.drivers.master.sim", "SimMaster"),
        "touch": Entry("telerobot.drivers.master.touch", "TouchMaster"),
    },
    # Leader arms, joint for joint (``telerobot master --device <name>-leader``)
    "leader": {
        "sim": Entry("telerobot.drivers.master.sim_leader", "SimLeader"),
        "so101": Entry("telerobot.drivers.robot.so101.leader", "So101Leader"),
    },
}


def driver_settings() -> list[type[DriverSettings]]:
    """Every registered driver's settings class, once each (the server's ``Settings``
    is composed of them)."""
    found: dict[str, type[DriverSettings]] = {}
    for entries in DRIVERS.values():
        for entry in entries.values():
            if entry.settings is not None and entry.settings not in found:
                module, _, name = entry.settings.partition(":")
                cls = getattr(importlib.import_module(module), name)
                if not (isinstance(cls, type) and issubclass(cls, DriverSettings)):
                    raise TypeError(f"{entry.settings} is not a DriverSettings class")
                found[entry.settings] = cls
    return list(found.values())


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
        module_name, class_name = DRIVERS[kind][name][:2]
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
