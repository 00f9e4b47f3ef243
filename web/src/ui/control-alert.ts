// Losing control is said where the operator looks: over the video, in red, with a
// sound, and the inputs held at that moment stop driving (each must be released and
// pressed again). Also the arm halted by the dead-man (the link stalled; the lease is
// kept a moment), and, after the link came back, the offer to take control again when
// this page held it (only on the operator's say-so: someone may have walked up to the
// arm meanwhile).
import { PAGE_SILENCE_MS } from "../transport/heartbeat";
import { ERROR_CODES, StateFlags } from "../transport/messages";

export interface ControlAlert {
  level: "lost" | "halted";
  text: string;
  /** Offer a button that takes control again (this page held it before the link dropped). */
  retake: boolean;
}

/** How long a lease event's reason explains a loss of control seen in STATE. */
const REASON_MS = 3000;
/** How long after control went a refusal of "not allowed" is a command that was already
 * on its way (the keys were held at 50 Hz): the alert says it once, the log not again. */
const IN_FLIGHT_MS = 2000;

/** The worker's heartbeat timer this late (ms) is this computer's doing: the server's
 * dead-man allows 150 ms of silence and the timer beats every 50. */
export const BUSY_LATE_MS = 100;

/** What a dead-man halt says: whose the stall was (this computer's, when the worker's
 * own timer fired late or the page's main thread stood still long enough for the
 * worker to stop beating; else the network's or the server's), never the operator's. */
/** Whose a dead-man halt was: the page stood still, its worker's timer ran late, or
 * (neither) the network or the server. */
export type HaltCause = "page" | "timer" | "link";

export function haltCause(timerLateMs: number, pageStallMs = 0): HaltCause {
  if (pageStallMs >= PAGE_SILENCE_MS) return "page";
  return timerLateMs >= BUSY_LATE_MS ? "timer" : "link";
}

export function haltedText(timerLateMs: number, pageStallMs = 0): string {
  const kept = "You keep control: keys still held drive again once the heartbeats are back.";
  if (pageStallMs >= PAGE_SILENCE_MS) {
    // The worker stops beating for a page silent this long (it may have hung): on a
    // busy machine that is the page's drawing waiting for the CPU, not a network fault.
    return `ARM HALTED: this computer is too busy: the page stood still for ${(pageStallMs / 1000).toFixed(1)} s, so its heartbeats stopped, and the arm stopped. ${kept} Closing other programs or turning the video off helps.`;
  }
  if (timerLateMs >= BUSY_LATE_MS) {
    return `ARM HALTED: this computer is too busy: the page's heartbeat ran ${Math.round(timerLateMs)} ms late, and the arm stopped. ${kept} Closing other programs or turning the video off helps.`;
  }
  return `ARM HALTED: the network or the server held the heartbeats (this page sent them on time), and the arm stopped. ${kept}`;
}

/** The page's control, from STATE flags, the link and the server's events: what to show. */
export class ControlWatch {
  private had = false; // this page held control at the last STATE
  private releasing = false; // the operator asked to release: no alarm
  // When a STATE first still showed control after the release was asked (ms): STATEs
  // already on their way say so for a while (a busy machine's, longer); past
  // IN_FLIGHT_MS the release is taken not to have happened.
  private releasingSeen: number | null = null;
  private heldWhenDropped = false;
  private dropped = false; // the link went down since the last WELCOME
  private reason = "";
  private reasonAt = -Infinity;
  private lostAt = -Infinity; // when this page last saw control go (ms)
  private haltedBy: HaltCause | null = null; // what the halt shown was said to be
  alert: ControlAlert | null = null;
  /** Called when the alert appears or changes (null: it went); `sound`: a new alarm. */
  onChange: ((alert: ControlAlert | null, sound: boolean) => void) | null = null;

  /** The operator released control (or took it: clears the offer). */
  released(): void {
    this.releasing = true;
    this.releasingSeen = null;
  }

  /** A server event: "control: nobody (dead-man: …)" says why control changed. */
  event(text: string, now: number): void {
    const m = /^control: [^(;]*\(([^)]*)\)/.exec(text);
    if (m) {
      this.reason = m[1]!;
      this.reasonAt = now;
    }
  }

  /** The realtime link went down or came back up. */
  connection(up: boolean): void {
    if (!up) this.dropped = true;
    if (!up && this.had) {
      this.had = false;
      this.heldWhenDropped = true;
      this.set({ level: "lost", text: "CONTROL LOST: the connection to the server dropped", retake: false }, true);
    }
  }

  /** The server welcomed this page (a new session: after a drop, maybe another server
   * process, restarted); `operator`: with the operator's role. */
  welcome(operator: boolean): void {
    const dropped = this.dropped;
    this.dropped = false;
    if (this.heldWhenDropped && operator) {
      this.set({ level: "lost", text: "Reconnected. You had control before the connection dropped.", retake: true }, false);
    } else if (dropped && !this.heldWhenDropped && this.alert) {
      // Said before the link dropped (a dead-man's loss, a halt): about a session that
      // has ended, and maybe a server that has since restarted. Stale now.
      this.set(null, false);
    }
  }

