// The episodes and the safety events: spans and ticks on a strip as wide as the force
// plot (the same time axis), and a list; a click on either seeks there. Under them, who
// drove when (a supervised policy's recording), and a cursor at the time shown.
import { $ } from "../ui/dom";
import { CursorRows } from "./cursor-rows";
import { episodeLabel, markRows, spanOf, verdictOf, type DroveSpan, type ReviewEpisode, type SafetyMark } from "./marks";
import type { ReviewContext } from "./recording";
import type { ReviewTestView } from "./test-view";
import { formatTime } from "./timeline";

/** One mark on the strip: a <div> of class `className` at `left`% (`width`% wide, or as
 * the page's style makes it), its words (if it shows any), its tooltip, and where a
 * click on it seeks to (null: not clickable). */
export interface StripMark {
  className: string;
  left: number;
  width: number | null;
  text: string | null;
  title: string;
  seekTo: number | null;
}

export interface MarksStripHandle {
  update(t: number): void;
  /** Draws the strip and the list again (the timeline's last piece brought more). */
  grow(): void;
  testView: Pick<ReviewTestView, "episodes" | "safety" | "drove">;
}

/** The strip's marks, in the order drawn: the episodes' spans (coloured by verdict), the
 * safety events' ticks, who drove's bands. */
export function stripMarks(episodes: readonly ReviewEpisode[], safety: readonly SafetyMark[], drove: readonly DroveSpan[], duration: number): StripMark[] {
  const spans = episodes.map((e) => {
    const span = spanOf(e.start, e.end, duration);
    const label = episodeLabel(e);
    return { className: `episode ${verdictOf(e)}`, left: span.left, width: span.width, text: label, title: label, seekTo: e.start };
  });
  const ticks = safety.map((m) => ({ className: `safety ${m.kind}`, left: spanOf(m.time, m.time, duration).left, width: null, text: null, title: `${formatTime(m.time)} ${m.text}`, seekTo: m.time }));
  const bands = drove.map((d) => {
    const span = spanOf(d.start, d.end, duration);
    return { className: `drove ${d.mode}`, left: span.left, width: span.width, text: null, title: `${formatTime(d.start)}–${formatTime(d.end)} ${d.who}`, seekTo: null };
  });
  return [...spans, ...ticks, ...bands];
}

export function setupMarksStrip({ recording }: ReviewContext, seekTo: (t: number) => void): MarksStripHandle {
  const { episodes, safety, drove } = recording; // (grown in place)
  const eventList = $("review-events");
  let cursor: HTMLElement;
  let greyed: CursorRows;
  const draw = () => {
    cursor = drawStrip(stripMarks(episodes, safety, drove, recording.duration), seekTo);
    const events = markRows(episodes, safety);
    eventList.replaceChildren();
    const rows = events.map((r) => {
      const li = document.createElement("li");
      li.className = r.kind;
      li.textContent = r.text;
      li.onclick = () => seekTo(r.time);
      eventList.append(li);
      return li;
    });
    eventList.hidden = rows.length === 0;
    greyed = new CursorRows(events, rows);
  };
  draw();
  return {
    update(t) {
      cursor.style.left = `${spanOf(t, t, recording.duration).left}%`;
      greyed.update(t);
    },
    grow: draw,
    testView: { episodes, safety, drove },
  };
}

/** Puts the marks on the strip (none: the strip hidden), the cursor over them; the cursor. */
function drawStrip(marks: readonly StripMark[], seekTo: (t: number) => void): HTMLElement {
  const strip = $("review-marks");
  strip.replaceChildren();
  const cursor = document.createElement("div");
  cursor.className = "cursor";
  for (const m of marks) {
    const div = document.createElement("div");
    div.className = m.className;
    div.style.left = `${m.left}%`;
    if (m.width !== null) div.style.width = `${m.width}%`;
    if (m.text !== null) div.textContent = m.text;
    div.title = m.title;
    const at = m.seekTo;
    if (at !== null) div.onclick = () => seekTo(at);
    strip.append(div);
  }
  strip.append(cursor);
  strip.hidden = marks.length === 0;
  return cursor;
}
