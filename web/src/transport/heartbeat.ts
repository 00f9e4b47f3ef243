// The dead-man heartbeat is sent by the realtime worker, not the page's main thread:
// rendering (a software GPU, a synchronous WebGL call in an XR runtime) can stall the
// main thread for longer than the server's dead-man timeout, and a stalled page must
// not lose its lease for that. The arm still never moves without fresh commands from
// the main thread, and the worker stops beating once the main thread has been silent
// for PAGE_SILENCE_MS (a hung page), so the server's dead-man then stops the arm.
export const HEARTBEAT_PERIOD_MS = 50;
export const PAGE_CHECK_IN_MS = 100;
export const PAGE_SILENCE_MS = 1000;
const MIN_GAP_MS = 40; // any command counts as a heartbeat

export interface HeartbeatInputs {
  now: number; // ms, the worker's clock
  wanted: boolean; // the page holds control or is asking for it
  lastSent: number; // the last heartbeat or command
  pageSeen: number; // the main thread's last check-in
}

export function heartbeatDue(i: HeartbeatInputs): boolean {
  return i.wanted && i.now - i.pageSeen <= PAGE_SILENCE_MS && i.now - i.lastSent >= MIN_GAP_MS;
}
