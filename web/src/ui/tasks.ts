// The Tasks panel (docs/tasks.md): repeat a recorded episode as a server-side task. Pick a
// recording and one of its episodes, the speed and the compliance; "Preview path" shows
// the episode's tool path over both eyes (the server's trajectory for it, before it
// runs: POST /tasks/preview); "Run" starts it with this page's
// lease (the task takes it over and hands it back at its end). A refused Run says the
// server's reason in the panel; when the reason is the distance to the first pose,
// "Approach first" offers the approach (a slow joint move there, drawn dashed amber
// before the path), after a confirm; when it cannot be pressed, it says why.
// While it runs: progress, state, Pause/Resume/Abort, polled at 4 Hz; the reason when it stops.
// A recording made with another arm model than the server's (a PUMA's on an SO-101) is
// listed greyed out, saying so: its tool path is another arm's (the server refuses it).
import { ApiError, type Api, type MessageLog, type Problem, type Schema } from "../api";
import { pathLength, type PathOverlay } from "../ar/path";
import type { Vec3 } from "../robot/math";
import { StateFlags } from "../transport/messages";

export const TASK_POLL_MS = 250;
/** After a task ends, how long the lease's return may lag behind its state here. */
export const HAND_BACK_MS = 3000;
type TaskView = Schema<"TaskView">;
type TaskPath = Schema<"TaskPath">;
type Recording = Schema<"RecordingEntry">;
/** The server's problem type for a start refused by the distance to the first pose. */
export const AWAY_FROM_START = "urn:telerobot:error:away_from_start";
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
  /** The server's arms' names (two or more: the panel's Arm choice; absent: one arm). */
  arms?: () => readonly string[];
}

/** The Arm choice on a server of several arms: "" repeats each recorded arm on the arm
 * of its name (a recording of several arms); an arm's name repeats a one-arm recording
 * on that arm. */
export function armOptions(arms: readonly string[]): { value: string; text: string }[] {
  if (arms.length < 2) return [];
  return [{ value: "", text: "each as recorded" }, ...arms.map((a) => ({ value: a, text: `on ${a} (a one-arm recording)` }))];
}

/** A stopped task's line: why, in the server's words. */
export function finishedText(view: Pick<TaskView, "state" | "reason">): string {
  return view.reason ? `${view.state}: ${view.reason}` : view.state;
}

/** A start refused because the tool is away from the task's first pose (the server's
 * problem type, not its words). */
export function farFromStart(error: unknown): boolean {
  const problem = error instanceof ApiError ? (error.problem as Problem | undefined) : undefined;
  return typeof problem === "object" && problem !== null && problem.type === AWAY_FROM_START;
}

/** The server's arm: its model's name in the settings ("so101") and for a person ("SO-101"). */
export interface ServerArmName {
  model: string;
  name: string;
}

/** Why a recording cannot be repeated on the server's arm ("" when it can): it was made
 * with another arm model. One whose model is not known (recorded before the list said
 * it) is offered: the server refuses it when asked if it is another's. */
export function otherArm(rec: Pick<Recording, "robot_model">, arm: ServerArmName | null): string {
  const made = rec.robot_model;
  if (!arm || !made || made === arm.model) return "";
  return `recorded with another arm model (${made}): this server drives the ${arm.name} (${arm.model}), and a task repeats the recorded tool path`;
}

export interface RecordingChoice {
  value: string;
  text: string;
  disabled: boolean;
  title: string;
}

/** The Recording list: each recording with its name, file and episodes; another arm's
 * greyed out saying so. The one chosen: `chosen` if it still can be, else the first that
 * can; none ("", a line saying why) when none can. */
