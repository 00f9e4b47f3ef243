import { afterEach, beforeEach, describe, expect, it, vi } from "vitest";
import type { GamepadState } from "./input/gamepad";
import { FRAME_IDS, InputLoop, MAX_FRAME_S, MAX_LINEAR, WANT_CONTROL_MS, increments } from "./input/loop";
import { IDLE, type MotionCommand } from "./input/motion";
import type { XRControllerReading } from "./input/xr";
import { LeaseAction, StateFlags } from "./transport/messages";

const FORWARD: MotionCommand = { deadman: true, linear: [1, 0, 0], angular: [0, 0, 0] };

// A view frame: away from the camera is base −x, the image's left −y, its up +z (a
// camera at +x looking back at the robot).
const VIEW = [-1, 0, 0, 0, -1, 0, 0, 0, 1];

function rig(flags = 0, view: number[] | null = null) {
  const calls: [string, ...unknown[]][] = [];
  const link = {
    cartesian: (dX: number[], rv: number[], frame: number) => void calls.push(["cartesian", dX, rv, frame]),
    lease: (action: number) => void calls.push(["lease", action]),
    wantControl: (on: boolean) => void calls.push(["wantControl", on]),
    estop: () => void calls.push(["estop"]),
  };
  const predicted: unknown[][] = [];
  const arm = { commandCartesian: (...args: unknown[]) => void predicted.push(args) };
  const inputs = { pad: { command: IDLE, cycleFrame: false, pad: null } as GamepadState, keys: IDLE };
  const state = { flags, speed: 0.5 };
  const loop = new InputLoop({
    link,
    arm,
    flags: () => state.flags,
    speed: () => state.speed,
    gamepad: { read: () => inputs.pad },
    keyboard: { read: () => inputs.keys },
    view,
    now: 1000,
  });
  return { loop, calls, predicted, inputs, state };
}

describe("the lease", () => {
  beforeEach(() => vi.useFakeTimers());
  afterEach(() => vi.useRealTimers());

  it("is asked for with heartbeats wanted, which stop being wanted after a while", () => {
    const { loop, calls } = rig();
    loop.take();
    expect(calls).toEqual([["lease", LeaseAction.TAKE], ["wantControl", true]]);
    vi.advanceTimersByTime(WANT_CONTROL_MS - 1);
    expect(calls).toHaveLength(2);
    vi.advanceTimersByTime(1);
    expect(calls[2]).toEqual(["wantControl", false]); // from then on: only while we hold it
  });

  it("is taken over from someone else, and released with the heartbeats stopped first", () => {
    const { loop, calls } = rig(StateFlags.SOMEONE_HAS_CONTROL);
    loop.take();
    expect(calls[0]).toEqual(["lease", LeaseAction.TAKE_OVER]);
    calls.length = 0;
    loop.release();
    expect(calls).toEqual([["wantControl", false], ["lease", LeaseAction.RELEASE]]);
  });
});

