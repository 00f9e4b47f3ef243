// The connection HUD: over the video, a compact box of the link's figures —
// round trip, loss, the video's rate, bitrate, layer and freezes, the playout delay and
// what FEC repaired, how old the newest
// force sample and the last command are, the clock offset — each row ok, amber or red
// against a named threshold, the box as bad as its worst row. Three parts: hudView
// (pure: figures → rows), the readers of RTCPeerConnection.getStats() and of frame
// arrivals (pure given their inputs), and ConnectionHud, which collects the figures
// from the video peer and the realtime link about twice a second and draws them.
import type { Rolling } from "../stats";

export type HudLevel = "ok" | "amber" | "red";

/** Redrawn this often (ms): figures change faster than the operator can read them. */
export const HUD_PERIOD_MS = 500;

// ---- thresholds (what each figure means to the person driving)
/** Round trip (ms): above 100 ms the arm visibly answers a stick after the hand has
 * moved on; above 250 ms a command would be refused as stale by the time its answer
 * could come back (the server's command age limit, below). */
export const RTT_AMBER_MS = 100;
export const RTT_RED_MS = 250;
/** Video packet loss (%, over the last STATS_WINDOW_MS): above 1 % the picture smears
 * and waits for key frames now and then; above 5 % it breaks up most seconds. */
export const LOSS_AMBER_PERCENT = 1;
export const LOSS_RED_PERCENT = 5;
/** Decoded frames per second: below 20 motion looks jerky, below 10 the operator
 * cannot follow a moving arm. A server set to send fewer (TELEROBOT_VIDEO_FPS) is
 * judged against its own rate: amber below 75 %, red below half of it. */
export const FPS_AMBER = 20;
export const FPS_RED = 10;
export const FPS_AMBER_SHARE = 0.75;
export const FPS_RED_SHARE = 0.5;
/** A freeze: no new frame for longer than this (ms) — four frames at 20 fps, a pause
 * the eye notices. Frozen right now for FROZEN_RED_MS: the operator is driving on a
 * picture that is half a second old. */
export const FREEZE_MS = 200;
export const FROZEN_RED_MS = 500;
/** Freezes are counted over this window (ms), short enough to say how the video is
 * now: one is amber, FREEZES_RED or more (a stutter every few seconds) red. */
export const FREEZE_WINDOW_MS = 10_000;
export const FREEZES_RED = 3;
/** Age of the newest force sample on the server's clock (now + offset − sample time,
 * ms): the sensor streams at 1 kHz in ~10 ms batches, so over 50 ms the force shown
 * (and the rumble) lags the contact; over 200 ms it is as old as the dead-man's limit. */
export const FORCE_AGE_AMBER_MS = 50;
export const FORCE_AGE_RED_MS = 200;
/** The last command's age when the server acknowledged it (ms): over 100 ms driving
 * feels late; 250 ms is the server's max command age (TELEROBOT_MAX_COMMAND_AGE_MS):
 * older commands are dropped, not applied. */
export const COMMAND_AGE_AMBER_MS = 100;
export const COMMAND_AGE_RED_MS = 250;
/** How exactly the clock offset is known (ms): ± half the round trip of the ping it was
 * taken from (NTP's bound). The offset's size says nothing (the server's clock counts
 * from its boot, the page's from its load); its error goes straight into every
 * command's age as the server judges it against TELEROBOT_MAX_COMMAND_AGE_MS (250 ms):
 * over ±25 ms (a tenth of that) the judgement is off noticeably, amber; over ±100 ms
 * fresh commands may be dropped as stale or stale ones taken, red. */
export const CLOCK_ERROR_AMBER_MS = 25;
export const CLOCK_ERROR_RED_MS = 100;
/** No command acknowledged for this long (ms): not driving, the last figure is history. */
export const COMMAND_IDLE_MS = 5000;
/** The playout delay (ms): the server holds frames back by this on a lossy link so that
 * a repaired frame is shown on time (backend/media/playout.py); it adds to the
 * picture's lag, so above PLAYOUT_AMBER_MS the row is amber (the picture is behind by
 * more than a slow link's one way). */
