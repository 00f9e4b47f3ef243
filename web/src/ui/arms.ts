// Two arms or more: each arm's colours (its AR ball's and its ghost's; the first keeps a
// one-arm page's), and the header's chip for each arm — its name in its ghost's colour,
// a ring in its ball's, its status and its contact force — the arm the keys drive
// outlined, the arms driven now filled. A click on a chip selects that arm for the keys.
// Hidden on a one-arm server: that page looks as it always has.
import { GHOST_RGB } from "../ar/ghost";
import { StateFlags } from "../transport/messages";

export interface ArmStyle {
  /** The AR ball's colour; null: the View panel's (the first arm's). */
  ball: string | null;
  ghost: readonly [number, number, number];
}

/** By the arm's place in the server's list: the first as a one-arm page draws it. */
export const ARM_STYLES: readonly ArmStyle[] = [
  { ball: null, ghost: GHOST_RGB },
  { ball: "#ffd400", ghost: [255, 128, 0] },
  { ball: "#40c0ff", ghost: [150, 255, 60] },
  { ball: "#ffffff", ghost: [255, 90, 90] },
];

export function armStyle(i: number): ArmStyle {
  return ARM_STYLES[i % ARM_STYLES.length]!;
}

/** `#rrggbb` at `factor` of its brightness (an arm not driven now: its ball fainter). */
export function dimmed(hex: string, factor: number): string {
  const m = /^#([0-9a-f]{6})$/i.exec(hex);
  if (!m) return hex;
  const v = parseInt(m[1]!, 16);
  const c = [v >> 16, (v >> 8) & 255, v & 255].map((x) => Math.round(x * factor));
  return `#${c.map((x) => x.toString(16).padStart(2, "0")).join("")}`;
}

export interface ArmChipInput {
  name: string;
  /** Its latest STATE (null: none yet). */
  state: { status: string; flags: number } | null;
  /** Its contact force's magnitude (N); null: no sample yet. */
  forceN: number | null;
  /** The keys drive it. */
  selected: boolean;
  /** A dead-man or a grip is held for it now. */
  driven: boolean;
}

export interface ArmChip {
  name: string;
  /** Its status and its force: "READY 1.2 N". */
  detail: string;
  /** Space-separated classes: arm-chip, selected, driven, over (force limited), error. */
  cls: string;
  title: string;
  /** CSS colours: the name's (the ghost's) and the ring's (the ball's). */
  nameColour: string;
  ringColour: string;
}

/** Each arm's chip (pure: tested in arms.test.ts). `ball`: the first arm's ball colour. */
export function armChips(arms: readonly ArmChipInput[], forceLimitN: number, ball: string): ArmChip[] {
  return arms.map((a, i) => {
    const style = armStyle(i);
    const limited = ((a.state?.flags ?? 0) & StateFlags.FORCE_LIMITED) !== 0;
    const status = limited ? "FORCE LIMIT" : (a.state?.status ?? "…");
    const force = a.forceN === null || !Number.isFinite(a.forceN) ? "— N" : `${a.forceN.toFixed(1)} N`;
    const cls = ["arm-chip", a.selected ? "selected" : "", a.driven ? "driven" : "", limited ? "over" : "", a.state?.status === "ERROR" ? "error" : ""].filter(Boolean).join(" ");
    const share = a.forceN !== null && forceLimitN > 0 ? ` (${Math.round((100 * a.forceN) / forceLimitN)} % of the ${forceLimitN.toFixed(0)} N limit)` : "";
    const title =
      `${a.name}: ${status}, contact force ${force}${share}` +
      (a.selected ? "; the keys drive it" : "; click (or [ / ]) to drive it with the keys") +
      (a.driven ? "; driven now" : "");
    const [r, g, b] = style.ghost;
    return { name: a.name, detail: `${status} ${force}`, cls, title, nameColour: `rgb(${r}, ${g}, ${b})`, ringColour: style.ball ?? ball };
  });
}

/** The header's chips, in `box` (hidden with fewer than two arms). */
export class ArmChipsView {
  private shown = "";

  constructor(
    private readonly box: HTMLElement,
    /** A chip was clicked: select that arm (its index). */
    private readonly select: (i: number) => void,
  ) {}

  show(chips: readonly ArmChip[]): void {
    const key = JSON.stringify(chips);
    if (key === this.shown) return; // redrawn only when something changed
    this.shown = key;
    this.box.hidden = chips.length < 2;
    this.box.replaceChildren(
      ...chips.map((c, i) => {
        const el = document.createElement("button");
        el.type = "button";
        el.className = c.cls;
        el.title = c.title;
        el.dataset.arm = String(i);
        const ring = document.createElement("span");
        ring.className = "ring";
        ring.style.borderColor = c.ringColour;
        const label = document.createElement("span");
        label.className = "name";
        label.style.color = c.nameColour;
        label.textContent = c.name;
        el.append(ring, label, ` ${c.detail}`);
        el.onclick = () => this.select(i);
        return el;
      }),
    );
  }
}