describe("the input loop", () => {
  it("moves nothing without the dead-man, or without control", () => {
    const { loop, calls, inputs, state } = rig(StateFlags.YOU_HAVE_CONTROL);
    inputs.keys = { ...FORWARD, deadman: false };
    loop.tick(1016);
    state.flags = StateFlags.SOMEONE_HAS_CONTROL; // someone else's lease
    inputs.keys = FORWARD;
    loop.tick(1032);
    expect(calls).toEqual([]);
    expect(increments({ ...FORWARD, linear: [0, 0, 0] }, 1, 0.1)).toBeNull(); // held, not deflected
  });

  it("sends increments for the time since the last frame while both hold, and stops at once", () => {
    const { loop, calls, predicted, inputs } = rig(StateFlags.YOU_HAVE_CONTROL | StateFlags.SOMEONE_HAS_CONTROL);
    inputs.keys = FORWARD;
    loop.tick(1020); // 20 ms at speed 0.5
    expect(calls).toHaveLength(1);
    const [, dX, rv, frame] = calls[0]!;
    expect((dX as number[])[0]).toBeCloseTo(MAX_LINEAR * 0.5 * 0.02);
    expect(rv).toEqual([0, 0, 0]);
    expect(frame).toBe(FRAME_IDS.base);
    expect(predicted).toHaveLength(1);
    loop.tick(6020); // a stalled page: no more than MAX_FRAME_S of motion
    expect((calls[1]![1] as number[])[0]).toBeCloseTo(MAX_LINEAR * 0.5 * MAX_FRAME_S);
    inputs.keys = { ...FORWARD, deadman: false }; // dead-man released
    loop.tick(6040);
    expect(calls).toHaveLength(2);
  });

  it("combines the gamepad with the keyboard, and says when the inputs change", () => {
    const { loop, calls, inputs } = rig(StateFlags.YOU_HAVE_CONTROL);
    const said: string[] = [];
    loop.onInputState = (text) => said.push(text);
    inputs.pad = { command: { deadman: true, linear: [0, 0, 0], angular: [0, 0, 0] }, cycleFrame: false, pad: {} as Gamepad };
    inputs.keys = { deadman: false, linear: [0, 1, 0], angular: [0, 0, 0] };
    loop.tick(1010);
    loop.tick(1020);
    expect(calls).toHaveLength(2);
    expect(said).toEqual(["gamepad · dead-man held"]); // once, not every frame
  });

  it("picks the frame by key or gamepad, and stops on Escape", () => {
    const { loop, calls, inputs } = rig(StateFlags.YOU_HAVE_CONTROL);
    const picked: string[] = [];
    loop.onFrameChange = (f) => picked.push(f);
    expect(loop.frame).toBe("view"); // the default
    loop.key("Digit3");
    const cycle = () => {
      inputs.pad = { command: IDLE, cycleFrame: true, pad: null };
      loop.tick(1010);
      inputs.pad = { command: IDLE, cycleFrame: false, pad: null };
    };
    cycle(); // tool → view (the cycle wraps)
    loop.key("Digit2");
    cycle(); // wrist → tool
    loop.key("Digit1");
    cycle(); // base → wrist
    loop.key("Digit4");
    inputs.keys = FORWARD;
    loop.tick(1020);
    expect(picked).toEqual(["tool", "view", "wrist", "tool", "base", "wrist", "view"]);
    expect(calls[0]![3]).toBe(FRAME_IDS.base); // the view frame is sent as the base frame
    loop.key("Escape");
    expect(calls[1]).toEqual(["estop"]);
  });

  it("turns view-frame increments into base ones, sends them and predicts the very same", () => {
    const { loop, calls, predicted, inputs } = rig(StateFlags.YOU_HAVE_CONTROL, VIEW);
    inputs.keys = { deadman: true, linear: [1, 1, 1], angular: [0, 0, 1] }; // W, A, R and Q
    loop.tick(1020);
    const step = MAX_LINEAR * 0.5 * 0.02;
    const [, dX, rv, frame] = calls[0]!;
    expect(frame).toBe(FRAME_IDS.base);
    (dX as number[]).forEach((v, i) => expect(v).toBeCloseTo([-step, -step, step][i]!, 12));
    expect((rv as number[])[2]).toBeGreaterThan(0); // Q about the image's up: base +z here
    expect(predicted[0]).toEqual([dX, rv, "base", 1020]);
    loop.key("Digit1"); // the base frame: as the keys say
    loop.tick(1040);
    (calls[1]![1] as number[]).forEach((v, i) => expect(v).toBeCloseTo([step, step, step][i]!, 12));
    expect(predicted[1]![2]).toBe("base");
  });

  it("drives with the XR controller's grip as the dead-man, only with control", () => {
    const { loop, calls, state } = rig(StateFlags.YOU_HAVE_CONTROL);
    const hand = (z: number, gripping = true): XRControllerReading => ({ gripping, position: [0, 1, z], orientation: [0, 0, 0, 1], gamepad: {} as Gamepad });
    loop.xrFrame(hand(0), 1000); // the clutch anchors
    loop.xrFrame(hand(-0.01), 1014); // 1 cm forward (−z in XR) → base +x, times the speed
    expect(calls).toHaveLength(1);
    expect((calls[0]![1] as number[])[0]).toBeCloseTo(0.01 * 0.5);
    expect(calls[0]![3]).toBe(FRAME_IDS.base);
    loop.xrFrame(hand(-0.02, false), 1028); // grip released
    loop.xrFrame(null, 1042); // no controller
    state.flags = 0;
    loop.xrFrame(hand(-0.03), 1056);
    loop.xrFrame(hand(-0.04), 1070); // no control
    expect(calls).toHaveLength(1);
  });
});
