// Recording from the operator page: the header's indicator (● REC mm:ss ·
// size, red, on every viewer's page) and the Recording panel — Record/Stop and the
// episodes (start with a task name, end as a success or a failure with notes) for the
// operator; every viewer sees what is being recorded and a link to review the last
// recording. Polled from GET /api/v1/recordings/active at 1 Hz, and at once on the
// realtime EVENT "RECORDING started/stopped". The pure parts (formatting, the panel's
// state from the status) are exported for the tests.
import type { Api, MessageLog, Schema } from "../api";
import { $ } from "./dom";

export type ActiveRecording = Schema<"ActiveRecording">;
export type RecordingEntry = Schema<"RecordingEntry">;
export type Episode = Schema<"Episode">;

export const POLL_MS = 1000;

// ---- pure helpers

/** Elapsed seconds as mm:ss (h:mm:ss from an hour on); nonsense reads 00:00. */
export function formatElapsed(seconds: number | null | undefined): string {
  const s = Number.isFinite(seconds) && (seconds as number) > 0 ? Math.floor(seconds as number) : 0;
  const two = (n: number) => String(n).padStart(2, "0");
  const h = Math.floor(s / 3600);
  const m = Math.floor((s % 3600) / 60);
  return h > 0 ? `${h}:${two(m)}:${two(s % 60)}` : `${two(m)}:${two(s % 60)}`;
}

/** A size in MB (10⁶ bytes): two decimals under 10 MB, one under 100, else none. */
export function formatSize(bytes: number | null | undefined): string {
  const mb = Number.isFinite(bytes) && (bytes as number) > 0 ? (bytes as number) / 1e6 : 0;
  return `${mb.toFixed(mb < 10 ? 2 : mb < 100 ? 1 : 0)} MB`;
}

/** The name the Record field suggests: `session-YYYYMMDD-HHMM` (local time); the server
 * puts its own UTC start time before it in the file's name. */
export function defaultName(date: Date): string {
  const two = (n: number) => String(n).padStart(2, "0");
  return `session-${date.getFullYear()}${two(date.getMonth() + 1)}${two(date.getDate())}-${two(date.getHours())}${two(date.getMinutes())}`;
}

/** The review page's address for a recording (review.ts reads `?id=<file name>`). */
export function reviewHref(file: string): string {
  return `review.html?id=${encodeURIComponent(file)}`;
}

/** The newest finished recording of a listing (newest first), or null. */
export function lastRecording(list: readonly Pick<RecordingEntry, "file" | "active">[]): string | null {
  return list.find((r) => !r.active)?.file ?? null;
}

/** The recorder's drop counters, non-zero ones only: "dropped: /force 3, /video/stereo 1". */
export function droppedText(dropped: Record<string, number> | undefined): string {
  const parts = Object.entries(dropped ?? {})
    .filter(([, n]) => n > 0)
    .map(([topic, n]) => `${topic} ${n}`);
  return parts.length ? `dropped: ${parts.join(", ")}` : "";
}

/** One episode as the panel shows it: "episode 0 “pick” ✓ — notes". Numbered as the
 * API numbers it (from 0: PATCH …/episodes/{n}, a task's episode, the file's /episodes),
 * as the Tasks panel and the review page show it too (this panel once said
 * "episode 1" for what the others call episode 0). */
export function episodeText(e: Pick<Episode, "episode" | "task" | "success" | "notes" | "ended">): string {
  const task = e.task ? ` “${e.task}”` : "";
  const verdict = e.ended === null ? " (recording)" : e.success === true ? " ✓" : e.success === false ? " ✗" : " (unlabelled)";
  const notes = e.ended !== null && e.notes ? ` — ${e.notes}` : "";
  return `episode ${e.episode}${task}${verdict}${notes}`;
}

export interface Shown {
  visible: boolean;
  enabled: boolean;
}

/** What the header and the panel show, from the active status (null: not known yet,
 * or the poll fails), the page's role and whether a request of this page is under way. */
export interface RecordingView {
  recording: boolean;
  /** The header's indicator. */
  indicator: { text: string; on: boolean; title: string };
  /** The panel's line: what is recorded, or why nothing can be. */
  summary: string;
  /** Record (with its name field) / Stop: the operator's only. */
  record: Shown;
  stop: Shown;
  /** The episode controls: start (task name) while none is open, end (✓/✗, notes) while one is. */
  episodeStart: Shown;
  episodeEnd: Shown;
  /** The open episode, else the last one ended ("" before any). */
  episode: string;
  episodes: number;
  dropped: string;
}

