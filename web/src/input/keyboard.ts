// Keyboard fallback: hold Space (the dead-man) and W/S, A/D, R/F to translate,
// Q/E to yaw. Alt+arrows shift the right image against the left (the thesis's
// alignment keys); 1/2/3 pick the base/wrist/tool frame; Escape is the e-stop.
import type { MotionCommand } from "./motion";

/** Inputs that take typed text: the keys are theirs. Any other control (a checkbox, a
 * slider, a button) does not keep the driving keys from the page, and Space never
 * toggles it (it is the dead-man). Duck-typed, so it can be tested without a DOM. */
export function takesText(target: EventTarget | null): boolean {
  const el = target as { tagName?: string; type?: string; isContentEditable?: boolean } | null;
  if (!el || typeof el.tagName !== "string") return false;
  if (el.isContentEditable || el.tagName === "TEXTAREA" || el.tagName === "SELECT") return true;
  if (el.tagName !== "INPUT") return false;
  return !NOT_TEXT.has((el.type ?? "text").toLowerCase());
}
const NOT_TEXT = new Set(["checkbox", "radio", "range", "button", "submit", "reset", "color", "file", "image"]);

export class KeyboardInput {
  private down = new Set<string>();
  // Keys held when control was lost: they move nothing until released and pressed again.
  private latched = new Set<string>();
  onKey: ((key: string, event: KeyboardEvent) => void) | null = null;

  constructor(target: Window) {
    target.addEventListener("keydown", (e) => {
      if (takesText(e.target)) return;
      this.down.add(e.code);
      this.onKey?.(e.code, e);
      if (e.code === "Space" || e.code.startsWith("Arrow")) e.preventDefault();
    });
    target.addEventListener("keyup", (e) => {
      this.down.delete(e.code);
      this.latched.delete(e.code);
      // A focused checkbox or button acts on Space's keyup: not while driving.
      if (e.code === "Space" && !takesText(e.target)) e.preventDefault();
    });
    target.addEventListener("blur", () => {
      this.down.clear(); // a lost focus never keeps moving
      this.latched.clear();
    });
  }

  /** Control was lost or the arm halted: the keys held now stop driving until each is
   * released (a key held through the loss must not move the arm when control returns). */
  latch(): void {
    for (const code of this.down) this.latched.add(code);
  }

  private held(code: string): boolean {
    return this.down.has(code) && !this.latched.has(code);
  }

  read(): MotionCommand {
    const k = (code: string) => (this.held(code) ? 1 : 0);
    return {
      deadman: this.held("Space"),
      linear: [k("KeyW") - k("KeyS"), k("KeyA") - k("KeyD"), k("KeyR") - k("KeyF")],
      angular: [0, 0, k("KeyQ") - k("KeyE")],
    };
  }
}
