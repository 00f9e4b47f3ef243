// The fiducials clicked in each frozen image, in order: which camera is next, the
// page's prompt, and the keys that nudge or undo the last click.
import type { Schema } from "../../api";

export type CameraName = Schema<"FitRequest">["camera"];
export type Method = Schema<"FitRequest">["method"];
export type Pixel = [number, number];
export const CAMERAS: readonly CameraName[] = ["left", "right"];
export const NUDGE_PX = 0.25;
const NUDGES: Record<string, Pixel> = { ArrowLeft: [-NUDGE_PX, 0], ArrowRight: [NUDGE_PX, 0], ArrowUp: [0, -NUDGE_PX], ArrowDown: [0, NUDGE_PX] };

/** Fiducials each method needs clicked: the affine fit takes the first four. */
export const neededFor = (method: Method, fiducials: number): number => (method === "affine" ? 4 : fiducials);

export class Clicks {
  /** Pixels clicked per camera, in fiducial order. */
  readonly byCamera: Record<CameraName, Pixel[]> = { left: [], right: [] };
  /** The camera clicked last: the keys act on its last click. */
  last: CameraName | null = null;

  /** The camera to click next; undefined when each has `needed`. */
  next(needed: number): CameraName | undefined {
    return CAMERAS.find((c) => this.byCamera[c].length < needed);
  }

  /** Add a click; false (nothing added) when the camera has all it needs. */
  add(cam: CameraName, p: Pixel, needed: number): boolean {
    if (this.byCamera[cam].length >= needed) return false;
    this.byCamera[cam].push(p);
    this.last = cam;
    return true;
  }

  clear(cam: CameraName): void {
    this.byCamera[cam] = [];
  }

  /** Backspace undoes the last click, arrows nudge it by NUDGE_PX: the camera whose
   * clicks changed, or null when the key is none of those. */
  key(key: string): CameraName | null {
    if (!this.last) return null;
    const pts = this.byCamera[this.last];
    const p = pts[pts.length - 1];
    const d = NUDGES[key];
    if (key === "Backspace") pts.pop();
    else if (p && d) pts[pts.length - 1] = [p[0] + d[0], p[1] + d[1]];
    else return null;
    return this.last;
  }

  prompt(needed: number, frozen: boolean): string {
    const cam = this.next(needed);
    if (!frozen) return "Freeze the images first.";
    if (cam) return `Click fiducial ${this.byCamera[cam].length + 1} of ${needed} in the ${cam.toUpperCase()} image.`;
    return "All fiducials clicked: compute.";
  }
}
