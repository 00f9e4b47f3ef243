import { describe, expect, it } from "vitest";
import { RUMBLE_PERIOD_MS, Rumble, rumbleStrength } from "./input/rumble";

function fakePads() {
  const effects: { strong: number }[] = [];
  const pulses: number[] = [];
  const gamepad = { vibrationActuator: { playEffect: (_t: string, p: { strongMagnitude: number }) => (effects.push({ strong: p.strongMagnitude }), Promise.resolve()) } };
  const xr = { hapticActuators: [{ pulse: (v: number) => (pulses.push(v), Promise.resolve(true)) }] };
  return { effects, pulses, pads: [gamepad, xr] as unknown as Gamepad[] };
}

describe("rumble", () => {
  it("is proportional to the force, clamped, and silent under the noise floor", () => {
    expect(rumbleStrength(30, 60)).toBeCloseTo(0.5);
    expect(rumbleStrength(-30, 60)).toBeCloseTo(0.5);
    expect(rumbleStrength(600, 60)).toBe(1);
    expect(rumbleStrength(1, 60)).toBe(0);
    expect(rumbleStrength(Number.NaN, 60)).toBe(0);
    expect(rumbleStrength(30, 0)).toBe(0);
  });

  it("pulses gamepads and XR controllers at most once a period, and not when switched off", () => {
    const { effects, pulses, pads } = fakePads();
    const r = new Rumble();
    r.drive(1000, 0.5, pads);
    r.drive(1000 + RUMBLE_PERIOD_MS / 2, 0.5, pads); // too soon
    expect(effects).toEqual([{ strong: 0.5 }]);
    expect(pulses).toEqual([0.5]);
    r.drive(1000 + RUMBLE_PERIOD_MS, 0.25, pads);
    expect(pulses).toEqual([0.5, 0.25]);
    r.drive(2000, 0, pads); // no contact: nothing
    r.enabled = false;
    r.drive(3000, 1, pads);
    expect(pulses).toEqual([0.5, 0.25]);
    r.drive(4000, 1, [null, undefined]); // no device: no error
  });

  it("uses one motor interface per device, and skips actuators it cannot drive", () => {
    const { effects, pulses } = fakePads();
    const both = {
      hapticActuators: [{ pulse: (v: number) => (pulses.push(v), Promise.resolve(true)) }],
      vibrationActuator: { type: "vibration" }, // no playEffect (an XR runtime's actuator)
    };
    const r = new Rumble();
    expect(() => r.drive(0, 0.5, [both as unknown as Gamepad])).not.toThrow();
    expect(pulses).toEqual([0.5]);
    expect(effects).toEqual([]);
    const odd = { vibrationActuator: { type: "vibration" } };
    expect(() => r.drive(100, 0.5, [odd as unknown as Gamepad])).not.toThrow();
  });
});
