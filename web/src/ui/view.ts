// The View panel: the stereo mode (remembered), the AR ball's settings, VR, and the
// link to the 3D view.
import type { Api, MessageLog } from "../api";
import { MODES, type Ball, type StereoView, type ViewMode } from "../view/stereo";
import { $, numberIn } from "./dom";
import { readXRSupport, vrFailureText, vrUnavailable } from "./vr-support";

const MODE_KEY = "telerobot.mode";

/** Fill the mode list, show the remembered mode; gives a function that switches it. */
export function setupModes(view: StereoView): (mode: ViewMode) => void {
  const select = $<HTMLSelectElement>("mode");
  for (const m of MODES) select.add(new Option(m, m));
  select.value = localStorage.getItem(MODE_KEY) ?? "side-by-side";
  view.setMode(select.value as ViewMode);
  select.onchange = () => {
    view.setMode(select.value as ViewMode);
    localStorage.setItem(MODE_KEY, select.value);
  };
  return (mode) => {
    select.value = mode;
    view.setMode(mode);
  };
}

/** Draw the ball with the panel's settings (shown or not, colour, size). */
export function showBall(view: StereoView, ball: Ball): void {
  view.setBall(ball, $<HTMLInputElement>("ar").checked, $<HTMLInputElement>("ar-colour").value, numberIn("ar-size"));
}

/** The fullscreen button over the stage; gives the toggle (the page binds F to it too). */
export function setupFullscreen(stage: HTMLElement, log: MessageLog): () => void {
  const toggle = () => {
    const done = document.fullscreenElement ? document.exitFullscreen() : stage.requestFullscreen();
    done.catch((e: Error) => log.add(`fullscreen: ${e.message}`, true));
  };
  $("fullscreen").onclick = toggle;
  return toggle;
}

/** "Enter VR": where VR cannot start (no headset, no WebXR, not a secure page) its
 * tooltip says what is needed, and a click says it in the log (vr-support.ts). */
export function setupXRButton(view: StereoView, log: MessageLog): void {
  const button = $("xr");
  const support = readXRSupport(window);
  void support.then((s) => {
    const why = vrUnavailable(s);
    button.title = why ?? "Show the stereo video in a WebXR headset";
    button.classList.toggle("unavailable", why !== null);
  });
  button.onclick = async () => {
    const s = await support;
    const why = vrUnavailable(s);
    if (why) return log.add(why, true);
    view.enterXR().catch((e: Error) => log.add(vrFailureText(e, s), true));
  };
}

/** The 3D view (viser) is served on its own port of this host, when it runs. */
export function link3dView(api: Api): void {
  api
    .request("get", "/api/v1/viewer")
    .then((v) => {
      if (v.port === null) return;
      const link = $<HTMLAnchorElement>("view3d");
      link.href = `http://${location.hostname}:${v.port}/`;
      link.hidden = false;
    })
    .catch(() => undefined);
}
