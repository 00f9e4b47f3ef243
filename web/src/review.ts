// The review page: a recording played back on one timeline — both eyes of the recorded
// video (the MP4 the server remuxes from the recorded H.264, played and seeked by a
// <video>) with the AR ball and the ghost arm at the recorded *predicted* pose (the
// commanded target joints, as the live page draws them) beside a thin ring at the
// recorded actual tool position, both projected with the calibration in force at that
// moment; the force plot with a cursor, the episodes and the safety events on a strip
// under it (and listed), and the command log. Pause, seek, 0.25–4× speed. The picture is
// the live page's: without the cameras' timecode stripe (review/frame.ts). Whatever the
// recording lacks (video, forces, commands, episodes) is left out, not shown empty.
// A multi-arm recording (review/arms.ts) plays every arm back: each arm's ghost and ring
// through P · its mount, its forces in a band of the plot of its own, and its joints at
// the cursor in a readout under the plot.
// Data: GET /api/v1/recordings/{id}/timeline, …/video.mp4, /api/v1/robot/arms and
// /api/v1/robot/model (each recorded arm's, from the server's arm of its name).
import { Api, MessageLog, readToken, withoutToken } from "./api";
import { GHOST_RGB, type Pixel, ghostChain } from "./ar/ghost";
import { project, type Projection } from "./ar/projection";
import { forceBand, jointsLine, modelArm, mountedProjection, recordedArms, severalArms } from "./review/arms";
import { shownFrame } from "./review/frame";
import { droveSpans, episodeLabel, episodesOf, markRows, safetyMarks, spanOf, verdictOf, whoSent, type EpisodeEvent, type SafetySnapshot } from "./review/marks";
import { SPEEDS, forceRange, formatTime, latestAt, timelineOf, videoTimeOf } from "./review/timeline";
import { $ } from "./ui/dom";
import { tracePolyline } from "./view/overlay";

const api = new Api(`${location.origin}/`, readToken(location.search, localStorage, sessionStorage));
const recordingId = new URLSearchParams(location.search).get("id") ?? "";
history.replaceState(history.state, "", withoutToken(location.href));
const log = new MessageLog($("messages"));

interface Timed {
  time: number;
  [key: string]: unknown;
}
const FORCE_COLOURS = ["#e44", "#4c4", "#48f", "#e9e", "#ee4", "#4ee"];

async function pickList(): Promise<void> {
  const pick = $<HTMLSelectElement>("review-pick");
  try {
    const response = await fetch(`${location.origin}/api/v1/recordings`, { cache: "no-store" });
    const list = (await response.json()) as { file: string; name?: string; active?: boolean }[] | { recordings?: { file: string }[] };
    const items = Array.isArray(list) ? list : (list.recordings ?? []);
    for (const r of items) {
      const o = document.createElement("option");
      o.value = r.file;
      o.textContent = r.file;
      o.selected = r.file === recordingId || r.file.replace(/\.mcap$/, "") === recordingId;
      pick.append(o);
    }
    pick.hidden = pick.options.length === 0; // no recordings: no empty list
  } catch {
    /* the list is a convenience: ?id= works without it */
  }
  pick.onchange = () => (location.search = `?id=${encodeURIComponent(pick.value)}`);
}

