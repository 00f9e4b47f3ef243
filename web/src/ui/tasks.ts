// The Tasks panel (issue 14): repeat a recorded episode as a server-side task. Pick a
// recording and one of its episodes, the speed and the compliance; "Preview path" shows
// the episode's tool path over both eyes (the server's trajectory for it, before it
// runs: POST /tasks/preview); "Run" starts it with this page's
// lease (the task takes it over and hands it back at its end); a start far from the
// first pose is refused and "Approach first" offers the guarded move, after a confirm.
// While it runs: progress, state, Pause/Resume/Abort, polled at 4 Hz; the reason when it stops.
import type { Api, MessageLog, Schema } from "../api";
import { pathLength, type PathOverlay } from "../ar/path";
import type { Vec3 } from "../robot/math";
import { StateFlags } from "../transport/messages";

export const TASK_POLL_MS = 250;
/** After a task ends, how long the lease's return may lag behind its state here. */
export const HAND_BACK_MS = 3000;
type TaskView = Schema<"TaskView">;
type Recording = Schema<"RecordingEntry">;
const FINISHED = new Set<TaskView["state"]>(["done", "stopped", "aborted"]);

export interface TaskSources {
  api: Api;
  log: MessageLog;
  link: { readonly operator: boolean; readonly clientId: string };
  /** This page's STATE flags now (0: none yet). */
  flags(): number;
  path: PathOverlay;
  /** Asks the operator (window.confirm on the page). */
  confirm?: (text: string) => boolean;
}

/** A stopped task's line: why, in the server's words. */
export function finishedText(view: Pick<TaskView, "state" | "reason">): string {
  return view.reason ? `${view.state}: ${view.reason}` : view.state;
}

/** A start refused because the tool is away from the task's first pose. */
export function farFromStart(message: string): boolean {
  return /first pose/.test(message);
}

function el<K extends keyof HTMLElementTagNameMap>(tag: K, props: Partial<HTMLElementTagNameMap[K]> = {}, ...children: (Node | string)[]): HTMLElementTagNameMap[K] {
  const e = Object.assign(document.createElement(tag), props);
  e.append(...children);
  return e;
}

export class TasksPanel {
  /** The task this page follows (the last it started), as last polled. */
  task: TaskView | null = null;
  recordings: Recording[] = [];
  private readonly recording = el("select", { id: "task-recording", title: "a recording (GET /api/v1/recordings)" });
  private readonly episode = el("select", { id: "task-episode", title: "the episode to repeat" });
  private readonly refreshButton = el("button", { id: "task-refresh", type: "button", title: "Read the recordings again", textContent: "↻" });
  private readonly speed = el("input", { id: "task-speed", type: "range", min: "0.1", max: "1", step: "0.05", value: "0.5" });
  private readonly speedValue = el("output", { id: "task-speed-value", textContent: "0.50" });
  private readonly compliance = el("input", { id: "task-compliance", type: "checkbox", title: "give way to contact forces (admittance)" });
  private readonly stiffness = el("input", { id: "task-stiffness", type: "number", min: "10", max: "1000000", step: "100", value: "1000", size: 7 });
  private readonly previewButton = el("button", { id: "task-preview", type: "button", textContent: "Preview path" });
  private readonly clearButton = el("button", { id: "task-clear", type: "button", textContent: "Clear", title: "Hide the path" });
  private readonly runButton = el("button", { id: "task-run", type: "button", textContent: "Run", title: "Repeat it (take control first)" });
  private readonly approachButton = el("button", { id: "task-approach", type: "button", textContent: "Approach first", hidden: true });
  private readonly progress = el("progress", { id: "task-progress", max: 1, value: 0 });
  private readonly stateText = el("span", { id: "task-state" });
  private readonly pauseButton = el("button", { id: "task-pause", type: "button", textContent: "Pause", hidden: true });
  private readonly resumeButton = el("button", { id: "task-resume", type: "button", textContent: "Resume", hidden: true });
  private readonly abortButton = el("button", { id: "task-abort", type: "button", textContent: "Abort", hidden: true });
  private readonly reason = el("div", { id: "task-reason", className: "hint" });
  private polling = false;
  private starting = false;
  private finishedAt = -Infinity; // when this page saw its task end (performance.now())

