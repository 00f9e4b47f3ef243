// The arms a server drives (GET /api/v1/robot/arms; one, named "arm", unless it drives
// more): each its model (GET /robot/model?arm=NAME) and its mount, the 4×4 of its base in
// the scene. Every arm's pose, model and commands are in its own base frame; the cameras'
// calibration is in the scene's (the first arm's base frame), so an arm is drawn through
// each camera's P · mount: a point of its base frame straight to that camera's pixels.
import type { Api, Schema } from "../api";
import type { CameraCalibration } from "../ar/ball";
import { type Mat4, identity4 } from "./math";

export type ArmInfo = Schema<"ArmInfo">;
export type RobotModel = Schema<"RobotModel">;

/** One arm as the page draws and drives it. */
export interface ServerArmEntry {
  /** What `?arm=` takes ("arm" on a one-arm server). */
  name: string;
  /** ARM's index on the wire (1 for the first). */
  index: number;
  /** Its base in the scene (row-major 4×4). */
  mount: Mat4;
  model: RobotModel;
}

/** `P · mount` for each camera: the arm's base-frame points straight to pixels. */
export function mountedCameras(cameras: readonly CameraCalibration[], mount: Mat4): CameraCalibration[] {
  return cameras.map((c) => ({
    ...c,
    P: c.P.map((row) =>
      [0, 1, 2, 3].map((j) => (row[0] ?? 0) * mount[j]! + (row[1] ?? 0) * mount[4 + j]! + (row[2] ?? 0) * mount[8 + j]! + (row[3] ?? 0) * mount[12 + j]!),
    ),
  }));
}

/** The server's arms and their models: one request for the list, one per model. A
 * one-arm server's model is asked for as before (no `?arm=`). */
export async function readServerArms(api: Pick<Api, "request">): Promise<ServerArmEntry[]> {
  const arms = await api.request("get", "/api/v1/robot/arms");
  if (arms.length <= 1) {
    const model = await api.request("get", "/api/v1/robot/model");
    const only = arms[0];
    return [{ name: only?.name ?? "arm", index: only?.index ?? 1, mount: only ? only.mount.flat() : identity4(), model }];
  }
  const models = await Promise.all(arms.map((a) => api.request("get", "/api/v1/robot/model", { query: { arm: a.name } })));
  return arms.map((a, i) => ({ name: a.name, index: a.index, mount: a.mount.flat(), model: models[i]! }));
}

/** How bad each status is, for one badge over several arms: the worst one shows. */
const STATUS_RANK: Record<string, number> = { ERROR: 0, NOT_CONNECTED: 1, WAITING: 2, CONNECTED: 3, MOVING: 4, READY: 5 };

/** Several arms' latest STATEs as one, for the header: the worst status, every flag any
 * of them has (FORCE_LIMITED is per arm; the lease's, the e-stop's and HALTED are every
 * arm's), the rest the first's. One arm's is itself. Null until every arm has one. */
export function combinedState<S extends { status: string; flags: number }>(states: readonly (S | null)[]): S | null {
  if (states.length === 0 || states.some((s) => s === null)) return states.length === 1 ? (states[0] ?? null) : null;
  const all = states as readonly S[];
  if (all.length === 1) return all[0]!;
  const worst = all.reduce((a, b) => ((STATUS_RANK[b.status] ?? -1) < (STATUS_RANK[a.status] ?? -1) ? b : a));
  return { ...all[0]!, status: worst.status, flags: all.reduce((f, s) => f | s.flags, 0) };
}