async function main(): Promise<void> {
  void pickList();
  if (!recordingId) {
    log.add("open a recording: review.html?id=<file name> (or pick one above)");
    return;
  }
  $("review-name").textContent = recordingId;
  const [tl, serverArms] = await Promise.all([
    api.request("get", "/api/v1/recordings/{recording_id}/timeline", {
      params: { recording_id: recordingId },
      query: { max_points: 4000 },
    }),
    api.request("get", "/api/v1/robot/arms").catch(() => []),
  ]);
  const topic = (name: string) => (tl.topics[name] ?? []) as Timed[];
  // Each recorded arm (one, "arm", unless the recording is of several) and its series.
  const arms = recordedArms(tl.topics);
  const several = severalArms(arms);
  // Its model to draw it with: the server's arm of its name (a one-arm server's only one).
  const serverNames = serverArms.map((a) => a.name);
  const models = await Promise.all(
    arms.map((a) => {
      const name = modelArm(a.name, serverNames);
      const asked = name === null ? api.request("get", "/api/v1/robot/model") : api.request("get", "/api/v1/robot/model", { query: { arm: name } });
      return asked.catch((e: Error) => {
        log.add(`the ${a.name} arm is not drawn: ${e.message}`, true);
        return null;
      });
    }),
  );
  type State = Timed & { position: number[]; target_joints?: number[]; joints?: number[] };
  const armStates = arms.map((a) => topic(a.stateTopic) as State[]);
  const armForces = arms.map((a) => topic(a.forceTopic) as (Timed & { values: number[] })[]);
  const forces = armForces.flat();
  const states = armStates.flat();
  // What the overlay shows now, per eye (for tests): the predicted tool and the actual one
  // (the first arm's; every arm's by name in `arms`).
  const overlay: { predicted: (Pixel | null)[]; actual: (Pixel | null)[]; arms: Record<string, { predicted: (Pixel | null)[]; actual: (Pixel | null)[] }> } = {
    predicted: [null, null],
    actual: [null, null],
    arms: Object.fromEntries(arms.map((a) => [a.name, { predicted: [null, null], actual: [null, null] }])),
  };
  const commands = topic("/commands") as (Timed & { kind: string; accepted: boolean; reason: string; source: string; client: string; args?: { arm?: unknown } })[];
  // As recorded: {cameras: {left: {P}, right: {P}}, ground_truth_P: {left, right}}.
  type RecordedCalibration = Timed & { cameras?: Record<string, { P?: Projection }>; ground_truth_P?: Record<string, Projection> };
  const episodes = episodesOf(topic("/episodes") as (Timed & EpisodeEvent)[]);
  const safety = safetyMarks(topic("/safety") as (Timed & SafetySnapshot)[]);
  // A supervised policy's recording: who drove when (the strip's coloured foot).
  const drove = droveSpans(topic("/autonomy") as (Timed & { mode: string; policy?: string | null; operator?: string | null })[], tl.duration);
  const calibrations = (topic("/calibration") as RecordedCalibration[]).map((c) => ({
    time: c.time,
    cameras: ["left", "right"].map((eye) => ({ P: c.cameras?.[eye]?.P ?? c.ground_truth_P?.[eye] ?? [] })),
  }));

  const video = $<HTMLVideoElement>("review-video");
  const canvas = $<HTMLCanvasElement>("review-view");
  const ctx = canvas.getContext("2d");
  const seek = $<HTMLInputElement>("review-seek");
  const play = $<HTMLButtonElement>("review-play");
  const speed = $<HTMLSelectElement>("review-speed");
  seek.max = String(tl.duration);
  for (const s of SPEEDS) {
    const o = document.createElement("option");
    o.value = String(s);
    o.textContent = `${s}×`;
    o.selected = s === 1;
    speed.append(o);
  }
  speed.onchange = () => (video.playbackRate = Number(speed.value));
  play.onclick = () => (video.paused ? void video.play() : video.pause());
  video.onplay = () => (play.textContent = "Pause");
  video.onpause = () => (play.textContent = "Play");
  seek.oninput = () => {
    video.currentTime = videoTimeOf(Number(seek.value), tl.video_start, video.duration);
  };
  const hasVideo = tl.video_start !== null && tl.video_start !== undefined;
  if (hasVideo) {
    video.src = `${location.origin}/api/v1/recordings/${encodeURIComponent(recordingId)}/video.mp4`;
    video.onerror = () => log.add(`video: ${video.error?.message ?? "cannot play"}`, true);
  } else log.add("this recording has no video");
  canvas.hidden = !hasVideo; // not a black box where there is no picture
  // The part of each frame shown: the rows below the timecode stripe (as the live page).
  const shown = { crop: 0, width: canvas.width, height: canvas.height };
  video.onloadedmetadata = () => {
    Object.assign(shown, shownFrame(video.videoWidth, video.videoHeight));
    canvas.width = shown.width;
    canvas.height = shown.height;
  };
  /** Go to timeline time t (the video follows; without one, the slider is the time). */
  function seekTo(t: number): void {
    seek.value = String(t);
    if (hasVideo) video.currentTime = videoTimeOf(t, tl.video_start, video.duration);
  }

  // The command log: every command, the ones after the cursor greyed.
  const list = $("review-commands");
  const rows = commands.map((c) => {
    const li = document.createElement("li");
    // Several arms: the arm a command moved (its args name it).
    const arm = several && typeof c.args?.arm === "string" ? ` ${c.args.arm}` : "";
    li.textContent = `${formatTime(c.time)} ${whoSent(c.source, c.client)} ${c.kind}${arm}${c.accepted ? "" : ` refused: ${c.reason}`}`;
    if (!c.accepted) li.classList.add("refused");
    list.append(li);
    return li;
  });
  list.hidden = rows.length === 0;
  let shownCommand = -2;

  // The episodes and the safety events: spans and ticks on a strip as wide as the force
  // plot (the same time axis), and a list; a click on either seeks there.
  const strip = $("review-marks");
  const cursor = document.createElement("div");
  cursor.className = "cursor";
  for (const e of episodes) {
    const span = spanOf(e.start, e.end, tl.duration);
    const div = document.createElement("div");
    div.className = `episode ${verdictOf(e)}`;
    div.style.left = `${span.left}%`;
    div.style.width = `${span.width}%`;
    div.textContent = div.title = episodeLabel(e);
    div.onclick = () => seekTo(e.start);
    strip.append(div);
  }
  for (const m of safety) {
    const tick = document.createElement("div");
    tick.className = `safety ${m.kind}`;
    tick.style.left = `${spanOf(m.time, m.time, tl.duration).left}%`;
    tick.title = `${formatTime(m.time)} ${m.text}`;
    tick.onclick = () => seekTo(m.time);
    strip.append(tick);
  }
  for (const d of drove) {
    const span = spanOf(d.start, d.end, tl.duration);
    const band = document.createElement("div");
    band.className = `drove ${d.mode}`;
    band.style.left = `${span.left}%`;
    band.style.width = `${span.width}%`;
    band.title = `${formatTime(d.start)}–${formatTime(d.end)} ${d.who}`;
    strip.append(band);
  }
  strip.append(cursor);
  strip.hidden = episodes.length + safety.length + drove.length === 0;
  const eventList = $("review-events");
  const eventRows = markRows(episodes, safety).map((r) => {
    const li = document.createElement("li");
    li.className = r.kind;
    li.textContent = r.text;
    li.onclick = () => seekTo(r.time);
    eventList.append(li);
    return { li, time: r.time };
  });
  eventList.hidden = eventRows.length === 0;
  let shownEvent = -2;

  const forcePlot = $<HTMLCanvasElement>("review-force");
  const fctx = forcePlot.getContext("2d");
  const range = forceRange(forces);
  forcePlot.hidden = forces.length === 0; // no force sensor recorded: no empty plot
  // Several arms: the plot twice as tall, a band for each arm's forces.
  if (several) forcePlot.height = forcePlot.height * Math.min(arms.length, 4);
  function drawForces(t: number): void {
    if (!fctx) return;
    const { width: w, height: h } = forcePlot;
    fctx.clearRect(0, 0, w, h);
    const x = (s: number) => (s / Math.max(tl.duration, 1e-6)) * w;
    armForces.forEach((series, k) => {
      const band = forceBand(k, armForces.length, h);
      const y = (v: number) => band.top + band.height / 2 - (v / range) * (band.height / 2 - 4);
      for (let axis = 0; axis < 6; axis++) {
        fctx.strokeStyle = FORCE_COLOURS[axis] ?? "#fff";
        fctx.beginPath();
        series.forEach((f, i) => (i ? fctx.lineTo(x(f.time), y(f.values[axis] ?? 0)) : fctx.moveTo(x(f.time), y(f.values[axis] ?? 0))));
        fctx.stroke();
      }
      fctx.fillStyle = "#ccc";
      fctx.fillText(several ? `${arms[k]?.name ?? ""}  ±${range.toFixed(1)} N / N·m` : `±${range.toFixed(1)} N / N·m`, 4, band.top + 12);
    });
    fctx.strokeStyle = "#fff";
    fctx.beginPath();
    fctx.moveTo(x(t), 0);
    fctx.lineTo(x(t), h);
    fctx.stroke();
  }

  // Several arms: each arm's joints at the cursor, under the plot.
  const jointsReadout = document.createElement("pre");
  jointsReadout.id = "review-joints";
  jointsReadout.hidden = !several;
  forcePlot.after(jointsReadout);

  function frame(): void {
    const t = tl.video_start === null || tl.video_start === undefined ? Number(seek.value) : timelineOf(video.currentTime, tl.video_start);
    if (document.activeElement !== seek) seek.value = String(t);
    $("review-time").textContent = `${formatTime(t)} / ${formatTime(tl.duration)}`;
    const now = armStates.map((series) => series[latestAt(series, t)]);
    if (several) {
      const text = arms.map((a, k) => jointsLine(a.name, now[k]?.joints, a.jointNames.length ? a.jointNames : (models[k]?.joint_names ?? []))).join("\n");
      if (jointsReadout.textContent !== text) jointsReadout.textContent = text;
    }
    if (ctx && video.readyState >= 2) {
      ctx.drawImage(video, 0, shown.crop, shown.width, shown.height, 0, 0, canvas.width, canvas.height);
      const cameras = calibrations[Math.max(0, latestAt(calibrations, t))]?.cameras ?? [];
      arms.forEach((arm, k) => {
        const model = models[k];
        const state = now[k];
        const p = state?.position;
        const q = state?.target_joints;
        const drawn = overlay.arms[arm.name] ?? { predicted: [null, null], actual: [null, null] };
        cameras.slice(0, 2).forEach((cam, eye) => {
          if (cam.P.length !== 3) return;
          // An arm's pose is in its own base frame: drawn through P · its mount.
          const P = several ? mountedProjection(cam.P, arm.mount) : cam.P;
          ctx.save();
          ctx.translate((eye * canvas.width) / 2, -shown.crop); // camera pixels, stripe cropped
          // The ghost arm and the ball where the gripper was commanded to be.
          const chain = model && q && q.length === model.joints.length ? ghostChain(model, q, P) : [];
          const tool = chain[chain.length - 1] ?? null;
          drawn.predicted[eye] = tool;
          if (k === 0) overlay.predicted[eye] = tool;
          if (chain.length) {
            const [r, g, b] = GHOST_RGB;
            ctx.strokeStyle = `rgba(${r}, ${g}, ${b}, 0.45)`;
            ctx.lineWidth = 7;
            ctx.lineCap = ctx.lineJoin = "round";
            ctx.beginPath();
            tracePolyline(ctx, chain);
            ctx.stroke();
          }
          if (tool) {
            ctx.strokeStyle = "#0f0";
            ctx.lineWidth = 3;
            ctx.beginPath();
            ctx.arc(tool[0], tool[1], 12, 0, 2 * Math.PI);
            ctx.stroke();
          }
          // Where it actually was: a thin white ring.
          const actual = p && p.length === 3 ? project(P, [p[0] ?? 0, p[1] ?? 0, p[2] ?? 0]) : null;
          drawn.actual[eye] = actual;
          if (k === 0) overlay.actual[eye] = actual;
          if (actual) {
            ctx.strokeStyle = "#fff";
            ctx.lineWidth = 1;
            ctx.beginPath();
            ctx.arc(actual[0], actual[1], 6, 0, 2 * Math.PI);
            ctx.stroke();
          }
          if (several && tool) {
            ctx.fillStyle = "#fff";
            ctx.fillText(arm.name, tool[0] + 14, tool[1] - 14);
          }
          ctx.restore();
        });
      });
    }
    drawForces(t);
    cursor.style.left = `${spanOf(t, t, tl.duration).left}%`;
    const last = latestAt(commands, t);
    if (last !== shownCommand) {
      rows.forEach((r, i) => r.classList.toggle("future", i > last));
      rows[last]?.scrollIntoView({ block: "nearest" });
      shownCommand = last;
    }
    const lastEvent = latestAt(eventRows, t);
    if (lastEvent !== shownEvent) {
      eventRows.forEach((r, i) => r.li.classList.toggle("future", i > lastEvent));
      shownEvent = lastEvent;
    }
    requestAnimationFrame(frame);
  }
  requestAnimationFrame(frame);
  // For tests: what the timeline holds, and the video.
  Object.assign(window, {
    review: {
      video,
      overlay,
      duration: tl.duration,
      videoStart: tl.video_start,
      forces: forces.length,
      states: states.length,
      commands: commands.length,
      episodes,
      safety,
      drove,
      frame: shown,
      // Each recorded arm: its name, and how many states and force samples it has.
      arms: arms.map((a, k) => ({ name: a.name, states: armStates[k]?.length ?? 0, forces: armForces[k]?.length ?? 0 })),
    },
  });
  document.body.dataset.reviewReady = "1";
}

main().catch((e: Error) => log.add(e.message, true));
