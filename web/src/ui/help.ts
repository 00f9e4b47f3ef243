// The help overlay: every key and control of the operator page. `?` or the header's
// "?" button toggles it; Escape closes it and does nothing else (ui/keys.ts: a key
// pressed to close a window must not latch the e-stop). Every other key still reaches
// the input loop while it is open, and the E-STOP button stays above it.
import { handArms } from "../input/arms";
import { FRAMES, FRAME_KEYS } from "../input/loop";
import { $ } from "./dom";

export interface HelpRow {
  keys: string;
  does: string;
}

/** What a server with two arms or more adds: which input drives which arm (input/arms.ts). */
export function armRows(names: readonly string[]): HelpRow[] {
  const { left, right } = handArms(names);
  const [l, r] = [names[left] ?? "left", names[right] ?? "right"];
  return [
    { keys: "[ / ]", does: `the arm the keys drive: the previous / the next (${names.join(", ")}); or click its chip in the header` },
    { keys: "gamepad L1 + left stick", does: `the ${l} arm: L1 (hold) its dead-man, the stick forward/back and left/right; with L2 pulled, up/down and turn` },
    { keys: "gamepad R1 + right stick", does: `the ${r} arm, the same with R1 and R2` },
    { keys: "gamepad Back / Select", does: "swap to one arm (the keys' arm, with the one-arm mapping: R1, both sticks, triggers) for fine work, and back to both" },
    { keys: "gamepad D-pad ← / →", does: "the previous / the next arm (for the keys and the gamepad alone)" },
    { keys: "VR left / right hand", does: `the left controller (or hand) drives the ${l} arm, the right the ${r}, each with its own grip (pinch); as the picture shows them` },
    { keys: "rumble", does: `each hand feels its own arm's contact: the left XR controller and the gamepad's left motor the ${l} arm's, the right the ${r}'s` },
  ];
}

/** What the overlay lists, in sections (`arms`: the server's arms' names; two or more
 * add a section saying which input drives which). */
export function helpSections(frames: readonly string[] = FRAMES, keys: Readonly<Record<string, string>> = FRAME_KEYS, arms: readonly string[] = []): { title: string; rows: HelpRow[] }[] {
  const picks = Object.entries(keys).sort(([a], [b]) => a.localeCompare(b));
  const digits = picks.map(([code]) => code.replace(/^Digit/, "")).join(" / ");
  return [
    {
      title: "Keyboard",
      rows: [
        { keys: "Space (hold)", does: "dead-man: nothing moves unless it is held" },
        { keys: "W / S", does: "forward / back: the frame's x (view: away from / toward the camera)" },
        { keys: "A / D", does: "left / right: its y" },
        { keys: "R / F", does: "up / down: its z" },
        { keys: "Q / E", does: "turn left / right about its z (view: about the image's up)" },
        { keys: "Escape", does: "E-STOP (latched; Reset e-stop clears it). With this help or another dialog open, Escape only closes it" },
        { keys: digits, does: `driving frame: ${picks.map(([, f]) => f).join(" / ")}` },
        ...(frames.includes("view")
          ? [{ keys: "view frame", does: "moves as the left image shows it: W/S away from / toward the camera, A/D left / right, R/F up / down in the image, Q/E about the image's up" }]
          : []),
        { keys: "Alt + arrows", does: "shift the right image against the left (stereo alignment)" },
        { keys: "F", does: "fullscreen video (not while Space is held: then F drives down)" },
        { keys: "T", does: "a policy drives: take over; the arm stops where it is. Pressing the dead-man or the XR grip takes over too, and letting go of it for 0.6 s hands back" },
        { keys: "H", does: "hand control back to the policy (or resume it when paused)" },
        { keys: "P", does: "pause the policy (it holds still); P again resumes it" },
        { keys: "?", does: "this help" },
      ],
    },
    {
      title: "Gamepad",
      rows: [
        { keys: "R1 (hold)", does: "dead-man" },
        { keys: "sticks", does: "translate and rotate the tool" },
        { keys: "Y", does: `next driving frame (${frames.join(" → ")})` },
      ],
    },
    {
      title: "VR (WebXR)",
      rows: [
        { keys: "grip / pinch (hold)", does: "dead-man: the controller's motion moves the tool" },
        { keys: "Enter VR", does: "the View panel's button" },
      ],
    },
    ...(arms.length > 1 ? [{ title: `Two arms (${arms.join(", ")})`, rows: armRows(arms) }] : []),
    {
      title: "A policy to supervise",
      rows: [
        { keys: "telerobot policy demo", does: "run beside this server: a scripted policy reaches for targets (AUTONOMOUS); take over with T or the dead-man, correct, hand back with H (docs/lerobot.md for a learned one)" },
      ],
    },
    {
      title: "Buttons",
      rows: [
        { keys: "Take / Release control", does: "the lease: one operator drives at a time" },
        { keys: "Home", does: `move ${arms.length > 1 ? "every arm to its" : "the arm to its"} home pose (click twice to confirm)` },
        { keys: "E-STOP", does: "stop at once, latched; anyone may press it" },
        { keys: "Reset e-stop", does: "clear the latch (the operator in control)" },
        { keys: "Speed", does: "scales every motion, 0.10–1.00" },
      ],
    },
  ];
}

/** What a key does to the overlay: `?` toggles it, Escape closes it (and only that). */
export function helpKeyAction(key: string, open: boolean): "toggle" | "close" | null {
  if (key === "?") return "toggle";
  if (key === "Escape" && open) return "close";
  return null;
}

const escape = (s: string) => s.replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]!);

export class HelpOverlay {
  readonly element: HTMLElement;

  constructor(doc: Document = document, button: HTMLElement | null = $("help-button"), arms: readonly string[] = []) {
    const el = doc.createElement("div");
    el.id = "help";
    el.hidden = true;
    el.setAttribute("role", "dialog");
    el.setAttribute("aria-label", "Keys and controls");
    this.element = el;
    this.setArms(arms);
    el.addEventListener("click", (e) => {
      if (e.target === el || (e.target as HTMLElement).classList.contains("help-close")) this.hide();
    });
    doc.body.append(el);
    if (button) button.onclick = () => this.toggle();
  }

  /** The server's arms (two or more: their section; fewer: none), as they are now: a
   * server restarted with other arms is followed without a reload. */
  setArms(arms: readonly string[]): void {
    this.element.innerHTML =
      `<div class="help-box"><button type="button" class="help-close" title="Escape">×</button><h2>Keys and controls</h2>` +
      helpSections(FRAMES, FRAME_KEYS, arms.length > 1 ? arms : [])
        .map((s) => `<h3>${escape(s.title)}</h3><table>${s.rows.map((r) => `<tr><th>${escape(r.keys)}</th><td>${escape(r.does)}</td></tr>`).join("")}</table>`)
        .join("") +
      `</div>`;
  }

  get open(): boolean {
    return !this.element.hidden;
  }

  toggle(): void {
    this.element.hidden = this.open;
  }

  hide(): void {
    this.element.hidden = true;
  }

  /** A key went down (KeyboardEvent.key). */
  key(key: string): void {
    const action = helpKeyAction(key, this.open);
    if (action === "toggle") this.toggle();
    else if (action === "close") this.hide();
  }
}
