// The operator's page: stereo video with the AR ball, inputs, panels. Composed here
// from the REST API (api.ts), the realtime link and the video (transport/), the input
// loop (input/), the AR ball (ar/), the view (view/) and the page's wiring (ui/).
// A server with two arms or more: each arm its own prediction, AR ball and ghost (in its
// own colours, placed through its mount), STATE and force; which input drives which arm
// is input/arms.ts's. The lease, the e-stop and the dead-man are one for all.
import { Api, MessageLog, TOKEN_KEY, readToken, saveToken, tokenVerdict, withoutToken } from "./api";
import { AxisMarker } from "./ar/axes";
import { ArBall, type CameraCalibration } from "./ar/ball";
import { GHOST_KEY, GhostArm, setupGhostSwitch } from "./ar/ghost";
import { PathOverlay } from "./ar/path";
import { handArms } from "./input/arms";
import { GamepadInput } from "./input/gamepad";
import { KeyboardInput } from "./input/keyboard";
import { type DriveArm, InputLoop } from "./input/loop";
import { viewFrame } from "./input/viewframe";
import { ContactRumble, rumbleStrength } from "./input/rumble";
import { XRMasterInput } from "./input/xr";
import { type ServerArmEntry, combinedState, mountedCameras, readServerArms } from "./robot/arms";
import { PredictedArm } from "./robot/model";
import { ServerArmReloader, type ServerArm } from "./robot/server-arm";
import { Rolling } from "./stats";
import type { ForceSample } from "./transport/codec";
import { RealtimeLink } from "./transport/link";
import { EventKind, StateFlags } from "./transport/messages";
import type { RobotState } from "./transport/realtime";
import { VideoConnection, layerParam } from "./transport/video";
import { Alignment, viewerName } from "./ui/alignment";
import { ArmChipsView, armChips, armStyle, dimmed } from "./ui/arms";
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
import { StereoView, type OverlayPainter } from "./view/stereo";

const token = readToken(location.search, localStorage, sessionStorage);
history.replaceState(history.state, "", withoutToken(location.href)); // read: out of the address bar
const viewer = viewerName(localStorage);
const api = new Api(`${location.origin}/`, token);
// Who this page is to everyone else (the header, the SAFETY events, the recording).
const pageName = readName(localStorage, navigator.platform);
const log = new MessageLog($("messages"));

/** One arm as the page draws and drives it. */
interface PageArm {
  entry: ServerArmEntry;
  /** The cameras as this arm's base frame sees them (each P · its mount). */
  cameras: CameraCalibration[];
  predicted: PredictedArm;
  ball: ArBall;
  ghost: GhostArm;
  state: RobotState | null;
  force: ForceSample | null;
}

/** The page's arms for the server's (`ghostOn`: the Ghost arm switch). With one, drawn
 * as always: the View panel's ball colour, the magenta ghost, no name. */
function pageArms(entries: readonly ServerArmEntry[], cameras: readonly CameraCalibration[], ghostOn: boolean): PageArm[] {
  return entries.map((entry, i) => {
    const own = mountedCameras(cameras, entry.mount);
    const ghost = new GhostArm(entry.model, own, entries.length > 1 ? { rgb: armStyle(i).ghost, label: entry.name } : undefined);
    ghost.setEnabled(ghostOn);
    return { entry, cameras: own, predicted: new PredictedArm(entry.model), ball: new ArBall(own), ghost, state: null, force: null };
  });
}

/** How the input loop drives them: each command names its arm (0: the only arm). */
function driveArms(arms: readonly PageArm[]): DriveArm[] {
  return arms.map((a) => ({
    index: arms.length > 1 ? a.entry.index : 0,
    name: a.entry.name,
    predictor: a.predicted,
    view: a.cameras[0] ? viewFrame(a.cameras[0].P) : null, // the left camera's
  }));
}

