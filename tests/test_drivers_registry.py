"""Drivers describe themselves (docs/architecture.md, rule 14): every registered driver is built
from the settings by its own ``from_settings``, what the server uses is on its
protocol, and a new device is one folder, one class and one registry line."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from pydantic import ValidationError

from telerobot.drivers.base import (
    ArmSnapshot,
    ForceSensor,
    Robot,
    SerialSettings,
    StereoCamera,
    TelerobotError,
)
from telerobot.drivers.camera.opencv import OpenCVSideBySideCamera, OpenCVStereoCamera
from telerobot.drivers.camera.sim import SimStereoCamera
from telerobot.drivers.force.netft import NetFtSensor
from telerobot.drivers.force.sim import SimForceSensor
from telerobot.drivers.registry import DRIVERS, Entry
from telerobot.drivers.robot.puma560.kinematics import NAMED_POSES
from telerobot.drivers.robot.puma560.val_serial import ValSerialPuma
from telerobot.drivers.robot.sim import SimArm
from telerobot.server.app import create_app
from telerobot.server.devices import (
    build_camera,
    build_force_sensor,
    build_robot,
    build_workcell,
    describe_robot,
)
from telerobot.server.settings import Settings
from tests.support import TOKEN

# A whole simulated force sensor, as a developer would add it: its folder (a package),
# its class with its config beside it, and nothing else but one registry line.
CONSTANT_FORCE = '''
"""A simulated sensor that feels a steady push of ``push_n`` down the tool's z axis."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Self

from telerobot.drivers.base import ArmSnapshot, DeviceContext, ForceSample
from telerobot.drivers.force.sampled import SampledForceSensor


@dataclass(frozen=True)
class ConstantForceConfig:
    rate_hz: float

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> Self:
        return cls(rate_hz=float(settings["force_rate_hz"]))


class ConstantForceSensor(SampledForceSensor):
    name = "constant-force"
    thread_name = "constant-force-sensor"
    push_n = 5.0

    def __init__(self, probe: Callable[[], ArmSnapshot], *, rate_hz: float) -> None:
        super().__init__(rate_hz)
        self.probe = probe
        self._seq = 0

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], context: DeviceContext) -> Self:
        return cls(context.arm_probe, rate_hz=ConstantForceConfig.from_settings(settings).rate_hz)

    def sample_at(self, t: float) -> ForceSample | None:
        self._seq += 1
        base = float(self.probe().joints[0])  # it reads the arm it is given
        return self._deliver(self._seq, t, (0.0, 0.0, -self.push_n, 0.0, 0.0, base))

    def _run(self) -> None:
        while not self._stop.wait(1.0 / self.rate_hz):
            self.sample_at(time.monotonic())
'''


@pytest.fixture
def constant_force(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The folder ``constant_force/`` and its registry line, for this test only."""
    package = tmp_path / "constant_force"
    package.mkdir()
    (package / "__init__.py").write_text('"""A constant simulated force sensor."""\n')
    (package / "sensor.py").write_text(textwrap.dedent(CONSTANT_FORCE))
    monkeypatch.syspath_prepend(str(tmp_path))
    # The one registry line:
    monkeypatch.setitem(
        DRIVERS["force"], "constant", Entry("constant_force.sensor", "ConstantForceSensor")
    )
    yield
    for name in ("constant_force.sensor", "constant_force"):
        sys.modules.pop(name, None)


def test_a_new_simulated_force_sensor_is_a_folder_a_class_and_a_registry_line(
    constant_force: None,
) -> None:
    settings = Settings(force="constant", force_rate_hz=250.0)  # the registry's names
    robot = build_robot(settings)
    sensor = build_force_sensor(settings, robot, build_workcell(settings))
    assert type(sensor).__name__ == "ConstantForceSensor"
    assert isinstance(sensor, ForceSensor)  # the protocol, all of it
    assert sensor.rate_hz == 250.0  # it read its own key
    assert sensor.counters == {} and sensor.error is None  # the protocol's defaults
    sample = sensor.sample_at(1.0)  # type: ignore[attr-defined]
    assert sample.values[2] == -5.0
    assert sample.values[5] == pytest.approx(robot.snapshot().joints[0])  # the arm it follows


def test_the_server_runs_a_new_sensor_it_has_never_heard_of(constant_force: None) -> None:
    """No edit to the server: the REST API serves the new sensor's state and samples."""
    app = create_app(Settings(force="constant", operator_token=TOKEN))
    with TestClient(app, base_url="http://localhost") as client:
        deadline = time.monotonic() + 5
        state = client.get("/api/v1/force").json()
        while state["latest"] is None and time.monotonic() < deadline:
            time.sleep(0.01)
            state = client.get("/api/v1/force").json()
    assert state["driver"] == "constant-force" and state["running"]
    assert state["counters"] == {} and state["error"] is None
    assert state["latest"]["values"][:3] == [0.0, 0.0, -5.0]


PUSHING_FORCE_SETTINGS = '''
"""The pushing sensor's own setting."""

