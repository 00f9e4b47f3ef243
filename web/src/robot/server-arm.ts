// The arms the page draws — the joint labels, the ghost, the AR ball, the axis marker and
// the predicted pose — come from the server's arms, each with its model and mount
// (GET /api/v1/robot/arms, robot/arms.ts), and its cameras (GET /api/v1/calibration).
// Both are read at start-up and again at each new session on the realtime link: a server
// restarted with another model (the PUMA, then `--model so101`) must not leave the old
// arm drawn over the new one's video.
import type { Schema } from "../api";
import type { CameraCalibration } from "../ar/ball";
import type { ServerArmEntry } from "./arms";

export type RobotModel = Schema<"RobotModel">;

/** What the page draws the arms from. */
export interface ServerArm {
  cameras: CameraCalibration[];
  /** Every arm the server drives, in order (one on most servers). */
  arms: ServerArmEntry[];
}

/** Tries to read the arm again after a new session (one a second, then it waits for the
 * next session): the server's HTTP side may still be starting as its socket welcomes. */
export const RELOAD_TRIES = 5;
export const RELOAD_RETRY_MS = 1000;

/** Equal when every figure the page draws from is (the model's joints, tool and names;
 * each camera's name and projection). */
export function sameArm(a: ServerArm, b: ServerArm): boolean {
  const key = (s: ServerArm) => JSON.stringify([s.cameras.map((c) => [c.name, c.P]), s.arms.map((a) => [a.name, a.index, a.mount, a.model])]);
  return key(a) === key(b);
}

/** "PUMA 560 (puma560)" */
const named = (m: RobotModel) => `${m.name} (${m.model})`;

export class ServerArmReloader {
  /** Reloads asked for; only the latest one's answer is applied. */
  private asked = 0;

  constructor(
    public current: ServerArm,
    /** Reads the model and the cameras from the server. */
    private readonly read: () => Promise<ServerArm>,
    /** Draws the arm from `arm` from now on (called only when it changed). */
    private readonly apply: (arm: ServerArm, was: ServerArm) => void,
    private readonly log: { add(text: string, error?: boolean): void },
    private readonly sleep: (ms: number) => Promise<void> = (ms) => new Promise((r) => setTimeout(r, ms)),
  ) {}

  /** A new session was welcomed: read the arm again and apply it if it changed. True
   * when it did; false when it is the same, a newer reload superseded this one, or it
   * could not be read (said in the log). */
  async reload(): Promise<boolean> {
    const ticket = ++this.asked;
    let next: ServerArm | null = null;
    for (let attempt = 1; next === null; attempt++) {
      try {
        next = await this.read();
      } catch (e) {
        if (ticket !== this.asked) return false;
        if (attempt >= RELOAD_TRIES) {
          this.log.add(`could not read the arm's model again after reconnecting (${(e as Error).message}): the arm drawn may be the previous server's; reload the page`, true);
          return false;
        }
        await this.sleep(RELOAD_RETRY_MS);
      }
      if (ticket !== this.asked) return false;
    }
    if (sameArm(next, this.current)) return false;
    const was = this.current;
    this.current = next;
    this.apply(next, was);
    const names = (a: ServerArm) => a.arms.map((x) => x.name).join(", ");
    const [now, before] = [next.arms[0]?.model, was.arms[0]?.model];
    if ((names(next) !== names(was) && next.arms.length + was.arms.length > 2) || !now || !before) {
      this.log.add(`the server now drives ${next.arms.length} arm(s) (${names(next)}), not ${was.arms.length} (${names(was)}): the page draws and drives them`);
      return true;
    }
    this.log.add(
      now.model === before.model
        ? `the server's arm or cameras changed (${named(now)}): the page draws them as they are now`
        : `the server now drives the ${named(now)}, not the ${named(before)}: the page draws the new arm`,
    );
    return true;
  }
}
