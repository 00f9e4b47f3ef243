import { afterEach, describe, expect, it, vi } from "vitest";
import { ARM_KEYS, armCommands, handArms, routingText, stepArm, type Routing } from "./input/arms";
import { GamepadInput, SHIFT_TRIGGER, side, type GamepadState } from "./input/gamepad";
import { type DriveArm, FRAME_IDS, InputLoop, MAX_LINEAR } from "./input/loop";
import { IDLE, type MotionCommand } from "./input/motion";
import { ContactRumble, RUMBLE_PERIOD_MS } from "./input/rumble";
import { XRMasterInput, type XRControllerReading } from "./input/xr";
import type { Vec3 } from "./robot/math";
import { combinedState, mountedCameras, type ServerArmEntry } from "./robot/arms";
import { ServerArmReloader, type ServerArm } from "./robot/server-arm";
import { SO101 } from "./so101.fixture";
import { armChips, dimmed } from "./ui/arms";
import { helpSections } from "./ui/help";
import { StateFlags } from "./transport/messages";

const zero = (v: readonly number[]) => v.map((x) => x + 0); // −0 → 0, for toEqual
const cmd = (c: MotionCommand) => ({ deadman: c.deadman, linear: zero(c.linear), angular: zero(c.angular) });
const FORWARD: MotionCommand = { deadman: true, linear: [1, 0, 0], angular: [0, 0, 0] };
const LEFTWARD: MotionCommand = { deadman: true, linear: [0, 1, 0], angular: [0, 0, 0] };
const UP: MotionCommand = { deadman: true, linear: [0, 0, 1], angular: [0, 0, 0] };

describe("which hand drives which arm", () => {
  it("is the arm named left (else the first) and the one named right (else another)", () => {
    expect(handArms(["left", "right"])).toEqual({ left: 0, right: 1 });
    expect(handArms(["right", "left"])).toEqual({ left: 1, right: 0 });
    expect(handArms(["a", "b"])).toEqual({ left: 0, right: 1 });
    expect(handArms(["a", "left", "c"])).toEqual({ left: 1, right: 0 });
    expect(handArms(["left", "a", "right"])).toEqual({ left: 0, right: 2 });
    expect(handArms(["arm"])).toEqual({ left: 0, right: 0 }); // one arm: both hands
  });

  it("the arm keys step through the arms without wrapping: [ is the left, ] the right", () => {
    expect(ARM_KEYS).toEqual({ BracketLeft: -1, BracketRight: 1 });
    expect(stepArm(0, 1, 2)).toBe(1);
    expect(stepArm(1, 1, 2)).toBe(1);
    expect(stepArm(1, -1, 2)).toBe(0);
    expect(stepArm(0, -1, 2)).toBe(0);
  });
});

describe("each arm's command", () => {
  const two: Routing = { count: 2, selected: 0, padMode: "both", hands: { left: 0, right: 1 } };

  it("with one arm, the gamepad's and the keys' together, as always", () => {
    const out = armCommands({ ...two, count: 1 }, { command: FORWARD, left: UP, right: UP }, LEFTWARD);
    expect(out.map(cmd)).toEqual([{ deadman: true, linear: [1, 1, 0], angular: [0, 0, 0] }]);
  });

  it("both arms: the keys the selected arm, each side of the gamepad its arm", () => {
    const out = armCommands({ ...two, selected: 1 }, { command: FORWARD, left: UP, right: FORWARD }, LEFTWARD);
    expect(out.map(cmd)).toEqual([cmd(UP), { deadman: true, linear: [1, 1, 0], angular: [0, 0, 0] }]);
  });

  it("one arm alone: the gamepad's one-arm command drives the selected arm, the other rests", () => {
    const out = armCommands({ ...two, padMode: "one", selected: 1 }, { command: FORWARD, left: UP, right: UP }, IDLE);
    expect(out.map(cmd)).toEqual([cmd(IDLE), cmd(FORWARD)]);
  });

  it("is said under Driving", () => {
    expect(routingText(["arm"], { ...two, count: 1 })).toBe("");
    expect(routingText(["left", "right"], two)).toBe("keys: left · gamepad: left (L1, left stick) + right (R1, right stick)");
    expect(routingText(["left", "right"], { ...two, padMode: "one", selected: 1 })).toBe("keys: right · gamepad: right alone");
  });
});