  constructor(
    private readonly box: HTMLElement,
    private readonly src: TaskSources,
  ) {
    box.append(
      el("label", {}, "Recording ", this.recording, " ", this.refreshButton),
      el("label", {}, "Episode ", this.episode),
      el("label", {}, "Speed ", this.speed, " ", this.speedValue),
      el("label", { title: "the arm gives way along x, y and z" }, this.compliance, " Compliant, stiffness ", this.stiffness, " N/m"),
      el("div", {}, this.previewButton, " ", this.clearButton, " ", this.runButton, " ", this.approachButton),
      el("div", { id: "task-status" }, this.progress, " ", this.stateText, " ", this.pauseButton, " ", this.resumeButton, " ", this.abortButton),
      this.reason,
    );
    this.speed.oninput = () => (this.speedValue.textContent = Number(this.speed.value).toFixed(2));
    this.recording.onchange = () => this.fillEpisodes();
    this.episode.onchange = () => this.src.path.clear(); // the shown path was another episode's
    this.refreshButton.onclick = () => void this.load();
    this.previewButton.onclick = () => void this.preview();
    this.clearButton.onclick = () => this.src.path.clear();
    this.runButton.onclick = () => void this.run(false);
    this.approachButton.onclick = () => {
      const ask = this.src.confirm ?? ((text: string) => window.confirm(text));
      if (ask("The tool is away from the task's first pose. Move it there first (a guarded move at low speed), then run the task?")) void this.run(true);
    };
    this.pauseButton.onclick = () => void this.command("pause");
    this.resumeButton.onclick = () => void this.command("resume");
    this.abortButton.onclick = () => void this.command("abort");
    setInterval(() => this.tick(), TASK_POLL_MS);
    this.show();
  }

  /** The path shown over the video (for tests). */
  get path(): PathOverlay {
    return this.src.path;
  }

  /** A task this page follows is under way: the lease is the task's, not lost (and
   * for a moment after its end, until the lease comes back). */
  get handedOver(): boolean {
    if (this.task === null) return false;
    if (!FINISHED.has(this.task.state)) return true;
    return performance.now() - this.finishedAt < HAND_BACK_MS && (this.src.flags() & StateFlags.YOU_HAVE_CONTROL) === 0;
  }

  private get underWay(): boolean {
    return this.task !== null && !FINISHED.has(this.task.state);
  }

  /** Read the recordings (and follow a task already under way). */
  async load(): Promise<void> {
    try {
      const [recordings, tasks] = await Promise.all([this.src.api.request("get", "/api/v1/recordings"), this.src.api.request("get", "/api/v1/tasks")]);
      this.recordings = recordings.filter((r) => !r.active && r.episodes.length > 0);
      const chosen = this.recording.value;
      this.recording.replaceChildren(
        ...this.recordings.map((r) => el("option", { value: r.file, textContent: `${r.name} — ${r.file.slice(0, 15)} (${r.episodes.length} ep.)` })),
      );
      if (this.recordings.some((r) => r.file === chosen)) this.recording.value = chosen;
      if (this.recordings.length === 0) this.recording.append(el("option", { value: "", textContent: "no recording with episodes" }));
      this.fillEpisodes();
      const running = tasks.find((t) => !FINISHED.has(t.state));
      if (running && !this.task) this.follow(running);
    } catch (e) {
      this.src.log.add(`tasks: ${(e as Error).message}`, true);
    }
  }

  private fillEpisodes(): void {
    const rec = this.chosenRecording();
    const chosen = this.episode.value;
    this.episode.replaceChildren(
      ...(rec?.episodes ?? []).map((ep) => {
        const mark = ep.success === true ? " ✓" : ep.success === false ? " ✗" : "";
        const span = ep.ended !== null ? ` ${(ep.ended - ep.started).toFixed(1)} s` : " (not ended)";
        return el("option", { value: String(ep.episode), textContent: `${ep.episode}: ${ep.task || "unlabelled"}${mark}${span}` });
      }),
    );
    if ([...this.episode.options].some((o) => o.value === chosen)) this.episode.value = chosen;
    this.src.path.clear();
    this.show();
  }

  private chosenRecording(): Recording | undefined {
    return this.recordings.find((r) => r.file === this.recording.value);
  }

  private chosenEpisode(): Schema<"Episode"> | undefined {
    return this.chosenRecording()?.episodes.find((e) => String(e.episode) === this.episode.value);
  }

  /** The chosen episode's tool path, from the recording's states (base frame). */
  async preview(): Promise<Vec3[] | null> {
    const rec = this.chosenRecording();
    const ep = this.chosenEpisode();
    if (!rec || !ep) {
      this.src.log.add("tasks: choose a recording and an episode first", true);
      return null;
    }
    try {
      // The server builds the path a task would follow (the same trajectory), moving nothing.
      const preview = await this.src.api.request("post", "/api/v1/tasks/preview", { body: { recording: rec.file, episode: ep.episode } });
      const points = preview.positions.map((p) => [...p] as Vec3);
      if (points.length === 0) {
        this.src.log.add(`tasks: episode ${ep.episode} of ${rec.file} has no robot states`, true);
        return null;
      }
      this.src.path.show(points);
      this.src.log.add(`task path: episode ${ep.episode}, ${(pathLength(points) * 100).toFixed(1)} cm (cyan)`);
      return points;
    } catch (e) {
      this.src.log.add(`preview: ${(e as Error).message}`, true);
      return null;
    }
  }

