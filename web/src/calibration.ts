// The camera calibration page: freeze the stereo video, click the fiducials in order
// in each image (with a loupe), edit their 3D positions, compute, judge the fit from
// the residuals and the projected fiducial frame drawn over both images. Composed here
// from api.ts, transport/video.ts and ui/calibration/.
import { Api, MessageLog, readToken, withoutToken } from "./api";
import { connectVideo } from "./transport/video";
import { BoardViews } from "./ui/calibration/charuco";
import { CAMERAS, Clicks, neededFor, type Method } from "./ui/calibration/clicks";
import { drawLoupe, toPixel } from "./ui/calibration/draw";
import { fillFiducials, markRow, readFiducials } from "./ui/calibration/fiducials";
import { fitBoth, type CalibrationState } from "./ui/calibration/fit";
import { FrozenImages } from "./ui/calibration/images";
import { $ } from "./ui/dom";

const api = new Api(`${location.origin}/`, readToken(location.search, localStorage, sessionStorage));
history.replaceState(history.state, "", withoutToken(location.href)); // read: out of the address bar
const log = new MessageLog($("messages"));

async function main(): Promise<void> {
  let state = await api.request("get", "/api/v1/calibration");
  const video = $<HTMLVideoElement>("video");
  const clicks = new Clicks();
  const images = new FrozenImages(video, clicks);
  const board = new BoardViews(video, api, log);

  const method = (): Method => (document.querySelector<HTMLInputElement>("input[name=method]:checked")?.value ?? "dlt") as Method;
  const needed = () => neededFor(method(), state.fiducials.length);
  const update = (s: CalibrationState) => (state = s);
  function showState(): void {
    const calibrated = state.cameras.filter((c) => c.source === "calibrated").map((c) => `${c.name}: ${c.method}`);
    $("source").textContent = calibrated.length ? `calibrated (${calibrated.join(", ")})` : "ground truth (simulation)";
    $("charuco-state").textContent = state.intrinsics_pending.length ? `intrinsics ready: ${state.intrinsics_pending.join(", ")}` : "";
    if (state.error) log.add(state.error, true);
  }
  function prompt(): void {
    const cam = clicks.next(needed());
    markRow(state.fiducials.length, cam === undefined ? null : clicks.byCamera[cam].length);
    $<HTMLButtonElement>("compute").disabled = cam !== undefined || !images.ready;
    $("prompt").textContent = clicks.prompt(needed(), images.ready);
  }
  fillFiducials(state.fiducials);

  setupClicking(images, clicks, needed, prompt);
  setupLiveImages(video, images, prompt);

  // ---- compute, ChArUco, reset
  $("compute").onclick = async () => {
    try {
      await fitBoth(api, clicks, method(), readFiducials(state.fiducials.length), images, update);
      log.add(`calibrated (${method()}); the operator page uses it from its next load`);
    } catch (e) {
      log.add((e as Error).message, true);
    }
    showState();
  };
  async function useViews(): Promise<void> {
    await board.calibrate();
    state = await api.request("get", "/api/v1/calibration");
    document.querySelector<HTMLInputElement>("input[value=charuco]")!.checked = true;
    prompt();
  }
  $("add-view").onclick = () => board.add();
  $("use-views").onclick = () => useViews().catch((e: Error) => log.add(e.message, true)).finally(showState);
  $("charuco").onclick = async () => {
    try {
      await board.captureSimulated();
      await useViews();
    } catch (e) {
      log.add((e as Error).message, true);
    }
    showState();
  };
  $("reset").onclick = async () => {
    try {
      state = await api.request("delete", "/api/v1/calibration");
      $("results").innerHTML = "";
      CAMERAS.forEach((c) => images.draw(c));
      log.add("calibration forgotten: the ground truth stands in");
    } catch (e) {
      log.add((e as Error).message, true);
    }
    showState();
  };

  showState();
  prompt();
  Object.assign(window, { calibration: { clicks: clicks.byCamera, frozen: images.frozen, get state() { return state; } } });
}

/** Clicking the fiducials on the frozen images (the loupe follows the pointer; keys
 * nudge or undo the last click); `prompt` says what is next. */
function setupClicking(images: FrozenImages, clicks: Clicks, needed: () => number, prompt: () => void): void {
  for (const cam of CAMERAS) {
    const canvas = images.canvases[cam];
    canvas.onmousemove = (e) => {
      if (images.frozen[cam]) drawLoupe($<HTMLCanvasElement>("loupe"), canvas, ...toPixel(canvas, e));
    };
    canvas.onclick = (e) => {
      if (!images.frozen[cam]) return;
      if (!clicks.add(cam, toPixel(canvas, e), needed())) return log.add(`all ${needed()} fiducials of the ${cam} image are clicked`);
      images.draw(cam);
      prompt();
    };
  }
  window.addEventListener("keydown", (e) => {
    if ((e.target as HTMLElement).tagName === "INPUT") return;
    const cam = clicks.key(e.key);
    if (!cam) return;
    e.preventDefault();
    images.draw(cam);
    prompt();
  });
  for (const radio of document.querySelectorAll<HTMLInputElement>("input[name=method]")) radio.onchange = prompt;
}

/** Video → live images → frozen images: each new frame is drawn on the images until
 * they are frozen. */
function setupLiveImages(video: HTMLVideoElement, images: FrozenImages, prompt: () => void): void {
  let drawingLive = false;
  const showLive = () => {
    drawingLive = !images.ready;
    if (!drawingLive) return;
    images.live();
    video.requestVideoFrameCallback(showLive);
  };
  connectVideo(api, (stream) => {
    video.srcObject = stream;
    void video.play();
    if (!drawingLive) video.requestVideoFrameCallback(showLive); // one chain, whatever the reconnects
    drawingLive = true;
    $("prompt").textContent = "Freeze the images when the scene is still.";
  }, "full").catch((e: Error) => log.add(`video: ${e.message}`, true)); // clicks are in full-size pixels
  $("freeze").onclick = () => (images.freeze() ? prompt() : log.add("no video yet", true));
}

main().catch((e: Error) => {
  $("banner").hidden = false;
  $("banner").textContent = `Cannot start: ${e.message}`;
});
