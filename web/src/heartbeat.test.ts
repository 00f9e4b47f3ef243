import { describe, expect, it } from "vitest";
import { BeatRecord, LATE_MEMORY_MS, PAGE_SILENCE_MS, TimerLateness, heartbeatDue, heartbeatSkip } from "./transport/heartbeat";

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
    expect(t.recent(0, 50)).toBe(0); // one firing: nothing to compare with
    t.fired(50, 50);
    t.fired(280, 50); // 180 ms late: the worker did not get its turn
    t.fired(330, 50);
    expect(t.recent(330, 50)).toBe(180);
    // Beating on time from then on: remembered for LATE_MEMORY_MS, then forgotten.
    let now = 330;
    while (now < 280 + LATE_MEMORY_MS) t.fired((now += 50), 50);
    expect(t.recent(now, 50)).toBe(180);
    t.fired((now += 50), 50);
    t.fired((now += 50), 50);
    expect(t.recent(now, 50)).toBe(0);
  });

  it("a later, smaller lateness does not hide a recent worse one", () => {
    const t = new TimerLateness();
    t.fired(0, 50);
    t.fired(200, 50); // 150 late
    t.fired(280, 50); // 30 late
    expect(t.recent(300, 50)).toBe(150);
  });

  it("an overdue timer counts now: news of a halt may come before the late timer fires", () => {
    const t = new TimerLateness();
    t.fired(0, 50);
    t.fired(50, 50);
    expect(t.recent(450, 50)).toBe(350); // nothing fired for 400 ms
  });
});

describe("what the worker's heartbeats did (whose a halt was, when the timer was on time)", () => {
  const base = { now: 10_000, wanted: true, lastSent: 9_950, pageSeen: 9_900 };

  it("says why a firing sent nothing", () => {
    expect(heartbeatSkip(base)).toBe(null);
    expect(heartbeatSkip({ ...base, wanted: false })).toBe("unwanted");
    expect(heartbeatSkip({ ...base, pageSeen: base.now - PAGE_SILENCE_MS - 1 })).toBe("pageSilent");
    expect(heartbeatSkip({ ...base, lastSent: 9_990 })).toBe("recent");
  });

  it("keeps the worst gap between messages sent and counts the skips by reason", () => {
    const b = new BeatRecord();
    b.fired(null, 0);
    b.fired(null, 50);
    expect(b.worstGap(60)).toBe(50);
    b.fired("pageSilent", 50); // a hung main thread: nothing sent at 100 …
    b.fired("pageSilent", 50); // … nor at 150
    expect(b.worstGap(150)).toBe(100); // overdue: counted now
    b.fired(null, 200);
    expect(b.worstGap(210)).toBe(150);
    expect(b.skips).toEqual({ unwanted: 0, pageSilent: 2, recent: 0 });
  });

  it("counts no gap while control is not wanted", () => {
    const b = new BeatRecord();
    b.fired(null, 0);
    b.fired("unwanted", 0);
    expect(b.worstGap(5_000)).toBe(0);
    b.fired(null, 5_000); // wanted again: the pause was not a gap
    b.fired(null, 5_050);
    expect(b.worstGap(5_060)).toBe(50);
  });
});
