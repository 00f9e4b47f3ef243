// The recording as the review page plays it: its timeline (GET
// /api/v1/recordings/{id}/timeline) shaped into what each part of the page draws — each
// recorded arm's states and forces, the commands, the episodes, the safety events, who
// drove, the calibration in force — and each arm's model to draw it with (/api/v1/robot/arms,
// /api/v1/robot/model). Whatever the recording lacks is an empty list here: each part of
// the page leaves out what is empty, not shows it empty.
// The timeline comes in pieces (issue 55): the first FIRST_PIECE_S s of it, then pieces
// each four times longer (pieceAfter), each appended here as it arrives (growRecording:
// the lists grow in place, so whatever a part of the page holds sees them grow).
import { ApiError, type Api, type MessageLog, type Schema } from "../api";
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
/** A piece of the timeline: the whole recording's length and video start, and the messages
 * logged in [start_s, end_s) (end_s undefined: to the end). */
export type TimelinePiece = Timeline & Partial<Pick<Schema<"Timeline">, "range_start" | "range_end">>;

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
  /** The events as recorded, which the marks above are made of (redone as pieces come). */
  events: { episodes: (Timed & EpisodeEvent)[]; safety: (Timed & SafetySnapshot)[]; autonomy: AutonomyChange[] };
}

type AutonomyChange = Timed & { mode: string; policy?: string | null; operator?: string | null };

/** What each part of the page is set up with: the recording, and the page's message log. */
export interface ReviewContext {
  recording: ReviewRecording;
  log: MessageLog;
}

/** The recording's timeline (or its first piece) shaped for the page (the models are
 * given: asked for apart). Its arms are the first piece's (the server names every arm's
 * series in every piece). */
export function shapeRecording(id: string, tl: Timeline, models: readonly (ArmModel | null)[]): ReviewRecording {
  // Each recorded arm (one, "arm", unless the recording is of several) and its series.
  const arms = recordedArms(tl.topics);
  const recording: ReviewRecording = {
    id,
    duration: tl.duration,
    videoStart: tl.video_start,
    arms,
    several: severalArms(arms),
    models: arms.map((_, k) => models[k] ?? null),
    armStates: arms.map(() => []),
    armForces: arms.map(() => []),
    commands: [],
    episodes: [],
    safety: [],
    drove: [],
    calibrations: [],
    events: { episodes: [], safety: [], autonomy: [] },
  };
  growRecording(recording, tl);
  return recording;
}

/** Appends a piece of the timeline (the next in time) to the recording: every list grows
 * in place, and the marks made of the events are made again (an episode's end may come
 * in a later piece than its start). */
export function growRecording(r: ReviewRecording, tl: Timeline): void {
  const topic = (name: string) => (tl.topics[name] ?? []) as Timed[];
  r.duration = tl.duration;
  r.videoStart = tl.video_start;
  r.arms.forEach((a, k) => {
    append(r.armStates[k], topic(a.stateTopic) as ArmState[]);
    append(r.armForces[k], topic(a.forceTopic) as ForceSample[]);
  });
  append(r.commands, topic("/commands") as RecordedCommand[]);
  append(r.events.episodes, topic("/episodes") as (Timed & EpisodeEvent)[]);
  append(r.events.safety, topic("/safety") as (Timed & SafetySnapshot)[]);
  append(r.events.autonomy, topic("/autonomy") as AutonomyChange[]);
  append(
    r.calibrations,
    (topic("/calibration") as RecordedCalibration[]).map((c) => ({
      time: c.time,
      cameras: ["left", "right"].map((eye) => ({ P: c.cameras?.[eye]?.P ?? c.ground_truth_P?.[eye] ?? [] })),
    })),
  );
  replace(r.episodes, episodesOf(r.events.episodes));
  replace(r.safety, safetyMarks(r.events.safety));
  // A supervised policy's recording: who drove when (the strip's coloured foot).
  replace(r.drove, droveSpans(r.events.autonomy, r.duration));
}

function append<T>(list: T[] | undefined, more: readonly T[]): void {
  if (list) for (const item of more) list.push(item); // (not push(...more): a long piece)
}

function replace<T>(list: T[], now: readonly T[]): void {
  list.length = 0;
  append(list, now);
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

// ---- the timeline in pieces

/** The first piece's length (s): the first seconds of the plots, and the recording's
 * length, arms and video start, as soon as can be. */
export const FIRST_PIECE_S = 10;
/** Each piece is this many times as long as the one before: a 2-minute recording in 3
 * pieces, an hour's in 6 (each piece is a read, and a job the first time: a tokenless
 * page's budget holds them). */
export const PIECE_GROWTH = 4;
/** Points per series over the whole recording: every piece is asked with it (the server
 * keeps the same samples in a piece as in the whole). */
export const MAX_POINTS = 4000;

/** A piece to ask for: from start_s to end_s (undefined: to the end). */
export interface PieceRange {
  start_s: number;
  end_s: number | undefined;
}

/** The piece after the timeline loaded up to `loadedTo` s of a recording of `duration` s
 * (null: not known yet): the ranges are always the same (0–10, 10–50, 50–210, …: kept by
 * the server, found again by the next page), the last one open-ended. */
export function pieceAfter(loadedTo: number, duration: number | null): PieceRange {
  const end = PIECE_GROWTH * loadedTo + FIRST_PIECE_S;
  return { start_s: loadedTo, end_s: duration !== null && end >= duration ? undefined : end };
}

/** Whether a piece asked as `range` was the last: open-ended, or ending past the recording. */
export function lastPiece(range: PieceRange, duration: number): boolean {
  return range.end_s === undefined || range.end_s > duration;
}

/** Times a piece is asked again while the server says to wait (~2.2 min in all). */
export const PIECE_ATTEMPTS = 40;

/** The answers worth asking again — a read budget spent (a page without the token: the
 * video it was just sent counts one read per 512 KiB, a few seconds of its budget), the
 * server's reads busy — and how long to wait: a second (the server's Retry-After) ten
 * times, then 4 s. Null: not to ask again. */
export function retryAfterMs(error: unknown, attempt: number): number | null {
  if (!(error instanceof ApiError) || (error.status !== 429 && error.status !== 503) || attempt >= PIECE_ATTEMPTS) return null;
  return attempt < 10 ? 1000 : 4000;
}

/** One piece of recording `id`'s timeline (asked again, later, while the server says to
 * wait: `waiting` is told why, and null once it has it). */
export async function loadPiece(api: Api, id: string, range: PieceRange, waiting: (why: string | null) => void = () => {}): Promise<TimelinePiece> {
  for (let attempt = 0; ; attempt++) {
    try {
      const piece = await api.request("get", "/api/v1/recordings/{recording_id}/timeline", {
        params: { recording_id: id },
        query: { max_points: MAX_POINTS, start_s: range.start_s, end_s: range.end_s },
      });
      waiting(null);
      return piece;
    } catch (e) {
      const wait = retryAfterMs(e, attempt);
      if (wait === null) throw e;
      waiting((e as Error).message);
      await new Promise((resolve) => setTimeout(resolve, wait));
    }
  }
}

/** Each recorded arm's model, put into `recording.models` as it comes (an arm whose model
 * cannot be had is said in the log and not drawn). */
export async function loadModels(api: Api, recording: ReviewRecording, log: MessageLog): Promise<void> {
  const serverArms = await api.request("get", "/api/v1/robot/arms").catch(() => []);
  const models = await armModels(api, recording.arms, serverArms.map((a) => a.name), log);
  models.forEach((m, k) => (recording.models[k] = m));
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
