// The operator's page: stereo video with the AR ball, inputs, panels.
import { project, type Projection } from "./ar/projection";
import { combine } from "./input/motion";
import { GamepadInput } from "./input/gamepad";
import { KeyboardInput } from "./input/keyboard";
import { Rumble, rumbleStrength } from "./input/rumble";
import { XRMaster } from "./input/xr";
import { position, type Vec3 } from "./robot/math";
import { PredictedArm, type FrameName, type RobotModelInfo } from "./robot/model";
import { Rolling } from "./stats";
import { type ForceSample } from "./transport/codec";
import { Frame, LeaseAction, StateFlags } from "./transport/messages";
import { RealtimeLink } from "./transport/link";
import type { RobotState } from "./transport/realtime";
import { connectVideo, saveAlignment } from "./transport/video";
import { MODES, StereoView, type ViewMode } from "./view/stereo";

const $ = <T extends HTMLElement = HTMLElement>(id: string) => document.getElementById(id) as T;
const base = `${location.origin}/`;
const params = new URLSearchParams(location.search);
if (params.get("token")) localStorage.setItem("telerobot.token", params.get("token")!);
const token = localStorage.getItem("telerobot.token") ?? "";
const viewerName = localStorage.getItem("telerobot.viewer") ?? `viewer-${Math.random().toString(36).slice(2, 8)}`;
localStorage.setItem("telerobot.viewer", viewerName);

const MAX_LINEAR = 0.1; // m/s at full deflection and speed 1
const MAX_ANGULAR = 0.5; // rad/s
const FRAMES: Record<FrameName, number> = { base: Frame.BASE, wrist: Frame.WRIST, tool: Frame.TOOL };

function message(text: string, error = false): void {
  const li = document.createElement("li");
  li.textContent = `${new Date().toLocaleTimeString()} ${text}`;
  if (error) li.style.color = "#f88";
  $("messages").prepend(li);
  while ($("messages").childElementCount > 50) $("messages").lastElementChild?.remove();
}

async function getJSON<T>(path: string): Promise<T> {
  const r = await fetch(base + path, { cache: "no-store" });
  if (!r.ok) throw new Error(`${path}: HTTP ${r.status}`);
  return (await r.json()) as T;
}

interface Camera {
  name: string;
  P: Projection;
}

