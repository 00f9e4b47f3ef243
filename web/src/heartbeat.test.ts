import { describe, expect, it } from "vitest";
import { LATE_MEMORY_MS, PAGE_SILENCE_MS, TimerLateness, heartbeatDue } from "./transport/heartbeat";

describe("dead-man heartbeat in the realtime worker", () => {
  const base = { now: 10_000, wanted: true, lastSent: 9_950, pageSeen: 9_900 };

  it("beats while control is wanted and the page checks in", () => {
    expect(heartbeatDue(base)).toBe(true);
  });

  it("does not beat without control, right after another message, or for a silent page", () => {
    expect(heartbeatDue({ ...base, wanted: false })).toBe(false);
    expect(heartbeatDue({ ...base, lastSent: 9_990 })).toBe(false); // a command just went
    expect(heartbeatDue({ ...base, pageSeen: base.now - PAGE_SILENCE_MS - 1 })).toBe(false);
    expect(heartbeatDue({ ...base, pageSeen: base.now - PAGE_SILENCE_MS })).toBe(true);
  });
});

describe("the worker's own timer lateness (whose a dead-man halt was)", () => {
  it("keeps the worst lateness for LATE_MEMORY_MS, then forgets it", () => {
    const t = new TimerLateness();
    t.fired(0, 50);
    expect(t.recent(0)).toBe(0); // one firing: nothing to compare with
    t.fired(50, 50);
    t.fired(280, 50); // 180 ms late: the worker did not get its turn
    t.fired(330, 50);
    expect(t.recent(330)).toBe(180);
    expect(t.recent(280 + LATE_MEMORY_MS)).toBe(180);
    expect(t.recent(281 + LATE_MEMORY_MS)).toBe(0);
  });

  it("a later, smaller lateness does not hide a recent worse one", () => {
    const t = new TimerLateness();
    t.fired(0, 50);
    t.fired(200, 50); // 150 late
    t.fired(280, 50); // 30 late
    expect(t.recent(300)).toBe(150);
  });
});