// A scripted standard-mapping gamepad, as navigator.getGamepads gives it.
function fakePad() {
  const pad = { axes: [0, 0, 0, 0], pressed: new Set<number>(), values: new Map<number, number>() };
  const gamepad = () =>
    ({
      connected: true,
      axes: pad.axes,
      buttons: Array.from({ length: 17 }, (_, i) => ({ pressed: pad.pressed.has(i), value: pad.values.get(i) ?? (pad.pressed.has(i) ? 1 : 0) })),
    }) as unknown as Gamepad;
  vi.stubGlobal("navigator", { getGamepads: () => [gamepad()] });
  return pad;
}

describe("the gamepad's sides", () => {
  afterEach(() => vi.unstubAllGlobals());

  it("a stick moves forward/back and left/right; with its trigger pulled, up/down and yaw", () => {
    expect(cmd(side(true, 0, -1, 0))).toEqual({ deadman: true, linear: [1, 0, 0], angular: [0, 0, 0] }); // stick forward
    expect(cmd(side(true, -1, 0, 0))).toEqual({ deadman: true, linear: [0, 1, 0], angular: [0, 0, 0] }); // stick left
    expect(cmd(side(true, 0, -1, SHIFT_TRIGGER))).toEqual({ deadman: true, linear: [0, 0, 1], angular: [0, 0, 0] }); // up
    expect(cmd(side(false, -1, 0, 1))).toEqual({ deadman: false, linear: [0, 0, 0], angular: [0, 0, 1] }); // yaw left
  });

  it("L1 is the left side's dead-man and R1 the right's (and the one-arm mapping's)", () => {
    const pad = fakePad();
    const input = new GamepadInput();
    pad.axes[1] = -1; // left stick forward
    pad.axes[3] = 1; // right stick back
    pad.pressed.add(4);
    let s = input.read();
    expect(cmd(s.left!)).toEqual({ deadman: true, linear: [1, 0, 0], angular: [0, 0, 0] });
    expect(cmd(s.right!)).toEqual({ deadman: false, linear: [-1, 0, 0], angular: [0, 0, 0] });
    expect(s.command.deadman).toBe(false);
    pad.pressed.add(5);
    pad.values.set(7, 0.9); // R2 pulled: the right stick goes down instead
    s = input.read();
    expect(cmd(s.right!)).toEqual({ deadman: true, linear: [0, 0, -1], angular: [0, 0, 0] });
    expect(s.command.deadman).toBe(true);
    input.latch(); // control lost: both held dead-men stop until released
    s = input.read();
    expect([s.left!.deadman, s.right!.deadman, s.command.deadman]).toEqual([false, false, false]);
    pad.pressed.delete(4);
    input.read();
    pad.pressed.add(4);
    expect(input.read().left!.deadman).toBe(true);
  });

  it("Back swaps once per press, and the D-pad picks the arm", () => {
    const pad = fakePad();
    const input = new GamepadInput();
    pad.pressed.add(8);
    expect(input.read().swapArms).toBe(true);
    expect(input.read().swapArms).toBe(false); // still held: once
    pad.pressed.delete(8);
    input.read();
    pad.pressed.add(15);
    expect(input.read().pickArm).toBe(1);
    expect(input.read().pickArm).toBe(0);
    pad.pressed.clear();
    pad.pressed.add(14);
    expect(input.read().pickArm).toBe(-1);
  });
});

/** An input loop on two arms (left, right: ARM indices 1, 2), with control. */
function twoArms(views: [number[] | null, number[] | null] = [null, null]) {
  const sent: { arm: number; dX: number[]; rv: number[]; frame: number }[] = [];
  const predicted: [string, Vec3][] = [];
  const link = {
    cartesian: (dX: number[], rv: number[], frame: number, arm = 0) => void sent.push({ arm, dX, rv, frame }),
    lease: () => undefined,
    wantControl: () => undefined,
    estop: () => undefined,
  };
  const inputs: { pad: GamepadState; keys: MotionCommand } = { pad: { command: IDLE, cycleFrame: false, pad: null }, keys: IDLE };
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
  const arm = (name: string, index: number, view: number[] | null): DriveArm => ({
    index,
    name,
    view,
    predictor: { commandCartesian: (dX) => void predicted.push([name, dX]) },
  });
  loop.setArms([arm("left", 1, views[0]), arm("right", 2, views[1])]);
  return { loop, sent, predicted, inputs };
}

