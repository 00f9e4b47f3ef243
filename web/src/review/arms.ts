// A multi-arm recording played back (docs/recording.md): its arms as its /arms message
// says them (name, model, joint names, where each base stands in the workcell), each
// arm's states and forces on channels of its own (/arms/<name>/state,
// /arms/<name>/force). A one-arm recording has none of these: its one arm, "arm", is on
// /robot/state and /force. Each arm's pose is in its own base frame and the cameras'
// calibration in the workcell's, so an arm is drawn through P · its mount. Pure: the
// page draws what these return (review/overlay.ts, force-plot.ts, joints-readout.ts).
import type { Projection } from "../ar/projection";

/** The one arm's name (a one-arm recording's). */
export const ONE_ARM = "arm";
const IDENTITY: number[][] = [
  [1, 0, 0, 0],
  [0, 1, 0, 0],
  [0, 0, 1, 0],
  [0, 0, 0, 1],
];
const ARM_TOPIC = /^\/arms\/([^/]+)\/(state|force)$/;

/** One recorded arm, and where its series are in the timeline's topics. */
export interface RecordedArm {
  name: string;
  model: string; // its model's settings name ("" if the recording does not say)
  jointNames: string[];
  mount: number[][]; // 4×4, its base in the workcell
  stateTopic: string;
  forceTopic: string;
}

/** One arm as /arms says it (docs/recording.md). */
interface ArmsMessage {
  arms?: { name?: unknown; model?: unknown; joint_names?: unknown; mount?: unknown }[];
}

function isMatrix(m: unknown): m is number[][] {
  return Array.isArray(m) && m.length === 4 && m.every((r) => Array.isArray(r) && r.length === 4 && r.every((v) => typeof v === "number"));
}

function armOf(name: string, model = "", jointNames: string[] = [], mount: number[][] = IDENTITY): RecordedArm {
  return { name, model, jointNames, mount, stateTopic: `/arms/${name}/state`, forceTopic: `/arms/${name}/force` };
}

/** The recording's arms, in order: as its /arms message says them; without one, as its
 * arms' channels name them (each at the workcell's origin); a one-arm recording's one. */
export function recordedArms(topics: Readonly<Record<string, readonly unknown[] | undefined>>): RecordedArm[] {
  const said = (topics["/arms"] ?? [])[0] as ArmsMessage | undefined;
  const listed = (said?.arms ?? []).filter((a) => typeof a.name === "string" && a.name !== "");
  if (listed.length > 0) {
    return listed.map((a) =>
      armOf(
        String(a.name),
        typeof a.model === "string" ? a.model : "",
        Array.isArray(a.joint_names) ? a.joint_names.map(String) : [],
        isMatrix(a.mount) ? a.mount : IDENTITY,
      ),
    );
  }
  const names: string[] = [];
  for (const topic of Object.keys(topics)) {
    const name = ARM_TOPIC.exec(topic)?.[1];
    if (name !== undefined && !names.includes(name)) names.push(name);
  }
  if (names.length > 0) return names.map((n) => armOf(n));
  return [{ name: ONE_ARM, model: "", jointNames: [], mount: IDENTITY, stateTopic: "/robot/state", forceTopic: "/force" }];
}

/** Whether the recording is of several arms (drawn and listed each by its name). */
export function severalArms(arms: readonly RecordedArm[]): boolean {
  return arms.length > 1 || (arms[0] !== undefined && arms[0].name !== ONE_ARM);
}

/** `P · mount`: an arm's base-frame points straight to the camera's pixels. */
export function mountedProjection(P: Projection, mount: readonly (readonly number[])[]): Projection {
  return P.map((row) => [0, 1, 2, 3].map((j) => [0, 1, 2, 3].reduce((sum, k) => sum + (row[k] ?? 0) * (mount[k]?.[j] ?? 0), 0)));
}

/** Where each arm is read from on the server: the recorded arm's own name if the
 * server drives an arm of that name, else its first arm's (the model the page draws
 * with); null on a one-arm server (its model is asked for without `?arm=`). */
export function modelArm(recorded: string, serverArms: readonly string[]): string | null {
  if (serverArms.length <= 1) return null;
  return serverArms.includes(recorded) ? recorded : (serverArms[0] ?? null);
}

/** One arm's joints at the cursor, for the readout: its name, then each joint in
 * degrees (named as the recording names them, else by number). */
export function jointsLine(arm: string, q: readonly number[] | undefined, names: readonly string[]): string {
  if (!q || q.length === 0) return `${arm}: —`;
  const joints = q.map((v, i) => `${names[i] ?? `j${i + 1}`} ${((v * 180) / Math.PI).toFixed(1)}°`);
  return `${arm}: ${joints.join("  ")}`;
}

/** The force plot's band for arm `i` of `n` (each arm its own, top to bottom). */
export function forceBand(i: number, n: number, height: number): { top: number; height: number } {
  const h = height / Math.max(n, 1);
  return { top: i * h, height: h };
}
