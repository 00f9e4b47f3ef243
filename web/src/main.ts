// The operator's page: stereo video with the AR ball, inputs, panels. Composed here
// from the REST API (api.ts), the realtime link and the video (transport/), the input
// loop (input/), the AR ball (ar/), the view (view/) and the page's wiring (ui/).
import { Api, MessageLog, TOKEN_KEY, readToken, saveToken, tokenVerdict, withoutToken } from "./api";
import { AxisMarker } from "./ar/axes";
import { ArBall } from "./ar/ball";
import { GhostArm, setupGhostSwitch } from "./ar/ghost";
import { PathOverlay } from "./ar/path";
import { GamepadInput } from "./input/gamepad";
import { KeyboardInput } from "./input/keyboard";
import { InputLoop } from "./input/loop";
import { viewFrame } from "./input/viewframe";
import { ContactRumble, rumbleStrength } from "./input/rumble";
import { XRMasterInput } from "./input/xr";
import { PredictedArm } from "./robot/model";
import { ServerArmReloader, type ServerArm } from "./robot/server-arm";
import { Rolling } from "./stats";
import type { ForceSample } from "./transport/codec";
import { RealtimeLink } from "./transport/link";
import { EventKind, StateFlags } from "./transport/messages";
import type { RobotState } from "./transport/realtime";
import { VideoConnection, layerParam } from "./transport/video";
import { Alignment, viewerName } from "./ui/alignment";
import { ConnectionHud } from "./ui/connection-hud";
import { Supervision, parseAutonomy } from "./ui/autonomy";
import { ControlWatch, showControlAlerts } from "./ui/control-alert";
import { setupControls } from "./ui/controls";
import { $, numberIn } from "./ui/dom";
import { HelpOverlay } from "./ui/help";
import { controllerIn, namedUrl, readName, setupNameField } from "./ui/operator-name";
import { pageDialogs, routeKey } from "./ui/keys";
import { RecordingPanel } from "./ui/recording";
import { showConnection, startPanels } from "./ui/panels";
import { TasksPanel } from "./ui/tasks";
import { link3dView, setupFullscreen, setupModes, setupXRButton, showBall } from "./ui/view";
import { measureGlass } from "./view/glass";
import { StereoView } from "./view/stereo";