export function recordingChoices(recordings: readonly Recording[], arm: ServerArmName | null, chosen: string): { options: RecordingChoice[]; value: string } {
  const options = recordings.map((r) => {
    const why = otherArm(r, arm);
    const text = `${r.name} — ${r.file.slice(0, 15)} (${r.episodes.length} ep.)${why ? ` — another arm (${r.robot_model})` : ""}`;
    return { value: r.file, text, disabled: why !== "", title: why };
  });
  const usable = options.filter((o) => !o.disabled);
  if (usable.length === 0) {
    const none = recordings.length === 0 ? "no recording with episodes" : `no recording of the ${arm?.name ?? "server's arm"} with episodes (${recordings.length} of another arm)`;
    return { options: [{ value: "", text: none, disabled: false, title: "" }, ...options], value: "" };
  }
  return { options, value: usable.some((o) => o.value === chosen) ? chosen : usable[0]!.value };
}

/** Why this page cannot start a task now ("" when it can). */
export function whyNotRun(p: { chosen: boolean; operator: boolean; control: boolean; underWay: boolean; starting: boolean; arm?: string }): string {
  if (p.arm) return p.arm;
  if (!p.chosen) return "choose a recording and an episode";
  if (!p.operator) return "this page has no operator token (open it with ?token=…)";
  if (!p.control) return "take control first (a task starts on this page's lease)";
  if (p.underWay) return "a task is under way";
  if (p.starting) return "starting…";
  return "";
}

/** What the panel shows after Run was refused: the server's reason in its words, and
 * "Approach first" (null: not offered) when the reason is the distance to the first pose,
 * enabled when a task could start now, else saying why not (`blocked`, from whyNotRun). */
export function refusalView(reason: string, awayFromStart: boolean, blocked: string): { text: string; approach: { disabled: boolean; title: string } | null } {
  const text = `Run refused: ${reason}`;
  if (!awayFromStart) return { text, approach: null };
  if (blocked) return { text: `${text} — to approach it: ${blocked}`, approach: { disabled: true, title: `Approach first: ${blocked}` } };
  return { text, approach: { disabled: false, title: "Move the tool to the task's first pose (a slow joint move, dashed amber), then run the task" } };
}

/** What the operator confirms before the approach: how far, and how the arm gets there
 * (from the preview's figures when there are some, else the server's reason). */
export function approachQuestion(start: Pick<TaskPath, "start_distance_m" | "start_angle_rad"> | null, reason: string): string {
  const far = start ? `The tool is ${(start.start_distance_m * 1000).toFixed(1)} mm / ${((start.start_angle_rad * 180) / Math.PI).toFixed(1)}° from the task's first pose.` : `${reason.charAt(0).toUpperCase()}${reason.slice(1)}.`;
  return `${far} Move it there first — a slow joint move, shown dashed amber — then run the task?`;
}

