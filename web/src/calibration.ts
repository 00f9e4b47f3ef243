// The camera calibration page: freeze the stereo video, click the fiducials in order
// in each image (with a loupe), edit their 3D positions, compute, judge the fit from
// the residuals and the projected fiducial frame drawn over both images.
import { project, type Projection } from "./ar/projection";
import { connectVideo } from "./transport/video";

type CameraName = "left" | "right";
type Method = "dlt" | "affine" | "charuco";
type Pixel = [number, number];

interface CameraCalibration {
  name: CameraName;
  source: string;
  method: string | null;
  P: Projection;
  width: number;
  height: number;
  rms_px: number | null;
  max_px: number | null;
  residuals_px: number[];
}

interface CalibrationState {
  cameras: CameraCalibration[];
  fiducials: [number, number, number][];
  baseline_m: number | null;
  intrinsics_pending: string[];
  error: string | null;
}

const $ = <T extends HTMLElement = HTMLElement>(id: string) => document.getElementById(id) as T;
const base = `${location.origin}/`;
const params = new URLSearchParams(location.search);
if (params.get("token")) localStorage.setItem("telerobot.token", params.get("token")!);
const token = localStorage.getItem("telerobot.token") ?? "";
const CAMERAS: CameraName[] = ["left", "right"];
const AXES = ["#ff4040", "#40ff40", "#4080ff"]; // x, y, z of the fiducial frame

function message(text: string, error = false): void {
  const li = document.createElement("li");
  li.textContent = `${new Date().toLocaleTimeString()} ${text}`;
  if (error) li.style.color = "#f88";
  $("messages").prepend(li);
}

