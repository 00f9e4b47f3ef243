// The review page's recording picker: the server's recordings in a list, the one under
// review selected; picking another opens it (?id=).
import { $ } from "../ui/dom";

/** Fills the picker from GET /api/v1/recordings (not awaited: the page works without it). */
export async function setupRecordingPick(recordingId: string): Promise<void> {
  const pick = $<HTMLSelectElement>("review-pick");
  try {
    const response = await fetch(`${location.origin}/api/v1/recordings`, { cache: "no-store" });
    const list = (await response.json()) as { file: string; name?: string; active?: boolean }[] | { recordings?: { file: string }[] };
    const items = Array.isArray(list) ? list : (list.recordings ?? []);
    for (const r of items) {
      const o = document.createElement("option");
      o.value = r.file;
      o.textContent = r.file;
      o.selected = r.file === recordingId || r.file.replace(/\.mcap$/, "") === recordingId;
      pick.append(o);
    }
    pick.hidden = pick.options.length === 0; // no recordings: no empty list
  } catch {
    /* the list is a convenience: ?id= works without it */
  }
  pick.onchange = () => (location.search = `?id=${encodeURIComponent(pick.value)}`);
}
