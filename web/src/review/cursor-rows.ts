// A list in time order whose rows after the review's cursor are greyed ("future"): the
// command log and the event list. Redone only when the cursor passes a row, not on every
// frame.
import { latestAt } from "./timeline";

/** A row of such a list: an <li>, or anything with its class list. */
export interface GreyableRow {
  classList: Pick<DOMTokenList, "toggle">;
}

export class CursorRows {
  private shown = -2; // none yet: the first update greys

  /** `times[i]` is when `rows[i]` happened (sorted by time). */
  constructor(
    private readonly times: readonly { time: number }[],
    private readonly rows: readonly GreyableRow[],
  ) {}

  /** Rows were added (the timeline's next piece): the next update greys them all again. */
  again(): void {
    this.shown = -2;
  }

  /** Greys the rows after timeline time t. The row at t (-1: before the first) if that
   * changed, else null. */
  update(t: number): number | null {
    const last = latestAt(this.times, t);
    if (last === this.shown) return null;
    this.rows.forEach((r, i) => r.classList.toggle("future", i > last));
    this.shown = last;
    return last;
  }
}
