import { afterEach, beforeEach, describe, expect, it, vi } from "vitest";
import type { GamepadState } from "./input/gamepad";
import { HAND_BACK_MS, InputLoop } from "./input/loop";
import { IDLE, type MotionCommand } from "./input/motion";
import { LeaseAction, StateFlags } from "./transport/messages";
import { Supervision, autonomyView, parseAutonomy, type AutonomyState } from "./ui/autonomy";

const state = (mode: AutonomyState["mode"], extra: Partial<AutonomyState> = {}): AutonomyState => ({
  mode,
  policy: "act-policy",
  operator: null,
  cause: "",
  rate_hz: 29.6,
  refused: 0,
  interventions: 0,
  ...extra,
});

describe("the supervision badge", () => {
  it("reads the server's EVENT autonomy, and nothing else", () => {
    const text = JSON.stringify({ mode: "paused", policy: "p", operator: "alice", cause: "e-stop", rate_hz: 30, refused: 2, interventions: 1 });
    expect(parseAutonomy(text)).toEqual({ mode: "paused", policy: "p", operator: "alice", cause: "e-stop", rate_hz: 30, refused: 2, interventions: 1 });
    expect(parseAutonomy("control: alice")).toBeNull();
    expect(parseAutonomy(JSON.stringify({ mode: "flying" }))).toBeNull();
  });

  it("says who drives, with lerobot's DAgger names, and offers what may be done", () => {
    expect(autonomyView(state("autonomous"), false)).toMatchObject({ badge: "AUTONOMOUS · act-policy · 30 Hz", pause: true, takeLabel: "Take over (T)" });
    expect(autonomyView(state("paused", { cause: "paused by 'alice'" }), false)).toMatchObject({ badge: "PAUSED · act-policy — press P to let it drive (paused by 'alice')", resume: true });
    expect(autonomyView(state("correcting", { operator: "alice" }), true)).toMatchObject({ badge: "CORRECTING · alice drives, act-policy waits", handBack: true });
    expect(autonomyView(state("correcting", { operator: "bob" }), false).handBack).toBe(false); // not this page's correction
    expect(autonomyView(null, false).badge).toBe("");
  });
});

describe("supervising from the keys", () => {
  function rig(mode: AutonomyState["mode"], control = false) {
    const calls: string[] = [];
    const s = new Supervision({
      take: () => void calls.push("take"),
      release: () => void calls.push("release"),
      lease: (a) => void calls.push(`lease ${a}`),
      youHaveControl: () => control,
    });
    s.update(state(mode));
    return { s, calls };
  }

  it("T takes over, P pauses, H does nothing while the policy drives", () => {
    const { s, calls } = rig("autonomous");
    s.key("KeyT");
    s.key("KeyP");
    s.key("KeyH");
    expect(calls).toEqual(["take", `lease ${LeaseAction.PAUSE}`]);
  });

  it("H hands back this page's correction; P or H resumes a paused policy", () => {
    const correcting = rig("correcting", true);
    correcting.s.key("KeyH");
    expect(correcting.calls).toEqual(["release"]);
    const paused = rig("paused");
    paused.s.key("KeyP");
    paused.s.key("KeyH");
    expect(paused.calls).toEqual([`lease ${LeaseAction.RESUME}`, `lease ${LeaseAction.RESUME}`]);
  });

  it("the keys are inert with no policy", () => {
    const { s, calls } = rig("off");
    for (const k of ["KeyT", "KeyP", "KeyH"]) s.key(k);
    expect(calls).toEqual([]);
  });
});

describe("the dead-man and the grip take over from a policy", () => {
  beforeEach(() => vi.useFakeTimers());
  afterEach(() => vi.useRealTimers());

  function loopRig(policyHolds: boolean) {
    const calls: unknown[][] = [];
    const flags = { value: StateFlags.SOMEONE_HAS_CONTROL as number };
    const link = {
      cartesian: () => void calls.push(["cartesian"]),
      lease: (a: number) => void calls.push(["lease", a]),
      wantControl: () => undefined,
      estop: () => undefined,
    };
    const keys: { cmd: MotionCommand } = { cmd: IDLE };
    const loop = new InputLoop({
      link,
      arm: { commandCartesian: () => undefined },
      flags: () => flags.value,
      speed: () => 0.5,
      gamepad: { read: () => ({ command: IDLE, cycleFrame: false, pad: null }) as GamepadState },
      keyboard: { read: () => keys.cmd },
      view: null,
      now: 0,
      policyHolds: () => policyHolds,
    });
    return { loop, calls, keys, flags };
  }

  it("pressing the dead-man takes over once, and sends nothing before control is given", () => {
    const { loop, calls, keys } = loopRig(true);
    keys.cmd = { deadman: true, linear: [1, 0, 0], angular: [0, 0, 0] };
    loop.tick(16);
    loop.tick(32); // still held: not asked again
    expect(calls).toEqual([["lease", LeaseAction.TAKE_OVER]]);
  });

  it("the XR grip does the same", () => {
    const { loop, calls } = loopRig(true);
    const reading = { gripping: true, position: [0, 0, 0], orientation: [0, 0, 0, 1] } as never;
    loop.xrFrame(reading, 16);
    loop.xrFrame(reading, 32);
    expect(calls).toEqual([["lease", LeaseAction.TAKE_OVER]]);
  });

  it("let go for a moment (a re-clutch) it keeps control; let go longer, it hands back", () => {
    const { loop, calls, keys, flags } = loopRig(true);
    const held: MotionCommand = { deadman: true, linear: [0, 0, 0], angular: [0, 0, 0] };
    keys.cmd = held;
    loop.tick(0);
    flags.value = StateFlags.SOMEONE_HAS_CONTROL | StateFlags.YOU_HAVE_CONTROL; // given
    keys.cmd = IDLE;
    loop.tick(100);
    loop.tick(100 + HAND_BACK_MS - 50);
    keys.cmd = held; // gripped again in time
    loop.tick(100 + HAND_BACK_MS);
    keys.cmd = IDLE;
    loop.tick(200 + HAND_BACK_MS);
    expect(calls).toEqual([["lease", LeaseAction.TAKE_OVER]]);
    loop.tick(200 + 2 * HAND_BACK_MS);
    expect(calls).toEqual([["lease", LeaseAction.TAKE_OVER], ["lease", LeaseAction.RELEASE]]);
    loop.tick(300 + 3 * HAND_BACK_MS);
    expect(calls).toHaveLength(2); // once
  });

  it("with a person in control, the dead-man takes nothing", () => {
    const { loop, calls, keys } = loopRig(false);
    keys.cmd = { deadman: true, linear: [1, 0, 0], angular: [0, 0, 0] };
    loop.tick(16);
    expect(calls).toEqual([]);
  });
});