export function recordingView(status: ActiveRecording | null, operator: boolean, busy = false): RecordingView {
  const hidden = { visible: false, enabled: false };
  if (!status || !status.recording) {
    return {
      recording: false,
      indicator: { text: status ? "not recording" : "recording: unknown", on: false, title: "" },
      summary: status ? (operator ? "Not recording." : "Not recording (the operator starts a recording).") : "Recording status unknown.",
      record: operator ? { visible: true, enabled: !busy && status !== null } : hidden,
      stop: hidden,
      episodeStart: hidden,
      episodeEnd: hidden,
      episode: "",
      episodes: 0,
      dropped: "",
    };
  }
  const episodes = status.episodes ?? [];
  const last = episodes[episodes.length - 1];
  const open = last !== undefined && last.ended === null;
  const elapsed = formatElapsed(status.elapsed_s);
  const size = formatSize(status.bytes);
  const dropped = droppedText(status.dropped);
  return {
    recording: true,
    indicator: { text: `● REC ${elapsed} · ${size}`, on: true, title: `recording ${status.file ?? status.name ?? ""}${dropped ? ` (${dropped})` : ""}` },
    summary: `Recording “${status.name ?? ""}”: ${elapsed}, ${size}, ${episodes.length} episode${episodes.length === 1 ? "" : "s"}.`,
    record: hidden,
    stop: operator ? { visible: true, enabled: !busy } : hidden,
    episodeStart: operator ? { visible: true, enabled: !busy && !open } : hidden,
    episodeEnd: operator ? { visible: true, enabled: !busy && open } : hidden,
    episode: last ? episodeText(last) : "",
    episodes: episodes.length,
    dropped,
  };
}

/** The realtime EVENT texts that announce a recording's start or stop. */
export const isRecordingEvent = (text: string): boolean => text.startsWith("RECORDING");

// ---- the page's panel

const PANEL = `
<div id="rec-summary" class="hint"></div>
<div id="rec-row" class="rec-row">
  <input id="rec-name" size="20" maxlength="64" aria-label="recording name" title="The recording's name (letters, digits, - and _ are kept)">
  <button id="rec-start" type="button" title="Start recording (video, force, state, commands)">● Record</button>
  <button id="rec-stop" type="button" hidden>■ Stop</button>
</div>
<div id="rec-episode" class="hint"></div>
<div id="rec-episode-start-row" class="rec-row" hidden>
  <input id="rec-task" size="20" maxlength="200" placeholder="task name" aria-label="task name">
  <button id="rec-episode-start" type="button">Start episode</button>
</div>
<div id="rec-episode-end-row" class="rec-row" hidden>
  <input id="rec-notes" size="14" maxlength="200" placeholder="notes" aria-label="episode notes">
  <button id="rec-success" type="button" title="End the episode: success">End ✓</button>
  <button id="rec-failure" type="button" title="End the episode: failure">End ✗</button>
</div>
<div id="rec-dropped" class="hint error"></div>
<a id="rec-review" href="review.html" target="_blank" hidden>Review the last recording ↗</a>
`;

export interface RecordingDeps {
  api: Api;
  log: MessageLog;
  /** The page's role (the RealtimeLink's `operator`, known once welcomed). */
  operator: () => boolean;
}

export class RecordingPanel {
  status: ActiveRecording | null = null;
  view: RecordingView = recordingView(null, false);
  /** The last finished recording's file (the review link), null before any. */
  last: string | null = null;
  polls = 0;
  private busy = false;
  private polling = false;
  private again = false;
  private pollError = "";
  private readonly indicator = $("rec-indicator");
  private readonly name: HTMLInputElement;

  constructor(private readonly deps: RecordingDeps) {
    $("recording").insertAdjacentHTML("beforeend", PANEL);
    this.name = $<HTMLInputElement>("rec-name");
    this.name.value = defaultName(new Date());
    $("rec-start").onclick = () => this.act("start the recording", () => this.start());
    $("rec-stop").onclick = () => this.act("stop the recording", () => this.stop());
    $("rec-episode-start").onclick = () =>
      this.act("start the episode", () => deps.api.request("post", "/api/v1/recordings/active/episodes", { body: { task: $<HTMLInputElement>("rec-task").value.trim() } }));
    $("rec-success").onclick = () => this.act("end the episode", () => this.endEpisode(true));
    $("rec-failure").onclick = () => this.act("end the episode", () => this.endEpisode(false));
    void this.poll();
    void this.refreshLast();
    setInterval(() => void this.poll(), POLL_MS);
  }