const token = readToken(location.search, localStorage, sessionStorage);
history.replaceState(history.state, "", withoutToken(location.href)); // read: out of the address bar
const viewer = viewerName(localStorage);
const api = new Api(`${location.origin}/`, token);
// Who this page is to everyone else (the header, the SAFETY events, the recording).
const pageName = readName(localStorage, navigator.platform);
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
  view.fitInto($("stage"));
  const glass = new Rolling(900); // capture → presented, ms
  const videoInterval = new Rolling(900);
  let state: RobotState | null = null;
  let lastForce: ForceSample | null = null;

  const setMode = setupModes(view);
  const alignment = await Alignment.load(view, api, viewer, log);
  setupXRButton(view, log);
  const toggleFullscreen = setupFullscreen($("stage"), log);
  link3dView(api);
  setupNameField($<HTMLInputElement>("operator-name"), $("name-status"), localStorage, pageName, navigator.platform);
  // Who has control, by name: the server's events say when it changes; read again at
  // each new session (events may have been missed while the link was down).
  let controller: string | null = safety.controller ?? null;

  // ---- real-time channel
  const control = new ControlWatch(); // control lost, said over the video
  let armReloader: ServerArmReloader | null = null; // the arm drawn, read again at each new session
  let welcomed = false;
  let tasks: TasksPanel | null = null; // a task this page started holds the lease: not lost
  let supervision: Supervision | null = null; // a learned policy's, when one drives
  // Recording: the header's REC indicator for every viewer, the operator's panel.
  const recording = new RecordingPanel({ api, log, operator: () => link.operator });
  const link = new RealtimeLink(namedUrl(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`, pageName), token, {
    state: (s) => {
      state = s;
      arm.report(s.joints, s.status === "MOVING", performance.now());
      if (supervision?.active) supervision.refresh();
      if (!tasks?.handedOver) control.state(s.flags, performance.now(), link.timerLateMs, link.pageStallMs);
    },
    forces: (samples) => {
      lastForce = samples[samples.length - 1] ?? lastForce;
    },
    event: (text, kind) => {
      if (kind === EventKind.AUTONOMY) {
        const s = parseAutonomy(text);
        if (s) {
          supervision?.update(s);
          log.add(`autonomy ${s.mode.toUpperCase()}: ${s.cause}`);
        }
        return;
      }
      log.add(text);
      const who = controllerIn(text);
      if (who !== undefined) controller = who;
      control.event(text, performance.now());
      recording.event(text);
    },
    error: (text, _seq, code) => {
      if (!control.quiet(code, performance.now())) log.add(text, true);
    },
    connection: (up, why) => {
      showConnection(up, why);
      control.connection(up);
    },
    welcome: (operator) => {
      // A new session after the first: the server may have restarted with another arm.
      void readAutonomy();
      if (welcomed) {
        void armReloader?.reload();
        api.request("get", "/api/v1/safety").then((s) => (controller = s.controller ?? null)).catch(() => undefined);
      }
      welcomed = true;
      control.welcome(operator);
      // Remembered only once accepted: a wrong token never replaces a good one.
      const verdict = tokenVerdict(token, operator, localStorage.getItem(TOKEN_KEY));
      if (verdict) log.add(verdict, true);
      else if (operator) saveToken(localStorage, token);
      $("token-status").textContent = verdict ?? "";
    },
  });
  link.connect();

  // ---- video
  // Kept up by itself: a failed or stalled peer is re-negotiated (with backoff).
  let glassMeter: { stop(): void } | null = null;
  const videoConnection = new VideoConnection(api, {
    onStream: (stream) => {
      video.srcObject = stream;
      void video.play();
      const track = stream.getVideoTracks()[0];
      glassMeter?.stop(); // the previous peer's copy: its frames are read no more
      glassMeter = track ? measureGlass(track.clone(), link, glass, () => (view.nativeSize ? 2 * view.nativeSize.width : null)) : null;
    },
    onPeer: (peer) => alignment.useVideoPeer(peer),
    onError: (text) => log.add(text),
    layer: layerParam(location.search),
  });
  // Leaving the page: the latency meter's queued frames are closed, not left to the
  // garbage collector (which Chromium reports on the console, "A VideoFrame was garbage
  // collected without being closed": seen as a page closed on a busy machine).
  addEventListener("pagehide", () => glassMeter?.stop());
  videoConnection.start().catch((e: Error) => log.add(`video: ${e.message}`, true));
  // The connection HUD over the video (RTT, loss, video, freezes, force and command age).
  const videoStatus = api.request("get", "/api/v1/video");
  videoStatus.then((v) => (view.nativeSize = { width: v.width, height: v.height })).catch(() => undefined);
  const hud = new ConnectionHud({ pc: () => videoConnection.peer?.pc ?? null, link, force: () => lastForce, video: videoStatus });
  hud.start($("hud"));
  view.onFrame = () => {
    const now = performance.now();
    videoInterval.tick(now);
    videoConnection.frame();
    hud.frame(now);
  };
  view.onStale = (ms) => videoConnection.stalled(ms);

  // ---- inputs → commands, and rumble in proportion to the contact force
  const keyboard = new KeyboardInput(window);
  const gamepad = new GamepadInput();
  const loop = new InputLoop({
    link,
    arm,
    flags: () => state?.flags ?? 0,
    speed: () => numberIn("speed"),
    gamepad,
    keyboard,
    view: cell.cameras[0] ? viewFrame(cell.cameras[0].P) : null, // the left camera's
    now: performance.now(),
    policyHolds: () => supervision?.policyHolds ?? false,
  });
  const youHaveControl = (): boolean => ((state?.flags ?? 0) & StateFlags.YOU_HAVE_CONTROL) !== 0;
  supervision = setupSupervision(view, loop, link, youHaveControl, () => control.released());
  // The active frame's axes at the gripper, in both eyes (shown with the AR ball).
  const axes = new AxisMarker(cell.cameras, model.tool.flat(), view);
  // The whole predicted arm, a translucent skeleton in both eyes (the "Ghost arm" switch).
  const ghost = new GhostArm(model, cell.cameras);
  view.addOverlay(ghost);
  setupGhostSwitch($<HTMLInputElement>("ghost"), ghost, localStorage, () => view.overlayChanged());
  setupControls(loop, link);
  const alarm = showControlAlerts(control, [keyboard, gamepad], () => loop.take());
  loop.onRelease = () => control.released(); // handing back to a policy, too
  const help = new HelpOverlay();
  // Escape closes an open dialog (the help…) and only that; else it is the e-stop.
  const keyTargets = {
    dialogs: () => pageDialogs(document),
    help,
    loop,
    alignment,
    fullscreen: toggleFullscreen,
    deadmanHeld: () => keyboard.read().deadman,
  };
  keyboard.onKey = (key, e) => {
    routeKey(keyTargets, key, e);
    if (!e.repeat && !e.altKey && !e.ctrlKey && !e.metaKey) supervision?.key(key);
  };
  const rumble = new ContactRumble(() => (lastForce ? rumbleStrength(Math.hypot(...lastForce.values.slice(0, 3)), safety.force_limit_n) : 0));
  const rumbleBox = $<HTMLInputElement>("rumble");
  rumble.enabled = rumbleBox.checked;
  rumbleBox.onchange = () => (rumble.enabled = rumbleBox.checked);
  // A WebXR controller (else a tracked hand) as a 6-DoF master: its grip (the hand's
  // pinch) is the dead-man.
  const xrInput = new XRMasterInput();
  view.onXRFrame = (frame, space) => {
    const controller = xrInput.read(frame, space);
    const now = performance.now();
    loop.xrFrame(controller, now);
    // (A headset pauses the page's own animation frames: the ghost follows here too.)
    if (ghost.update(arm.joints)) view.overlayChanged();
    if (controller?.gamepad) rumble.driveXR(now, controller.gamepad);
  };
  const tick = () => {
    const now = performance.now();
    rumble.drivePad(now, loop.tick(now).pad);
    showBall(view, ar.update(arm.pose));
    if (ghost.update(arm.joints)) view.overlayChanged();
    axes.update(loop.frame, arm.pose, loop.view, $<HTMLInputElement>("ar").checked);
    requestAnimationFrame(tick);
  };
  requestAnimationFrame(tick);

  // Repeating a recorded episode as a task, its path shown in both eyes before it runs.
  // Run and Approach need the lease: none is known to be held while the link is down.
  const path = new PathOverlay(cell.cameras, view);
  tasks = new TasksPanel($("tasks"), { api, log, link, flags: () => (link.open ? (state?.flags ?? 0) : 0), path });
  void tasks.load();

  // The arm drawn follows the server's: read again at each new session (a restart with
  // another model redraws the labels, the ghost, the ball and the axes for the new arm).
  const readArm = async (): Promise<ServerArm> => {
    const [m, c] = await Promise.all([api.request("get", "/api/v1/robot/model"), api.request("get", "/api/v1/calibration")]);
    return { model: m, cameras: c.cameras };
  };
  const arms = new ServerArmReloader(
    { model, cameras: cell.cameras },
    readArm,
    (next) => {
      arm.setModel(next.model);
      ar.setCameras(next.cameras);
      axes.setArm(next.cameras, next.model.tool.flat());
      if (ghost.setArm(next.model, next.cameras)) view.overlayChanged();
      path.setCameras(next.cameras);
      loop.view = next.cameras[0] ? viewFrame(next.cameras[0].P) : null;
      void tasks?.load(); // which recordings this arm can repeat
    },
    log,
  );
  armReloader = arms;
  const panels = startPanels({
    state: () => state,
    force: () => lastForce,
    link,
    glass,
    videoInterval,
    forceLimitN: safety.force_limit_n,
    controller: () => controller,
    get jointNames() {
      return arms.current.model.joint_names;
    },
    api,
    log,
  });

  // For tests and benchmarks (read-only figures and a few switches).
  Object.assign(window, {
    telerobot: {
      view,
      client: link,
      glass,
      rumble,
      videoInterval,
      video: videoConnection,
      ball: ar.ball,
      axes,
      ghost,
      arm,
      loop,
      get state() {
        return state;
      },
      get force() {
        return lastForce;
      },
      setMode,
      help,
      panels,
      control,
      alarm,
      tasks,
      recording,
      hud,
      arms,
      supervision,
    },
  });
}

/** Who drives while a policy is connected (GET /autonomy): at each new session, as
 * events may have been missed while the link was down. */
async function readAutonomy(): Promise<void> {
  try {
    supervisionRef?.update(parseAutonomy(JSON.stringify(await api.request("get", "/api/v1/autonomy"))));
  } catch {
    // the server said nothing: the next EVENT autonomy says it
  }
}
let supervisionRef: Supervision | null = null;

/** The header's supervision badge and buttons, wired to the loop and the link. */
/** The headset's supervision line, coloured as the header's badge (style.css). */
const XR_BADGE_COLOURS: Record<string, string> = { autonomous: "#1d5fa8", paused: "#9a7a10", correcting: "#2e7d32" };

function setupSupervision(view: StereoView, loop: InputLoop, link: RealtimeLink, youHaveControl: () => boolean, givingUp: () => void): Supervision {
  const lease = (action: number): void => {
    if (youHaveControl()) givingUp(); // pausing or resuming from a correction hands control back
    link.lease(action);
  };
  const s = new Supervision({ take: () => loop.take(), release: () => loop.release(), lease, youHaveControl });
  const badge = $("autonomy");
  s.onChange = (v) => {
    badge.hidden = v.badge === "";
    badge.textContent = v.badge;
    badge.dataset.mode = s.state?.mode ?? "off";
    const operator = link.operator;
    $("pause-policy").hidden = !(operator && v.pause);
    $("resume-policy").hidden = !(operator && v.resume);
    $("hand-back").hidden = !(operator && v.handBack);
    $("take").textContent = v.takeLabel;
    view.setXRBadge(v.badge, XR_BADGE_COLOURS[s.state?.mode ?? "off"] ?? "#444");
  };
  $("pause-policy").onclick = () => s.pause();
  $("resume-policy").onclick = () => s.handBack();
  $("hand-back").onclick = () => s.handBack();
  supervisionRef = s;
  void readAutonomy();
  return s;
}

main().catch((e: Error) => log.add(`start-up failed: ${e.message}`, true));
