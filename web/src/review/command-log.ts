// The review's command log: every recorded command — when, who sent it, what (with
// several arms, which arm), refused and why — the ones after the cursor greyed.
import { $ } from "../ui/dom";
import { CursorRows } from "./cursor-rows";
import { whoSent } from "./marks";
import type { RecordedCommand, ReviewContext } from "./recording";
import type { ReviewTestView } from "./test-view";
import { formatTime } from "./timeline";

export interface CommandLogHandle {
  update(t: number): void;
  /** Lists the commands the timeline's last piece brought. */
  grow(): void;
  testView: Pick<ReviewTestView, "commands">;
}

/** A command's line in the log: "0:01.5 ws 127.0.0.1:5000 cartesian_increment left refused: …". */
export function commandLine(c: RecordedCommand, several: boolean): string {
  // Several arms: the arm a command moved (its args name it).
  const arm = several && typeof c.args?.arm === "string" ? ` ${c.args.arm}` : "";
  return `${formatTime(c.time)} ${whoSent(c.source, c.client)} ${c.kind}${arm}${c.accepted ? "" : ` refused: ${c.reason}`}`;
}

export function setupCommandLog({ recording }: ReviewContext): CommandLogHandle {
  const list = $("review-commands");
  const rows: HTMLLIElement[] = [];
  const greyed = new CursorRows(recording.commands, rows);
  const testView = { commands: 0 };
  const grow = () => {
    for (const c of recording.commands.slice(rows.length)) {
      const li = document.createElement("li");
      li.textContent = commandLine(c, recording.several);
      if (!c.accepted) li.classList.add("refused");
      list.append(li);
      rows.push(li);
    }
    list.hidden = rows.length === 0;
    testView.commands = rows.length;
    greyed.again();
  };
  grow();
  return {
    update(t) {
      const at = greyed.update(t);
      if (at !== null) rows[at]?.scrollIntoView({ block: "nearest" });
    },
    grow,
    testView,
  };
}
