"""``TouchMaster``: a 3D Systems Touch (Phantom Omni) through pyOpenHaptics.

An optional extra: ``pip install 'telerobot[touch]'`` and the vendor's OpenHaptics
runtime (libHD). Without them, choosing this device fails with a message that says
so; nothing else needs them. OpenHaptics runs its own 1 kHz servo loop: the callback
below copies the pose and buttons out and the newest force in.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from telerobot.drivers.base import DriverUnavailable, FloatArray, MasterState

# Touch axes: x right, y up, z toward the operator → robot base: x forward, y left, z up.
TOUCH_TO_BASE: FloatArray = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


class TouchMaster:
    name = "touch"
    max_force_n = 3.3  # the Touch's peak force
    mass_kg = 0.045  # its apparent mass at the stylus tip (the vendor's figure)
    to_base = TOUCH_TO_BASE

    def __init__(self, device_name: str = "Default Device") -> None:
        self.device_name = device_name
        self._lock = threading.Lock()
        self._position = np.zeros(3)
        self._rotation = np.eye(3)
        self._clutch = False
        self._force = [0.0, 0.0, 0.0]
        self._device: Any = None

    def open(self) -> None:
        try:
            import pyOpenHaptics.hd as hd
            from pyOpenHaptics.hd_callback import hd_callback
            from pyOpenHaptics.hd_device import HapticDevice
        except (ImportError, OSError) as exc:  # the wrapper, or the vendor's libHD
            raise DriverUnavailable(
                "the Touch needs pyOpenHaptics and the OpenHaptics runtime (libHD): "
                f"pip install 'telerobot[touch]' and install OpenHaptics ({exc})"
            ) from None

        @hd_callback  # type: ignore[untyped-decorator]
        def servo() -> None:
            transform = hd.get_transform()
            with self._lock:
                m = np.array(transform, dtype=float).reshape(4, 4).T  # column-major
                self._position = m[:3, 3] / 1000.0  # mm → m
                self._rotation = m[:3, :3]
                self._clutch = bool(hd.get_buttons() & 1)
                force = list(self._force)
            hd.set_force(force)

        try:
            self._device = HapticDevice(
                callback=servo, device_name=self.device_name, scheduler_type="async"
            )
        except Exception as exc:  # the vendor library raises its own kinds
            raise DriverUnavailable(f"cannot open the Touch {self.device_name!r}: {exc}") from None

    def close(self) -> None:
        with self._lock:
            self._force = [0.0, 0.0, 0.0]
        if self._device is not None:
            self._device.close()
            self._device = None

    def read(self) -> MasterState:
        with self._lock:
            return MasterState(
                time.monotonic(), self._position.copy(), self._rotation.copy(), self._clutch
            )

    def set_force(self, force: FloatArray) -> None:
        with self._lock:
            self._force = [float(v) for v in force]