describe("the input loop with two arms", () => {
  it("sends the keys to the selected arm, named by its index; ] and [ select", () => {
    const { loop, sent, predicted, inputs } = twoArms();
    const changes: [string, number][] = [];
    loop.onArmChange = (why) => changes.push([why, loop.selected]);
    inputs.keys = FORWARD;
    loop.key("Digit1"); // the base frame
    loop.tick(1020);
    loop.key("BracketRight");
    loop.tick(1040);
    loop.key("BracketRight"); // no further
    loop.key("BracketLeft");
    loop.tick(1060);
    expect(sent.map((s) => s.arm)).toEqual([1, 2, 1]);
    expect(sent[0]!.dX[0]).toBeCloseTo(MAX_LINEAR * 0.5 * 0.02);
    expect(sent[0]!.frame).toBe(FRAME_IDS.base);
    expect(predicted.map(([name]) => name)).toEqual(["left", "right", "left"]); // each arm's model
    expect(changes).toEqual([
      ["select", 1],
      ["select", 0],
    ]);
  });

  it("drives both arms from the gamepad's sides at once, and one alone after Back", () => {
    const { loop, sent, inputs } = twoArms();
    inputs.pad = { command: FORWARD, cycleFrame: false, pad: null, left: UP, right: FORWARD };
    loop.tick(1020);
    expect(sent.map((s) => [s.arm, zero(s.dX).map(Math.sign)])).toEqual([
      [1, [0, 0, 1]],
      [2, [1, 0, 0]],
    ]);
    expect(loop.held).toEqual([0, 1]);
    sent.length = 0;
    inputs.pad = { ...inputs.pad, swapArms: true };
    loop.tick(1040); // one arm alone: the selected (left), with the one-arm command
    expect(loop.padMode).toBe("one");
    expect(sent.map((s) => [s.arm, zero(s.dX).map(Math.sign)])).toEqual([[1, [1, 0, 0]]]);
    sent.length = 0;
    inputs.pad = { ...inputs.pad, swapArms: false, pickArm: 1 }; // D-pad →: the right arm
    loop.tick(1060);
    expect(sent.map((s) => s.arm)).toEqual([2]);
    inputs.pad = { ...inputs.pad, pickArm: 0, swapArms: true };
    loop.tick(1080);
    expect(loop.padMode).toBe("both");
  });

  it("moves each arm in the view frame as its own base frame has it", () => {
    // The left arm looks into the picture (view x = its base +y); the right arm, turned
    // half a turn, has the same view along its base −y.
    const left = [0, -1, 0, 1, 0, 0, 0, 0, 1];
    const right = [0, 1, 0, -1, 0, 0, 0, 0, 1];
    const { loop, sent, inputs } = twoArms([left, right]);
    inputs.pad = { command: IDLE, cycleFrame: false, pad: null, left: FORWARD, right: FORWARD };
    loop.tick(1020);
    expect(sent.map((s) => zero(s.dX).map(Math.sign))).toEqual([
      [0, 1, 0],
      [0, -1, 0],
    ]);
  });

  it("the left XR hand drives the left arm and the right the right, each with its own clutch", () => {
    const { loop, sent } = twoArms();
    const hand = (z: number, gripping = true): XRControllerReading => ({ gripping, position: [0, 1, z], orientation: [0, 0, 0, 1], gamepad: null });
    loop.xrHands({ left: hand(0), right: hand(0, false) }, 1000); // the left clutch anchors
    loop.xrHands({ left: hand(-0.01), right: hand(-0.01, false) }, 1014); // 1 cm forward
    expect(sent.map((s) => s.arm)).toEqual([1]);
    expect(sent[0]!.dX[0]).toBeCloseTo(0.01 * 0.5); // no camera: the base frame's forward
    expect(loop.held).toEqual([0]);
    loop.xrHands({ left: hand(-0.01, false), right: hand(-0.01) }, 1028); // the right anchors
    loop.xrHands({ left: null, right: hand(-0.03) }, 1042); // 2 cm
    expect(sent.map((s) => s.arm)).toEqual([1, 2]);
    expect(sent[1]!.dX[0]).toBeCloseTo(0.02 * 0.5);
    expect(loop.driven).toEqual([1]);
    loop.xrHands({ left: null, right: null }, 1056);
    expect(loop.driven).toEqual([0]); // none held: the selected arm
  });

  it("a one-arm loop names no arm (0: the only one)", () => {
    const sent: number[] = [];
    const loop = new InputLoop({
      link: { cartesian: (_d, _r, _f, arm = -1) => void sent.push(arm), lease: () => undefined, wantControl: () => undefined, estop: () => undefined },
      arm: { commandCartesian: () => undefined },
      flags: () => StateFlags.YOU_HAVE_CONTROL,
      speed: () => 1,
      gamepad: { read: () => ({ command: IDLE, cycleFrame: false, pad: null, left: FORWARD, right: FORWARD, swapArms: true, pickArm: 1 }) },
      keyboard: { read: () => FORWARD },
      view: null,
      now: 0,
    });
    loop.key("BracketRight");
    loop.tick(20);
    expect(sent).toEqual([0]);
    expect([loop.selected, loop.padMode]).toEqual([0, "both"]);
  });
});