  private canRun(): boolean {
    return this.src.link.operator && (this.src.flags() & StateFlags.YOU_HAVE_CONTROL) !== 0 && !this.underWay && !this.starting;
  }

  /** Start the chosen episode as a task (`approach`: the operator confirmed the guarded move). */
  async run(approach: boolean): Promise<void> {
    const rec = this.chosenRecording();
    const ep = this.chosenEpisode();
    if (!rec || !ep) return this.src.log.add("tasks: choose a recording and an episode first", true);
    if (!this.canRun()) return this.src.log.add("tasks: take control first (an operator page with the lease starts a task)", true);
    this.starting = true;
    this.approachButton.hidden = true;
    this.show();
    try {
      if (!this.src.path.shown) await this.preview();
      const view = await this.src.api.request("post", "/api/v1/tasks", {
        headers: { "X-Client-Id": this.src.link.clientId },
        body: {
          recording: rec.file,
          episode: ep.episode,
          speed: Number(this.speed.value),
          compliance: this.compliance.checked ? { axes: "xyz", stiffness_n_per_m: Number(this.stiffness.value), damping_n_s_per_m: 2000, max_offset_m: 0.01, max_rate_m_s: 0.02 } : null,
          force_margin_n: 15,
          approach,
        },
      });
      this.src.log.add(`task ${view.id} ${view.state}: episode ${ep.episode} of ${rec.file} at ${view.speed.toFixed(2)}×`);
      this.follow(view);
      // The path the server follows (the same episode, resampled).
      const path = await this.src.api.request("get", "/api/v1/tasks/{task_id}/path", { params: { task_id: view.id } });
      if (path.positions.length > 0) this.src.path.show(path.positions);
    } catch (e) {
      const message = (e as Error).message;
      this.src.log.add(`task: ${message}`, true);
      if (!approach && farFromStart(message)) this.approachButton.hidden = false;
    } finally {
      this.starting = false;
      this.show();
    }
  }

  private follow(view: TaskView): void {
    this.task = view;
    this.reason.textContent = "";
    this.show();
  }

  private async command(what: "pause" | "resume" | "abort"): Promise<void> {
    const task = this.task;
    if (!task) return;
    try {
      const view = await this.src.api.request("post", `/api/v1/tasks/{task_id}/${what}`, {
        params: { task_id: task.id },
        headers: { "X-Client-Id": this.src.link.clientId },
      });
      this.update(view);
    } catch (e) {
      this.src.log.add(`task ${what}: ${(e as Error).message}`, true);
    }
  }

  private tick(): void {
    this.show();
    const task = this.task;
    if (!task || FINISHED.has(task.state) || this.polling) return;
    this.polling = true;
    this.src.api
      .request("get", "/api/v1/tasks/{task_id}", { params: { task_id: task.id } })
      .then((view) => this.update(view))
      .catch((e: Error) => this.src.log.add(`task ${task.id}: ${e.message}`, true))
      .finally(() => (this.polling = false));
  }

  private update(view: TaskView): void {
    const was = this.task;
    if (was && was.id !== view.id) return;
    this.task = view;
    if (FINISHED.has(view.state) && was && !FINISHED.has(was.state)) {
      this.finishedAt = performance.now();
      this.src.log.add(`task ${view.id} ${finishedText(view)}`, view.state !== "done");
    }
    this.show();
  }

  /** The controls as the task and this page's control stand. */
  private show(): void {
    const t = this.task;
    const active = this.underWay;
    const recordingChosen = this.chosenEpisode() !== undefined;
    this.runButton.disabled = !recordingChosen || !this.canRun();
    this.approachButton.disabled = this.runButton.disabled;
    this.previewButton.disabled = !recordingChosen;
    this.clearButton.disabled = !this.src.path.shown;
    this.recording.disabled = this.episode.disabled = active;
    this.pauseButton.hidden = !t || !(t.state === "running" || t.state === "approaching");
    this.resumeButton.hidden = !t || t.state !== "paused";
    this.abortButton.hidden = !active;
    this.progress.value = t ? t.progress : 0;
    this.stateText.textContent = t ? `task ${t.id}: ${t.state} ${Math.round(t.progress * 100)}%` : "";
    this.reason.textContent = t && FINISHED.has(t.state) ? finishedText(t) : "";
    this.box.classList.toggle("task-active", active);
  }
}
