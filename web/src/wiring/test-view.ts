// What tests and benchmarks read of the operator page (`window.telerobot`), built in one
// place from the wiring steps' handles. The browser tests (tests/test_web*.py,
// tests/support/browser.py) and the benches (bench/browser.py, held_control.py, wan.py)
// use this surface only: read-only figures and a few switches, each documented here, so
// the page's insides can change without them.
import { HandEyeRecorder } from "../view/handeye";
import { decodedFrames } from "../view/motion-mark";
import type { Ball, StereoView, ViewMode } from "../view/stereo";
import type { Rolling } from "../stats";
import type { LinkMeta } from "../transport/link";
import type { RobotState } from "../transport/realtime";
import type { ControlAlert } from "../ui/control-alert";
import type { ArmDrawingHandle } from "./arm-drawing";
import type { PageContext } from "./context";
import type { ControlsHandle } from "./controls";
import type { InputsHandle } from "./inputs";
import type { RealtimeHandle } from "./realtime";
import type { TasksHandle } from "./tasks";
import type { VideoHandle } from "./video";

/** The handles the test view reads. */
export interface PageHandles {
  ctx: PageContext;
  realtime: RealtimeHandle;
  video: VideoHandle;
  inputs: InputsHandle;
  drawing: ArmDrawingHandle;
  controls: ControlsHandle;
  tasks: TasksHandle;
  setMode: (mode: ViewMode) => void;
}

/** The last alerts shown, kept for a test (a halt's alert is gone within ~100 ms once
 * heartbeats come: polling would miss most). */
const ALERTS_KEPT = 1000;

export function pageTestView(h: PageHandles) {
  const { ctx, realtime, video, inputs, drawing, controls, tasks } = h;
  const { view, arms } = ctx;
  const first = () => arms.list[0]!;
  return {
    /** The stereo view: frames given and drawn, staleness, and what it shows. */
    view: viewTestView(view),
    /** The view mode (side-by-side, anaglyph, …), as the View panel sets it. */
    setMode: h.setMode,
    /** The header's state: every arm's newest STATE as one (null before the first). */
    get state(): RobotState | null {
      return arms.combined;
    },
    /** The realtime link's figures (operator, client id, heartbeats, resumes). */
    get client(): LinkMeta {
      const l = realtime.link;
      return {
        operator: l.operator,
        clientId: l.clientId,
        open: l.open,
        bestRtt: l.bestRtt,
        offset: l.offset,
        timerLateMs: l.timerLateMs,
        pageStallMs: l.pageStallMs,
        beatGapMs: l.beatGapMs,
        beatSkips: { ...l.beatSkips },
        resumes: l.resumes,
      };
    },
    /** The video peer: its id (null: none now), re-negotiations, no video on the server. */
    video: videoTestView(video),
    /** Capture → presented (ms) of every frame decoded; `listen` sees each as it comes. */
    glass: glassTestView(video),
    /** The connection HUD: its judgment, rows and figures (and its test seam, `pinned`). */
    hud: video.hud,
    /** The first arm's AR ball, in each eye's pixels (the only arm's, mostly). */
    get ball(): Ball {
      return first().ball.ball;
    },
    /** Each arm's AR ball, in the arms' order. */
    get balls(): Ball[] {
      return arms.list.map((a) => a.ball.ball);
    },
    /** The first arm's ghost: its chain in each eye's pixels. */
    get ghost(): { pixels: unknown; highlighted: boolean } {
      return { pixels: first().ghost.pixels, highlighted: first().ghost.highlighted };
    },
    /** Every arm: its name, and its ghost as drawn (chain pixels, highlighted). */
    get arms(): { name: string; ghost: { pixels: unknown; highlighted: boolean } }[] {
      return arms.list.map((a) => ({ name: a.entry.name, ghost: { pixels: a.ghost.pixels, highlighted: a.ghost.highlighted } }));
    },
    /** The axis marker at the selected arm's gripper, in each eye's pixels. */
    get axes(): { pixels: unknown } {
      return { pixels: drawing.axes.pixels };
    },
    /** The input loop: the selected arm, the frame driven in; `release()` lets control go. */
    loop: loopTestView(inputs),
    /** Control lost, said over the video: the alert shown, the sounds played, and every
     * alert since `recordAlerts()` (null: the alert cleared). */
    control: controlTestView(realtime, controls),
    /** The task this page follows, and the path shown. */
    tasks: tasksTestView(tasks),
    /** The recording panel: the header's REC state, the last file, the polls made. */
    recording: recordingTestView(realtime),
    /** Hand to eye (view/handeye.ts; bench/hand_to_eye.py): `start()` records key
     * presses, commands and frames; `motions()` joins them, one per motion key press. */
    handEye: handEyeTestView(realtime, view),
  };
}

