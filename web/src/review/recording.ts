// The recording as the review page plays it: its timeline (GET
// /api/v1/recordings/{id}/timeline) shaped into what each part of the page draws — each
// recorded arm's states and forces, the commands, the episodes, the safety events, who
// drove, the calibration in force — and each arm's model to draw it with (/api/v1/robot/arms,
// /api/v1/robot/model). Whatever the recording lacks is an empty list here: each part of
// the page leaves out what is empty, not shows it empty.
import type { Api, MessageLog, Schema } from "../api";
import type { Projection } from "../ar/projection";
import { modelArm, recordedArms, severalArms, type RecordedArm } from "./arms";
import { droveSpans, episodesOf, safetyMarks, type DroveSpan, type EpisodeEvent, type ReviewEpisode, type SafetyMark, type SafetySnapshot } from "./marks";
import { latestAt } from "./timeline";

/** A recorded message: its timeline time, and its fields. */
export interface Timed {
  time: number;
  [key: string]: unknown;
}
/** One arm's state: where its tool was, the joints commanded (the predicted pose) and the joints it had. */
export type ArmState = Timed & { position: number[]; target_joints?: number[]; joints?: number[] };
/** One force/torque sample: fx, fy, fz, tx, ty, tz. */
export type ForceSample = Timed & { values: number[] };
/** One command as recorded: what, whether it was accepted (and why not), who sent it. */
export type RecordedCommand = Timed & { kind: string; accepted: boolean; reason: string; source: string; client: string; args?: { arm?: unknown } };
/** The cameras' projections at a time: the left eye's, then the right's ([] if not recorded). */
export interface CamerasAt {
  time: number;
  cameras: { P: Projection }[];
}
/** An arm's model as GET /api/v1/robot/model gives it. */
export type ArmModel = Schema<"RobotModel">;

// As recorded: {cameras: {left: {P}, right: {P}}, ground_truth_P: {left, right}}.
type RecordedCalibration = Timed & { cameras?: Record<string, { P?: Projection }>; ground_truth_P?: Record<string, Projection> };
type Timeline = Pick<Schema<"Timeline">, "duration" | "video_start"> & { topics: Readonly<Record<string, readonly unknown[] | undefined>> };

/** The recording as the page plays it (each arm's series in the order of `arms`). */
export interface ReviewRecording {
  id: string;
  duration: number; // s from the first message to the last
  videoStart: number | null | undefined; // timeline s of the MP4's 0; null: no video
  arms: RecordedArm[];
  several: boolean; // several arms: each drawn and listed by its name
  models: (ArmModel | null)[]; // null: that arm is not drawn
  armStates: ArmState[][];
  armForces: ForceSample[][];
  commands: RecordedCommand[];
  episodes: ReviewEpisode[];
  safety: SafetyMark[];
  drove: DroveSpan[];
  calibrations: CamerasAt[];
}

/** What each part of the page is set up with: the recording, and the page's message log. */
export interface ReviewContext {
  recording: ReviewRecording;
  log: MessageLog;
}

/** The recording's timeline shaped for the page (the models are given: asked for apart). */
export function shapeRecording(id: string, tl: Timeline, models: readonly (ArmModel | null)[]): ReviewRecording {
  const topic = (name: string) => (tl.topics[name] ?? []) as Timed[];
  // Each recorded arm (one, "arm", unless the recording is of several) and its series.
  const arms = recordedArms(tl.topics);
  return {
    id,
    duration: tl.duration,
    videoStart: tl.video_start,
    arms,
    several: severalArms(arms),
    models: arms.map((_, k) => models[k] ?? null),
    armStates: arms.map((a) => topic(a.stateTopic) as ArmState[]),
    armForces: arms.map((a) => topic(a.forceTopic) as ForceSample[]),
    commands: topic("/commands") as RecordedCommand[],
    episodes: episodesOf(topic("/episodes") as (Timed & EpisodeEvent)[]),
    safety: safetyMarks(topic("/safety") as (Timed & SafetySnapshot)[]),
    // A supervised policy's recording: who drove when (the strip's coloured foot).
    drove: droveSpans(topic("/autonomy") as (Timed & { mode: string; policy?: string | null; operator?: string | null })[], tl.duration),
    calibrations: (topic("/calibration") as RecordedCalibration[]).map((c) => ({
      time: c.time,
      cameras: ["left", "right"].map((eye) => ({ P: c.cameras?.[eye]?.P ?? c.ground_truth_P?.[eye] ?? [] })),
    })),
  };
}

/** Whether the recording has video (the MP4 the server remuxes from the recorded H.264). */
export function hasVideo(recording: Pick<ReviewRecording, "videoStart">): boolean {
  return recording.videoStart !== null && recording.videoStart !== undefined;
}

/** Each arm's state at timeline time t (undefined: none recorded yet). */
export function armStatesAt(recording: Pick<ReviewRecording, "armStates">, t: number): (ArmState | undefined)[] {
  return recording.armStates.map((series) => series[latestAt(series, t)]);
}

/** The cameras' projections in force at timeline time t (the first calibration's before it). */
export function camerasAt(recording: Pick<ReviewRecording, "calibrations">, t: number): { P: Projection }[] {
  return recording.calibrations[Math.max(0, latestAt(recording.calibrations, t))]?.cameras ?? [];
}

/** Loads recording `id`: its timeline and each recorded arm's model (an arm whose model
 * cannot be had is said in the log and not drawn). */
export async function loadRecording(api: Api, id: string, log: MessageLog): Promise<ReviewRecording> {
  const [tl, serverArms] = await Promise.all([
    api.request("get", "/api/v1/recordings/{recording_id}/timeline", {
      params: { recording_id: id },
      query: { max_points: 4000 },
    }),
    api.request("get", "/api/v1/robot/arms").catch(() => []),
  ]);
  const models = await armModels(api, recordedArms(tl.topics), serverArms.map((a) => a.name), log);
  return shapeRecording(id, tl, models);
}

/** Each recorded arm's model to draw it with: the server's arm of its name (a one-arm server's only one). */
async function armModels(api: Api, arms: readonly RecordedArm[], serverNames: readonly string[], log: MessageLog): Promise<(ArmModel | null)[]> {
  return Promise.all(
    arms.map((a) => {
      const name = modelArm(a.name, serverNames);
      const asked = name === null ? api.request("get", "/api/v1/robot/model") : api.request("get", "/api/v1/robot/model", { query: { arm: name } });
      return asked.catch((e: Error) => {
        log.add(`the ${a.name} arm is not drawn: ${e.message}`, true);
        return null;
      });
    }),
  );
}
