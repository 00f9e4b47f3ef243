// The page's arms: one per arm the server drives, each with its prediction, AR ball,
// ghost (in its own colours, placed through its mount), STATE and force. Replaced whole
// when the server's arms change (wiring/tasks.ts's reloader). Which input drives which
// arm is input/arms.ts's; the lease, the e-stop and the dead-man are one for all.
import { ArBall, type CameraCalibration } from "../ar/ball";
import { GhostArm } from "../ar/ghost";
import type { DriveArm } from "../input/loop";
import { viewFrame } from "../input/viewframe";
import { type ServerArmEntry, combinedState, mountedCameras } from "../robot/arms";
import { PredictedArm } from "../robot/model";
import type { ForceSample } from "../transport/codec";
import type { RobotState } from "../transport/realtime";
import { armStyle } from "../ui/arms";

/** One arm as the page draws and drives it. */
export interface PageArm {
  entry: ServerArmEntry;
  /** The cameras as this arm's base frame sees them (each P · its mount). */
  cameras: CameraCalibration[];
  predicted: PredictedArm;
  ball: ArBall;
  ghost: GhostArm;
  state: RobotState | null;
  force: ForceSample | null;
}

/** The page's arms for the server's (`ghostOn`: the Ghost arm switch). With one, drawn
 * as always: the View panel's ball colour, the magenta ghost, no name. */
export function pageArms(entries: readonly ServerArmEntry[], cameras: readonly CameraCalibration[], ghostOn: boolean): PageArm[] {
  return entries.map((entry, i) => {
    const own = mountedCameras(cameras, entry.mount);
    const ghost = new GhostArm(entry.model, own, entries.length > 1 ? { rgb: armStyle(i).ghost, label: entry.name } : undefined);
    ghost.setEnabled(ghostOn);
    return { entry, cameras: own, predicted: new PredictedArm(entry.model), ball: new ArBall(own), ghost, state: null, force: null };
  });
}

/** How the input loop drives them: each command names its arm (0: the only arm). */
export function driveArms(arms: readonly PageArm[]): DriveArm[] {
  return arms.map((a) => ({
    index: arms.length > 1 ? a.entry.index : 0,
    name: a.entry.name,
    predictor: a.predicted,
    view: a.cameras[0] ? viewFrame(a.cameras[0].P) : null, // the left camera's
  }));
}

/** The page's arms and what the server last said of them. */
export class PageArms {
  list: PageArm[];
  /** The header's state: every arm's as one (the newest STATE of each). */
  combined: RobotState | null = null;

  constructor(
    entries: readonly ServerArmEntry[],
    cameras: readonly CameraCalibration[],
    /** The Ghost arm switch, kept for arms drawn anew. */
    public ghostOn: boolean,
  ) {
    this.list = pageArms(entries, cameras, ghostOn);
  }

  /** The arm whose STATE or FORCE names `index` (a one-arm server's is its only one). */
  of(index: number): PageArm | undefined {
    return this.list.length === 1 ? this.list[0] : this.list.find((a) => a.entry.index === index);
  }

  /** Every arm drawn and driven anew (the header's state follows at the next STATEs). */
  replace(entries: readonly ServerArmEntry[], cameras: readonly CameraCalibration[]): void {
    this.list = pageArms(entries, cameras, this.ghostOn);
  }

  /** One STATE: its arm's prediction follows it; the arm, if the page draws it. */
  report(s: RobotState, now: number): PageArm | undefined {
    const a = this.of(s.arm);
    if (!a) return undefined;
    a.state = s;
    a.predicted.report(s.joints, s.status === "MOVING", now);
    this.combined = combinedState(this.list.map((x) => x.state)) ?? this.combined;
    return a;
  }

  /** One FORCE batch: its arm keeps the newest sample. */
  force(samples: readonly ForceSample[], index: number): void {
    const a = this.of(index);
    if (a) a.force = samples[samples.length - 1] ?? a.force;
  }

  /** The newest force sample of any arm (the connection HUD's force age). */
  newestForce(): ForceSample | null {
    return this.list.reduce<ForceSample | null>((n, a) => (a.force && (!n || a.force.time > n.time) ? a.force : n), null);
  }

  /** The Ghost arm switch: true if a ghost is drawn now. */
  setGhosts(on: boolean): boolean {
    this.ghostOn = on;
    return this.list.map((a) => a.ghost.setEnabled(on)).some(Boolean);
  }
}
