// The fiducials table: their 3D positions (m, robot base), editable, in clicking order;
// the row to click next is highlighted.
import type { Vec3 } from "../../robot/math";
import { $ } from "../dom";

export function fillFiducials(fiducials: number[][]): void {
  $<HTMLTableElement>("fiducials").innerHTML =
    `<tr><th>#</th><th>x</th><th>y</th><th>z</th></tr>` +
    fiducials
      .map((p, i) => `<tr id="row${i}"><td>${i + 1}</td>${p.map((v, k) => `<td><input id="f${i}-${k}" type="number" step="0.001" value="${v}"></td>`).join("")}</tr>`)
      .join("");
}

/** The positions as edited now. */
export function readFiducials(count: number): Vec3[] {
  return Array.from({ length: count }, (_, i) => [0, 1, 2].map((k) => Number($<HTMLInputElement>(`f${i}-${k}`).value)) as Vec3);
}

/** Highlight row `active` (none: null). */
export function markRow(count: number, active: number | null): void {
  for (let i = 0; i < count; i++) $(`row${i}`).classList.toggle("active", i === active);
}