export const PLAYOUT_AMBER_MS = 150;
/** Loss, bitrate and (without framesPerSecond) the frame rate are taken over this window (ms). */
export const STATS_WINDOW_MS = 2000;
/** The server's own video rate (GET /api/v1/video: fps_target, fps_why) is read this
 * often (ms): it changes at most every few seconds (backend/media/frame_rate.py). */
export const SERVER_VIDEO_PERIOD_MS = 5000;

/** What the HUD shows, measured just now (null: not known). */
export interface HudFigures {
  /** The video peer is up (negotiated, not failed or closed). */
  videoUp: boolean;
  /** Round trip of the video's selected ICE candidate pair (ms). */
  videoRttMs: number | null;
  /** The realtime channel's least recent ping round trip (ms). */
  pingRttMs: number | null;
  lossPercent: number | null;
  fps: number | null;
  /** The rate the server sends at (TELEROBOT_VIDEO_FPS), when known. */
  nominalFps: number | null;
  /** The rate the server encodes at now (its fps_target: 30 when the machine cannot
   * keep a configured 60), and why it is below nominalFps; null: not known. */
  serverFps?: number | null;
  serverFpsWhy?: string | null;
  bitrateKbps: number | null;
  /** The video layer the server sends this page: "full", or "low" (half each way) when
   * the link cannot carry the full one ("—" before a frame). */
  layer: string;
  frameSize: string | null;
  /** Since the last new frame (ms); null before the first. */
  sinceFrameMs: number | null;
  /** Freezes in the last FREEZE_WINDOW_MS, and the longest of them (ms). */
  freezes: number;
  longestFreezeMs: number;
  /** The decoder's own count for this peer (inbound-rtp freezeCount, totalFreezesDuration
   * in s; Chromium's rule: a frame later than 3× the mean interval or mean + 150 ms). */
  decoderFreezes?: number | null;
  decoderFreezeS?: number | null;
  /** How long the browser held each frame before showing it, over the last
   * STATS_WINDOW_MS (jitterBufferDelay / jitterBufferEmittedCount; ms). */
  playoutMs?: number | null;
  /** The server's cap on it (GET /api/v1/video playout_max_ms): a repair that takes
   * longer is not waited for. */
  playoutCapMs?: number | null;
  /** FEC packets received, and those used (not discarded), over the peer's life. */
  fecPackets?: number | null;
  fecUsed?: number | null;
  linkOpen: boolean;
  /** The clock sync has an estimate (a ping came back). */
  synced: boolean;
  /** Server − page clock (ms). */
  offsetMs: number;
  /** Age of the newest force sample on the server's clock (ms); null: none yet. */
  forceAgeMs: number | null;
  /** The last acknowledged command's latency (ms); null: none yet. */
  commandAgeMs: number | null;
  /** How long ago that acknowledgement came (ms). */
  commandSeenAgoMs: number | null;
}

export type HudKey = "rtt" | "loss" | "video" | "freezes" | "playout" | "force" | "command" | "clock";

export interface HudRow {
  key: HudKey;
  label: string;
  /** The figure, and for amber or red the limit it crossed. */
  text: string;
  level: HudLevel;
  /** The thresholds, for the row's tooltip. */
  limits: string;
}

export interface HudView {
  level: HudLevel;
  rows: HudRow[];
  /** The amber and red rows, worst first ("" when all is well). */
  reason: string;
}

const RANK: Record<HudLevel, number> = { ok: 0, amber: 1, red: 2 };
export const worst = (levels: readonly HudLevel[]): HudLevel => levels.reduce<HudLevel>((w, l) => (RANK[l] > RANK[w] ? l : w), "ok");

/** ok / amber / red for a figure where more is worse (amber above `amber`, red above `red`). */
export const above = (v: number, amber: number, red: number): HudLevel => (v > red ? "red" : v > amber ? "amber" : "ok");