from pydantic import Field

from telerobot.drivers.settings import DriverSettings


class PushingSettings(DriverSettings):
    pushing_push_n: float = Field(5.0, gt=0, le=100, description="how hard it pushes, N")
'''

PUSHING_FORCE = '''
"""A simulated force sensor that pushes down as hard as its setting says."""

from telerobot.drivers.force.sim import SimForceSensor
from pushing_force.settings import PushingSettings


class PushingForceSensor(SimForceSensor):
    @classmethod
    def from_settings(cls, settings, context):
        sensor = super().from_settings(settings, context)
        sensor.push_n = PushingSettings.of(settings).pushing_push_n
        return sensor
'''

# In a process of its own: the server's Settings is composed of the registered
# drivers' settings when it is first imported, after the registry line has run.
PUSHING_PROBE = """
from telerobot.drivers.registry import DRIVERS, Entry
DRIVERS["force"]["pushing"] = Entry(  # the one registry line
    "pushing_force.sensor", "PushingForceSensor", "pushing_force.settings:PushingSettings"
)
from telerobot.server.devices import build_force_sensor, build_robot, build_workcell
from telerobot.server.settings import load_settings
try:
    settings = load_settings()
except ValueError as exc:
    print("refused:", str(exc).splitlines()[1:3])
else:
    sensor = build_force_sensor(settings, build_robot(settings), build_workcell(settings))
    print(type(sensor).__name__, settings.pushing_push_n, sensor.push_n)
"""


def test_a_new_device_declares_its_own_setting_and_the_server_takes_it(tmp_path: Path) -> None:
    # One folder and one registry line: no edit to the server's Settings, and the new
    # setting is set by its environment variable (and checked) like any other.
    package = tmp_path / "pushing_force"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "settings.py").write_text(PUSHING_FORCE_SETTINGS)
    (package / "sensor.py").write_text(PUSHING_FORCE)

    def probe(**env: str) -> str:
        done = subprocess.run(
            [sys.executable, "-c", PUSHING_PROBE],
            capture_output=True, text=True, timeout=60, check=True,
            env={**os.environ, "PYTHONPATH": str(tmp_path), "TELEROBOT_FORCE": "pushing", **env},
        )  # fmt: skip
        return done.stdout.strip()

    assert probe(TELEROBOT_PUSHING_PUSH_N="7.5") == "PushingForceSensor 7.5 7.5"
    assert probe() == "PushingForceSensor 5.0 5.0"  # its default
    refused = probe(TELEROBOT_PUSHING_PUSH_N="-1")
    assert refused.startswith("refused:") and "pushing_push_n" in refused, refused


def test_a_setting_two_drivers_declare_is_refused() -> None:
    from telerobot.drivers.settings import DriverSettings
    from telerobot.server import settings as server_settings

    class Clash(DriverSettings):
        http_port: int = 1  # the server's own

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(server_settings, "driver_settings", lambda: [Clash])
        with pytest.raises(TypeError, match="'http_port' of Clash is declared twice"):
            server_settings._with_driver_settings()


def test_driver_names_come_from_the_registry(constant_force: None) -> None:
    assert Settings(force="constant").force == "constant"
    with pytest.raises(
        ValidationError, match=r"unknown force driver 'kistler' \(known: constant, netft, sim\)"
    ):
        Settings(force="kistler")
    with pytest.raises(
        ValidationError, match=r"unknown robot driver 'kuka' \(known: sim, so101, val\)"
    ):
        Settings(robot="kuka")
    with pytest.raises(
        ValidationError, match=r"unknown camera driver 'gige' \(known: opencv, opencv-sbs, sim\)"
    ):
        Settings(camera="gige")


def test_every_registered_driver_builds_itself_from_the_settings() -> None:
    settings = Settings(
        robot="val",
        serial_port="socket://127.0.0.1:5000",
        serial_baudrate=19200,
        serial_reply_timeout=2.5,
        home_pose="qz",
        tool_length=0.2,
        force="netft",
        netft_address="10.0.0.7:49153",
        netft_counts_per_force=1e6,
        netft_counts_per_torque=2e6,
        force_rate_hz=500.0,
    )
    val = build_robot(settings)
    assert isinstance(val, ValSerialPuma) and isinstance(val, Robot)
    assert val.serial_settings == SerialSettings(
        port="socket://127.0.0.1:5000", baudrate=19200, reply_timeout=2.5
    )
    np.testing.assert_allclose(val.home, NAMED_POSES["qz"])
    assert val.kinematics.tool[2, 3] == pytest.approx(0.2)
    assert describe_robot(settings) == "the val robot on socket://127.0.0.1:5000"

    netft = build_force_sensor(settings, val, build_workcell(settings))
    assert isinstance(netft, NetFtSensor) and isinstance(netft, ForceSensor)
    assert netft.address == ("10.0.0.7", 49153)
    assert (netft.counts_per_force, netft.counts_per_torque, netft.rate_hz) == (1e6, 2e6, 500.0)

    sim = Settings()
    puma = build_robot(sim)
    assert isinstance(puma, SimArm) and isinstance(puma, Robot)
    assert puma.model.name == "puma560" and puma.name == "sim-puma560"
    assert describe_robot(sim) == "the simulation"
    so101 = build_robot(Settings(robot_model="so101"))
    assert isinstance(so101, SimArm) and so101.name == "sim-so101" and so101.dof == 6
    np.testing.assert_allclose(so101.home, so101.model.pose("ready"))
    assert so101.kinematics.joint_names[-1] == "gripper"
    force = build_force_sensor(sim, puma, build_workcell(sim))
    assert isinstance(force, SimForceSensor) and isinstance(force, ForceSensor)
    assert force.probe == puma.snapshot and force.counters == {"lost": 0} and force.error is None

    probe = puma.snapshot
    camera = build_camera(Settings(video_fps=24.0, video_width=320, video_height=240), probe)
    assert isinstance(camera, SimStereoCamera) and isinstance(camera, StereoCamera)
    assert (camera.width, camera.height, camera.fps) == (320, 240, 24.0)
    stereo = build_camera(
        Settings(camera="opencv", camera_devices=["2", "/dev/video4"], video_fps=15.0), probe
    )
    assert isinstance(stereo, OpenCVStereoCamera) and isinstance(stereo, StereoCamera)
    assert (stereo.devices, stereo.fps, stereo.width) == ((2, "/dev/video4"), 15.0, 1280)
    sbs = build_camera(Settings(camera="opencv-sbs", camera_devices=["1"]), probe)
    assert isinstance(sbs, OpenCVSideBySideCamera) and sbs.device == 1


def test_only_the_simulated_camera_shows_a_board() -> None:
    probe = build_robot(Settings()).snapshot
    sim = build_camera(Settings(video_width=320, video_height=240), probe)
    sim.show_board(3)
    assert isinstance(sim, SimStereoCamera) and sim.board is not None
    sim.show_board(None)
    assert sim.board is None
    real = build_camera(Settings(camera="opencv"), probe)
    with pytest.raises(TelerobotError, match="hold a printed ChArUco board in front of the real"):
        real.show_board(0)


def test_the_val_arm_reports_its_snapshot_from_its_moved_events() -> None:
    arm = ValSerialPuma(joint_offsets=np.full(6, 0.01))
    first = arm.snapshot()  # nothing reported yet: where it is, at rest
    assert first.time == 0.0 and not first.velocities.any()
    np.testing.assert_allclose(first.joints, np.full(6, 0.01))
    seen: list[ArmSnapshot] = []
    arm.events.moved.subscribe(lambda e: seen.append(arm.snapshot()))
    arm._raw = np.array([0.1, 0.2, 0.3, 0.0, 0.0, 0.0])  # a DONE reply arrived
    arm._report_moved()
    (snap,) = seen
    np.testing.assert_allclose(snap.joints, [0.11, 0.21, 0.31, 0.01, 0.01, 0.01])
    assert snap is arm.snapshot() and snap.time > 0 and not snap.velocities.any()


def test_drivers_never_import_the_server() -> None:
    root = Path(__file__).resolve().parents[1] / "drivers"
    offenders = [
        str(path.relative_to(root))
        for path in root.rglob("*.py")
        if any(
            line.lstrip().startswith(("from telerobot.server", "import telerobot.server"))
            for line in path.read_text().splitlines()
        )
    ]
    assert offenders == []