  /** Every STATE's flags, at `now` (ms); `timerLateMs`: how late the worker's heartbeat
   * timer fired lately, `pageStallMs`: the page's longest silence to the worker lately
   * (the link's figures), which say whose the halt was. */
  state(flags: number, now: number, timerLateMs = 0, pageStallMs = 0): void {
    const mine = (flags & StateFlags.YOU_HAVE_CONTROL) !== 0;
    if (mine) {
      this.had = true;
      this.heldWhenDropped = false;
      if (this.releasing) {
        this.releasingSeen ??= now;
        if (now - this.releasingSeen > IN_FLIGHT_MS) this.releasing = false;
      }
      if ((flags & StateFlags.HALTED) !== 0) {
        const cause = haltCause(timerLateMs, pageStallMs);
        if (this.alert?.level !== "halted") {
          this.set({ level: "halted", text: haltedText(timerLateMs, pageStallMs), retake: false }, true);
        } else if (cause !== this.haltedBy) {
          // Still halted, for another reason now (a busy page that missed the moment
          // the arm moved again sees one long halt): said again, without a second alarm.
          this.set({ level: "halted", text: haltedText(timerLateMs, pageStallMs), retake: false }, false);
        }
        this.haltedBy = cause;
      } else if (this.alert) this.set(null, false);
      return;
    }
    if (this.had) this.lostAt = now;
    if (this.had && !this.releasing) {
      const why = now - this.reasonAt < REASON_MS && this.reason ? this.reason : "the server took it back";
      this.set({ level: "lost", text: `CONTROL LOST: ${why}`, retake: false }, true);
    } else if (this.alert?.level === "halted") this.set(null, false);
    this.had = false;
    this.releasing = false;
  }

  /** A refusal from the server (ERROR's code) at `now` (ms). True: leave it out of the
   * log: "not allowed" while this page held control or just after it went is a command
   * sent before the page knew; the alert over the video already says control went. */
  quiet(code: number, now: number): boolean {
    return code === ERROR_CODES.not_allowed && (this.had || now - this.lostAt < IN_FLIGHT_MS);
  }

  /** The operator dismissed the alert, or took control again from it. */
  dismiss(): void {
    this.heldWhenDropped = false;
    this.set(null, false);
  }

  private set(alert: ControlAlert | null, sound: boolean): void {
    this.alert = alert;
    this.onChange?.(alert, sound);
  }
}

/** Two short beeps (WebAudio: the page has had a click by the time it holds control). */
export class AlarmSound {
  played = 0;
  private ctx: AudioContext | null = null;

  play(): void {
    this.played += 1;
    try {
      this.ctx ??= new AudioContext();
      const t = this.ctx.currentTime;
      for (const start of [0, 0.25]) {
        const osc = this.ctx.createOscillator();
        const gain = this.ctx.createGain();
        osc.frequency.value = 880;
        gain.gain.setValueAtTime(0.2, t + start);
        gain.gain.setValueAtTime(0, t + start + 0.15);
        osc.connect(gain).connect(this.ctx.destination);
        osc.start(t + start);
        osc.stop(t + start + 0.16);
      }
    } catch {
      // no audio output: the alert over the video still says it
    }
  }
}

/** Which alerts stop the inputs held at that moment: a lost lease (a key held through
 * it must not drive when control comes back; it is pressed again). Not a dead-man halt:
 * the lease is kept, and on a loaded machine the page misses the dead-man every few
 * seconds; a key still held drives again once the heartbeats are back. */
export function stopsHeldInputs(alert: ControlAlert): boolean {
  return alert.level === "lost";
}

/** Show the watch's alerts over the video (#control-alert), sound the alarm, stop the
 * held inputs on a lost lease, and wire the alert's buttons: take control again, dismiss. */
export function showControlAlerts(
  watch: ControlWatch,
  inputs: { latch(): void }[],
  take: () => void,
  sound = new AlarmSound(),
): AlarmSound {
  const box = document.getElementById("control-alert")!;
  const text = document.getElementById("control-alert-text")!;
  const retake = document.getElementById("retake") as HTMLButtonElement;
  watch.onChange = (alert, alarm) => {
    box.hidden = alert === null;
    box.className = alert?.level ?? "";
    text.textContent = alert?.text ?? "";
    retake.hidden = !alert?.retake;
    if (alert && alarm) {
      if (stopsHeldInputs(alert)) for (const input of inputs) input.latch();
      sound.play();
    }
  };
  retake.onclick = () => {
    watch.dismiss();
    take();
  };
  document.getElementById("dismiss-alert")!.onclick = () => watch.dismiss();
  document.getElementById("release")?.addEventListener("click", () => watch.released());
  return sound;
}