function viewTestView(view: StereoView) {
  return {
    /** Video frames the view was given (drawn or skipped). */
    get frames(): number {
      return view.frames;
    },
    /** Times drawn (each costs the main thread a WebGL frame). */
    get renders(): number {
      return view.renders;
    },
    /** Frames drawn for a headset. */
    get xrFrames(): number {
      return view.xrFrames;
    },
    /** How long the video has been stale (ms), null while frames come. */
    get staleMs(): number | null {
      return view.staleMs;
    },
    /** The last time the view turned stale (performance.now() ms). */
    get lastStale(): { lastFrameAt: number; reportedAt: number } | null {
      return view.lastStale;
    },
    /** Each eye's top rows not shown (the cameras' timecode stripe). */
    get croppedRows(): number {
      return view.croppedRows;
    },
    /** The canvas drawn (with preserveDrawingBuffer): its pixels are what is seen. */
    get canvas(): HTMLCanvasElement {
      return view.canvas;
    },
    /** The decoded picture's size, both eyes side by side. */
    get videoSize(): { width: number; height: number } {
      return { width: view.video.videoWidth, height: view.video.videoHeight };
    },
    /** The draw pacer: a draw waiting for the GPU, frames drawn late or skipped. */
    get pacer(): { waiting: boolean; waited: number; skipped: number } {
      return { waiting: view.pacer.waiting, waited: view.pacer.waited, skipped: view.pacer.skipped };
    },
    get xrPresenting(): boolean {
      return view.drawn.xrPresenting;
    },
    /** The supervision line shown in the headset. */
    get xrBadgeVisible(): boolean {
      return view.drawn.xrBadgeVisible;
    },
    /** AR balls the view's programs draw, and which of them are shown (1/0). */
    get ballSlots(): number {
      return view.drawn.ballSlots;
    },
    get ballsShown(): number[] {
      return view.drawn.ballsShown;
    },
    /** Where camera pixels land on the canvas (each eye's width, rows cropped, the
     * alignment shift, the canvas's height). */
    get layout(): { eyeWidth: number; cropTop: number; shift: [number, number]; outHeight: number } {
      return view.drawn.layout;
    },
    /** The overlay is drawn on the CPU (willReadFrequently): no GPU read-back. */
    get overlayOnCpu(): boolean {
      return view.drawn.overlayOnCpu;
    },
    /** Draw again now (e.g. a paused video, to read a still). */
    redraw: () => view.redraw(),
  };
}

function videoTestView(video: VideoHandle) {
  return {
    get peerId(): string | null {
      return video.connection.peer?.peerId ?? null;
    },
    /** The peer's own credentials, for a test that closes it on the server as a
     * crashed media worker would (the page holds them anyway). */
    get peerSecret(): string | null {
      return video.connection.peer?.secret ?? null;
    },
    get renegotiations(): number {
      return video.connection.renegotiations;
    },
    get noVideo(): boolean {
      return video.connection.noVideo;
    },
    /** The peer's session descriptions (what was offered and answered). */
    get sdp(): { local: string; remote: string } | null {
      const pc = video.connection.peer?.pc;
      return pc ? { local: pc.localDescription?.sdp ?? "", remote: pc.remoteDescription?.sdp ?? "" } : null;
    },
    /** The peer's WebRTC stats (null: no peer now). */
    stats: async (): Promise<RTCStatsReport | null> => (await video.connection.peer?.pc.getStats()) ?? null,
    /** Close the peer in the page, as a failed link would: the page re-negotiates. */
    closePeer: () => video.connection.peer?.pc.close(),
  };
}

