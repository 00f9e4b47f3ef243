import { describe, expect, it } from "vitest";
import { PAGE_SILENCE_MS, heartbeatDue } from "./transport/heartbeat";

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