/** The log's line for a preview: the path's length, and where the tool is from its start. */
export function previewText(episode: number, points: readonly Vec3[], preview: Pick<TaskPath, "start_distance_m" | "start_angle_rad" | "approach" | "approach_refused">): string {
  const line = `task path: episode ${episode}, ${(pathLength(points) * 100).toFixed(1)} cm (cyan)`;
  if (preview.approach_refused) return `${line}; the tool cannot approach its start: ${preview.approach_refused}`;
  if (preview.approach.length === 0) return line;
  const far = `${(preview.start_distance_m * 1000).toFixed(0)} mm / ${((preview.start_angle_rad * 180) / Math.PI).toFixed(1)}°`;
  return `${line}; the tool is ${far} from its start: the approach, a joint move, dashed amber`;
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
  /** The server's arm, as last read (null: not yet). */
  arm: ServerArmName | null = null;
  private readonly recording = el("select", { id: "task-recording", title: "a recording (GET /api/v1/recordings)" });
  private readonly episode = el("select", { id: "task-episode", title: "the episode to repeat" });
  private readonly armChoice = el("select", { id: "task-arm", title: "which arm repeats it: a one-arm recording on the arm named, a recording of several arms each on the arm of its name" });
  private readonly armRow = el("label", { hidden: true }, "Arm ", this.armChoice);
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
  /** The last refused Run (null: none since), and whether it was the distance to the start. */
  refusal: { reason: string; away: boolean } | null = null;
  /** The last preview's figures: how far the tool was from the path's start. */
  private start: TaskPath | null = null;
  private finishedAt = -Infinity; // when this page saw its task end (performance.now())

  constructor(
    private readonly box: HTMLElement,
    private readonly src: TaskSources,
  ) {
    box.append(
      el("label", {}, "Recording ", this.recording, " ", this.refreshButton),
      el("label", {}, "Episode ", this.episode),
      this.armRow,
      el("label", {}, "Speed ", this.speed, " ", this.speedValue),
      el("label", { title: "the arm gives way along x, y and z" }, this.compliance, " Compliant, stiffness ", this.stiffness, " N/m"),
      el("div", {}, this.previewButton, " ", this.clearButton, " ", this.runButton, " ", this.approachButton),
      el("div", { id: "task-status" }, this.progress, " ", this.stateText, " ", this.pauseButton, " ", this.resumeButton, " ", this.abortButton),
      this.reason,
    );
    this.speed.oninput = () => (this.speedValue.textContent = Number(this.speed.value).toFixed(2));
    this.recording.onchange = () => this.fillEpisodes();
    this.episode.onchange = () => this.forget(); // the shown path was another episode's
    this.armChoice.onchange = () => {
      this.forget();
      void this.load(); // the recordings this arm's model can repeat
    };
    this.refreshButton.onclick = () => void this.load();
    this.previewButton.onclick = () => void this.preview();
    this.clearButton.onclick = () => this.src.path.clear();
    this.runButton.onclick = () => void this.run(false);
    this.approachButton.onclick = () => {
      const ask = this.src.confirm ?? ((text: string) => window.confirm(text));
      if (ask(approachQuestion(this.start, this.refusal?.reason ?? "the tool is away from the task's first pose"))) void this.run(true);
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
    const names = this.src.arms?.() ?? [];
    const options = armOptions(names);
    if (options.map((o) => o.value).join() !== [...this.armChoice.options].map((o) => o.value).join()) {
      const was = this.armChoice.value;
      this.armChoice.replaceChildren(...options.map((o) => el("option", { value: o.value, textContent: o.text })));
      this.armChoice.value = options.some((o) => o.value === was) ? was : "";
    }
    this.armRow.hidden = options.length === 0;
    // The arm whose model the recordings are checked against: the one chosen, else the first.
    const arm = names.length > 1 ? this.armChoice.value || names[0]! : null;
    try {
      const [recordings, tasks, model] = await Promise.all([
        this.src.api.request("get", "/api/v1/recordings"),
        this.src.api.request("get", "/api/v1/tasks"),
        arm ? this.src.api.request("get", "/api/v1/robot/model", { query: { arm } }) : this.src.api.request("get", "/api/v1/robot/model"),
      ]);
      this.arm = { model: model.model, name: model.name };
      this.recordings = recordings.filter((r) => !r.active && r.episodes.length > 0);
      const choices = recordingChoices(this.recordings, this.arm, this.recording.value);
      this.recording.replaceChildren(...choices.options.map((o) => el("option", { value: o.value, textContent: o.text, disabled: o.disabled, title: o.title })));
      this.recording.value = choices.value;
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
    this.forget();
  }

  /** Another episode chosen: the path shown and a refusal were the last one's. */
  private forget(): void {
    this.src.path.clear();
    this.refusal = null;
    this.start = null;
    this.show();
  }

  private chosenRecording(): Recording | undefined {
    return this.recordings.find((r) => r.file === this.recording.value && !otherArm(r, this.arm));
  }

  /** The arm a one-arm recording is repeated on ({} : each recorded arm on its own). */
  private onto(): { arm?: string } {
    return this.armRow.hidden || !this.armChoice.value ? {} : { arm: this.armChoice.value };
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
      const preview = await this.src.api.request("post", "/api/v1/tasks/preview", { body: { recording: rec.file, episode: ep.episode, ...this.onto() } });
      const points = preview.positions.map((p) => [...p] as Vec3);
      if (points.length === 0) {
        this.src.log.add(`tasks: episode ${ep.episode} of ${rec.file} has no robot states`, true);
        return null;
      }
      this.start = preview;
      this.src.path.show(points, preview.approach);
      this.src.log.add(previewText(ep.episode, points, preview));
      return points;
    } catch (e) {
      this.src.log.add(`preview: ${(e as Error).message}`, true);
      return null;
    }
  }

  /** Why Run (and Approach) cannot be pressed now ("" when they can). */
  private blocked(): string {
    const none = this.recordings.length > 0 && this.recordings.every((r) => otherArm(r, this.arm));
    return whyNotRun({
      arm: none ? `every recording here was made with another arm model than this server's ${this.arm?.name ?? "arm"}` : "",
      chosen: this.chosenEpisode() !== undefined,
      operator: this.src.link.operator,
      control: (this.src.flags() & StateFlags.YOU_HAVE_CONTROL) !== 0,
      underWay: this.underWay,
      starting: this.starting,
    });
  }

  /** Start the chosen episode as a task (`approach`: the operator confirmed the guarded move). */
  async run(approach: boolean): Promise<void> {
    const rec = this.chosenRecording();
    const ep = this.chosenEpisode();
    if (!rec || !ep) return this.src.log.add("tasks: choose a recording and an episode first", true);
    const blocked = this.blocked();
    if (blocked) return this.src.log.add(`tasks: ${blocked}`, true);
    this.starting = true;
    this.refusal = null;
    this.show();
    try {
      // The path and the approach from where the tool is now (an approach is drawn
      // before the operator is asked to confirm it).
      await this.preview();
      const view = await this.src.api.request("post", "/api/v1/tasks", {
        headers: { "X-Client-Id": this.src.link.clientId },
        body: {
          recording: rec.file,
          episode: ep.episode,
          speed: Number(this.speed.value),
          compliance: this.compliance.checked ? { axes: "xyz", stiffness_n_per_m: Number(this.stiffness.value), damping_n_s_per_m: 2000, max_offset_m: 0.01, max_rate_m_s: 0.02 } : null,
          force_margin_n: 15,
          approach,
          ...this.onto(),
        },
      });
      this.src.log.add(`task ${view.id} ${view.state}: episode ${ep.episode} of ${rec.file} at ${view.speed.toFixed(2)}×`);
      this.follow(view);
      // The path the server follows (the same episode, resampled).
      const path = await this.src.api.request("get", "/api/v1/tasks/{task_id}/path", { params: { task_id: view.id } });
      if (path.positions.length > 0) this.src.path.show(path.positions, path.approach);
    } catch (e) {
      const message = (e as Error).message;
      this.src.log.add(`task: ${message}`, true);
      // Said in the panel too, by the button it concerns (the log scrolls away).
      this.refusal = { reason: message, away: !approach && farFromStart(e) };
    } finally {
      this.starting = false;
      this.show();
    }
  }

  private follow(view: TaskView): void {
    this.task = view;
    this.refusal = null;
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
    const blocked = this.blocked();
    this.runButton.disabled = blocked !== "";
    this.runButton.title = blocked ? `Run: ${blocked}` : "Repeat it";
    const refused = this.refusal ? refusalView(this.refusal.reason, this.refusal.away, blocked) : null;
    this.approachButton.hidden = !refused?.approach;
    this.approachButton.disabled = refused?.approach?.disabled ?? true;
    this.approachButton.title = refused?.approach?.title ?? "";
    this.previewButton.disabled = !recordingChosen;
    this.clearButton.disabled = !this.src.path.shown;
    this.recording.disabled = this.episode.disabled = active;
    this.pauseButton.hidden = !t || !(t.state === "running" || t.state === "approaching");
    this.resumeButton.hidden = !t || t.state !== "paused";
    this.abortButton.hidden = !active;
    this.progress.value = t ? t.progress : 0;
    this.stateText.textContent = t ? `task ${t.id}: ${t.state} ${Math.round(t.progress * 100)}%` : "";
    this.reason.textContent = refused ? refused.text : t && FINISHED.has(t.state) ? finishedText(t) : "";
    this.box.classList.toggle("task-active", active);
  }
}
