"""``telerobot so101-calibrate``: record an SO-101's (or its leader's) joint
calibration by hand. The arm's torque is switched off; for each pose the person
moves the arm there and presses Enter; the zeros and directions are solved
(``CalibrationRecorder``) and stored where the server or the mirror reads them."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path

from telerobot.drivers.base import TelerobotError
from telerobot.drivers.robot.models import load_model
from telerobot.drivers.robot.so101.arm import So101Arm
from telerobot.drivers.robot.so101.calibration import CalibrationRecorder

POSES = ("zero", "quarter")
SAYS = {
    "zero": "every joint in the middle of its range (the model's 'zero', as the page draws it)",
    "quarter": "every joint turned a quarter turn (90°) from 'zero', each the positive way",
    "ready": "the model's 'ready' pose",
    "rest": "folded, as it is parked (the model's 'rest')",
}


async def record(
    port: str,
    out: Path,
    *,
    baudrate: int,
    poses: tuple[str, ...] = POSES,
    ask: Callable[[str], str] = input,
    say: Callable[[str], None] = print,
) -> None:
    model = load_model("so101")
    arm = So101Arm(port, baudrate=baudrate, calibration=None, calibration_path=None)
    await arm.connect()  # uncalibrated: it reads, it does not move
    try:
        await arm.release()
        say(f"Torque is off on {port}: the arm can be moved by hand.")
        recorder = CalibrationRecorder(model, arm.ids)
        for pose in poses:
            await asyncio.to_thread(
                ask, f"Move the arm to '{pose}': {SAYS.get(pose, pose)}; then press Enter "
            )
            recorder.record_pose(pose, arm.raw_positions(), await arm.read_homing_offsets())
            say(f"  recorded '{pose}': {arm.raw_positions()}")
        calibration = recorder.solve()
        calibration.save(out)
        for name, joint in zip(calibration.joint_names, calibration.joints, strict=True):
            way = "+" if joint.direction > 0 else "−"
            say(f"  {name}: servo {joint.id}, zero at {joint.zero_steps:.0f} steps, {way}")
        say(f"Calibration written to {out}")
    finally:
        await arm.disconnect()


def main(port: str, out: Path, baudrate: int, poses: tuple[str, ...]) -> int:
    try:
        asyncio.run(record(port, out, baudrate=baudrate, poses=poses))
    except TelerobotError as exc:
        print(f"telerobot so101-calibrate: {exc}")
        return 1
    except (EOFError, KeyboardInterrupt):
        print("\ntelerobot so101-calibrate: stopped, nothing written")
        return 1
    return 0
