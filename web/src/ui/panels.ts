// The operator's panels, redrawn at 5 Hz: the header (one state model, status.ts:
// badge, role, control, buttons, the E-STOP's latched look, the banner), joints and
// pose, forces, the speed's value and the timing figures; and the Home button.
import type { Api, MessageLog } from "../api";
import type { Vec3 } from "../robot/math";
import type { Rolling } from "../stats";
import type { ForceSample } from "../transport/codec";
import type { RobotState } from "../transport/realtime";
import { drawArrow, drawHistogram } from "./charts";
import { $, numberIn } from "./dom";
import { forceRows, jointTable, orientationText, speedText } from "./readouts";
import { headerView, type HeaderView, type HomeStep } from "./status";

export const PANEL_PERIOD_MS = 200;
/** A Home click waits this long for the confirming click. */
export const HOME_CONFIRM_MS = 4000;

/** The figures the panels show, read at each redraw. */
export interface PanelSources {
  /** The header's state (with two arms or more, every arm's as one: robot/arms.ts). */
  state(): RobotState | null;
  /** The Robot panel's arm's state (the arm the keys drive); by default `state()`'s. */
  armState?: () => RobotState | null;
  /** That arm's name beside the Robot and Force panels' titles ("" with one arm). */
  armName?: () => string;
  /** The Force panel's: that arm's sensor. */
  force(): ForceSample | null;
  link: {
    readonly operator: boolean;
    readonly open: boolean;
    readonly clientId: string;
    readonly commandLatency: Rolling;
    readonly forceInterval: Rolling;
    readonly stateInterval: Rolling;
  };
  glass: Rolling; // capture → presented, ms
  videoInterval: Rolling;
  forceLimitN: number;
  /** The arm's joints, as GET /api/v1/robot/model names them (the joints table's heads). */
  jointNames: readonly string[];
  /** Who has control, by name (the SAFETY events, GET /api/v1/safety); null: not known. */
  controller?: () => string | null;
  /** A policy holds control: its supervisor (this page) may reset the e-stop. */
  policyHolds?: () => boolean;
  /** For the Home button (POST /api/v1/robot/initialize) and its errors. */
  api?: Api;
  log?: MessageLog;
  /** The arms' names with two arms or more (Home moves each); none or one: the only arm. */
  arms?: () => readonly string[];
}

let disconnectReason = "";

/** The link's connection handler: remembers why it closed, for the banner. */
export function showConnection(up: boolean, why: string): void {
  disconnectReason = up ? "" : why;
}

/** The Home button: a first click asks for a second (it moves the arm), the second
 * initialises the arm to the home pose as the client holding the lease. */
export class HomeButton {
  step: HomeStep = "idle";
  private timer: ReturnType<typeof setTimeout> | undefined;

  constructor(
    private readonly api: Pick<Api, "request">,
    private readonly link: { readonly clientId: string },
    private readonly log: Pick<MessageLog, "add">,
    private readonly changed: () => void = () => {},
    private readonly arms: () => readonly string[] = () => [],
  ) {}

  click(): void {
    if (this.step === "moving") return;
    clearTimeout(this.timer);
    if (this.step === "idle") {
      this.step = "confirm";
      this.timer = setTimeout(() => this.set("idle"), HOME_CONFIRM_MS);
      this.changed();
      return;
    }
    this.set("moving");
    this.log.add("home: moving to the home pose…");
    const headers = { "X-Client-Id": this.link.clientId };
    const arms = this.arms();
    // Two arms or more: each to its home pose, at the same time.
    const done =
      arms.length > 1
        ? Promise.all(arms.map((arm) => this.api.request("post", "/api/v1/robot/initialize", { body: {}, headers, query: { arm } })))
        : this.api.request("post", "/api/v1/robot/initialize", { body: {}, headers });
    done
      .then(() => this.log.add(arms.length > 1 ? "home: every arm at its home pose" : "home: at the home pose"))
      .catch((e: Error) => this.log.add(`home: ${e.message}`, true))
      .finally(() => this.set("idle"));
  }

  private set(step: HomeStep): void {
    this.step = step;
    this.changed();
  }
}

const fmt = (v: number, digits: number) => (Number.isFinite(v) ? v.toFixed(digits) : "—"); // nothing measured yet

function showButton(id: string, b: { visible: boolean; enabled: boolean }): void {
  const el = $<HTMLButtonElement>(id);
  el.hidden = !b.visible;
  el.disabled = !b.enabled;
}

