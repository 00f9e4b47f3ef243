// The operator's page: stereo video with the AR ball, inputs, panels. Composed here, in
// order, from the wiring steps in wiring/ (each a `setupX(ctx, …)` returning a small
// handle): the page's arms, the view's controls, the real-time channel, the video, the
// inputs, the arms drawn, the keys and buttons, supervision, tasks, panels, the frame
// loops, and what tests read (`window.telerobot`, wiring/test-view.ts).
// A server with two arms or more: each arm its own prediction, AR ball and ghost (in its
// own colours, placed through its mount), STATE and force; which input drives which arm
// is input/arms.ts's. The lease, the e-stop and the dead-man are one for all.
import { Api, MessageLog, readToken, withoutToken } from "./api";
import { GHOST_KEY } from "./ar/ghost";
import { readServerArms } from "./robot/arms";
import { viewerName } from "./ui/alignment";
import { $ } from "./ui/dom";
import { titleFollowsText } from "./ui/header-fit";
import { readName } from "./ui/operator-name";
import { StereoView } from "./view/stereo";
import { setupArmDrawing } from "./wiring/arm-drawing";
import type { PageContext } from "./wiring/context";
import { setupPageControls } from "./wiring/controls";
import { startFrames } from "./wiring/frames";
import { setupInputs } from "./wiring/inputs";
import { PageArms } from "./wiring/page-arms";
import { setupPanels } from "./wiring/panels";
import { setupRealtime } from "./wiring/realtime";
import { setupSupervision } from "./wiring/supervision";
import { setupTasks } from "./wiring/tasks";
import { pageTestView } from "./wiring/test-view";
import { setupVideo } from "./wiring/video";
import { setupViewControls } from "./wiring/view-controls";

const token = readToken(location.search, localStorage, sessionStorage);
history.replaceState(history.state, "", withoutToken(location.href)); // read: out of the address bar
const api = new Api(`${location.origin}/`, token);
const log = new MessageLog($("messages"));

async function main(): Promise<void> {
  const [served, cell, safety] = await Promise.all([
    readServerArms(api), // GET /robot/arms, and each arm's model
    api.request("get", "/api/v1/calibration"), // calibrated, or the ground truth until then
    api.request("get", "/api/v1/safety"),
  ]);
  const video = $<HTMLVideoElement>("video");
  const view = new StereoView($<HTMLCanvasElement>("view"), video);
  view.fitInto($("stage"));
  const ctx: PageContext = {
    api,
    log,
    token,
    pageName: readName(localStorage, navigator.platform),
    viewer: viewerName(localStorage),
    safety,
    cell,
    arms: new PageArms(served, cell.cameras, localStorage.getItem(GHOST_KEY) !== "off"),
    view,
    video,
    controller: safety.controller ?? null,
    late: { supervision: null, tasks: null, reloader: null, help: null },
  };
  titleFollowsText([$("control-owner"), $("autonomy")]); // (cut to keep the header one line)
  const viewControls = await setupViewControls(ctx);
  const realtime = setupRealtime(ctx);
  const videoHandle = setupVideo(ctx, realtime.link, viewControls.alignment);
  const inputs = setupInputs(ctx, realtime.link);
  setupSupervision(ctx, inputs.loop, realtime.link, () => realtime.control.released());
  const drawing = setupArmDrawing(ctx, inputs.loop, inputs.selected);
  const controls = setupPageControls(ctx, { link: realtime.link, control: realtime.control, inputs, drawing, ...viewControls });
  startFrames(ctx, inputs, drawing);
  const tasks = setupTasks(ctx, realtime.link, inputs.loop, { cameras: cell.cameras, arms: served });
  setupPanels(ctx, realtime, videoHandle, inputs);
  const telerobot = pageTestView({ ctx, realtime, video: videoHandle, inputs, drawing, controls, tasks, setMode: viewControls.setMode });
  Object.assign(window, { telerobot });
}

main().catch((e: Error) => log.add(`start-up failed: ${e.message}`, true));
