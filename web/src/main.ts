// The operator's page: stereo video with the AR ball, inputs, panels. Composed here
// from the REST API (api.ts), the realtime link and the video (transport/), the input
// loop (input/), the AR ball (ar/), the view (view/) and the page's wiring (ui/).
import { Api, MessageLog, readToken } from "./api";
import { ArBall } from "./ar/ball";
import { GamepadInput } from "./input/gamepad";
import { KeyboardInput } from "./input/keyboard";
import { InputLoop } from "./input/loop";
import { ContactRumble, rumbleStrength } from "./input/rumble";
import { readController } from "./input/xr";
import { PredictedArm } from "./robot/model";
import { Rolling } from "./stats";
import type { ForceSample } from "./transport/codec";
import { RealtimeLink } from "./transport/link";
import type { RobotState } from "./transport/realtime";
import { connectVideo } from "./transport/video";
import { Alignment, viewerName } from "./ui/alignment";
import { setupControls } from "./ui/controls";
import { $, numberIn } from "./ui/dom";
import { showConnection, startPanels } from "./ui/panels";
import { link3dView, setupModes, setupXRButton, showBall } from "./ui/view";
import { measureGlass } from "./view/glass";
import { StereoView } from "./view/stereo";

const token = readToken(location.search, localStorage);
const viewer = viewerName(localStorage);
const api = new Api(`${location.origin}/`, token);
const log = new MessageLog($("messages"));

async function main(): Promise<void> {
  const [model, cell, safety] = await Promise.all([
    api.request("get", "/api/v1/robot/model"),
    api.request("get", "/api/v1/calibration"), // calibrated, or the ground truth until then
    api.request("get", "/api/v1/safety"),
  ]);
  const arm = new PredictedArm(model);
  const ar = new ArBall(cell.cameras);
  const video = $<HTMLVideoElement>("video");
  const view = new StereoView($<HTMLCanvasElement>("view"), video);
  const glass = new Rolling(900); // capture → presented, ms
  const videoInterval = new Rolling(900);
  let state: RobotState | null = null;
  let lastForce: ForceSample | null = null;

  const setMode = setupModes(view);
  const alignment = await Alignment.load(view, api, viewer, log);
  setupXRButton(view, log);
  link3dView(api);

  // ---- real-time channel
  const link = new RealtimeLink(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`, token, {
    state: (s) => {
      state = s;
      arm.report(s.joints, s.status === "MOVING", performance.now());
    },
    forces: (samples) => {
      lastForce = samples[samples.length - 1] ?? lastForce;
    },
    event: (text) => log.add(text),
    error: (text) => log.add(text, true),
    connection: showConnection,
  });
  link.connect();

  // ---- video
  const videoPeer = connectVideo(api, (stream) => {
    video.srcObject = stream;
    void video.play();
    const track = stream.getVideoTracks()[0];
    if (track) void measureGlass(track.clone(), link, glass);
  });
  videoPeer.catch((e: Error) => log.add(`video: ${e.message}`, true));
  alignment.useVideoPeer(videoPeer);
  view.onFrame = () => videoInterval.tick(performance.now());

  // ---- inputs → commands, and rumble in proportion to the contact force
  const keyboard = new KeyboardInput(window);
  const loop = new InputLoop({
    link,
    arm,
    flags: () => state?.flags ?? 0,
    speed: () => numberIn("speed"),
    gamepad: new GamepadInput(),
    keyboard,
    now: performance.now(),
  });
  setupControls(loop, link);
  keyboard.onKey = (key, e) => {
    loop.key(key);
    alignment.key(key, e);
  };
  const rumble = new ContactRumble(() => (lastForce ? rumbleStrength(Math.hypot(...lastForce.values.slice(0, 3)), safety.force_limit_n) : 0));
  const rumbleBox = $<HTMLInputElement>("rumble");
  rumble.enabled = rumbleBox.checked;
  rumbleBox.onchange = () => (rumble.enabled = rumbleBox.checked);
  // A WebXR controller as a 6-DoF master: its grip is the dead-man.
  view.onXRFrame = (frame, space) => {
    const controller = readController(frame, space);
    const now = performance.now();
    loop.xrFrame(controller, now);
    if (controller) rumble.driveXR(now, controller.gamepad);
  };
  const tick = () => {
    const now = performance.now();
    rumble.drivePad(now, loop.tick(now).pad);
    showBall(view, ar.update(arm.pose));
    requestAnimationFrame(tick);
  };
  requestAnimationFrame(tick);

  startPanels({ state: () => state, force: () => lastForce, link, glass, videoInterval, forceLimitN: safety.force_limit_n });

  // For tests and benchmarks (read-only figures and a few switches).
  Object.assign(window, {
    telerobot: {
      view,
      client: link,
      glass,
      rumble,
      videoInterval,
      ball: ar.ball,
      arm,
      loop,
      get state() {
        return state;
      },
      get force() {
        return lastForce;
      },
      setMode,
    },
  });
}

main().catch((e: Error) => log.add(`start-up failed: ${e.message}`, true));