function glassTestView(video: VideoHandle) {
  return {
    get count(): number {
      return video.glass.count;
    },
    get total(): number {
      return video.glass.total;
    },
    snapshot: (): number[] => video.glass.snapshot(),
    listen: (f: (ms: number) => void) => listenTo(video.glass, f),
  };
}

function loopTestView(inputs: InputsHandle) {
  return {
    get selected(): number {
      return inputs.loop.selected;
    },
    get frame(): string {
      return inputs.loop.frame;
    },
    release: () => inputs.loop.release(),
    /** Whether a driving key drives at its keydown (else at the next frame only). */
    get driveOnKey(): boolean {
      return inputs.loop.driveOnKey;
    },
    set driveOnKey(on: boolean) {
      inputs.loop.driveOnKey = on;
    },
  };
}

function controlTestView(realtime: RealtimeHandle, controls: ControlsHandle) {
  // Every alert the control watch shows, from the last `recordAlerts()`.
  let alerts: (string | null)[] = [];
  const shown = realtime.control.onChange;
  realtime.control.onChange = (alert: ControlAlert | null, sound: boolean) => {
    if (alerts.length < ALERTS_KEPT) alerts.push(alert ? alert.text : null);
    shown?.(alert, sound);
  };
  return {
    get alert(): ControlAlert | null {
      return realtime.control.alert;
    },
    get played(): number {
      return controls.alarm.played;
    },
    recordAlerts: () => {
      alerts = realtime.control.alert ? [realtime.control.alert.text] : [];
    },
    get alerts(): (string | null)[] {
      return alerts;
    },
  };
}

function tasksTestView(tasks: TasksHandle) {
  return {
    get task() {
      return tasks.tasks.task;
    },
    get path(): { shown: boolean; points: unknown; approach: unknown } {
      const p = tasks.path;
      return { shown: p.shown, points: p.points, approach: p.approach };
    },
  };
}

function recordingTestView(realtime: RealtimeHandle) {
  return {
    get view() {
      return realtime.recording.view;
    },
    get last(): string | null {
      return realtime.recording.last;
    },
    get polls(): number {
      return realtime.recording.polls;
    },
  };
}

function handEyeTestView(realtime: RealtimeHandle, view: StereoView) {
  const recorder = new HandEyeRecorder();
  return {
    start: () => {
      if (recorder.started) return;
      realtime.link.onAck = (sentAt, appliedAt) => recorder.command({ sentAt, appliedAt });
      recorder.start(window, view.video);
    },
    get started(): boolean {
      return recorder.started;
    },
    /** Every motion found so far (times in ms), the presses left out and why, and the
     * frames recorded (decoded with their mark, presented). */
    motions: (threshold?: number) => recorder.motions(threshold),
    /** The raw records (presses, ACKed commands, decoded frames with their mark,
     * presented frames), for a bench that looks closer. */
    records: () => ({
      presses: recorder.presses.items,
      commands: recorder.commands.items,
      decoded: decodedFrames.log.items,
      presented: recorder.presented.items,
    }),
    /** How many of each are recorded. */
    get counts(): { presses: number; commands: number; presented: number } {
      return { presses: recorder.presses.items.length, commands: recorder.commands.items.length, presented: recorder.presented.items.length };
    },
  };
}

export type PageTestView = ReturnType<typeof pageTestView>;

/** `f` told of every value added to `r` (a bench's own record of them, with its times). */
function listenTo(r: Rolling, f: (ms: number) => void): void {
  const add = r.add.bind(r);
  r.add = (v: number) => {
    f(v);
    add(v);
  };
}