const ms = (v: number): string => (v < 10 ? v.toFixed(1) : v.toFixed(0)) + " ms";
const seconds = (v: number): string => (v / 1000).toFixed(1) + " s";
/** The limit crossed, said after the figure: " (> 100 ms)". */
const over = (level: HudLevel, amber: string, red: string): string => (level === "red" ? ` (> ${red})` : level === "amber" ? ` (> ${amber})` : "");

/** The frame-rate thresholds for a server sending `nominal` frames per second. */
export function fpsLimits(nominal: number | null): { amber: number; red: number } {
  if (nominal === null || !(nominal > 0)) return { amber: FPS_AMBER, red: FPS_RED };
  return { amber: Math.min(FPS_AMBER, FPS_AMBER_SHARE * nominal), red: Math.min(FPS_RED, FPS_RED_SHARE * nominal) };
}

function rttRow(f: HudFigures): HudRow {
  const limits = `amber > ${RTT_AMBER_MS} ms, red > ${RTT_RED_MS} ms`;
  const known = [f.videoRttMs, f.pingRttMs].filter((v): v is number => v !== null);
  if (known.length === 0) return { key: "rtt", label: "RTT", text: "not measured yet", level: "amber", limits };
  const rtt = Math.max(...known); // judged by the slower path
  const level = above(rtt, RTT_AMBER_MS, RTT_RED_MS);
  const parts = [f.videoRttMs !== null ? `video ${ms(f.videoRttMs)}` : null, f.pingRttMs !== null ? `ping ${ms(f.pingRttMs)}` : null];
  return { key: "rtt", label: "RTT", text: parts.filter(Boolean).join(" · ") + over(level, `${RTT_AMBER_MS} ms`, `${RTT_RED_MS} ms`), level, limits };
}

function lossRow(f: HudFigures): HudRow {
  const limits = `video packets lost over ${STATS_WINDOW_MS / 1000} s: amber > ${LOSS_AMBER_PERCENT} %, red > ${LOSS_RED_PERCENT} %`;
  if (f.lossPercent === null) return { key: "loss", label: "loss", text: "—", level: "ok", limits };
  const level = above(f.lossPercent, LOSS_AMBER_PERCENT, LOSS_RED_PERCENT);
  return { key: "loss", label: "loss", text: `${f.lossPercent.toFixed(1)} %` + over(level, `${LOSS_AMBER_PERCENT} %`, `${LOSS_RED_PERCENT} %`), level, limits };
}

/** The server's reason in a few words: its first clause ("encoding took 15.0 ms a
 * frame (p90 over 5 s), over …" → "encoding took 15.0 ms a frame"). */