/** Draw the header as the model says. */
export function showHeader(v: HeaderView): void {
  $("status").textContent = v.badge.text;
  $("status").className = `badge ${v.badge.cls}`;
  $("role").textContent = v.role;
  $("control-owner").textContent = v.control;
  $("token-row").hidden = !v.tokenRow;
  showButton("take", v.take);
  showButton("release", v.release);
  showButton("reset", v.reset);
  showButton("home", v.home);
  $("home").textContent = v.home.text;
  const estop = $("estop");
  estop.textContent = v.estop.text;
  estop.classList.toggle("latched", v.estop.latched);
  estop.setAttribute("aria-pressed", String(v.estop.latched));
  const banner = $("banner");
  banner.hidden = v.banner.text === "";
  banner.className = v.banner.error ? "error" : "";
  banner.textContent = v.banner.text;
}

/** When the latest STATE came and when the link last opened (ms, performance.now()). */
interface Freshness {
  state: RobotState | null;
  stateAt: number;
  open: boolean;
  openedAt: number;
}

export function updatePanels(src: PanelSources, fresh: Freshness, home: HomeStep = "idle", now = performance.now()): void {
  const s = src.state();
  if (s !== fresh.state) [fresh.state, fresh.stateAt] = [s, now];
  if (src.link.open && !fresh.open) fresh.openedAt = now;
  fresh.open = src.link.open;
  showHeader(
    headerView({
      linkOpen: src.link.open,
      disconnectReason,
      operator: src.link.operator,
      state: s,
      stateAgeMs: now - Math.max(s ? fresh.stateAt : -Infinity, fresh.openedAt),
      home,
      controller: src.controller?.() ?? null,
      policyHolds: src.policyHolds?.() ?? false,
    }),
  );
  $("speed-value").textContent = speedText(numberIn("speed"));
  const arm = src.armState ? src.armState() : s;
  if (arm) {
    $("joints").innerHTML = jointTable(src.jointNames, arm.joints);
    $("pose").textContent = `tool at ${arm.position.map((v) => v.toFixed(3)).join(", ")} m`;
    $("orientation").textContent = arm.rotation ? orientationText(arm.rotation) : "";
  }
  const name = src.armName?.() ?? "";
  $("robot-arm").textContent = name;
  $("force-arm").textContent = name;
  const limit = src.forceLimitN;
  const f = src.force()?.values ?? [0, 0, 0, 0, 0, 0];
  $("force-limit").textContent = `limit ${limit.toFixed(0)} N`;
  $("force-bars").innerHTML = forceRows(f, limit)
    .map(
      (r) =>
        `<div class="force-row${r.over ? " over" : ""}"><span class="axis">${r.axis}</span>` +
        `<span class="track"><span class="bar" style="width:${r.percent.toFixed(1)}%"></span></span><span class="value">${r.text}</span></div>`,
    )
    .join("");
  drawArrow($<HTMLCanvasElement>("force-arrow"), f.slice(0, 3) as Vec3, limit);
  const { link, glass, videoInterval } = src;
  $("latency").textContent =
    `glass-to-glass p50 ${fmt(glass.percentile(50), 0)} ms · command p50 ${fmt(link.commandLatency.percentile(50), 2)} ms · ` +
    `video ${fmt(1000 / videoInterval.percentile(50), 1)} fps · force ${fmt(link.forceInterval.percentile(50), 2)} ms`;
  drawHistogram($<HTMLCanvasElement>("hist-force"), link.forceInterval, 30, "force message inter-arrival (0–30 ms)");
  drawHistogram($<HTMLCanvasElement>("hist-state"), link.stateInterval, 60, "state inter-arrival (0–60 ms)");
  drawHistogram($<HTMLCanvasElement>("hist-video"), videoInterval, 100, "video inter-arrival (0–100 ms)");
}

/** Redraw the panels every PANEL_PERIOD_MS (and at once when the Home button changes);
 * wire the Home button and the speed's value. */
export function startPanels(src: PanelSources): { home: HomeButton | null; redraw: () => void } {
  const fresh: Freshness = { state: null, stateAt: 0, open: false, openedAt: performance.now() };
  let home: HomeButton | null = null;
  const redraw = () => updatePanels(src, fresh, home?.step);
  if (src.api && src.log) {
    home = new HomeButton(src.api, src.link, src.log, redraw, src.arms);
    const button = home;
    $("home").onclick = () => button.click();
  }
  $("speed").addEventListener("input", () => ($("speed-value").textContent = speedText(numberIn("speed"))));
  setInterval(redraw, PANEL_PERIOD_MS);
  redraw();
  return { home, redraw };
}
