// Hand to eye: a key pressed in this page → the arm's motion on screen, measured in the
// page for every motion (bench/hand_to_eye.py, docs/hand-to-eye.md). The simulated
// camera draws a motion mark beside the timecode (drivers/camera/motion_mark.py: the
// tool's position as three rulers at 0.1 mm a pixel, wrapping every 96 px); the glass
// meter's worker reads it with the timecode in every decoded frame (view/glass.ts), a
// requestVideoFrameCallback here tells which decoded frame is presented when (by its
// media timestamp: no pixel read on the main thread), and the realtime worker tells
// each command's send and the server's applying of it (its ACK).
// Joined per key press:
//   press ─ input_to_sent ─ sent ─ sent_to_applied ─ applied ─ applied_to_exposure ─
//   exposure (the first frame whose mark moved) ─ exposure_to_decoded ─ decoded ─
//   decoded_to_presented ─ presented (the first frame shown from that exposure on),
// every time on this page's clock (performance.now(), ms), the server's through the
// ping clock sync; the parts sum to the whole (presented − press) by construction.
import { type DecodedFrame, Kept, MOVED_PX, decodedFrames, movedPx } from "./motion-mark";

/** A motion whose parts are not all found within this long of its press is not counted. */
export const WITHIN_MS = 2000;

/** A frame presented: its media timestamp (requestVideoFrameCallback's mediaTime, µs:
 * the decoded VideoFrame's timestamp, so no pixel of it is read on the page's main
 * thread: reading each presented frame's timecode there cut the glass meter's reads
 * from 30 to 5 a second on a software GPU), when it was handed to the compositor
 * (presentationTime: decoded by then) and expected on screen (expectedDisplayTime), ms. */
export interface PresentedFrame {
  mediaUs: number;
  submittedAt: number;
  presentedAt: number;
}
/** A command: when it went out of the realtime worker, when the server's driver took it
 * (the ACK's server time on the page's clock), ms. */
export interface CommandTimes {
  sentAt: number;
  appliedAt: number;
}
/** A motion key pressed (its KeyboardEvent's timeStamp, ms). */
export interface Press {
  key: string;
  at: number;
}

export const PARTS = ["input_to_sent", "sent_to_applied", "applied_to_exposure", "exposure_to_decoded", "decoded_to_presented"] as const;
export type Part = (typeof PARTS)[number];
export interface Motion {
  key: string;
  /** presented − press (ms). */
  wholeMs: number;
  parts: Record<Part, number>;
  /** The frame that first showed it: its timecode, and how far its mark moved (px). */
  code: number;
  movedPx: number;
}

/** Each press's motion, from the records (each in time order); presses whose parts
 * are not all found (no command sent: the lease or the dead-man missing; no frame with
 * the mark moved; not yet presented) are left out, counted in `missed`. */
export function joinMotions(
  presses: readonly Press[],
  commands: readonly CommandTimes[],
  decoded: readonly DecodedFrame[],
  presented: readonly PresentedFrame[],
  threshold = MOVED_PX,
): { motions: Motion[]; missed: Record<string, number> } {
  const motions: Motion[] = [];
  const missed: Record<string, number> = {};
  const miss = (why: string) => (missed[why] = (missed[why] ?? 0) + 1);
  const marked = decoded.filter((f) => f.mark !== null);
  presses.forEach((press, i) => {
    const until = Math.min(press.at + WITHIN_MS, presses[i + 1]?.at ?? Infinity);
    const cmd = commands.find((c) => c.sentAt >= press.at && c.sentAt < until);
    if (!cmd) return miss("no command");
    let base: DecodedFrame | undefined;
    let moved: DecodedFrame | undefined;
    let most = 0;
    for (const f of marked) {
      if (f.exposureAt <= press.at) base = f;
      else if (f.exposureAt >= until) break;
      else if (base && (most = movedPx(base.mark!, f.mark!)) >= threshold) {
        moved = f;
        break;
      }
    }
    if (!base) return miss("no frame before");
    if (!moved) return miss("no motion seen");
    const shown = presented.find((p) => p.mediaUs >= moved.mediaUs && p.presentedAt >= moved.exposureAt);
    if (!shown) return miss("not presented");
    // Decoded: when the glass meter's worker read it, or when the <video> had it for the
    // compositor if that was earlier (a worker held up reads late).
    const own = presented.find((p) => p.mediaUs === moved.mediaUs && p.presentedAt >= moved.exposureAt);
    const decodedAt = Math.min(moved.decodedAt, own?.submittedAt ?? Infinity);
    const parts: Record<Part, number> = {
      input_to_sent: cmd.sentAt - press.at,
      sent_to_applied: cmd.appliedAt - cmd.sentAt,
      applied_to_exposure: moved.exposureAt - cmd.appliedAt,
      exposure_to_decoded: decodedAt - moved.exposureAt,
      decoded_to_presented: shown.presentedAt - decodedAt,
    };
    motions.push({ key: press.key, wholeMs: shown.presentedAt - press.at, parts, code: moved.code, movedPx: most });
  });
  return { motions, missed };
}

/** The keys that move the arm (input/keyboard.ts): a press of one starts a motion. */
export const MOTION_KEYS = new Set(["KeyW", "KeyS", "KeyA", "KeyD", "KeyR", "KeyF", "KeyQ", "KeyE"]);

/** Records presses, commands and presented frames once started (the decoded frames
 * come from the glass meter through `decodedFrames`). */
export class HandEyeRecorder {
  readonly presses = new Kept<Press>();
  readonly commands = new Kept<CommandTimes>();
  readonly presented = new Kept<PresentedFrame>();
  started = false;

  /** Start recording: key presses on `target`, and every frame `video` presents. */
  start(target: Window, video: HTMLVideoElement): void {
    if (this.started) return;
    this.started = true;
    decodedFrames.on = true;
    target.addEventListener("keydown", (e) => {
      if (!e.repeat && MOTION_KEYS.has(e.code)) this.presses.push({ key: e.code, at: e.timeStamp });
    });
    const tick = (_now: number, md: VideoFrameCallbackMetadata) => {
      video.requestVideoFrameCallback(tick);
      this.presented.push({ mediaUs: Math.round(md.mediaTime * 1e6), submittedAt: md.presentationTime, presentedAt: md.expectedDisplayTime });
    };
    video.requestVideoFrameCallback(tick);
  }

  /** A command's times (the realtime worker's ACK, on this page's clock). */
  command(c: CommandTimes): void {
    if (this.started) this.commands.push(c);
  }

  motions(threshold = MOVED_PX): ReturnType<typeof joinMotions> & { decoded: number; presented: number } {
    const out = joinMotions(this.presses.items, this.commands.items, decodedFrames.log.items, this.presented.items, threshold);
    return { ...out, decoded: decodedFrames.log.items.length, presented: this.presented.items.length };
  }
}
