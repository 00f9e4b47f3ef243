// What every wiring step of the operator page shares (main.ts composes them in order).
import type { Api, MessageLog, ResponseOf } from "../api";
import type { ServerArmReloader } from "../robot/server-arm";
import type { Supervision } from "../ui/autonomy";
import type { HelpOverlay } from "../ui/help";
import type { TasksPanel } from "../ui/tasks";
import type { StereoView } from "../view/stereo";
import type { PageArms } from "./page-arms";

export type Safety = ResponseOf<"get", "/api/v1/safety">;
export type Calibration = ResponseOf<"get", "/api/v1/calibration">;

export interface PageContext {
  readonly api: Api;
  readonly log: MessageLog;
  /** The operator token this page was opened with (never shown, never logged). */
  readonly token: string;
  /** Who this page is to everyone else (the header, the SAFETY events, the recording). */
  readonly pageName: string;
  /** This browser's name for its saved view alignment. */
  readonly viewer: string;
  readonly safety: Safety;
  /** The cameras: calibrated, or the ground truth until then. */
  readonly cell: Calibration;
  readonly arms: PageArms;
  readonly view: StereoView;
  readonly video: HTMLVideoElement;
  /** Who has control, by name: the server's events say when it changes; read again at
   * each new session (events may have been missed while the link was down). */
  controller: string | null;
  /** Handles made by later steps that earlier ones call back into (null until made). */
  readonly late: {
    /** A learned policy's supervision, when one drives. */
    supervision: Supervision | null;
    /** A task this page started holds the lease: not lost. */
    tasks: TasksPanel | null;
    /** The arm drawn, read again at each new session. */
    reloader: ServerArmReloader | null;
    /** The keys' overlay: its arms section follows the server's arms. */
    help: HelpOverlay | null;
  };
}