async function main(): Promise<void> {
  const [model, cell, safety] = await Promise.all([
    getJSON<RobotModelInfo>("api/v1/robot/model"),
    getJSON<{ cameras: Camera[] }>("api/v1/calibration"), // calibrated, or the ground truth until then
    getJSON<{ force_limit_n: number }>("api/v1/safety"),
  ]);
  const [camL, camR] = cell.cameras;
  const arm = new PredictedArm(model);
  const video = $<HTMLVideoElement>("video");
  const view = new StereoView($<HTMLCanvasElement>("view"), video);
  const glass = new Rolling(900); // capture → presented, ms
  const videoInterval = new Rolling(900);
  let state: RobotState | null = null;
  let lastForce: ForceSample | null = null;
  let frameName: FrameName = "base";

  // ---- view settings, remembered
  const modeSelect = $<HTMLSelectElement>("mode");
  for (const m of MODES) modeSelect.add(new Option(m, m));
  modeSelect.value = localStorage.getItem("telerobot.mode") ?? "side-by-side";
  view.setMode(modeSelect.value as ViewMode);
  modeSelect.onchange = () => {
    view.setMode(modeSelect.value as ViewMode);
    localStorage.setItem("telerobot.mode", modeSelect.value);
  };
  // This page's own copy first (the server keeps a bounded table); re-sent once the video peer is up.
  const savedAlign = localStorage.getItem("telerobot.align");
  let align: { dx: number; dy: number } = savedAlign
    ? JSON.parse(savedAlign)
    : await getJSON<{ dx: number; dy: number }>(`api/v1/video/alignment?viewer=${viewerName}`).catch(() => ({ dx: 0, dy: 0 }));
  const showAlign = () => {
    $("align").textContent = `${align.dx}, ${align.dy}`;
    view.setAlignment(align.dx, align.dy);
  };
  showAlign();
  $("xr").onclick = () => view.enterXR().catch((e: Error) => message(e.message, true));
  // The 3D view (viser) is served on its own port of this host.
  getJSON<{ port: number | null; error: string | null }>("api/v1/viewer")
    .then((v) => {
      const link = $<HTMLAnchorElement>("view3d");
      if (v.port === null) return;
      link.href = `http://${location.hostname}:${v.port}/`;
      link.hidden = false;
    })
    .catch(() => undefined);

  // ---- real-time channel
  const client = new RealtimeLink(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`, token, {
    state: (s) => {
      state = s;
      arm.report(s.joints, s.status === "MOVING", performance.now());
    },
    forces: (samples) => {
      lastForce = samples[samples.length - 1] ?? lastForce;
    },
    event: (text) => message(text),
    error: (text) => message(text, true),
    connection: (up, why) => {
      $("banner").hidden = up;
      $("banner").className = "error";
      $("banner").textContent = up ? "" : `Disconnected: ${why}`;
    },
  });
  client.connect();
  const hasControl = () => ((state?.flags ?? 0) & StateFlags.YOU_HAVE_CONTROL) !== 0;

  // Heartbeats (sent by the realtime worker) start the moment we ask for control,
  // before a STATE confirms it, and go on while we hold it.
  $("take").onclick = () => {
    client.lease(((state?.flags ?? 0) & StateFlags.SOMEONE_HAS_CONTROL) ? LeaseAction.TAKE_OVER : LeaseAction.TAKE);
    client.wantControl(true);
    setTimeout(() => client.wantControl(false), 2000); // from then on: only while we hold it
  };
  $("release").onclick = () => {
    client.wantControl(false);
    client.lease(LeaseAction.RELEASE);
  };
  $("estop").onclick = () => client.estop();
  $("reset").onclick = () => client.reset();
  $<HTMLInputElement>("token").onchange = (e) => {
    localStorage.setItem("telerobot.token", (e.target as HTMLInputElement).value);
    location.reload();
  };
  $<HTMLSelectElement>("frame").onchange = (e) => {
    frameName = (e.target as HTMLSelectElement).value as FrameName;
  };

  // ---- video
  const videoPeer = connectVideo(base, (stream) => {
    video.srcObject = stream;
    void video.play();
    const track = stream.getVideoTracks()[0];
    if (track) void measureGlass(track.clone(), client, glass);
  });
  videoPeer.catch((e: Error) => message(`video: ${e.message}`, true));
  // The alignment is saved with this page's video peer's secret, one PUT at a time (the last wins).
  let alignSaved = Promise.resolve();
  const saveAlign = () => {
    localStorage.setItem("telerobot.align", JSON.stringify(align));
    alignSaved = alignSaved.then(async () => {
      const peer = await videoPeer.catch(() => null);
      if (peer) await saveAlignment(base, peer, viewerName, align).catch((e: Error) => message(`alignment: ${e.message}`, true));
    });
  };
  if (savedAlign) saveAlign();
  view.onFrame = () => videoInterval.tick(performance.now());

  // ---- inputs
  const gamepad = new GamepadInput();
  const keyboard = new KeyboardInput(window);
  keyboard.onKey = (key, e) => {
    if (key === "Escape") client.estop();
    if (key === "Digit1" || key === "Digit2" || key === "Digit3") {
      frameName = (["base", "wrist", "tool"] as const)[Number(key.slice(5)) - 1]!;
      $<HTMLSelectElement>("frame").value = frameName;
    }
    if (e.altKey && key.startsWith("Arrow")) {
      const d = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, -1], ArrowDown: [0, 1] }[key] ?? [0, 0];
      align = { dx: align.dx + d[0]!, dy: align.dy + d[1]! };
      showAlign();
      saveAlign();
    }
  };

  // ---- rumble in proportion to the contact force (gamepad and XR controllers)
  const rumble = { pad: new Rumble(), xr: new Rumble() }; // each paced on its own
  const rumbleBox = $<HTMLInputElement>("rumble");
  const rumbleSwitch = () => (rumble.pad.enabled = rumble.xr.enabled = rumbleBox.checked);
  rumbleSwitch();
  rumbleBox.onchange = rumbleSwitch;
  const contactStrength = () =>
    lastForce ? rumbleStrength(Math.hypot(...lastForce.values.slice(0, 3)), safety.force_limit_n) : 0;

  // ---- a WebXR controller as a 6-DoF master: while its grip (squeeze) is held, its
  // motion moves the gripper, scaled by the speed setting; the grip is the dead-man.
  const xrMaster = new XRMaster();
  view.onXRFrame = (frame, space) => {
    const sources = Array.from(frame.session.inputSources).filter((s) => s.gripSpace && s.gamepad);
    const source = sources.find((s) => s.handedness === "right") ?? sources[0];
    if (!source?.gripSpace || !source.gamepad) {
      xrMaster.update(false, [0, 0, 0], [0, 0, 0, 1], 0);
      return;
    }
    const pose = frame.getPose(source.gripSpace, space);
    // xr-standard mapping: button 1 is the squeeze. An emulated (lost) position is no grip.
    const gripping = (source.gamepad.buttons[1]?.pressed ?? false) && !!pose && !pose.emulatedPosition;
    const p = pose?.transform.position ?? { x: 0, y: 0, z: 0 };
    const o = pose?.transform.orientation ?? { x: 0, y: 0, z: 0, w: 1 };
    const now = performance.now();
    const delta = xrMaster.update(gripping, [p.x, p.y, p.z], [o.x, o.y, o.z, o.w], now / 1000);
    if (delta && hasControl()) {
      const speed = Number($<HTMLInputElement>("speed").value);
      const dX = delta.dX.map((v) => v * speed) as Vec3;
      const rv = delta.rotvec.map((v) => v * speed) as Vec3;
      client.cartesian(dX, rv, Frame.BASE);
      arm.commandCartesian(dX, rv, "base", now);
    }
    rumble.xr.drive(now, contactStrength(), [source.gamepad]);
  };

  let last = performance.now();
  let shownInputState = "";
  const tick = () => {
    const now = performance.now();
    const dt = Math.min(0.1, (now - last) / 1000);
    last = now;
    const pad = gamepad.read();
    if (pad.cycleFrame) {
      frameName = frameName === "base" ? "wrist" : frameName === "wrist" ? "tool" : "base";
      $<HTMLSelectElement>("frame").value = frameName;
    }
    const cmd = combine(pad.command, keyboard.read());
    const speed = Number($<HTMLInputElement>("speed").value);
    const moving = cmd.linear.some((v) => v !== 0) || cmd.angular.some((v) => v !== 0);
    // Written only when it changes: a DOM write every animation frame costs a layout and
    // a paint each time, which a software-rendered page cannot afford.
    const inputState = `${pad.pad ? "gamepad" : "no gamepad"} · dead-man ${cmd.deadman ? "held" : "released"}`;
    if (inputState !== shownInputState) $("input-state").textContent = shownInputState = inputState;
    if (hasControl() && cmd.deadman && moving) {
      const dX = cmd.linear.map((v) => v * MAX_LINEAR * speed * dt) as Vec3;
      const rv = cmd.angular.map((v) => v * MAX_ANGULAR * speed * dt) as Vec3;
      client.cartesian(dX, rv, FRAMES[frameName]);
      arm.commandCartesian(dX, rv, frameName, now);
    }
    rumble.pad.drive(now, contactStrength(), [pad.pad]);
    updateBall();
    requestAnimationFrame(tick);
  };
  requestAnimationFrame(tick);

  const ball = { left: null as [number, number] | null, right: null as [number, number] | null };
  function updateBall(): void {
    const T = arm.pose;
    if (T && camL && camR) {
      const p = position(T);
      ball.left = project(camL.P, p);
      ball.right = project(camR.P, p);
    }
    view.setBall(ball, $<HTMLInputElement>("ar").checked, $<HTMLInputElement>("ar-colour").value, Number($<HTMLInputElement>("ar-size").value));
  }

  // ---- panels, 5 Hz
  setInterval(() => {
    const s = state;
    const flags = s?.flags ?? 0;
    $("status").textContent = s?.status ?? "…";
    $("status").className = `badge ${s?.status ?? ""}`;
    $("role").textContent = client.operator ? "operator" : "observer (watching only)";
    $("token-row").hidden = client.operator;
    $("take").hidden = !client.operator || hasControl();
    $("release").hidden = !hasControl();
    $("reset").hidden = (flags & StateFlags.ESTOP) === 0;
    $("control-owner").textContent = hasControl() ? "you have control" : flags & StateFlags.SOMEONE_HAS_CONTROL ? "someone else has control" : "nobody has control";
    if (flags & StateFlags.ESTOP) showBanner("E-STOP latched: reset it to move again");
    else if (flags & StateFlags.FORCE_LIMITED) showBanner("Force limit: back away from the contact");
    else if (client.open) $("banner").hidden = true;
    if (s) {
      $("joints").innerHTML = `<tr>${s.joints.map((q) => `<td>${((q * 180) / Math.PI).toFixed(1)}°</td>`).join("")}</tr>`;
      $("pose").textContent = `tool at ${s.position.map((v) => v.toFixed(3)).join(", ")} m`;
    }
    const f = lastForce?.values ?? [0, 0, 0, 0, 0, 0];
    $("force-bars").innerHTML = f
      .map((v, i) => `<div title="${["Fx", "Fy", "Fz", "Tx", "Ty", "Tz"][i]} ${v.toFixed(2)}"><div class="bar" style="width:${Math.min(100, (Math.abs(v) / safety.force_limit_n) * 100)}%"></div></div>`)
      .join("");
    drawArrow($<HTMLCanvasElement>("force-arrow"), f.slice(0, 3) as Vec3, safety.force_limit_n);
    const fmt = (v: number, digits: number) => (Number.isFinite(v) ? v.toFixed(digits) : "—"); // nothing measured yet
    $("latency").textContent =
      `glass-to-glass p50 ${fmt(glass.percentile(50), 0)} ms · command p50 ${fmt(client.commandLatency.percentile(50), 2)} ms · ` +
      `video ${fmt(1000 / videoInterval.percentile(50), 1)} fps · force ${fmt(client.forceInterval.percentile(50), 2)} ms`;
    drawHistogram($<HTMLCanvasElement>("hist-force"), client.forceInterval, 30, "force message inter-arrival (0–30 ms)");
    drawHistogram($<HTMLCanvasElement>("hist-state"), client.stateInterval, 60, "state inter-arrival (0–60 ms)");
    drawHistogram($<HTMLCanvasElement>("hist-video"), videoInterval, 100, "video inter-arrival (0–100 ms)");
  }, 200);

  function showBanner(text: string): void {
    $("banner").hidden = false;
    $("banner").className = "";
    $("banner").textContent = text;
  }

  // For tests and benchmarks (read-only figures and a few switches).
  Object.assign(window, {
    telerobot: { view, client, glass, rumble, videoInterval, ball, arm, get state() { return state; }, get force() { return lastForce; }, setMode: (m: ViewMode) => { modeSelect.value = m; view.setMode(m); } },
  });
}

/** Capture → decoded frame in this page, for every frame: each decoded frame carries its
 * capture time as a timecode (32 blocks of 16 px at (8, 8) in the left image), read from
 * the decoder's own frame (a 512×2 luma copy; no GPU read-back), on the server's clock
 * through the ping offset. */
async function measureGlass(track: MediaStreamTrack, client: { bestRtt: number; offset: number }, glass: Rolling): Promise<void> {
  const Processor = (window as unknown as { MediaStreamTrackProcessor?: new (i: { track: MediaStreamTrack }) => { readable: ReadableStream<VideoFrame> } })
    .MediaStreamTrackProcessor;
  if (!Processor) return; // not Chromium: the panel shows no glass-to-glass figure
  const reader = new Processor({ track }).readable.getReader();
  const rect = { x: 8, y: 16, width: 512, height: 2 };
  for (;;) {
    const { value: frame, done } = await reader.read();
    if (done || !frame) return;
    const now = performance.now() / 1000;
    try {
      const buffer = new Uint8Array(frame.allocationSize({ rect }));
      const layout = await frame.copyTo(buffer, { rect });
      const rgb = (frame.format ?? "").startsWith("RGB") || (frame.format ?? "").startsWith("BGR");
      let code = 0;
      for (let i = 0; i < 32; i++) {
        const x = i * 16 + 8;
        code = code * 2 + ((buffer[(layout[0]?.offset ?? 0) + (rgb ? x * 4 + 1 : x)] ?? 0) > 128 ? 1 : 0);
      }
      if (client.bestRtt < Infinity) {
        const wrap = 2 ** 32;
        const server = now + client.offset;
        const behind = ((((Math.round(server / 1e-4) - code) % wrap) + wrap) % wrap) / 10; // ms
        if (behind < 5000) glass.add(behind);
      }
    } finally {
      frame.close();
    }
  }
}

function drawHistogram(canvas: HTMLCanvasElement, stats: Rolling, max: number, label: string): void {
  const ctx = canvas.getContext("2d");
  if (!ctx) return;
  const bins = stats.histogram(40, max);
  const top = Math.max(1, ...bins);
  ctx.fillStyle = "#111";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = "#4a8";
  bins.forEach((n, i) => {
    const h = (n / top) * (canvas.height - 14);
    ctx.fillRect((i * canvas.width) / bins.length, canvas.height - h, canvas.width / bins.length - 1, h);
  });
  ctx.fillStyle = "#ccc";
  ctx.font = "10px sans-serif";
  ctx.fillText(`${label} · p50 ${stats.percentile(50).toFixed(2)} p99 ${stats.percentile(99).toFixed(2)}`, 2, 10);
}

function drawArrow(canvas: HTMLCanvasElement, f: Vec3, limit: number): void {
  const ctx = canvas.getContext("2d");
  if (!ctx) return;
  ctx.fillStyle = "#111";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  const cx = canvas.width / 2;
  const cy = canvas.height / 2;
  const k = 50 / limit;
  // An oblique view of the sensor frame: x right, y up-right, z up.
  const ex = [1, 0];
  const ey = [0.5, -0.35];
  const ez = [0, -1];
  const tip = [cx + k * (f[0] * ex[0]! + f[1] * ey[0]! + f[2] * ez[0]!), cy + k * (f[0] * ex[1]! + f[1] * ey[1]! + f[2] * ez[1]!)];
  ctx.strokeStyle = "#555";
  for (const e of [ex, ey, ez]) {
    ctx.beginPath();
    ctx.moveTo(cx, cy);
    ctx.lineTo(cx + 40 * e[0]!, cy + 40 * e[1]!);
    ctx.stroke();
  }
  ctx.strokeStyle = "#f84";
  ctx.lineWidth = 3;
  ctx.beginPath();
  ctx.moveTo(cx, cy);
  ctx.lineTo(tip[0]!, tip[1]!);
  ctx.stroke();
  ctx.lineWidth = 1;
}

main().catch((e: Error) => message(`start-up failed: ${e.message}`, true));
