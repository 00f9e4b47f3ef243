// Repeating a recorded episode as a task, its path shown in both eyes before it runs
// (Run and Approach need the lease: none is known to be held while the link is down);
// and the arm drawn following the server's, read again at each new session (a restart
// with another model redraws the labels, the ghost, the ball and the axes for the new arm).
import { PathOverlay } from "../ar/path";
import type { InputLoop } from "../input/loop";
import { readServerArms } from "../robot/arms";
import { ServerArmReloader, type ServerArm } from "../robot/server-arm";
import type { RealtimeLink } from "../transport/link";
import { $ } from "../ui/dom";
import { TasksPanel } from "../ui/tasks";
import type { PageContext } from "./context";
import { driveArms } from "./page-arms";

export interface TasksHandle {
  tasks: TasksPanel;
  /** The path of the episode previewed or run, in both eyes. */
  path: PathOverlay;
  reloader: ServerArmReloader;
}

export function setupTasks(ctx: PageContext, link: RealtimeLink, loop: InputLoop, served: ServerArm): TasksHandle {
  const { api, log, arms, view } = ctx;
  const path = new PathOverlay(ctx.cell.cameras, view);
  const tasks = new TasksPanel($("tasks"), {
    api,
    log,
    link,
    flags: () => (link.open ? (arms.combined?.flags ?? 0) : 0),
    path,
    arms: () => arms.list.map((a) => a.entry.name),
  });
  ctx.late.tasks = tasks;
  void tasks.load();
  const readArm = async (): Promise<ServerArm> => {
    const [entries, c] = await Promise.all([readServerArms(api), api.request("get", "/api/v1/calibration")]);
    return { cameras: c.cameras, arms: entries };
  };
  const reloader = new ServerArmReloader(
    served,
    readArm,
    (next) => {
      arms.replace(next.arms, next.cameras);
      view.setBallCount(arms.list.length);
      loop.setArms(driveArms(arms.list)); // the axis marker follows (onArmChange)
      view.overlayChanged();
      path.setCameras(next.cameras);
      ctx.late.help?.setArms(arms.list.map((a) => a.entry.name)); // the keys' overlay too
      void tasks.load(); // which recordings this arm can repeat
    },
    log,
  );
  ctx.late.reloader = reloader;
  return { tasks, path, reloader };
}
