// What the review page marks on its timeline besides the plots: the
// recording's episodes (task, ✓/✗, notes) as spans and its safety events (e-stop, its
// reset, force-limit trips, dead-man halts, the lease changing hands) as ticks, and who
// sent each command, named once. Pure: the page draws what these
// return (review/marks-strip.ts, command-log.ts).
import { episodeText } from "../ui/recording";
import { formatTime } from "./timeline";

/** One /episodes message as the timeline gives it (docs/recording.md). */
export interface EpisodeEvent {
  time: number;
  event: string; // start, end, label
  episode: number;
  task?: string;
  success?: boolean | null;
  notes?: string;
}

/** An episode as the review shows it: from its start to its end (null: never ended —
 * the recording stopped while it was open, or the file was cut short). */
export interface ReviewEpisode {
  episode: number;
  task: string;
  success: boolean | null;
  notes: string;
  start: number;
  end: number | null;
}

/** The episodes in a recording's /episodes messages, by number: each message carries
 * the episode's whole label as it stood (the recorder logs task, success and notes on
 * start, end and every relabel), so the last one seen is its label. A label or an end
 * whose start was not kept (the timeline keeps the first 5000 events) starts it there. */
export function episodesOf(events: readonly EpisodeEvent[]): ReviewEpisode[] {
  const byNumber = new Map<number, ReviewEpisode>();
  for (const e of events) {
    if (!Number.isInteger(e.episode)) continue;
    let ep = byNumber.get(e.episode);
    if (!ep) {
      ep = { episode: e.episode, task: "", success: null, notes: "", start: e.time, end: null };
      byNumber.set(e.episode, ep);
    }
    if (e.event === "start") ep.start = e.time;
    if (e.event === "end") ep.end = e.time;
    ep.task = e.task ?? ep.task;
    ep.success = e.success ?? null;
    ep.notes = e.notes ?? ep.notes;
  }
  return [...byNumber.values()].sort((a, b) => a.start - b.start);
}

/** An episode in words, worded and numbered as the Recording panel words it (one
 * numbering everywhere: the API's, from 0): "episode 0 “pick” ✓ — notes". */
export function episodeWords(e: ReviewEpisode): string {
  // episodeText says "(recording)" for an episode without an end: here the recording is
  // over, so one never ended is said so, with its verdict and notes as they were left.
  const text = episodeText({ episode: e.episode, task: e.task, success: e.success, notes: e.notes, ended: e.end ?? e.start });
  return e.end === null ? `${text} (not ended)` : text;
}

/** An episode with when it ran: "0:01.0–0:04.5 episode 0 “pick” ✓ — notes". */
export function episodeLabel(e: ReviewEpisode): string {
  return `${formatTime(e.start)}–${e.end === null ? "end" : formatTime(e.end)} ${episodeWords(e)}`;
}

/** One /safety message: the DecisionServer's whole safety state after each change. */
export interface SafetySnapshot {
  time: number;
  estop?: boolean;
  estop_reason?: string;
  force_limited?: boolean;
  halted?: boolean;
  lease_holder?: string | null;
  lease_holder_name?: string | null;
  lease_note?: string;
}

export type MarkKind = "estop" | "reset" | "force" | "force-clear" | "halt" | "resume" | "lease";

/** A safety event at a time, in words. */
export interface SafetyMark {
  time: number;
  kind: MarkKind;
  text: string;
}

/** The safety events in a recording's /safety messages. Each message is the state after
 * one change, so the events are what differs from the message before; a recording
 * starts with nothing latched (its first message says what changed first) and with the
 * lease's holder unknown (the first message names it only if the lease is what changed:
 * a first e-stop does not also claim the lease changed hands then). */
