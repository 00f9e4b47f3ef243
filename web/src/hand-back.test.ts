// H at the page (issue 55): it hands back whenever this page holds control in a
// correction, and says why whenever it cannot, never silently nothing; a dead-man pressed
// while T's take is on its way drives that correction without making letting go hand it
// back; and the link hears of the dead-man (its worker keeps a stalled page's lease only
// while it is held).
import { afterEach, beforeEach, describe, expect, it, vi } from "vitest";
import type { GamepadState } from "./input/gamepad";
import { HAND_BACK_MS, InputLoop, WANT_CONTROL_MS } from "./input/loop";
import { IDLE, type MotionCommand } from "./input/motion";
import { LeaseAction, StateFlags } from "./transport/messages";
import { Supervision, handBackNote, type AutonomyState } from "./ui/autonomy";

const state = (mode: AutonomyState["mode"], extra: Partial<AutonomyState> = {}): AutonomyState => ({
  mode,
  policy: "act-policy",
  operator: "alice",
  cause: "",
  rate_hz: 30,
  refused: 0,
  interventions: 1,
  ...extra,
});
const LAPSED = "alice's control lapsed: dead-man: no heartbeat from 'alice' for 2889 ms (the limit is 180 ms, then 2.7 s of grace)";

function rig() {
  const calls: string[] = [];
  const said: string[] = [];
  const control = { value: false };
  const s = new Supervision({
    take: () => void calls.push("take"),
    release: () => void calls.push("release"),
    lease: (a) => void calls.push(`lease ${a}`),
    youHaveControl: () => control.value,
    say: (text) => void said.push(text),
  });
  return { s, calls, said, control };
}

describe("H hands back whenever this page has control", () => {
  it("in a correction, and while the page's mode still lags the STATE that gave control", () => {
    for (const mode of ["correcting", "autonomous", "paused"] as const) {
      const { s, calls, said, control } = rig();
      control.value = true;
      s.update(state(mode));
      s.key("KeyH");
      expect(calls, mode).toEqual(["release"]);
      expect(said, mode).toEqual([]);
    }
  });
});