describe("rumble per hand", () => {
  it("the gamepad's left motor feels one arm's force and its right motor the other's", () => {
    const effects: [number, number][] = [];
    const pad = { vibrationActuator: { playEffect: (_t: string, p: { strongMagnitude: number; weakMagnitude: number }) => (effects.push([p.strongMagnitude, p.weakMagnitude]), Promise.resolve()) } };
    const force = [0.2, 0.7];
    const r = new ContactRumble((arm) => force[arm] ?? 0);
    r.drivePad(0, pad as unknown as Gamepad, { strong: 0, weak: 1 });
    r.drivePad(RUMBLE_PERIOD_MS, pad as unknown as Gamepad, { strong: 1, weak: null }); // one arm alone: the right
    r.drivePad(2 * RUMBLE_PERIOD_MS, pad as unknown as Gamepad); // one arm: the first, as always
    expect(effects).toEqual([
      [0.2, 0.7],
      [0.7, 0],
      [0.2, 0],
    ]);
  });

  it("each XR controller pulses with its own arm's force, each paced on its own", () => {
    const pulses: [string, number][] = [];
    const controller = (name: string) => ({ hapticActuators: [{ pulse: (v: number) => (pulses.push([name, v]), Promise.resolve(true)) }] }) as unknown as Gamepad;
    const r = new ContactRumble((arm) => [0.3, 0][arm] ?? 0);
    r.driveXR(0, controller("left"), 0, "left");
    r.driveXR(0, controller("right"), 1, "right"); // the right arm is in no contact
    r.driveXR(1, controller("left"), 0, "left"); // too soon for the left
    expect(pulses).toEqual([["left", 0.3]]);
  });
});

describe("the XR hands", () => {
  const poseOf = (p: Vec3) => ({ emulatedPosition: false, transform: { position: { x: p[0], y: p[1], z: p[2] }, orientation: { x: 0, y: 0, z: 0, w: 1 } } });
  const controller = (handedness: string, squeeze: boolean, at: Vec3) => ({ handedness, gripSpace: { at }, gamepad: { buttons: [{ pressed: false }, { pressed: squeeze }] } });
  const frame = (sources: object[]) => ({ session: { inputSources: sources }, getPose: (space: { at: Vec3 }) => poseOf(space.at) }) as unknown as XRFrame;

  it("reads each hand's controller, and lets a hand go for a frame when its input changes", () => {
    const input = new XRMasterInput();
    const left = controller("left", true, [-0.2, 1, 0]);
    const right = controller("right", true, [0.2, 1, 0]);
    const space = {} as XRReferenceSpace;
    let r = input.readHands(frame([left, right]), space);
    expect([r.left?.gripping, r.right?.gripping]).toEqual([false, false]); // new: not yet
    r = input.readHands(frame([left, right]), space);
    expect(r.left).toMatchObject({ gripping: true, position: [-0.2, 1, 0] });
    expect(r.right).toMatchObject({ gripping: true, position: [0.2, 1, 0] });
    r = input.readHands(frame([left]), space);
    expect(r.right).toBeNull();
    expect(r.left?.gripping).toBe(true); // the left hand's clutch is its own
  });
});

