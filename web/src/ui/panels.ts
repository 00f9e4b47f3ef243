// The operator's panels, redrawn at 5 Hz: status and role, who has control and the
// buttons that go with it, the banner, joints and pose, forces, and the timing figures.
import type { Vec3 } from "../robot/math";
import type { Rolling } from "../stats";
import type { ForceSample } from "../transport/codec";
import { hasControl } from "../input/loop";
import { StateFlags } from "../transport/messages";
import type { RobotState } from "../transport/realtime";
import { drawArrow, drawHistogram } from "./charts";
import { $ } from "./dom";

export const PANEL_PERIOD_MS = 200;
const AXES = ["Fx", "Fy", "Fz", "Tx", "Ty", "Tz"];

/** The figures the panels show, read at each redraw. */
export interface PanelSources {
  state(): RobotState | null;
  force(): ForceSample | null;
  link: {
    readonly operator: boolean;
    readonly open: boolean;
    readonly commandLatency: Rolling;
    readonly forceInterval: Rolling;
    readonly stateInterval: Rolling;
  };
  glass: Rolling; // capture → presented, ms
  videoInterval: Rolling;
  forceLimitN: number;
}

/** The banner over the view: a warning, or (error) the lost connection. */
export function showBanner(text: string, error = false): void {
  const banner = $("banner");
  banner.hidden = text === "";
  banner.className = error ? "error" : "";
  banner.textContent = text;
}

export function showConnection(up: boolean, why: string): void {
  showBanner(up ? "" : `Disconnected: ${why}`, true);
}

const fmt = (v: number, digits: number) => (Number.isFinite(v) ? v.toFixed(digits) : "—"); // nothing measured yet

export function updatePanels(src: PanelSources): void {
  const s = src.state();
  const flags = s?.flags ?? 0;
  const mine = hasControl(flags);
  $("status").textContent = s?.status ?? "…";
  $("status").className = `badge ${s?.status ?? ""}`;
  $("role").textContent = src.link.operator ? "operator" : "observer (watching only)";
  $("token-row").hidden = src.link.operator;
  $("take").hidden = !src.link.operator || mine;
  $("release").hidden = !mine;
  $("reset").hidden = (flags & StateFlags.ESTOP) === 0;
  $("control-owner").textContent = mine ? "you have control" : flags & StateFlags.SOMEONE_HAS_CONTROL ? "someone else has control" : "nobody has control";
  if (flags & StateFlags.ESTOP) showBanner("E-STOP latched: reset it to move again");
  else if (flags & StateFlags.FORCE_LIMITED) showBanner("Force limit: back away from the contact");
  else if (src.link.open) $("banner").hidden = true;
  if (s) {
    $("joints").innerHTML = `<tr>${s.joints.map((q) => `<td>${((q * 180) / Math.PI).toFixed(1)}°</td>`).join("")}</tr>`;
    $("pose").textContent = `tool at ${s.position.map((v) => v.toFixed(3)).join(", ")} m`;
  }
  const limit = src.forceLimitN;
  const f = src.force()?.values ?? [0, 0, 0, 0, 0, 0];
  $("force-bars").innerHTML = f
    .map((v, i) => `<div title="${AXES[i]} ${v.toFixed(2)}"><div class="bar" style="width:${Math.min(100, (Math.abs(v) / limit) * 100)}%"></div></div>`)
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

export function startPanels(src: PanelSources): void {
  setInterval(() => updatePanels(src), PANEL_PERIOD_MS);
}