  /** Every realtime EVENT: a recording's start or stop polls at once. */
  event(text: string): void {
    if (!isRecordingEvent(text)) return;
    void this.poll();
    if (text.startsWith("RECORDING stopped")) void this.refreshLast();
  }

  async poll(): Promise<void> {
    if (this.polling) {
      this.again = true; // after the one under way: it may have been answered before a change
      return;
    }
    this.polling = true;
    try {
      this.status = await this.deps.api.request("get", "/api/v1/recordings/active");
      this.pollError = "";
    } catch (e) {
      this.status = null;
      const text = `recording status: ${(e as Error).message}`;
      if (text !== this.pollError) this.deps.log.add(text, true); // once, not every second
      this.pollError = text;
    } finally {
      this.polling = false;
      this.polls += 1;
      this.render();
    }
    if (this.again) {
      this.again = false;
      await this.poll();
    }
  }

  render(): void {
    const v = (this.view = recordingView(this.status, this.deps.operator(), this.busy));
    this.indicator.textContent = v.indicator.text;
    this.indicator.title = v.indicator.title;
    this.indicator.classList.toggle("rec-on", v.indicator.on);
    $("rec-summary").textContent = v.summary;
    const show = (id: string, s: Shown) => {
      const el = $<HTMLButtonElement>(id);
      el.hidden = !s.visible;
      el.disabled = !s.enabled;
    };
    $("rec-row").hidden = !v.record.visible && !v.stop.visible;
    this.name.hidden = !v.record.visible;
    show("rec-start", v.record);
    show("rec-stop", v.stop);
    $("rec-episode-start-row").hidden = !v.episodeStart.visible;
    show("rec-episode-start", v.episodeStart);
    $("rec-episode-end-row").hidden = !v.episodeEnd.visible;
    $("rec-success").toggleAttribute("disabled", !v.episodeEnd.enabled);
    $("rec-failure").toggleAttribute("disabled", !v.episodeEnd.enabled);
    $("rec-episode").textContent = v.episode;
    $("rec-dropped").textContent = v.dropped;
    const review = $<HTMLAnchorElement>("rec-review");
    review.hidden = this.last === null;
    if (this.last !== null) {
      review.href = reviewHref(this.last);
      review.title = this.last;
    }
  }

  private async start(): Promise<void> {
    const name = this.name.value.trim() || defaultName(new Date());
    const status = await this.deps.api.request("post", "/api/v1/recordings", { body: { name } });
    this.status = status;
    this.render();
    this.deps.log.add(`recording ${status.file ?? name}`);
  }

  private async stop(): Promise<void> {
    const entry = await this.deps.api.request("post", "/api/v1/recordings/active/stop");
    this.last = entry.file;
    const n = entry.episodes.length;
    this.deps.log.add(`recorded ${entry.file}: ${formatElapsed(entry.duration_s)}, ${formatSize(entry.bytes)}, ${n} episode${n === 1 ? "" : "s"}`);
    this.name.value = defaultName(new Date());
  }

  private async endEpisode(success: boolean): Promise<void> {
    const notes = $<HTMLInputElement>("rec-notes");
    await this.deps.api.request("post", "/api/v1/recordings/active/episodes/end", { body: { success, notes: notes.value.trim() } });
    notes.value = "";
  }

  /** One request of the operator's: the buttons wait for it, errors go to the log, and
   * the status is polled again after it. */
  private async act(what: string, request: () => Promise<unknown>): Promise<void> {
    if (this.busy) return;
    this.busy = true;
    this.render();
    try {
      await request();
    } catch (e) {
      this.deps.log.add(`cannot ${what}: ${(e as Error).message}`, true);
    } finally {
      this.busy = false;
      await this.poll();
    }
  }

  private async refreshLast(): Promise<void> {
    try {
      const last = lastRecording(await this.deps.api.request("get", "/api/v1/recordings"));
      if (last !== null) this.last = last;
    } catch (e) {
      this.deps.log.add(`recordings: ${(e as Error).message}`, true);
    }
    this.render();
  }
}
