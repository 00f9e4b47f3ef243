// A driving key drives at its keydown, not at the next animation frame (issue 56 item 3:
// hand to eye), with the increments of the time since the last frame, so the next frame
// goes on from there and the motion is the same.
import { describe, expect, it } from "vitest";
import type { GamepadState } from "./input/gamepad";
import { InputLoop, MAX_LINEAR, TICKING_MS } from "./input/loop";
import { IDLE, type MotionCommand } from "./input/motion";
import { StateFlags } from "./transport/messages";

const FORWARD: MotionCommand = { deadman: true, linear: [1, 0, 0], angular: [0, 0, 0] };

function rig() {
  const sent: number[][] = [];
  const link = {
    cartesian: (dX: number[]) => void sent.push(dX),
    lease: () => undefined,
    wantControl: () => undefined,
    estop: () => undefined,
  };
  const inputs = { pad: { command: IDLE, cycleFrame: false, pad: null } as GamepadState, keys: IDLE };
  const loop = new InputLoop({
    link,
    arm: { commandCartesian: () => undefined },
    flags: () => StateFlags.YOU_HAVE_CONTROL,
    speed: () => 0.5,
    gamepad: { read: () => inputs.pad },
    keyboard: { read: () => inputs.keys },
    view: null,
    now: 1000,
  });
  loop.frame = "base";
  return { loop, sent, inputs };
}

describe("a driving key", () => {
  it("sends at its keydown, the next frame going on from there", () => {
    const { loop, sent, inputs } = rig();
    loop.tick(1016);
    inputs.keys = FORWARD; // Space and W held: W just went down
    loop.key("KeyW", 1020);
    expect(sent).toHaveLength(1);
    expect(sent[0]![0]).toBeCloseTo(MAX_LINEAR * 0.5 * 0.004, 12); // 4 ms since the frame
    loop.tick(1032);
    expect(sent[1]![0]).toBeCloseTo(MAX_LINEAR * 0.5 * 0.012, 12); // the frame: 12 ms more
  });

  it("sends nothing without the dead-man, for other keys, or with no frames ticking (XR)", () => {
    const { loop, sent, inputs } = rig();
    loop.tick(1016);
    inputs.keys = { ...FORWARD, deadman: false };
    loop.key("KeyW", 1020);
    inputs.keys = FORWARD;
    loop.key("Digit1", 1021); // picks a frame, drives nothing
    loop.key("KeyW", 1016 + TICKING_MS + 1); // the frames stopped (an XR session)
    expect(sent).toHaveLength(0);
  });
});
