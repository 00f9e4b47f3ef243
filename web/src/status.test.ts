import { describe, expect, it } from "vitest";
import { StateFlags } from "./transport/messages";
import { STALE_MS, headerView, type HeaderInput } from "./ui/status";

const { YOU_HAVE_CONTROL, SOMEONE_HAS_CONTROL, ESTOP, FORCE_LIMITED, OPERATOR } = StateFlags;
const view = (over: Partial<HeaderInput> = {}, flags = OPERATOR | YOU_HAVE_CONTROL, status = "READY") =>
  headerView({ linkOpen: true, operator: true, state: { status, flags }, stateAgeMs: 20, ...over });

describe("the header's state model", () => {
  it("in control, connected and fresh: the robot's status, you have control, Release and Home", () => {
    const v = view();
    expect(v.badge).toEqual({ text: "READY", cls: "READY" });
    expect(v.role).toBe("operator");
    expect(v.control).toBe("you have control");
    expect(v.take.visible).toBe(false);
    expect(v.release).toEqual({ visible: true, enabled: true });
    expect(v.home).toMatchObject({ visible: true, enabled: true, text: "Home" });
    expect(v.reset.visible).toBe(false);
    expect(v.estop).toEqual({ latched: false, text: "E-STOP", cls: "" });
    expect(v.banner.text).toBe("");
    expect(v.tokenRow).toBe(false);
  });

  it("disconnected: DISCONNECTED, never 'you have control', no control buttons, an error banner", () => {
    // the last STATE still said we had control
    const v = view({ linkOpen: false, disconnectReason: "server went away" });
    expect(v.badge).toEqual({ text: "DISCONNECTED", cls: "DISCONNECTED" });
    expect(v.control).toBe("control: unknown (disconnected)");
    expect(v.control).not.toContain("you have control");
    expect(v.role).toBe("role: unknown");
    for (const b of [v.take, v.release, v.reset, v.home]) expect(b.visible).toBe(false);
    expect(v.banner).toEqual({ text: "Disconnected: server went away; reconnecting…", error: true });
    expect(v.estop.latched).toBe(false); // unknown, not claimed
  });

  it("e-stop latched: the badge says E-STOP, the button is latched, Reset shows, Home is disabled", () => {
    const v = view({}, OPERATOR | YOU_HAVE_CONTROL | ESTOP, "READY");
    expect(v.badge).toEqual({ text: "E-STOP", cls: "ESTOP" });
    expect(v.estop).toEqual({ latched: true, text: "E-STOP LATCHED", cls: "latched" });
    expect(v.reset).toEqual({ visible: true, enabled: true });
    expect(v.home).toMatchObject({ visible: true, enabled: false });
    expect(v.banner.text).toContain("E-STOP latched");
    // the e-stop wins over the force limit
    expect(view({}, YOU_HAVE_CONTROL | ESTOP | FORCE_LIMITED).badge.text).toBe("E-STOP");
  });

  it("e-stop latched while someone else has control: Reset shows but is theirs", () => {
    const v = view({}, OPERATOR | SOMEONE_HAS_CONTROL | ESTOP);
    expect(v.estop.latched).toBe(true);
    expect(v.reset).toEqual({ visible: true, enabled: false });
    expect(v.banner.text).toContain("whoever has control");
  });

  it("e-stop latched while a policy holds control: its supervisor may reset it", () => {
    const v = view({ policyHolds: true }, OPERATOR | SOMEONE_HAS_CONTROL | ESTOP);
    expect(v.reset).toEqual({ visible: true, enabled: true });
  });

  it("force limited: FORCE LIMIT and its banner", () => {
    const v = view({}, YOU_HAVE_CONTROL | FORCE_LIMITED, "MOVING");
    expect(v.badge).toEqual({ text: "FORCE LIMIT", cls: "FORCE_LIMIT" });
    expect(v.banner).toEqual({ text: "Force limit: back away from the contact", error: false });
    expect(v.control).toBe("you have control");
    expect(v.estop.latched).toBe(false);
  });

  it("an observer: watching only, no Take, the token field, no Reset even in an e-stop", () => {
    const v = view({ operator: false }, SOMEONE_HAS_CONTROL | ESTOP);
    expect(v.role).toBe("observer (watching only)");
    expect(v.take.visible).toBe(false);
    expect(v.reset.visible).toBe(false);
    expect(v.home.visible).toBe(false);
    expect(v.tokenRow).toBe(true);
    expect(v.badge.text).toBe("E-STOP");
    expect(v.estop.latched).toBe(true);
  });

  it("someone else in control: Take (over) shows, no Release or Home", () => {
    const v = view({}, OPERATOR | SOMEONE_HAS_CONTROL, "MOVING");
    expect(v.control).toBe("someone else has control");
    expect(v.take).toEqual({ visible: true, enabled: true });
    expect(v.release.visible).toBe(false);
    expect(v.home.visible).toBe(false);
    expect(v.badge.text).toBe("MOVING");
  });

  it("someone else in control, by the name it gave itself (not 'someone else')", () => {
    const v = view({ controller: "Ana at the bench" }, OPERATOR | SOMEONE_HAS_CONTROL);
    expect(v.control).toBe("Ana at the bench has control");
    // Mine, the name is mine: still "you have control"; nobody, a stale name says nothing.
    expect(view({ controller: "Ana at the bench" }).control).toBe("you have control");
    expect(view({ controller: "Ana at the bench" }, OPERATOR).control).toBe("nobody has control");
    expect(view({ controller: null }, OPERATOR | SOMEONE_HAS_CONTROL).control).toBe("someone else has control");
  });

  it("nobody in control", () => {
    const v = view({}, OPERATOR);
    expect(v.control).toBe("nobody has control");
    expect(v.take).toEqual({ visible: true, enabled: true });
  });

  it("stale: no STATE for over a second while the socket says open: STALE, control unknown, a banner", () => {
    expect(view({ stateAgeMs: STALE_MS - 1 }).badge.text).toBe("READY");
    const v = view({ stateAgeMs: 2500 }, OPERATOR | YOU_HAVE_CONTROL | ESTOP);
    expect(v.badge).toEqual({ text: "STALE", cls: "STALE" });
    expect(v.control).toBe("control: unknown (no state)");
    expect(v.banner).toEqual({ text: "No robot state for 2.5 s: what this page shows is out of date", error: true });
    expect(v.release.visible).toBe(false);
    expect(v.home.visible).toBe(false);
    expect(v.take).toEqual({ visible: true, enabled: false }); // an operator: shown, but nothing to act on
    expect(v.estop.latched).toBe(false);
  });

  it("connected but no STATE yet: connecting…, then NO STATE after a second", () => {
    expect(view({ state: null, stateAgeMs: 100 }).badge.text).toBe("connecting…");
    expect(view({ state: null, stateAgeMs: 100 }).control).not.toContain("you have control");
    expect(view({ state: null, stateAgeMs: 1500 }).badge).toEqual({ text: "NO STATE", cls: "STALE" });
  });

  it("the Home button: asks to confirm, then is disabled while its move is in flight", () => {
    expect(view({ home: "confirm" }).home).toMatchObject({ visible: true, enabled: true, text: "Confirm: move home" });
    expect(view({ home: "moving" }).home).toMatchObject({ visible: true, enabled: false, text: "Homing…" });
  });


  it("halted by the dead-man with the lease kept: HALTED: link stalled", () => {
    const v = view({}, OPERATOR | YOU_HAVE_CONTROL | StateFlags.HALTED);
    expect(v.badge).toEqual({ text: "HALTED: link stalled", cls: "HALTED" });
    expect(v.control).toBe("you have control");
    expect(v.banner.text).toContain("halted");
    expect(view({}, YOU_HAVE_CONTROL | StateFlags.HALTED | ESTOP).badge.text).toBe("E-STOP");
  });
});
