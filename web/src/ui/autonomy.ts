// Supervising a policy (docs/protocol.md, Supervised autonomy). When a learned policy
// drives, the header says AUTONOMOUS / PAUSED / CORRECTING (lerobot's DAgger names)
// with the policy's name and rate, and one action takes over: T or "Take over", the
// dead-man (Space, the gamepad's R1) or the XR grip (input/loop.ts). The arm stops
// where it is and the operator drives from there. H or "Hand back" gives control back
// to the policy, as does letting go of the dead-man or the grip that took over for
// HAND_BACK_MS (a quicker re-clutch keeps control); P or "Pause" holds it still (look,
// think) and P again resumes it. A policy that took control, or was stopped (the e-stop,
// the force limit, a pause, a lapse, a reconnect), waits PAUSED until P (or Resume).
// The server decides; the page shows what it said (EVENT autonomy, GET /autonomy).
import type { components } from "../api/schema";
import { LeaseAction } from "../transport/messages";

/** What GET /autonomy says, and each EVENT autonomy's JSON. */
export type AutonomyState = components["schemas"]["AutonomyView"];
export type AutonomyMode = AutonomyState["mode"];

const MODES: readonly AutonomyMode[] = ["off", "autonomous", "paused", "correcting"];

/** An EVENT autonomy's text (JSON) as a state; null if it is not one. */
export function parseAutonomy(text: string): AutonomyState | null {
  let v: unknown;
  try {
    v = JSON.parse(text);
  } catch {
    return null;
  }
  if (typeof v !== "object" || v === null) return null;
  const o = v as Record<string, unknown>;
  if (!MODES.includes(o.mode as AutonomyMode)) return null;
  const str = (x: unknown): string | null => (typeof x === "string" ? x : null);
  const num = (x: unknown): number => (typeof x === "number" && Number.isFinite(x) ? x : 0);
  return {
    mode: o.mode as AutonomyMode,
    policy: str(o.policy),
    operator: str(o.operator),
    cause: str(o.cause) ?? "",
    rate_hz: num(o.rate_hz),
    refused: num(o.refused),
    interventions: num(o.interventions),
  };
}

/** What the header shows: the badge's text (empty: hidden), and which buttons. */
export interface AutonomyView {
  badge: string;
  pause: boolean; // "Pause" (the policy drives)
  resume: boolean; // "Resume" (paused)
  handBack: boolean; // "Hand back" (this page corrects)
  takeLabel: string;
}

export function autonomyView(s: AutonomyState | null, youHaveControl: boolean): AutonomyView {
  const policy = s?.policy ?? "the policy";
  switch (s?.mode ?? "off") {
    case "autonomous":
      return {
        badge: `AUTONOMOUS · ${policy}${s && s.rate_hz > 0 ? ` · ${Math.round(s.rate_hz)} Hz` : ""}`,
        pause: true,
        resume: false,
        handBack: false,
        takeLabel: "Take over (T)",
      };
    case "paused":
      // Said plainly: a policy never drives again until a person lets it (the server's rule).
      return {
        badge: `PAUSED · ${policy} — press P to let it drive (${s?.cause ?? ""})`,
        pause: false,
        resume: true,
        handBack: false,
        takeLabel: "Take over (T)",
      };
    case "correcting":
      return {
        badge: `CORRECTING · ${s?.operator ?? "an operator"} drives, ${policy} waits`,
        pause: false,
        resume: false,
        handBack: youHaveControl,
        takeLabel: "Take control",
      };
    default:
      return { badge: "", pause: false, resume: false, handBack: false, takeLabel: "Take control" };
  }
}

/** The keys (KeyboardEvent.code) that supervise a policy. */
export const AUTONOMY_KEYS: Record<string, "take" | "pause" | "handBack"> = { KeyT: "take", KeyP: "pause", KeyH: "handBack" };

export interface AutonomyActions {
  /** Take control (over the policy: the server needs no force for it). */
  take(): void;
  /** Give control back (correcting: the server hands it to the policy). */
  release(): void;
  lease(action: number): void;
  youHaveControl(): boolean;
  /** Tell the operator (the page's messages) why H did not hand back, or what it did instead. */
  say?(text: string): void;
}

