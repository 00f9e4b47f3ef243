// Several arms: each arm's joints at the cursor, in a readout under the force plot.
import { $ } from "../ui/dom";
import { jointsLine, type RecordedArm } from "./arms";
import { armStatesAt, type ArmModel, type ArmState, type ReviewContext } from "./recording";

export interface JointsReadoutHandle {
  update(t: number): void;
}

/** The readout: a line per arm, its joints named as the recording names them, else as its model does. */
export function jointsText(arms: readonly RecordedArm[], states: readonly (ArmState | undefined)[], models: readonly (Pick<ArmModel, "joint_names"> | null)[]): string {
  return arms.map((a, k) => jointsLine(a.name, states[k]?.joints, a.jointNames.length ? a.jointNames : (models[k]?.joint_names ?? []))).join("\n");
}

export function setupJointsReadout({ recording }: ReviewContext): JointsReadoutHandle {
  const readout = document.createElement("pre");
  readout.id = "review-joints";
  readout.hidden = !recording.several;
  $("review-force").after(readout);
  return {
    update(t) {
      if (!recording.several) return;
      const text = jointsText(recording.arms, armStatesAt(recording, t), recording.models);
      if (readout.textContent !== text) readout.textContent = text;
    },
  };
}