async function call<T>(method: string, path: string, body?: unknown): Promise<T> {
  const r = await fetch(base + path, {
    method,
    headers: { "Content-Type": "application/json", ...(token ? { Authorization: `Bearer ${token}` } : {}) },
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const data = (await r.json().catch(() => ({}))) as { detail?: string };
  if (!r.ok) {
    const why = r.status === 403 ? "the operator token is needed (open this page with ?token=…)" : (data.detail ?? `HTTP ${r.status}`);
    throw new Error(why);
  }
  return data as T;
}

async function main(): Promise<void> {
  let state = await call<CalibrationState>("GET", "api/v1/calibration");
  const clicks: Record<CameraName, Pixel[]> = { left: [], right: [] };
  const frozen: Partial<Record<CameraName, ImageData>> = {};
  const canvases = { left: $<HTMLCanvasElement>("left"), right: $<HTMLCanvasElement>("right") };
  const video = $<HTMLVideoElement>("video");
  let last: CameraName | null = null;

  const method = (): Method => (document.querySelector<HTMLInputElement>("input[name=method]:checked")?.value ?? "dlt") as Method;
  const needed = () => (method() === "affine" ? 4 : state.fiducials.length);
  const fiducials = (): [number, number, number][] =>
    state.fiducials.map((_, i) => [0, 1, 2].map((k) => Number($<HTMLInputElement>(`f${i}-${k}`).value)) as [number, number, number]);

  function showState(): void {
    const calibrated = state.cameras.filter((c) => c.source === "calibrated").map((c) => `${c.name}: ${c.method}`);
    $("source").textContent = calibrated.length ? `calibrated (${calibrated.join(", ")})` : "ground truth (simulation)";
    $("charuco-state").textContent = state.intrinsics_pending.length ? `intrinsics ready: ${state.intrinsics_pending.join(", ")}` : "";
    if (state.error) message(state.error, true);
  }

  // ---- fiducials table (editable 3D positions; defaults from the server's settings)
  const table = $<HTMLTableElement>("fiducials");
  table.innerHTML = `<tr><th>#</th><th>x</th><th>y</th><th>z</th></tr>` +
    state.fiducials.map((p, i) => `<tr id="row${i}"><td>${i + 1}</td>${p.map((v, k) => `<td><input id="f${i}-${k}" type="number" step="0.001" value="${v}"></td>`).join("")}</tr>`).join("");

  function prompt(): void {
    const cam = CAMERAS.find((c) => clicks[c].length < needed());
    for (let i = 0; i < state.fiducials.length; i++) $(`row${i}`).classList.toggle("active", cam !== undefined && clicks[cam].length === i);
    $<HTMLButtonElement>("compute").disabled = cam !== undefined || !frozen.left;
    $("prompt").textContent = !frozen.left
      ? "Freeze the images first."
      : cam
        ? `Click fiducial ${clicks[cam].length + 1} of ${needed()} in the ${cam.toUpperCase()} image.`
        : "All fiducials clicked: compute.";
  }

  function draw(cam: CameraName, model?: CameraCalibration): void {
    const canvas = canvases[cam];
    const g = canvas.getContext("2d")!;
    const image = frozen[cam];
    if (image) g.putImageData(image, 0, 0);
    g.lineWidth = 1.5;
    clicks[cam].forEach(([u, v], i) => {
      g.strokeStyle = "#ff0";
      g.beginPath();
      g.moveTo(u - 8, v); g.lineTo(u + 8, v); g.moveTo(u, v - 8); g.lineTo(u, v + 8);
      g.stroke();
      g.fillStyle = "#ff0";
      g.fillText(String(i + 1), u + 6, v - 6);
    });
    if (!model) return;
    // The fit, to judge by eye: every fiducial where the model puts it, and the frame.
    const pts = fiducials().map((p) => project(model.P, p));
    g.strokeStyle = "#0ff";
    for (const p of pts) {
      if (!p) continue;
      g.beginPath();
      g.arc(p[0], p[1], 6, 0, 2 * Math.PI);
      g.stroke();
    }
    const o = pts[0];
    for (let k = 1; k <= 3; k++) {
      const p = pts[k];
      if (!o || !p) continue;
      g.strokeStyle = AXES[k - 1]!;
      g.lineWidth = 2.5;
      g.beginPath();
      g.moveTo(o[0], o[1]);
      g.lineTo(p[0], p[1]);
      g.stroke();
    }
  }

  function loupe(cam: CameraName, u: number, v: number): void {
    const l = $<HTMLCanvasElement>("loupe").getContext("2d")!;
    l.imageSmoothingEnabled = false;
    const zoom = 8;
    const half = 100 / zoom;
    l.clearRect(0, 0, 200, 200);
    l.drawImage(canvases[cam], u - half, v - half, 2 * half, 2 * half, 0, 0, 200, 200);
    l.strokeStyle = "#f0f";
    l.strokeRect(99, 99, 2, 2);
  }

  const toPixel = (canvas: HTMLCanvasElement, e: MouseEvent): Pixel => {
    const r = canvas.getBoundingClientRect();
    return [((e.clientX - r.left) * canvas.width) / r.width, ((e.clientY - r.top) * canvas.height) / r.height];
  };

  for (const cam of CAMERAS) {
    const canvas = canvases[cam];
    canvas.onmousemove = (e) => {
      if (frozen[cam]) loupe(cam, ...toPixel(canvas, e));
    };
    canvas.onclick = (e) => {
      if (!frozen[cam]) return;
      if (clicks[cam].length >= needed()) return message(`all ${needed()} fiducials of the ${cam} image are clicked`);
      clicks[cam].push(toPixel(canvas, e));
      last = cam;
      draw(cam);
      prompt();
    };
  }
  window.addEventListener("keydown", (e) => {
    if (!last || (e.target as HTMLElement).tagName === "INPUT") return;
    const pts = clicks[last];
    const p = pts[pts.length - 1];
    const d: Record<string, Pixel> = { ArrowLeft: [-0.25, 0], ArrowRight: [0.25, 0], ArrowUp: [0, -0.25], ArrowDown: [0, 0.25] };
    if (e.key === "Backspace") pts.pop();
    else if (p && d[e.key]) pts[pts.length - 1] = [p[0] + d[e.key]![0], p[1] + d[e.key]![1]];
    else return;
    e.preventDefault();
    draw(last);
    prompt();
  });
  for (const radio of document.querySelectorAll<HTMLInputElement>("input[name=method]")) radio.onchange = prompt;

  // ---- video → frozen images
  connectVideo(base, (stream) => {
    video.srcObject = stream;
    void video.play();
    $("prompt").textContent = "Freeze the images when the scene is still.";
  }).catch((e: Error) => message(`video: ${e.message}`, true));
  $("freeze").onclick = () => {
    if (!video.videoWidth) return message("no video yet", true);
    const w = video.videoWidth / 2;
    const h = video.videoHeight;
    const whole = document.createElement("canvas");
    whole.width = 2 * w;
    whole.height = h;
    const g = whole.getContext("2d")!;
    g.drawImage(video, 0, 0);
    CAMERAS.forEach((cam, i) => {
      canvases[cam].width = w;
      canvases[cam].height = h;
      frozen[cam] = g.getImageData(i * w, 0, w, h);
      clicks[cam] = [];
      draw(cam);
    });
    prompt();
  };

  // ---- compute, ChArUco, reset
  $("compute").onclick = async () => {
    const rows: string[] = [];
    try {
      for (const cam of CAMERAS) {
        state = await call<CalibrationState>("POST", "api/v1/calibration/fit", {
          camera: cam,
          method: method(),
          points: fiducials().slice(0, clicks[cam].length),
          pixels: clicks[cam],
        });
        const model = state.cameras.find((c) => c.name === cam)!;
        draw(cam, model);
        rows.push(`<tr><td>${cam}</td><td>${model.method}</td><td>rms ${model.rms_px?.toFixed(2)} px</td><td>max ${model.max_px?.toFixed(2)} px</td></tr>`,
          `<tr><td colspan="4" class="hint">${model.residuals_px.map((r, i) => `${i + 1}: ${r.toFixed(2)}`).join(" · ")}</td></tr>`);
      }
      if (state.baseline_m !== null) rows.push(`<tr><td colspan="4">stereo baseline ${(state.baseline_m * 1000).toFixed(1)} mm</td></tr>`);
      $("results").innerHTML = rows.join("");
      message(`calibrated (${method()}); the operator page uses it from its next load`);
    } catch (e) {
      message((e as Error).message, true);
    }
    showState();
  };
  // ---- ChArUco: views of the board from both cameras → intrinsics, then the fit
  const views: Record<CameraName, string[]> = { left: [], right: [] };
  const nextFrames = (n: number) =>
    new Promise<void>((resolve) => {
      const step = (left: number) => (left <= 0 ? resolve() : video.requestVideoFrameCallback(() => step(left - 1)));
      step(n);
    });
  function addView(): void {
    if (!video.videoWidth) return message("no video yet", true);
    const w = video.videoWidth / 2;
    const h = video.videoHeight;
    const eye = document.createElement("canvas");
    eye.width = w;
    eye.height = h;
    const g = eye.getContext("2d")!;
    CAMERAS.forEach((cam, i) => {
      g.drawImage(video, i * w, 0, w, h, 0, 0, w, h);
      views[cam].push(eye.toDataURL("image/jpeg", 0.95));
    });
    $("view-count").textContent = String(views.left.length);
    $<HTMLButtonElement>("use-views").disabled = views.left.length < 4;
  }
  async function useViews(): Promise<void> {
    for (const cam of CAMERAS) {
      const r = await call<{ rms_px: number; views_used: number }>("POST", "api/v1/calibration/intrinsics/views", { camera: cam, images: views[cam] });
      message(`${cam}: intrinsics from ${r.views_used} of ${views[cam].length} views, rms ${r.rms_px.toFixed(2)} px`);
    }
    views.left = [];
    views.right = [];
    $("view-count").textContent = "0";
    $<HTMLButtonElement>("use-views").disabled = true;
    state = await call<CalibrationState>("GET", "api/v1/calibration");
    document.querySelector<HTMLInputElement>("input[value=charuco]")!.checked = true;
    prompt();
  }
  $("add-view").onclick = addView;
  $("use-views").onclick = () => useViews().catch((e: Error) => message(e.message, true)).finally(showState);
  $("charuco").onclick = async () => {
    // On the simulation the server holds the board up at 12 poses in the live video;
    // with real cameras, hold a printed board and use "Add view" instead.
    try {
      for (let view = 0; view < 12; view++) {
        await call("POST", "api/v1/calibration/board", { view });
        await nextFrames(4); // the new pose has reached the decoder
        addView();
      }
      await call("POST", "api/v1/calibration/board", { view: null });
      await useViews();
    } catch (e) {
      message((e as Error).message, true);
      await call("POST", "api/v1/calibration/board", { view: null }).catch(() => undefined);
    }
    showState();
  };
  $("reset").onclick = async () => {
    try {
      state = await call<CalibrationState>("DELETE", "api/v1/calibration");
      $("results").innerHTML = "";
      CAMERAS.forEach((c) => draw(c));
      message("calibration forgotten: the ground truth stands in");
    } catch (e) {
      message((e as Error).message, true);
    }
    showState();
  };

  showState();
  prompt();
  Object.assign(window, { calibration: { clicks, frozen, get state() { return state; } } });
}

main().catch((e: Error) => {
  $("banner").hidden = false;
  $("banner").textContent = `Cannot start: ${e.message}`;
});
