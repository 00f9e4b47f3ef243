// The header's one state model: from what the page knows (the link, the role, the
// latest STATE and how old it is, a Home move in flight) to everything the header
// shows — the status badge, role and control text, which buttons show and work, the
// E-STOP button's latched look and the banner. Pure, so every case is tested.
import { StateFlags } from "../transport/messages";

/** No STATE for this long while the socket says open: what the page shows is stale. */
export const STALE_MS = 1000;

export type HomeStep = "idle" | "confirm" | "moving";

export interface HeaderInput {
  /** The realtime socket is open. */
  linkOpen: boolean;
  /** Why it closed (shown while it is). */
  disconnectReason?: string;
  /** The server welcomed this page as an operator (its token). */
  operator: boolean;
  /** The latest STATE (null: none yet). */
  state: { status: string; flags: number } | null;
  /** How long ago the latest STATE came (ms); with no STATE, how long the link has been open. */
  stateAgeMs: number;
  /** The Home button: waiting for its confirming click, or its move in flight. */
  home?: HomeStep;
  /** Who has control, by the name it gave itself (null or absent: not known, or nobody). */
  controller?: string | null;
  /** A policy holds control (autonomous or paused): an operator supervising it may reset
   * the e-stop, as the server allows; the policy drives again only when a person says go. */
  policyHolds?: boolean;
}

export interface ButtonView {
  visible: boolean;
  enabled: boolean;
}

export interface HeaderView {
  badge: { text: string; cls: string };
  role: string;
  control: string;
  take: ButtonView;
  release: ButtonView;
  reset: ButtonView;
  home: ButtonView & { text: string };
  estop: { latched: boolean; text: string; cls: string };
  tokenRow: boolean;
  /** "": no banner. */
  banner: { text: string; error: boolean };
}

const hidden: ButtonView = { visible: false, enabled: false };

export function headerView(i: HeaderInput): HeaderView {
  const flags = i.state?.flags ?? 0;
  const has = (bit: number) => bit !== 0 && (flags & bit) !== 0;
  const stale = i.linkOpen && i.stateAgeMs > STALE_MS;
  // What the flags say holds only while they are fresh.
  const known = i.linkOpen && !stale && i.state !== null;
  const mine = known && has(StateFlags.YOU_HAVE_CONTROL);
  const estop = known && has(StateFlags.ESTOP);
  const halted = known && has(StateFlags.HALTED);
  const forceLimited = known && has(StateFlags.FORCE_LIMITED);
  const seconds = (Math.min(i.stateAgeMs, 3_600_000) / 1000).toFixed(1);

  let badge: HeaderView["badge"];
  let banner: HeaderView["banner"] = { text: "", error: false };
  let control: string;
  if (!i.linkOpen) {
    badge = { text: "DISCONNECTED", cls: "DISCONNECTED" };
    control = "control: unknown (disconnected)";
    banner = { text: `Disconnected: ${i.disconnectReason || "no connection to the server"}; reconnecting…`, error: true };
  } else if (i.state === null && !stale) {
    badge = { text: "connecting…", cls: "" };
    control = "control: unknown (no state yet)";
  } else if (stale) {
    badge = { text: i.state ? "STALE" : "NO STATE", cls: "STALE" };
    control = "control: unknown (no state)";
    banner = { text: `No robot state for ${seconds} s: what this page shows is out of date`, error: true };
  } else {
    if (estop) badge = { text: "E-STOP", cls: "ESTOP" };
    else if (halted) badge = { text: "HALTED: link stalled", cls: "HALTED" };
    else if (forceLimited) badge = { text: "FORCE LIMIT", cls: "FORCE_LIMIT" };
    else badge = { text: i.state?.status ?? "…", cls: i.state?.status ?? "" };
    const other = i.controller ? `${i.controller} has control` : "someone else has control";
    control = mine ? "you have control" : has(StateFlags.SOMEONE_HAS_CONTROL) ? other : "nobody has control";
    if (estop && !mine && i.policyHolds) banner = { text: "E-STOP latched: reset it; the policy then waits until you press P", error: false };
    else if (estop) banner = { text: mine || !has(StateFlags.SOMEONE_HAS_CONTROL) ? "E-STOP latched: reset it to move again" : "E-STOP latched: whoever has control must reset it", error: false };
    else if (halted) banner = { text: "Arm halted: the link stalled (you keep control): keys still held drive again once it is back", error: false };
    else if (forceLimited) banner = { text: "Force limit: back away from the contact", error: false };
  }

  const home = i.home ?? "idle";
  return {
    badge,
    role: !i.linkOpen ? "role: unknown" : i.operator ? "operator" : "observer (watching only)",
    control,
    take: i.operator && i.linkOpen && !mine ? { visible: true, enabled: known } : hidden,
    release: mine ? { visible: true, enabled: true } : hidden,
    reset: estop && i.operator ? { visible: true, enabled: mine || !has(StateFlags.SOMEONE_HAS_CONTROL) || (i.policyHolds ?? false) } : hidden,
    home: mine
      ? { visible: true, enabled: home !== "moving" && !estop, text: home === "confirm" ? "Confirm: move home" : home === "moving" ? "Homing…" : "Home" }
      : { ...hidden, text: "Home" },
    // The e-stop always works (anyone may send it); latched, it says so.
    estop: estop ? { latched: true, text: "E-STOP LATCHED", cls: "latched" } : { latched: false, text: "E-STOP", cls: "" },
    tokenRow: i.linkOpen && !i.operator,
    banner,
  };
}