export function shortWhy(why: string): string {
  const cut = why.search(/ \(|: |, /);
  return cut > 0 ? why.slice(0, cut) : why;
}

/** " · sent at 30 of 60 fps: <why>" while the server encodes below its configured rate. */
export function serverRate(f: HudFigures): string {
  if (f.serverFps == null || f.nominalFps === null || f.serverFps >= f.nominalFps) return "";
  return ` · sent at ${f.serverFps} of ${f.nominalFps} fps${f.serverFpsWhy ? `: ${shortWhy(f.serverFpsWhy)}` : ""}`;
}

function videoRow(f: HudFigures): HudRow {
  // Judged against the rate the server sends now (30 while it cannot keep a configured 60).
  const sending = f.serverFps != null && f.nominalFps !== null && f.serverFps < f.nominalFps ? f.serverFps : f.nominalFps;
  const { amber, red } = fpsLimits(sending);
  const why = serverRate(f) && f.serverFpsWhy ? `; the server sends ${f.serverFps} of ${f.nominalFps} fps: ${f.serverFpsWhy}` : "";
  const limits = `amber below ${amber} fps or no new frame for ${FREEZE_MS} ms; red below ${red} fps or none for ${FROZEN_RED_MS} ms${why}`;
  const row = (text: string, level: HudLevel): HudRow => ({ key: "video", label: "video", text: text + serverRate(f), level, limits });
  if (!f.videoUp) return row("no video peer (reconnecting)", "red");
  if (f.sinceFrameMs === null) return row("waiting for the first frame", "amber");
  if (f.sinceFrameMs > FREEZE_MS) return row(`frozen: no new frame for ${seconds(f.sinceFrameMs)}`, f.sinceFrameMs > FROZEN_RED_MS ? "red" : "amber");
  const layer = `${f.layer}${f.frameSize ? ` ${f.frameSize}` : ""}`;
  const rate = f.bitrateKbps !== null ? ` · ${f.bitrateKbps.toFixed(0)} kbit/s` : "";
  if (f.fps === null) return row(`— fps${rate} · ${layer}`, "ok");
  const level: HudLevel = f.fps < red ? "red" : f.fps < amber ? "amber" : "ok";
  const of = sending !== null && level !== "ok" ? ` of ${sending}` : "";
  const below = level === "red" ? ` (< ${red})` : level === "amber" ? ` (< ${amber})` : "";
  return row(`${f.fps.toFixed(0)} fps${of}${below}${rate} · ${layer}`, level);
}

function freezesRow(f: HudFigures): HudRow {
  const limits = `no new frame for > ${FREEZE_MS} ms, counted over ${FREEZE_WINDOW_MS / 1000} s: amber ≥ 1, red ≥ ${FREEZES_RED}`;
  const window = `${FREEZE_WINDOW_MS / 1000} s`;
  // The decoder's count is shown beside the page's (it is the peer's whole life, not the window).
  const decoder = f.decoderFreezes ? ` · decoder ${f.decoderFreezes}${f.decoderFreezeS != null ? ` (${f.decoderFreezeS.toFixed(1)} s)` : ""}` : "";
  if (f.freezes === 0) return { key: "freezes", label: "freezes", text: `none in ${window}${decoder}`, level: "ok", limits };
  const level: HudLevel = f.freezes >= FREEZES_RED ? "red" : "amber";
  return { key: "freezes", label: "freezes", text: `${f.freezes} in ${window} (longest ${seconds(f.longestFreezeMs)})${decoder}`, level, limits };
}

function playoutRow(f: HudFigures): HudRow {
  const cap = f.playoutCapMs != null ? ` · cap ${f.playoutCapMs} ms` : "";
  const limits = `frames held to wait for repairs on a lossy link (0 on a clean one), never for a repair longer than the server's cap: amber > ${PLAYOUT_AMBER_MS} ms`;
  const fec = f.fecPackets ? ` · FEC ${f.fecPackets} packets${f.fecUsed != null ? `, ${f.fecUsed} used` : ""}` : "";
  if (f.playoutMs == null) return { key: "playout", label: "playout", text: `—${fec}`, level: "ok", limits };
  const level: HudLevel = f.playoutMs > PLAYOUT_AMBER_MS ? "amber" : "ok";
  return { key: "playout", label: "playout", text: `${ms(f.playoutMs)}${over(level, `${PLAYOUT_AMBER_MS} ms`, "")}${cap}${fec}`, level, limits };
}

function forceRow(f: HudFigures): HudRow {
  const limits = `newest sample's age on the server's clock: amber > ${FORCE_AGE_AMBER_MS} ms, red > ${FORCE_AGE_RED_MS} ms`;
  const row = (text: string, level: HudLevel): HudRow => ({ key: "force", label: "force age", text, level, limits });
  if (!f.linkOpen) return row("realtime link down", "red");
  if (!f.synced) return row("waiting for the clock sync", "amber");
  if (f.forceAgeMs === null) return row("no force samples yet", "red");
  const level = above(f.forceAgeMs, FORCE_AGE_AMBER_MS, FORCE_AGE_RED_MS);
  const text = f.forceAgeMs > 1000 ? `no new sample for ${seconds(f.forceAgeMs)}` : ms(f.forceAgeMs);
  return row(text + over(level, `${FORCE_AGE_AMBER_MS} ms`, `${FORCE_AGE_RED_MS} ms`), level);
}

function commandRow(f: HudFigures): HudRow {
  const limits = `last command's age when acknowledged: amber > ${COMMAND_AGE_AMBER_MS} ms, red > ${COMMAND_AGE_RED_MS} ms (the server drops older ones)`;
  const row = (text: string, level: HudLevel): HudRow => ({ key: "command", label: "command age", text, level, limits });
  if (f.commandAgeMs === null) return row("— (no command yet)", "ok");
  if (f.commandSeenAgoMs !== null && f.commandSeenAgoMs > COMMAND_IDLE_MS) return row(`idle (last ${ms(f.commandAgeMs)})`, "ok");
  const level = above(f.commandAgeMs, COMMAND_AGE_AMBER_MS, COMMAND_AGE_RED_MS);
  return row(ms(f.commandAgeMs) + over(level, `${COMMAND_AGE_AMBER_MS} ms`, `${COMMAND_AGE_RED_MS} ms`), level);
}

function clockRow(f: HudFigures): HudRow {
  const limits =
    "server − page clock, from the ping with the least round trip; judged by how exactly it is known " +
    `(± half that round trip; its size is arbitrary): amber beyond ± ${CLOCK_ERROR_AMBER_MS} ms, red beyond ± ${CLOCK_ERROR_RED_MS} ms`;
  if (!f.synced) return { key: "clock", label: "clock offset", text: "not synced yet", level: "amber", limits };
  const v = f.offsetMs;
  const offset = Math.abs(v) >= 1000 ? `${v >= 0 ? "+" : "−"}${(Math.abs(v) / 1000).toFixed(3)} s` : `${v >= 0 ? "+" : "−"}${Math.abs(v).toFixed(1)} ms`;
  if (f.pingRttMs === null) return { key: "clock", label: "clock offset", text: offset, level: "ok", limits };
  const error = f.pingRttMs / 2;
  const level = above(error, CLOCK_ERROR_AMBER_MS, CLOCK_ERROR_RED_MS);
  return { key: "clock", label: "clock offset", text: `${offset} ± ${ms(error)}` + over(level, `± ${CLOCK_ERROR_AMBER_MS} ms`, `± ${CLOCK_ERROR_RED_MS} ms`), level, limits };
}

/** The HUD's rows for these figures; its level is the worst row's. */
export function hudView(f: HudFigures): HudView {
  const rows = [rttRow(f), lossRow(f), videoRow(f), freezesRow(f), playoutRow(f), forceRow(f), commandRow(f), clockRow(f)];
  const bad = rows.filter((r) => r.level !== "ok").sort((a, b) => RANK[b.level] - RANK[a.level]);
  return { level: worst(rows.map((r) => r.level)), rows, reason: bad.map((r) => `${r.label}: ${r.text}`).join("; ") };
}

// ---- reading the video peer's getStats()

/** The counters of one getStats() report that the HUD uses (absent ones are null). */
export interface VideoStatsSample {
  at: number; // ms
  framesDecoded: number | null;
  framesPerSecond: number | null;
  bytesReceived: number | null;
  packetsLost: number | null;
  packetsReceived: number | null;
  freezeCount: number | null;
  totalFreezesDuration: number | null;
  frameWidth: number | null;
  frameHeight: number | null;
  /** Seconds all emitted frames spent in the jitter buffer, and their count. */
  jitterBufferDelay: number | null;
  jitterBufferEmittedCount: number | null;
  fecPacketsReceived: number | null;
  /** FEC packets not used (Chromium: those that came after the packets they cover). */
  fecPacketsDiscarded: number | null;
  /** The selected candidate pair's current round trip (s). */
  rttS: number | null;
}

type Stat = { type: string; id?: string } & Record<string, unknown>;
const num = (v: unknown): number | null => (typeof v === "number" && Number.isFinite(v) ? v : null);

/** The inbound video stream's counters and the selected candidate pair's round trip. */
export function readVideoStats(report: Iterable<Stat>, at: number): VideoStatsSample {
  const stats = [...report];
  const video = stats.find((s) => s.type === "inbound-rtp" && (s.kind ?? s.mediaType) === "video");
  const selectedId = stats.find((s) => s.type === "transport" && typeof s.selectedCandidatePairId === "string")?.selectedCandidatePairId;
  const pairs = stats.filter((s) => s.type === "candidate-pair");
  const pair = pairs.find((s) => s.id === selectedId) ?? pairs.find((s) => s.selected === true) ?? pairs.find((s) => s.nominated === true && s.state === "succeeded");
  const v = (name: string) => num(video?.[name]);
  return {
    at,
    framesDecoded: v("framesDecoded"),
    framesPerSecond: v("framesPerSecond"),
    bytesReceived: v("bytesReceived"),
    packetsLost: v("packetsLost"),
    packetsReceived: v("packetsReceived"),
    freezeCount: v("freezeCount"),
    totalFreezesDuration: v("totalFreezesDuration"),
    frameWidth: v("frameWidth"),
    frameHeight: v("frameHeight"),
    jitterBufferDelay: v("jitterBufferDelay"),
    jitterBufferEmittedCount: v("jitterBufferEmittedCount"),
    fecPacketsReceived: v("fecPacketsReceived"),
    fecPacketsDiscarded: v("fecPacketsDiscarded"),
    rttS: num(pair?.currentRoundTripTime),
  };
}

/** Rates between an older and a newer sample of the same stream. */
export function videoRates(
  older: VideoStatsSample | undefined,
  newer: VideoStatsSample,
): { fps: number | null; kbps: number | null; lossPercent: number | null; playoutMs: number | null } {
  const dt = older ? (newer.at - older.at) / 1000 : 0;
  const delta = (k: "framesDecoded" | "bytesReceived" | "packetsLost" | "packetsReceived" | "jitterBufferDelay" | "jitterBufferEmittedCount") => {
    const a = older?.[k];
    const b = newer[k];
    return dt > 0 && a != null && b != null ? b - a : null;
  };
  const frames = delta("framesDecoded");
  const bytes = delta("bytesReceived");
  const lost = delta("packetsLost");
  const received = delta("packetsReceived");
  const lostOrNot = lost !== null && received !== null ? Math.max(0, lost) + received : 0; // duplicates make lost go down
  const held = delta("jitterBufferDelay");
  const emitted = delta("jitterBufferEmittedCount");
  return {
    playoutMs: held !== null && emitted ? (1000 * held) / emitted : null,
    fps: newer.framesPerSecond ?? (frames !== null ? frames / dt : null),
    kbps: bytes !== null ? (bytes * 8) / 1000 / dt : null,
    lossPercent: lostOrNot > 0 ? (100 * Math.max(0, lost ?? 0)) / lostOrNot : null,
  };
}

/** Freezes as the page sees them: gaps over FREEZE_MS between new frames, remembered
 * for FREEZE_WINDOW_MS. */
export class FreezeCounter {
  lastFrameAt: number | null = null;
  total = 0;
  private recent: { at: number; ms: number }[] = [];

  /** A new frame at `now` (ms). */
  frame(now: number): void {
    if (this.lastFrameAt !== null && now - this.lastFrameAt > FREEZE_MS) {
      this.total += 1;
      this.recent.push({ at: now, ms: now - this.lastFrameAt });
    }
    this.lastFrameAt = now;
  }

  /** Freezes in the last FREEZE_WINDOW_MS before `now`, and the longest (ms). */
  window(now: number): { count: number; longestMs: number } {
    this.recent = this.recent.filter((f) => now - f.at <= FREEZE_WINDOW_MS);
    return { count: this.recent.length, longestMs: Math.max(0, ...this.recent.map((f) => f.ms)) };
  }

  /** Since the last new frame (ms); null before the first. */
  since(now: number): number | null {
    return this.lastFrameAt === null ? null : Math.max(0, now - this.lastFrameAt);
  }
}

// ---- collecting and drawing

/** The layer a picture `frameWidth` wide (both eyes) is, for eyes `fullWidth` wide. */
export function layerOf(frameWidth: number | null, fullWidth: number | null): string {
  if (!frameWidth) return "—";
  if (!fullWidth) return "full";
  return frameWidth / 2 < 0.75 * fullWidth ? "low" : "full";
}

/** Where the HUD's figures come from. */
export interface HudSources {
  /** The current video peer (null while there is none). */
  pc(): RTCPeerConnection | null;
  link: { readonly open: boolean; readonly bestRtt: number; readonly offset: number; readonly commandLatency: Rolling };
  /** The newest force sample (its time on the server's clock, s). */
  force(): { time: number } | null;
  /** The server's video settings (GET /api/v1/video): its frame rate and one eye's full
   * size (a smaller picture is the low layer). */
  video?: Promise<{ fps: number; width: number; playout_max_ms?: number } & Record<string, unknown>>;
  /** The same read again, every SERVER_VIDEO_PERIOD_MS: its stats' fps_target and fps_why. */
  serverVideo?: () => Promise<{ stats?: Record<string, unknown> | null } & Record<string, unknown>>;
}

export class ConnectionHud implements HudView {
  level: HudLevel = "amber";
  rows: HudRow[] = [];
  reason = "";
  figures: HudFigures | null = null;
  /** A test seam, for the browser tests only (the page never sets it): these figures
   * replace the measured ones before they are judged, e.g. the frame rate and the
   * freezes, which on a slow machine's software decoder say more about its CPU than
   * about the link. The HUD only shows; nothing reads it to decide. */
  pinned: Partial<HudFigures> | null = null;
  readonly freezes = new FreezeCounter();
  private history: VideoStatsSample[] = [];
  private pcSeen: RTCPeerConnection | null = null;
  private nominalFps: number | null = null;
  private fullWidth: number | null = null;
  private playoutCapMs: number | null = null;
  private serverFps: number | null = null;
  private serverFpsWhy: string | null = null;
  private serverReadAt = -Infinity;
  private commandsSeen = 0;
  private commandAt: number | null = null;

  constructor(private readonly src: HudSources) {
    src.video
      ?.then((v) => {
        this.nominalFps = v.fps;
        this.fullWidth = v.width;
        this.playoutCapMs = v.playout_max_ms ?? null;
      })
      .catch(() => undefined);
  }

  /** A new frame was presented (the view's frame callback). */
  frame(now = performance.now()): void {
    this.freezes.frame(now);
  }

  /** The server's rate of the moment, from its video stats (null where it does not say). */
  private readServerRate(now: number): void {
    const read = this.src.serverVideo;
    if (!read || now - this.serverReadAt < SERVER_VIDEO_PERIOD_MS) return;
    this.serverReadAt = now;
    read()
      .then((v) => {
        const target = v.stats?.fps_target;
        const why = v.stats?.fps_why;
        this.serverFps = typeof target === "number" ? target : null;
        this.serverFpsWhy = typeof why === "string" ? why : null;
      })
      .catch(() => undefined);
  }

  /** Read every source once, now. */
  async collect(now = performance.now()): Promise<HudFigures> {
    this.readServerRate(now);
    const pc = this.src.pc();
    if (pc !== this.pcSeen) {
      // A new peer: its counters start again from zero. (The frames' gap across a
      // re-negotiation is a freeze the operator saw: it is counted.)
      this.pcSeen = pc;
      this.history = [];
    }
    const up = pc !== null && pc.connectionState !== "failed" && pc.connectionState !== "closed";
    let sample: VideoStatsSample | null = null;
    if (pc && up) {
      sample = readVideoStats((await pc.getStats()).values() as Iterable<Stat>, now);
      this.history.push(sample);
      while (this.history.length > 2 && now - (this.history[1]?.at ?? now) >= STATS_WINDOW_MS) this.history.shift();
    }
    const rates = sample
      ? videoRates(this.history[0] === sample ? undefined : this.history[0], sample)
      : { fps: null, kbps: null, lossPercent: null, playoutMs: null };
    const { link } = this.src;
    if (link.commandLatency.total !== this.commandsSeen) {
      this.commandsSeen = link.commandLatency.total;
      this.commandAt = now;
    }
    const lastCommand = link.commandLatency.count > 0 ? (link.commandLatency.snapshot().at(-1) ?? null) : null;
    const synced = Number.isFinite(link.bestRtt);
    const force = this.src.force();
    const freezes = this.freezes.window(now);
    return {
      videoUp: up,
      videoRttMs: sample?.rttS != null ? sample.rttS * 1000 : null,
      pingRttMs: synced ? link.bestRtt * 1000 : null,
      lossPercent: rates.lossPercent,
      fps: rates.fps,
      nominalFps: this.nominalFps,
      serverFps: this.serverFps,
      serverFpsWhy: this.serverFpsWhy,
      bitrateKbps: rates.kbps,
      layer: layerOf(sample?.frameWidth ?? null, this.fullWidth),
      frameSize: sample?.frameWidth && sample.frameHeight ? `${sample.frameWidth}×${sample.frameHeight}` : null,
      sinceFrameMs: this.freezes.since(now),
      freezes: freezes.count,
      longestFreezeMs: freezes.longestMs,
      decoderFreezes: sample?.freezeCount ?? null,
      decoderFreezeS: sample?.totalFreezesDuration ?? null,
      playoutMs: rates.playoutMs,
      playoutCapMs: this.playoutCapMs,
      fecPackets: sample?.fecPacketsReceived ?? null,
      fecUsed: sample?.fecPacketsReceived != null ? sample.fecPacketsReceived - (sample.fecPacketsDiscarded ?? 0) : null,
      linkOpen: link.open,
      synced,
      offsetMs: link.offset * 1000,
      forceAgeMs: force && synced ? Math.max(0, (now / 1000 + link.offset - force.time) * 1000) : null,
      commandAgeMs: lastCommand,
      commandSeenAgoMs: this.commandAt === null ? null : now - this.commandAt,
    };
  }

  /** Collect, judge and keep the result (level, rows, reason). */
  async update(now = performance.now()): Promise<HudView> {
    const figures = { ...(await this.collect(now)), ...this.pinned };
    const view = hudView(figures);
    Object.assign(this, view, { figures });
    return view;
  }

  /** Redraw `box` every HUD_PERIOD_MS. */
  start(box: HTMLElement, periodMs = HUD_PERIOD_MS): void {
    let busy = false;
    const tick = () => {
      if (busy) return; // a slow getStats() is not queued up behind
      busy = true;
      this.update()
        .then((view) => drawHud(box, view))
        .catch(() => undefined)
        .finally(() => (busy = false));
    };
    setInterval(tick, periodMs);
    tick();
  }
}

/** The box: a title line with the overall level, then one line per row. */
export function drawHud(box: HTMLElement, view: HudView): void {
  box.className = `hud-${view.level}`;
  box.title = view.reason || "connection ok";
  const title = document.createElement("div");
  title.className = "hud-title";
  title.textContent = view.level === "ok" ? "connection ok" : view.level === "amber" ? "connection degraded" : "connection bad";
  const lines = view.rows.map((r) => {
    const line = document.createElement("div");
    line.className = `hud-row hud-${r.level}`;
    line.dataset.key = r.key;
    line.title = r.limits;
    const label = document.createElement("span");
    label.textContent = r.label;
    const value = document.createElement("span");
    value.textContent = r.text;
    line.append(label, value);
    return line;
  });
  box.replaceChildren(title, ...lines);
}