describe("H says why when it cannot hand back", () => {
  it("this page's correction lapsed: the policy was paused; H lets it drive again and says so", () => {
    const { s, calls, said, control } = rig();
    control.value = true;
    s.update(state("correcting"));
    control.value = false; // the lease lapsed…
    s.refresh();
    s.update(state("paused", { cause: LAPSED })); // …and the server paused the policy
    s.key("KeyH");
    expect(calls).toEqual([`lease ${LeaseAction.RESUME}`]);
    expect(said).toEqual([`H: this page's control was lost before H (${LAPSED}), which paused the policy; H lets it drive again.`]);
    s.key("KeyH"); // said once
    expect(said).toHaveLength(1);
  });

  it("control went and the news of why has not come yet, or another operator took over", () => {
    const { s, calls, said, control } = rig();
    control.value = true;
    s.update(state("correcting"));
    control.value = false;
    s.refresh();
    s.key("KeyH");
    expect(calls).toEqual([]);
    expect(said[0]).toMatch(/^H did not hand back: this page's control was lost; alice is correcting now/);
    s.update(state("correcting", { operator: "bob", cause: "taken over by 'bob'" }));
    s.key("KeyH");
    expect(said[1]).toBe("H did not hand back: this page does not have control; bob is correcting, and hands back.");
  });

  it("the policy already drives (the dead-man let go handed back first), or another page corrects", () => {
    const { s, calls, said } = rig();
    s.update(state("autonomous", { cause: "handed back by 'alice'" }));
    s.key("KeyH");
    expect(said).toEqual(["H did not hand back: the policy already drives."]);
    expect(calls).toEqual([]);
    expect(handBackNote(state("correcting", { operator: "bob" }), false, false)).toMatch(/bob is correcting/);
  });

  it("a policy a person paused: H resumes it, nothing to say", () => {
    const { s, calls, said } = rig();
    s.update(state("paused", { cause: "paused by 'alice'" }));
    s.key("KeyH");
    expect(calls).toEqual([`lease ${LeaseAction.RESUME}`]);
    expect(said).toEqual([]);
  });
});

describe("T, then the dead-man before control came", () => {
  beforeEach(() => vi.useFakeTimers());
  afterEach(() => vi.useRealTimers());

  function loopRig() {
    const calls: unknown[][] = [];
    const flags = { value: StateFlags.SOMEONE_HAS_CONTROL as number };
    const keys: { cmd: MotionCommand } = { cmd: IDLE };
    const loop = new InputLoop({
      link: {
        cartesian: () => void calls.push(["cartesian"]),
        lease: (a: number) => void calls.push(["lease", a]),
        wantControl: (on: boolean) => void calls.push(["want", on]),
        estop: () => undefined,
        deadman: (held: boolean) => void calls.push(["deadman", held]),
      },
      arm: { commandCartesian: () => undefined },
      flags: () => flags.value,
      speed: () => 0.5,
      gamepad: { read: () => ({ command: IDLE, cycleFrame: false, pad: null }) as GamepadState },
      keyboard: { read: () => keys.cmd },
      view: null,
      now: 0,
      policyHolds: () => (flags.value & StateFlags.YOU_HAVE_CONTROL) === 0,
    });
    return { loop, calls, keys, flags };
  }

  it("drives T's correction: letting go keeps control", () => {
    const { loop, calls, keys, flags } = loopRig();
    loop.take(); // T
    keys.cmd = { deadman: true, linear: [1, 0, 0], angular: [0, 0, 0] };
    loop.tick(16); // Space, before the STATE says control came: no second take
    flags.value |= StateFlags.YOU_HAVE_CONTROL;
    loop.tick(32);
    keys.cmd = IDLE;
    loop.tick(48);
    loop.tick(48 + 2 * HAND_BACK_MS);
    const leases = calls.filter((c) => c[0] === "lease");
    expect(leases).toEqual([["lease", LeaseAction.TAKE_OVER]]); // never released
    expect(calls.filter((c) => c[0] === "cartesian").length).toBeGreaterThan(0);
  });

  it("once the take was answered, a dead-man pressed after the hand-back takes over again", () => {
    const { loop, calls, keys, flags } = loopRig();
    loop.take(); // T (or the button)
    flags.value |= StateFlags.YOU_HAVE_CONTROL;
    loop.tick(16); // control came
    loop.release(); // H
    flags.value &= ~StateFlags.YOU_HAVE_CONTROL;
    loop.tick(32);
    keys.cmd = { deadman: true, linear: [0, 0, 0], angular: [0, 0, 0] };
    loop.tick(48); // well within WANT_CONTROL_MS of T
    expect(calls.filter((c) => c[0] === "lease")).toEqual([
      ["lease", LeaseAction.TAKE_OVER],
      ["lease", LeaseAction.RELEASE],
      ["lease", LeaseAction.TAKE_OVER],
    ]);
  });

  it("tells the link when the dead-man or the XR grip is pressed and let go, once each", () => {
    const { loop, calls, keys } = loopRig();
    keys.cmd = { deadman: true, linear: [0, 0, 0], angular: [0, 0, 0] };
    loop.tick(16);
    loop.tick(32);
    keys.cmd = IDLE;
    loop.tick(48);
    const grip = { gripping: true, position: [0, 0, 0], orientation: [0, 0, 0, 1] } as never;
    loop.xrFrame(grip, 64);
    loop.xrFrame(null, 80);
    expect(calls.filter((c) => c[0] === "deadman")).toEqual([["deadman", true], ["deadman", false], ["deadman", true], ["deadman", false]]);
  });

  it("a later take's WANT_CONTROL_MS is not cut short by an earlier one's", () => {
    const { loop, calls } = loopRig();
    loop.take();
    vi.advanceTimersByTime(WANT_CONTROL_MS - 500);
    loop.take(); // asked again before the first answer came
    vi.advanceTimersByTime(600); // the first take's time is up
    expect(calls.filter((c) => c[0] === "want")).toEqual([["want", true], ["want", true]]);
    vi.advanceTimersByTime(WANT_CONTROL_MS);
    expect(calls.filter((c) => c[0] === "want").at(-1)).toEqual(["want", false]);
  });
});
