// The right image's shift against the left (Alt+arrows: the thesis's alignment keys),
// remembered for this viewer: in this browser, and on the server through this page's
// video peer.
import type { Api, MessageLog, Schema } from "../api";
import { saveAlignment, type VideoPeer } from "../transport/video";
import type { StereoView } from "../view/stereo";
import { $ } from "./dom";

type Shift = Schema<"Alignment">;
type KeyValueStore = Pick<Storage, "getItem" | "setItem">;
const VIEWER_KEY = "telerobot.viewer";
const ALIGN_KEY = "telerobot.align";
const ARROWS: Record<string, [number, number]> = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, -1], ArrowDown: [0, 1] };

/** This browser's viewer name (made up once, then remembered). */
export function viewerName(storage: KeyValueStore): string {
  const name = storage.getItem(VIEWER_KEY) ?? `viewer-${Math.random().toString(36).slice(2, 8)}`;
  storage.setItem(VIEWER_KEY, name);
  return name;
}

export class Alignment {
  private peer: Promise<VideoPeer | null> = Promise.resolve(null);
  private saved = Promise.resolve();

  private constructor(
    private shift: Shift,
    private readonly remembered: boolean,
    private readonly view: StereoView,
    private readonly api: Api,
    private readonly viewer: string,
    private readonly log: MessageLog,
  ) {
    this.show();
  }

  /** This page's own copy first (the server keeps a bounded table), else the server's. */
  static async load(view: StereoView, api: Api, viewer: string, log: MessageLog): Promise<Alignment> {
    const remembered = localStorage.getItem(ALIGN_KEY);
    const shift: Shift = remembered
      ? (JSON.parse(remembered) as Shift)
      : await api.request("get", "/api/v1/video/alignment", { query: { viewer } }).catch(() => ({ dx: 0, dy: 0 }));
    return new Alignment(shift, remembered !== null, view, api, viewer, log);
  }

  get value(): Shift {
    return this.shift;
  }

  /** Saves go through this page's video peer; a remembered shift is re-sent once it is up. */
  useVideoPeer(peer: Promise<VideoPeer>): void {
    this.peer = peer.catch(() => null);
    if (this.remembered) this.save();
  }

  /** Alt+arrow keys shift the right image by a pixel; true when the key was one. */
  key(code: string, e: { altKey: boolean }): boolean {
    const d = ARROWS[code];
    if (!e.altKey || !d) return false;
    this.shift = { dx: this.shift.dx + d[0], dy: this.shift.dy + d[1] };
    this.show();
    this.save();
    return true;
  }

  private show(): void {
    $("align").textContent = `${this.shift.dx}, ${this.shift.dy}`;
    this.view.setAlignment(this.shift.dx, this.shift.dy);
  }

  /** One PUT at a time, with this page's video peer's secret (the last wins). */
  private save(): void {
    localStorage.setItem(ALIGN_KEY, JSON.stringify(this.shift));
    this.saved = this.saved.then(async () => {
      const peer = await this.peer;
      if (peer) await saveAlignment(this.api, peer, this.viewer, this.shift).catch((e: Error) => this.log.add(`alignment: ${e.message}`, true));
    });
  }
}
