// Compute: each camera's fit from its clicks, drawn over its image, and the figures
// to judge it by (residuals, the stereo baseline) in the results table.
import type { Api, Schema } from "../../api";
import type { Vec3 } from "../../robot/math";
import { $ } from "../dom";
import { CAMERAS, type Clicks, type Method } from "./clicks";
import type { FrozenImages } from "./images";

export type CalibrationState = Schema<"CalibrationState">;
type CameraCalibration = Schema<"CameraCalibration">;

export function resultRows(model: CameraCalibration): string[] {
  return [
    `<tr><td>${model.name}</td><td>${model.method}</td><td>rms ${model.rms_px?.toFixed(2)} px</td><td>max ${model.max_px?.toFixed(2)} px</td></tr>`,
    `<tr><td colspan="4" class="hint">${model.residuals_px.map((r, i) => `${i + 1}: ${r.toFixed(2)}`).join(" · ")}</td></tr>`,
  ];
}

/** Fit both cameras in turn; `update` gets the server's state after each. */
export async function fitBoth(
  api: Api,
  clicks: Clicks,
  method: Method,
  fiducials: Vec3[],
  images: FrozenImages,
  update: (state: CalibrationState) => void,
): Promise<void> {
  const rows: string[] = [];
  let state: CalibrationState | null = null;
  for (const cam of CAMERAS) {
    const pixels = clicks.byCamera[cam];
    state = await api.request("post", "/api/v1/calibration/fit", { body: { camera: cam, method, points: fiducials.slice(0, pixels.length), pixels } });
    update(state);
    const model = state.cameras.find((c) => c.name === cam)!;
    images.draw(cam, { P: model.P, fiducials });
    rows.push(...resultRows(model));
  }
  if (state?.baseline_m != null) rows.push(`<tr><td colspan="4">stereo baseline ${(state.baseline_m * 1000).toFixed(1)} mm</td></tr>`);
  $("results").innerHTML = rows.join("");
}
