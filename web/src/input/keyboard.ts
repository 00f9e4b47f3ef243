// Keyboard fallback: hold Space (the dead-man) and W/S, A/D, R/F to translate,
// Q/E to yaw. Alt+arrows shift the right image against the left (the thesis's
// alignment keys); 1/2/3 pick the base/wrist/tool frame; Escape is the e-stop.
import type { MotionCommand } from "./motion";

export class KeyboardInput {
  private down = new Set<string>();
  onKey: ((key: string, event: KeyboardEvent) => void) | null = null;

  constructor(target: Window) {
    target.addEventListener("keydown", (e) => {
      if ((e.target as HTMLElement | null)?.tagName === "INPUT") return;
      this.down.add(e.code);
      this.onKey?.(e.code, e);
      if (e.code === "Space" || e.code.startsWith("Arrow")) e.preventDefault();
    });
    target.addEventListener("keyup", (e) => this.down.delete(e.code));
    target.addEventListener("blur", () => this.down.clear()); // a lost focus never keeps moving
  }

  read(): MotionCommand {
    const k = (code: string) => (this.down.has(code) ? 1 : 0);
    return {
      deadman: this.down.has("Space"),
      linear: [k("KeyW") - k("KeyS"), k("KeyA") - k("KeyD"), k("KeyR") - k("KeyF")],
      angular: [0, 0, k("KeyQ") - k("KeyE")],
    };
  }
}