/** The supervision changed because a correcting operator's control lapsed (the server's
 * cause: "<name>'s control lapsed: <why>", backend/control/autonomy.py). */
function lapsed(s: AutonomyState | null): boolean {
  return /'s control lapsed: /.test(s?.cause ?? "");
}

/** What H says when it has no correction of this page's to hand back (null: nothing to
 * say: it hands back, or resumes a policy a person paused). `lostHere`: this page was
 * correcting and its control went without its hand-back (a lapse, another's takeover). */
export function handBackNote(s: AutonomyState | null, youHaveControl: boolean, lostHere: boolean): string | null {
  if (youHaveControl) return null;
  const mode = s?.mode ?? "off";
  const why = s?.cause ? ` (${s.cause})` : "";
  if (mode === "paused") return lostHere ? `H: this page's control was lost before H${why}, which paused the policy; H lets it drive again.` : null;
  if (mode === "correcting") {
    const who = s?.operator ?? "another operator";
    return lostHere
      ? `H did not hand back: this page's control was lost${why}; ${who} is correcting now, and hands back.`
      : `H did not hand back: this page does not have control; ${who} is correcting, and hands back.`;
  }
  if (mode === "autonomous") return `H did not hand back: the policy already drives${lostHere ? `; this page's control was lost${why}` : ""}.`;
  return null;
}

/** The supervision's state and what the operator's actions send. */
export class Supervision {
  state: AutonomyState | null = null;
  onChange: ((view: AutonomyView) => void) | null = null;
  // This page held control in a correction, which has not ended by a hand-back since
  // (it is going on, or it ended by a lapse): H then says if the control was lost.
  private correctingHere = false;

  constructor(private readonly a: AutonomyActions) {}

  /** A policy is connected and supervised (autonomous, paused or corrected). */
  get active(): boolean {
    return (this.state?.mode ?? "off") !== "off";
  }

  /** A policy holds control (autonomous or paused): the dead-man or the grip takes over. */
  get policyHolds(): boolean {
    const mode = this.state?.mode;
    return mode === "autonomous" || mode === "paused";
  }

  update(state: AutonomyState | null): void {
    this.state = state;
    this.refresh();
  }

  refresh(): void {
    const control = this.a.youHaveControl();
    const mode = this.state?.mode ?? "off";
    if (mode === "correcting" && control) this.correctingHere = true;
    else if (mode !== "correcting" && !lapsed(this.state)) this.correctingHere = false;
    this.onChange?.(autonomyView(this.state, control));
  }

  takeOver(): void {
    if (this.policyHolds) this.a.take();
  }

  pause(): void {
    if (this.state?.mode === "autonomous" || this.state?.mode === "correcting") this.a.lease(LeaseAction.PAUSE);
    else if (this.state?.mode === "paused") this.a.lease(LeaseAction.RESUME);
  }

  /** H: hand this page's correction back. Whenever the page has control the release
   * goes (the server hands a correction back; the page's mode may lag the STATE that
   * says control came, on a loaded machine); a paused policy is resumed; otherwise
   * nothing is sent and the page says why (handBackNote), never silently nothing. */
  handBack(): void {
    const control = this.a.youHaveControl();
    const lost = this.correctingHere && !control && (this.state?.mode === "correcting" || lapsed(this.state));
    this.correctingHere = false; // said once; handed back on purpose is not a loss
    const note = handBackNote(this.state, control, lost);
    if (note) this.a.say?.(note);
    if (control) this.a.release();
    else if (this.state?.mode === "paused") this.a.lease(LeaseAction.RESUME);
  }

  /** A key went down (KeyboardEvent.code): T, P and H act only while a policy is supervised. */
  key(code: string): void {
    const action = AUTONOMY_KEYS[code];
    if (!action || !this.active) return;
    if (action === "take") this.takeOver();
    else if (action === "pause") this.pause();
    else this.handBack();
  }
}