describe("the arms drawn and shown", () => {
  it("places each arm's points through its mount: P · mount", () => {
    const P = [
      [1, 0, 0, 0],
      [0, 1, 0, 0],
      [0, 0, 1, 2],
    ];
    const turned = [-1, 0, 0, 0.5, 0, -1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]; // x 0.5, half a turn
    const [cam] = mountedCameras([{ name: "left", P }], turned);
    // The arm's own (0.1, 0, 0) is the scene's (0.4, 0, 0).
    const p = [0.1, 0, 0, 1];
    const row = (r: number[]) => r.reduce((s, v, i) => s + v * p[i]!, 0);
    expect(cam!.P.map(row)).toEqual([0.4, 0, 2]);
  });

  it("the header's state is the worst status and every flag of them", () => {
    const a = { status: "READY", flags: StateFlags.YOU_HAVE_CONTROL, joints: [1] };
    const b = { status: "MOVING", flags: StateFlags.YOU_HAVE_CONTROL | StateFlags.FORCE_LIMITED, joints: [2] };
    expect(combinedState([a])).toBe(a); // one arm: its own, the very object
    expect(combinedState([a, null])).toBeNull();
    expect(combinedState([a, b])).toEqual({ status: "MOVING", flags: StateFlags.YOU_HAVE_CONTROL | StateFlags.FORCE_LIMITED, joints: [1] });
    expect(combinedState([b, { ...a, status: "ERROR" }])!.status).toBe("ERROR");
  });

  it("a chip per arm: its status and force, the keys' arm and the driven ones marked", () => {
    const chips = armChips(
      [
        { name: "left", state: { status: "READY", flags: 0 }, forceN: 1.24, selected: true, driven: false },
        { name: "right", state: { status: "MOVING", flags: StateFlags.FORCE_LIMITED }, forceN: 61, selected: false, driven: true },
      ],
      60,
      "#00ff66",
    );
    expect(chips.map((c) => [c.name, c.detail, c.cls])).toEqual([
      ["left", "READY 1.2 N", "arm-chip selected"],
      ["right", "FORCE LIMIT 61.0 N", "arm-chip driven over"],
    ]);
    expect(chips[0]!.ringColour).toBe("#00ff66"); // the first arm's ball: the View panel's
    expect(chips[1]!.title).toContain("102 % of the 60 N limit");
    expect(dimmed("#ff8000", 0.5)).toBe("#804000");
  });

  it("the help says what drives which arm only on a server with two", () => {
    const titles = (arms: string[]) => helpSections(undefined, undefined, arms).map((s) => s.title);
    expect(titles([])).not.toContain("Two arms (left, right)");
    const two = helpSections(undefined, undefined, ["left", "right"]);
    const rows = JSON.stringify(two.find((s) => s.title === "Two arms (left, right)"));
    for (const words of ["[ / ]", "L1 + left stick", "Back / Select", "left controller (or hand) drives the left arm"]) expect(rows).toContain(words);
  });
});

describe("the arms after a new session", () => {
  it("a server restarted with two arms where it had one: every arm drawn anew, and said", async () => {
    const I = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
    const entry = (name: string, index: number): ServerArmEntry => ({ name, index, mount: I, model: SO101 });
    const cameras = [{ name: "left", P: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 2]] }];
    const one: ServerArm = { cameras, arms: [entry("arm", 1)] };
    const two: ServerArm = { cameras, arms: [entry("left", 1), entry("right", 2)] };
    const applied: ServerArm[] = [];
    const said: string[] = [];
    const r = new ServerArmReloader(one, () => Promise.resolve(two), (a) => applied.push(a), { add: (t) => said.push(t) }, () => Promise.resolve());
    expect(await r.reload()).toBe(true);
    expect(applied).toEqual([two]);
    expect(said).toEqual(["the server now drives 2 arm(s) (left, right), not 1 (arm): the page draws and drives them"]);
    expect(await r.reload()).toBe(false); // the same again: nothing
  });
});