async function main(): Promise<void> {
  const [served, cell, safety] = await Promise.all([
    readServerArms(api), // GET /robot/arms, and each arm's model
    api.request("get", "/api/v1/calibration"), // calibrated, or the ground truth until then
    api.request("get", "/api/v1/safety"),
  ]);
  const model = served[0]!.model;
  let ghostOn = localStorage.getItem(GHOST_KEY) !== "off";
  let arms = pageArms(served, cell.cameras, ghostOn);
  /** The arm whose STATE or FORCE names `index` (a one-arm server's is its only one). */
  const armOf = (index: number): PageArm | undefined => (arms.length === 1 ? arms[0] : arms.find((a) => a.entry.index === index));
  const video = $<HTMLVideoElement>("video");
  const view = new StereoView($<HTMLCanvasElement>("view"), video);
  view.fitInto($("stage"));
  const glass = new Rolling(900); // capture → presented, ms
  const videoInterval = new Rolling(900);
  let state: RobotState | null = null; // the header's: every arm's as one
  /** The newest force sample of any arm (the connection HUD's force age). */
  const newestForce = (): ForceSample | null => arms.reduce<ForceSample | null>((n, a) => (a.force && (!n || a.force.time > n.time) ? a.force : n), null);

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
      const a = armOf(s.arm);
      if (!a) return;
      a.state = s;
      a.predicted.report(s.joints, s.status === "MOVING", performance.now());
      state = combinedState(arms.map((x) => x.state)) ?? state;
      if (a !== arms[0]) return; // the lease's flags are every arm's: said once a tick
      if (supervision?.active) supervision.refresh();
      if (!tasks?.handedOver) control.state(s.flags, performance.now(), link.timerLateMs, link.pageStallMs);
    },
    forces: (samples, index) => {
      const a = armOf(index);
      if (a) a.force = samples[samples.length - 1] ?? a.force;
    },
    arms: (announced) => {
      // The server's arms (its ARM messages): others than those drawn are read again.
      if (announced.map((x) => x.name).join() !== arms.map((x) => x.entry.name).join()) void armReloader?.reload();
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
  const hud = new ConnectionHud({ pc: () => videoConnection.peer?.pc ?? null, link, force: newestForce, video: videoStatus });
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
    arm: arms[0]!.predicted,
    flags: () => state?.flags ?? 0,
    speed: () => numberIn("speed"),
    gamepad,
    keyboard,
    view: cell.cameras[0] ? viewFrame(cell.cameras[0].P) : null, // the left camera's
    now: performance.now(),
    policyHolds: () => supervision?.policyHolds ?? false,
  });
  loop.setArms(driveArms(arms));
  view.setBallCount(arms.length);
  /** The arm the keys drive (and the gamepad alone). */
  const selectedArm = (): PageArm => arms[loop.selected] ?? arms[0]!;
  const youHaveControl = (): boolean => ((state?.flags ?? 0) & StateFlags.YOU_HAVE_CONTROL) !== 0;
  supervision = setupSupervision(view, loop, link, youHaveControl, () => control.released());
  // The active frame's axes at the gripper, in both eyes (shown with the AR ball): the
  // selected arm's.
  const axes = new AxisMarker(arms[0]!.cameras, model.tool.flat(), view);
  // The whole predicted arm, a translucent skeleton in both eyes (the "Ghost arm" switch);
  // each arm's, in its colour.
  const ghosts: OverlayPainter = { paint: (ctx, eye, size) => arms.forEach((a) => a.ghost.paint(ctx, eye, size)) };
  view.addOverlay(ghosts);
  const ghostSwitch = {
    setEnabled: (on: boolean) => {
      ghostOn = on;
      return arms.map((a) => a.ghost.setEnabled(on)).some(Boolean);
    },
  };
  setupGhostSwitch($<HTMLInputElement>("ghost"), ghostSwitch, localStorage, () => view.overlayChanged());
  // Two arms or more: the header's chip for each (a click selects it for the keys).
  const chips = new ArmChipsView($("arms"), (i) => loop.selectArm(i));
  const showChips = () =>
    chips.show(
      arms.length < 2
        ? []
        : armChips(
            arms.map((a, i) => ({
              name: a.entry.name,
              state: a.state,
              forceN: a.force ? Math.hypot(...a.force.values.slice(0, 3)) : null,
              selected: i === loop.selected,
              driven: loop.held.includes(i),
            })),
            safety.force_limit_n,
            $<HTMLInputElement>("ar-colour").value,
          ),
    );
  setInterval(showChips, 200);
  loop.onArmChange = (why) => {
    // What a held key or dead-man drives has changed: it drives again once pressed anew.
    if (why !== "swap") keyboard.latch();
    if (why !== "select" || loop.padMode === "one") gamepad.latch();
    const sel = selectedArm();
    axes.setArm(sel.cameras, sel.entry.model.tool.flat());
    showChips();
  };
  setupControls(loop, link);
  const alarm = showControlAlerts(control, [keyboard, gamepad], () => loop.take());
  loop.onRelease = () => control.released(); // handing back to a policy, too
  const help = new HelpOverlay(document, $("help-button"), arms.length > 1 ? arms.map((a) => a.entry.name) : []);
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
  const rumble = new ContactRumble((i) => {
    const f = arms[i]?.force;
    return f ? rumbleStrength(Math.hypot(...f.values.slice(0, 3)), safety.force_limit_n) : 0;
  });
  const rumbleBox = $<HTMLInputElement>("rumble");
  rumble.enabled = rumbleBox.checked;
  rumbleBox.onchange = () => (rumble.enabled = rumbleBox.checked);
  /** Each arm's AR ball and ghost where its prediction is; with two arms or more the
   * arms driven now at full strength, the others fainter. */
  const drawArms = () => {
    if (arms.length === 1) {
      const only = arms[0]!;
      showBall(view, only.ball.update(only.predicted.pose));
      if (only.ghost.update(only.predicted.joints)) view.overlayChanged();
      return;
    }
    const driven = loop.driven;
    const show = $<HTMLInputElement>("ar").checked;
    const colour = $<HTMLInputElement>("ar-colour").value;
    const radius = numberIn("ar-size");
    arms.forEach((a, i) => {
      const on = driven.includes(i);
      view.setBall(a.ball.update(a.predicted.pose), show, dimmed(armStyle(i).ball ?? colour, on ? 1 : 0.6), radius, i);
      const moved = a.ghost.update(a.predicted.joints);
      if (a.ghost.setHighlight(on) || moved) view.overlayChanged();
    });
  };
  // A WebXR controller (else a tracked hand) as a 6-DoF master: its grip (the hand's
  // pinch) is the dead-man. Two arms: each hand its arm (input/arms.ts), each its clutch.
  const xrInput = new XRMasterInput();
  view.onXRFrame = (frame, space) => {
    const now = performance.now();
    if (arms.length > 1) {
      const hands = xrInput.readHands(frame, space);
      loop.xrHands(hands, now);
      // (A headset pauses the page's own animation frames: the arms follow here too.)
      drawArms();
      const to = handArms(loop.armNames);
      if (hands.left?.gamepad) rumble.driveXR(now, hands.left.gamepad, to.left, "left");
      if (hands.right?.gamepad) rumble.driveXR(now, hands.right.gamepad, to.right, "right");
      return;
    }
    const controller = xrInput.read(frame, space);
    loop.xrFrame(controller, now);
    // (A headset pauses the page's own animation frames: the ghost follows here too.)
    const only = arms[0]!;
    if (only.ghost.update(only.predicted.joints)) view.overlayChanged();
    if (controller?.gamepad) rumble.driveXR(now, controller.gamepad);
  };
  const tick = () => {
    const now = performance.now();
    const pad = loop.tick(now).pad;
    // The gamepad's left motor feels the first arm's force (one arm), the selected
    // arm's (one arm alone), or the left arm's with the right's on its right motor.
    const to = handArms(loop.armNames);
    rumble.drivePad(now, pad, arms.length === 1 ? undefined : loop.padMode === "one" ? { strong: loop.selected, weak: null } : { strong: to.left, weak: to.right });
    drawArms();
    const sel = selectedArm();
    axes.update(loop.frame, sel.predicted.pose, loop.view, $<HTMLInputElement>("ar").checked);
    requestAnimationFrame(tick);
  };
  requestAnimationFrame(tick);

  // Repeating a recorded episode as a task, its path shown in both eyes before it runs.
  // Run and Approach need the lease: none is known to be held while the link is down.
  const path = new PathOverlay(cell.cameras, view);
  tasks = new TasksPanel($("tasks"), { api, log, link, flags: () => (link.open ? (state?.flags ?? 0) : 0), path, arm: () => (arms.length > 1 ? arms[0]!.entry.name : null) });
  void tasks.load();

  // The arm drawn follows the server's: read again at each new session (a restart with
  // another model redraws the labels, the ghost, the ball and the axes for the new arm).
  const readArm = async (): Promise<ServerArm> => {
    const [entries, c] = await Promise.all([readServerArms(api), api.request("get", "/api/v1/calibration")]);
    return { model: entries[0]!.model, cameras: c.cameras, arms: entries };
  };
  const reloader = new ServerArmReloader(
    { model, cameras: cell.cameras, arms: served },
    readArm,
    (next) => {
      // Every arm drawn and driven anew (the header's state follows at the next STATEs).
      arms = pageArms(next.arms ?? [], next.cameras, ghostOn);
      view.setBallCount(arms.length);
      loop.setArms(driveArms(arms)); // the axis marker follows (onArmChange)
      view.overlayChanged();
      path.setCameras(next.cameras);
      void tasks?.load(); // which recordings this arm can repeat
    },
    log,
  );
  armReloader = reloader;
  const panels = startPanels({
    state: () => state,
    armState: () => selectedArm().state,
    armName: () => (arms.length > 1 ? selectedArm().entry.name : ""),
    arms: () => (arms.length > 1 ? arms.map((a) => a.entry.name) : []),
    force: () => selectedArm().force,
    link,
    glass,
    videoInterval,
    forceLimitN: safety.force_limit_n,
    controller: () => controller,
    policyHolds: () => supervision?.policyHolds ?? false,
    get jointNames() {
      return selectedArm().entry.model.joint_names;
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
      /** The first arm's AR ball, ghost and prediction (the only arm's, mostly). */
      get ball() {
        return arms[0]!.ball.ball;
      },
      axes,
      get ghost() {
        return arms[0]!.ghost;
      },
      get arm() {
        return arms[0]!.predicted;
      },
      /** Every arm: its name, index, STATE, force, ball, ghost and prediction. */
      get arms() {
        return arms;
      },
      /** Each arm's AR ball (pixels in each eye), in the arms' order. */
      get balls() {
        return arms.map((a) => a.ball.ball);
      },
      loop,
      get state() {
        return state;
      },
      /** The selected arm's newest force sample (the only arm's). */
      get force() {
        return selectedArm().force;
      },
      setMode,
      help,
      panels,
      control,
      alarm,
      tasks,
      recording,
      hud,
      reloader,
      chips,
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
