import { describe, expect, it } from "vitest";
import { PAGE_SILENCE_MS } from "./transport/heartbeat";
import { BUSY_LATE_MS, ControlWatch, haltedText, stopsHeldInputs, type ControlAlert } from "./ui/control-alert";
import { ERROR_CODES, StateFlags } from "./transport/messages";

const MINE = StateFlags.YOU_HAVE_CONTROL | StateFlags.SOMEONE_HAS_CONTROL | StateFlags.OPERATOR;
const NOBODY = StateFlags.OPERATOR;

function watched() {
  const w = new ControlWatch();
  const seen: { alert: ControlAlert | null; sound: boolean }[] = [];
  w.onChange = (alert, sound) => seen.push({ alert, sound });
  return { w, seen };
}

describe("losing control", () => {
  it("is said loudly, with the server's reason, when the lease goes without the operator releasing it", () => {
    const { w, seen } = watched();
    w.state(MINE, 0);
    expect(seen).toEqual([]);
    w.event("control: nobody (dead-man: no heartbeat from 'page' for 2180 ms (the limit is 150 ms, then 2 s of grace))", 10);
    w.state(NOBODY, 20);
    expect(seen).toHaveLength(1);
    expect(seen[0]!.sound).toBe(true);
    expect(seen[0]!.alert?.level).toBe("lost");
    expect(seen[0]!.alert?.text).toContain("dead-man: no heartbeat");
    w.state(NOBODY, 40); // once, not every STATE
    expect(seen).toHaveLength(1);
  });

  it("says so when someone takes it over, and an old reason is not reused", () => {
    const { w, seen } = watched();
    w.event("control: page (taken by 'page')", 0);
    w.state(MINE, 10);
    w.state(StateFlags.SOMEONE_HAS_CONTROL | StateFlags.OPERATOR, 10_000);
    expect(seen[0]!.alert?.text).toBe("CONTROL LOST: the server took it back");
  });

  it("is quiet when the operator released it", () => {
    const { w, seen } = watched();
    w.state(MINE, 0);
    w.released();
    w.state(NOBODY, 10);
    expect(seen).toEqual([]);
  });

  it("is quiet when a STATE sent before the release still showed control", () => {
    const { w, seen } = watched();
    w.state(MINE, 0);
    w.released();
    w.state(MINE, 20); // already on its way when the release was sent (a busy machine)
    w.state(MINE, 40);
    w.state(NOBODY, 60);
    expect(seen).toEqual([]);
  });

  it("a release that never happened does not hide a later loss", () => {
    const { w, seen } = watched();
    w.state(MINE, 0);
    w.released();
    w.state(MINE, 10);
    w.state(MINE, 5_000); // still ours long after: the release did not take
    w.state(NOBODY, 6_000);
    expect(seen[0]!.alert?.text).toContain("CONTROL LOST");
  });

  it("halted by the dead-man: an alarm while the lease is kept, gone when the link is back", () => {
    const { w, seen } = watched();
    w.state(MINE, 0);
    w.state(MINE | StateFlags.HALTED, 10);
    w.state(MINE | StateFlags.HALTED, 30);
    expect(seen).toHaveLength(1);
    expect(seen[0]!.alert?.level).toBe("halted");
    expect(seen[0]!.sound).toBe(true);
    w.state(MINE, 50);
    expect(seen[1]).toEqual({ alert: null, sound: false });
  });

  it("a lost lease stops the held inputs; a dead-man halt (lease kept) lets held keys drive on", () => {
    const { w, seen } = watched();
    w.state(MINE, 0);
    w.state(MINE | StateFlags.HALTED, 10);
    expect(stopsHeldInputs(seen[0]!.alert!)).toBe(false);
    w.state(MINE, 20);
    w.state(NOBODY, 30);
    expect(stopsHeldInputs(seen[2]!.alert!)).toBe(true);
  });

  it("a halt says whose the stall was: this computer's when the worker's timer ran late", () => {
    const { w, seen } = watched();
    w.state(MINE, 0);
    w.state(MINE | StateFlags.HALTED, 10, 180);
    expect(seen[0]!.alert!.text).toContain("this computer is too busy");
    expect(seen[0]!.alert!.text).toContain("180 ms late");
    w.state(MINE, 20);
    w.state(MINE | StateFlags.HALTED, 30, 12);
    expect(seen[2]!.alert!.text).toContain("the network or the server");
    expect(seen[2]!.alert!.text).not.toContain("busy");
    expect(haltedText(BUSY_LATE_MS)).toContain("too busy");
  });

  it("a halt still shown when its cause changes is said again, with no second alarm", () => {
    const { w, seen } = watched();
    w.state(MINE, 0);
    w.state(MINE | StateFlags.HALTED, 10, 5); // the link's
    w.state(MINE | StateFlags.HALTED, 20, 5); // the same: nothing new
    expect(seen).toHaveLength(1);
    w.state(MINE | StateFlags.HALTED, 30, 5, PAGE_SILENCE_MS + 200); // the page stood still
    expect(seen).toHaveLength(2);
    expect(seen[1]!.alert!.text).toContain("this computer is too busy");
    expect(seen[1]!.sound).toBe(false);
  });

  it("a halt after the page's main thread stood still (the worker stops beating) is this computer's", () => {
    const { w, seen } = watched();
    w.state(MINE, 0);
    w.state(MINE | StateFlags.HALTED, 10, 5, PAGE_SILENCE_MS + 400); // the worker's timer on time
    expect(seen[0]!.alert!.text).toContain("this computer is too busy");
    expect(seen[0]!.alert!.text).toContain("stood still for 1.4 s");
    expect(seen[0]!.alert!.text).not.toContain("network");
    w.state(MINE, 20);
    w.state(MINE | StateFlags.HALTED, 30, 5, PAGE_SILENCE_MS - 100); // still beating
    expect(seen[2]!.alert!.text).toContain("the network or the server");
  });

  it("with the connection: an alarm, then after reconnecting as operator an offer to take it again", () => {
    const { w, seen } = watched();
    w.state(MINE, 0);
    w.connection(false);
    expect(seen[0]!.alert?.text).toContain("connection to the server dropped");
    expect(seen[0]!.sound).toBe(true);
    w.connection(true);
    w.welcome(true);
    expect(seen[1]!.alert?.retake).toBe(true);
    expect(seen[1]!.sound).toBe(false);
    w.state(NOBODY, 100); // the new connection holds nothing yet: no second alarm
    expect(seen).toHaveLength(2);
    w.state(MINE, 200); // taken again
    expect(seen[2]).toEqual({ alert: null, sound: false });
  });

  it("offers nothing to a page that did not hold control, or reconnects as an observer", () => {
    const { w, seen } = watched();
    w.state(NOBODY, 0);
    w.connection(false);
    w.welcome(true);
    expect(seen).toEqual([]);
    const b = watched();
    b.w.state(MINE, 0);
    b.w.connection(false);
    b.w.welcome(false);
    expect(b.seen.map((s) => s.alert?.retake)).toEqual([false]);
  });

  it("clears an alert said before the link dropped once a new session is welcomed (a restarted server)", () => {
    const { w, seen } = watched();
    w.state(MINE, 0);
    w.event("control: nobody (dead-man: no heartbeat for 2653 ms)", 10);
    w.state(NOBODY, 20); // CONTROL LOST, with the server's reason
    expect(seen[0]!.alert?.text).toContain("CONTROL LOST: dead-man");
    w.connection(false); // the server restarts…
    w.connection(true);
    w.welcome(true); // …and welcomes this page: the old session's loss is history
    expect(seen.at(-1)).toEqual({ alert: null, sound: false });
    expect(w.alert).toBeNull();
  });

  it("keeps an alert said on this connection: only a drop makes it stale", () => {
    const { w, seen } = watched();
    w.state(MINE, 0);
    w.state(NOBODY, 20);
    w.welcome(true); // the first WELCOME (or one without a drop before it)
    expect(seen).toHaveLength(1);
    expect(w.alert?.level).toBe("lost");
  });
});

describe("refusals of commands already on their way", () => {
  const NOT_ALLOWED = ERROR_CODES.not_allowed;

  it("are left out of the log while control is held and just after it went: the alert says it", () => {
    const { w } = watched();
    w.state(MINE, 0);
    expect(w.quiet(NOT_ALLOWED, 5)).toBe(true); // refused before this page's STATE said so
    w.state(NOBODY, 20);
    expect(w.quiet(NOT_ALLOWED, 1000)).toBe(true);
    expect(w.quiet(NOT_ALLOWED, 2100)).toBe(false); // long after: a refusal worth reading
  });

  it("are logged when this page never held control, and other refusals always are", () => {
    const { w } = watched();
    w.state(NOBODY, 0);
    expect(w.quiet(NOT_ALLOWED, 10)).toBe(false);
    w.state(MINE, 20);
    expect(w.quiet(ERROR_CODES.limit_exceeded, 30)).toBe(false);
  });
});
