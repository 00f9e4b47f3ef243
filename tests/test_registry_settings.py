from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from telerobot.drivers.base import DriverUnavailable
from telerobot.drivers.registry import DRIVERS, Entry, load_driver
from telerobot.drivers.robot.sim import SimArm
from telerobot.server.settings import Settings, load_settings


def test_registry_loads_drivers_lazily() -> None:
    assert load_driver("robot", "sim") is SimArm  # any model; SimPuma is the PUMA's case


def test_unknown_driver_names_the_known_ones() -> None:
    with pytest.raises(
        DriverUnavailable, match=r"unknown robot driver 'kuka' \(known: sim, so101, val\)"
    ):
        load_driver("robot", "kuka")


def test_missing_sdk_fails_only_when_chosen(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(
        DRIVERS["robot"], "vendor", Entry("vendor_sdk_that_is_not_installed.arm", "Arm")
    )
    with pytest.raises(DriverUnavailable, match="needs vendor_sdk_that_is_not_installed"):
        load_driver("robot", "vendor")


def test_settings_from_env_toml_and_overrides(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    toml = tmp_path / "telerobot.toml"
    toml.write_text('robot = "val"\nserial_port = "socket://127.0.0.1:5000"\nhttp_port = 9000\n')
    monkeypatch.setenv("TELEROBOT_HTTP_PORT", "9100")
    s = load_settings(toml, serial_baudrate=19200, host=None)
    assert (s.robot, s.serial_port, s.http_port, s.serial_baudrate) == (
        "val",
        "socket://127.0.0.1:5000",
        9100,
        19200,
    )
    assert Settings().robot == "sim"  # the file applied to that load only


def test_bad_settings_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValidationError, match="home_pose must be one of"):
        Settings(home_pose="qx")
    with pytest.raises(
        ValidationError, match=r"unknown robot driver 'kuka' \(known: sim, so101, val\)"
    ):
        Settings(robot="kuka")
    with pytest.raises(FileNotFoundError):
        load_settings(tmp_path / "missing.toml")
