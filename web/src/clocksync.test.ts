import { describe, expect, it } from "vitest";
import { ClockSync, WINDOW } from "./transport/clocksync";

describe("ClockSync", () => {
  it("takes the offset of the exchange with the least round trip", () => {
    const c = new ClockSync();
    expect(c.synced).toBe(false);
    expect(c.bestRtt).toBe(Infinity);
    // server = page + 100 s; a slow exchange with asymmetric delay first, then a quick one
    c.add(0, 100.08, 100.08, 0.1); // 80 ms out, 20 back: offset off by 30 ms
    c.add(1, 101.005, 101.006, 1.011); // 5 ms each way
    expect(c.synced).toBe(true);
    expect(c.offset).toBeCloseTo(100, 6);
    expect(c.bestRtt).toBeCloseTo(0.01, 6);
  });

  it("follows a drifting clock: old exchanges leave the window", () => {
    const c = new ClockSync();
    c.add(0, 100.001, 100.001, 0.002); // the best round trip ever, offset 100
    for (let i = 1; i <= WINDOW; i++) {
      // later, the server has drifted 0.5 s ahead; every exchange takes 4 ms
      const t0 = 10 * i;
      c.add(t0, t0 + 100.502, t0 + 100.502, t0 + 0.004);
    }
    expect(c.offset).toBeCloseTo(100.5, 6);
  });

  it("ignores an impossible exchange", () => {
    const c = new ClockSync();
    c.add(5, 1, 1, 4); // back before it was sent
    c.add(0, Number.NaN, 1, 1);
    expect(c.synced).toBe(false);
  });
});
