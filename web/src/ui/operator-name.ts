// The name this page gives itself: who has control is said by name
// wherever control is listed — the header here and on every other page, the SAFETY
// event, GET /api/v1/safety, the recording — not "ws 127.0.0.1:51186". Typed once in
// the Driving panel and kept in localStorage; by default "browser on <platform>". It
// goes in the /ws URL (?name=…): the HELLO stays as it is. The server's rule
// (telerobot/protocol/names.py) is checked here first, so the page never connects with a
// name the server would refuse (it would close the connection, again and again).

export const NAME_KEY = "telerobot.name";
export const MAX_NAME = 64;
/** Besides letters and digits (any script). Not ( ) ;: the page reads "control: NAME (why)". */
const PUNCTUATION = " .,:_-@#+/'";
const LETTER_OR_DIGIT = /^[\p{L}\p{N}]$/u;
export const NAME_RULE = `1–${MAX_NAME} characters: letters, digits, spaces and . , : _ - @ # + / ' (no brackets, quotes or control characters)`;

const allowed = (c: string): boolean => PUNCTUATION.includes(c) || LETTER_OR_DIGIT.test(c);

/** Why `name` (trimmed) cannot be this page's name; "" if it can. */
export function nameProblem(name: string): string {
  const chars = [...name];
  if (chars.length === 0) return `a name is ${NAME_RULE}: this one is empty`;
  if (chars.length > MAX_NAME) return `a name is ${NAME_RULE}: this one has ${chars.length} characters`;
  const bad = [...new Set(chars.filter((c) => !allowed(c)))];
  if (bad.length > 0) return `a name is ${NAME_RULE}: this one has ${bad.slice(0, 5).map((c) => JSON.stringify(c)).join(", ")}`;
  return "";
}

/** The name a page has until its operator types one: "browser on Linux x86_64". */
export function defaultName(platform: string): string {
  const plain = [...platform]
    .map((c) => (allowed(c) ? c : " "))
    .join("")
    .replace(/ +/g, " ")
    .trim();
  return [...`browser on ${plain || "an unknown platform"}`].slice(0, MAX_NAME).join("").trim();
}

/** This page's name: the one kept (if it is still a name), else the default. */
export function readName(storage: Pick<Storage, "getItem">, platform: string): string {
  const kept = storage.getItem(NAME_KEY)?.trim() ?? "";
  return kept && !nameProblem(kept) ? kept : defaultName(platform);
}

/** The realtime channel's URL with this page's name. */
export function namedUrl(url: string, name: string): string {
  return `${url}${url.includes("?") ? "&" : "?"}name=${encodeURIComponent(name)}`;
}

/** Who has control, from a server event: "control: NAME (why); …" → NAME, "control:
 * nobody…" → null; undefined when the event does not say who has control. */
export function controllerIn(text: string): string | null | undefined {
  const m = /^control: ([^(;]*)/.exec(text);
  if (!m) return undefined;
  const name = m[1]!.trim();
  return name === "nobody" ? null : name;
}

/** What the name field does with what was typed: keep it (or, empty, go back to the
 * default) and say so, or say why it is no name. `current`: the name this connection has. */
export function nameEdit(typed: string, current: string, platform: string): { save: string | null; forget: boolean; text: string; error: boolean } {
  const name = typed.trim();
  const next = name || defaultName(platform);
  const later = next === current ? "" : `Kept: this page is "${next}" from its next connection (reload the page to use it now)`;
  if (!name) return { save: null, forget: true, text: later, error: false };
  const problem = nameProblem(name);
  if (problem) return { save: null, forget: false, text: `Not kept: ${problem}`, error: true };
  return { save: name, forget: false, text: later, error: false };
}

/** The Driving panel's name field: shows this page's name, keeps what is typed. */
export function setupNameField(input: HTMLInputElement, hint: HTMLElement, storage: Pick<Storage, "setItem" | "removeItem">, current: string, platform: string): void {
  input.value = current;
  input.maxLength = MAX_NAME;
  input.title = `Who has control is shown by this name to everyone (${NAME_RULE})`;
  input.onchange = () => {
    const edit = nameEdit(input.value, current, platform);
    if (edit.save !== null) storage.setItem(NAME_KEY, edit.save);
    if (edit.forget) {
      storage.removeItem(NAME_KEY);
      input.value = defaultName(platform);
    }
    hint.textContent = edit.text;
    hint.classList.toggle("error", edit.error);
  };
}