export function safetyMarks(snapshots: readonly SafetySnapshot[]): SafetyMark[] {
  const marks: SafetyMark[] = [];
  let estop = false;
  let forceLimited = false;
  let halted = false;
  let holder: string | null | undefined;
  for (const s of snapshots) {
    const before = marks.length;
    const at = (kind: MarkKind, text: string) => marks.push({ time: s.time, kind, text });
    if (!!s.estop !== estop) {
      if (s.estop) at("estop", `e-stop: ${s.estop_reason || "pressed"}`);
      else at("reset", "e-stop reset");
    }
    if (!!s.force_limited !== forceLimited) {
      if (s.force_limited) at("force", "force limit: motion stopped");
      else at("force-clear", "force limit released");
    }
    if (!!s.halted !== halted) {
      // The live page's words for a halt: the link stalled, not the operator.
      if (s.halted) at("halt", "dead-man halt: the link stalled (lease kept)");
      else at("resume", "dead-man: heartbeats back");
    }
    const now = s.lease_holder ?? null;
    const changedHands = holder === undefined ? marks.length === before : now !== holder;
    if (changedHands) {
      const name = s.lease_holder_name ?? now;
      at("lease", `lease: ${s.lease_note || (name ? `held by ${name}` : "free")}`);
    }
    estop = !!s.estop;
    forceLimited = !!s.force_limited;
    halted = !!s.halted;
    holder = now;
  }
  return marks;
}

/** Where a span of the recording sits on a strip as wide as the timeline, in % of it:
 * clamped inside, and at least a sliver wide (an instant is still seen). */
export function spanOf(start: number, end: number | null, duration: number): { left: number; width: number } {
  const d = duration > 0 ? duration : 1;
  const pct = (t: number) => Math.min(Math.max((t / d) * 100, 0), 100);
  const left = pct(start);
  const right = pct(end ?? d);
  return { left, width: Math.max(right - left, 0.3) };
}

/** Who sent a command, named once. An unnamed connection's name already says how it
 * came ("ws 127.0.0.1:51234", "priority …"), as do a task's ("task 3") and the
 * server's own ("server"); a named client (a script's lease) gets its way in brackets. */
export function whoSent(source: string, client: string): string {
  if (!client) return source;
  if (!source || client === source || client.startsWith(`${source} `)) return client;
  return `${client} (${source})`;
}

/** One line of the review's event list: an episode (at its start) or a safety event. */
export interface MarkRow {
  time: number;
  /** For the page's colours: an episode's verdict, or a safety event's kind. */
  kind: MarkKind | "success" | "failure" | "unlabelled";
  text: string;
}

/** The episodes and the safety events as one list in time order, each with its time. */
export function markRows(episodes: readonly ReviewEpisode[], marks: readonly SafetyMark[]): MarkRow[] {
  const rows: MarkRow[] = [
    ...episodes.map((e) => ({ time: e.start, kind: verdictOf(e), text: episodeLabel(e) })),
    ...marks.map((m) => ({ time: m.time, kind: m.kind, text: `${formatTime(m.time)} ${m.text}` })),
  ];
  return rows.sort((a, b) => a.time - b.time);
}

/** An episode's verdict as a class name: success, failure or unlabelled. */
export function verdictOf(e: Pick<ReviewEpisode, "success">): "success" | "failure" | "unlabelled" {
  return e.success === true ? "success" : e.success === false ? "failure" : "unlabelled";
}

/** Who drove when, from a supervised policy's /autonomy changes: a span per mode until
 * the next change (or the end); "off" (no policy) is not drawn. */
export interface DroveSpan {
  mode: "autonomous" | "paused" | "correcting";
  start: number;
  end: number;
  who: string;
}

export function droveSpans(changes: readonly { time: number; mode: string; policy?: string | null; operator?: string | null }[], duration: number): DroveSpan[] {
  const sorted = [...changes].sort((a, b) => a.time - b.time);
  const out: DroveSpan[] = [];
  sorted.forEach((c, i) => {
    if (c.mode !== "autonomous" && c.mode !== "paused" && c.mode !== "correcting") return;
    const end = sorted[i + 1]?.time ?? duration;
    if (end <= c.time) return;
    const who = c.mode === "correcting" ? `${c.operator ?? "an operator"} corrected` : c.mode === "paused" ? `${c.policy ?? "the policy"} paused` : `${c.policy ?? "the policy"} drove`;
    out.push({ mode: c.mode, start: c.time, end, who });
  });
  return out;
}
