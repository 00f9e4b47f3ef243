import { describe, expect, it } from "vitest";
import { NAME_KEY, controllerIn, defaultName, nameEdit, nameProblem, namedUrl, readName } from "./ui/operator-name";

// A page names itself: it was "ws 127.0.0.1:51186" everywhere.
const store = (kept: string | null) => ({ getItem: (k: string) => (k === NAME_KEY ? kept : null) });

describe("the page's name", () => {
  it("is 'browser on <platform>' until one is typed, kept plain", () => {
    expect(defaultName("Linux x86_64")).toBe("browser on Linux x86_64");
    expect(defaultName("MacIntel")).toBe("browser on MacIntel");
    expect(defaultName("")).toBe("browser on an unknown platform");
    expect(defaultName("Weird (v2); <x>")).toBe("browser on Weird v2 x");
    expect(defaultName("x".repeat(100))).toHaveLength(64);
    for (const p of ["Linux x86_64", "", "Weird (v2); <x>", "x".repeat(100)]) expect(nameProblem(defaultName(p))).toBe("");
    expect(readName(store(null), "Win32")).toBe("browser on Win32");
  });

  it("is the one kept, if it is still a name", () => {
    expect(readName(store("  Ana at the bench "), "Linux x86_64")).toBe("Ana at the bench");
    expect(readName(store("a;b"), "Linux x86_64")).toBe("browser on Linux x86_64");
    expect(readName(store(""), "Linux x86_64")).toBe("browser on Linux x86_64");
  });

  it("follows the server's rule (telerobot/protocol/names.py): letters and digits of any script, a little punctuation", () => {
    for (const ok of ["Ana", "Ana's arm-bench #2: Zoë/Jürgen @ lab.4", "操作员 1", "x".repeat(64), "a_b,c+d"]) expect(nameProblem(ok)).toBe("");
    expect(nameProblem("")).toMatch(/this one is empty$/);
    expect(nameProblem("x".repeat(65))).toMatch(/this one has 65 characters$/);
    // Not ( ) ; (the page reads "control: NAME (why)"), quotes, brackets, control characters.
    for (const bad of ["alice (bench)", "a;b", "<script>", 'say "hi"', "two\nlines", "tab\there", "nul\u0000"]) {
      expect(nameProblem(bad)).toMatch(/^a name is 1–64 characters: letters, digits, spaces/);
    }
  });

  it("goes in the /ws URL (the HELLO stays as it is)", () => {
    expect(namedUrl("ws://h:8000/ws", "Ana at the bench")).toBe("ws://h:8000/ws?name=Ana%20at%20the%20bench");
    expect(namedUrl("ws://h/ws?x=1", "Zoë/1")).toBe("ws://h/ws?x=1&name=Zo%C3%AB%2F1");
  });

  it("is kept when typed, or said why not; empty goes back to the default", () => {
    expect(nameEdit(" Ana ", "browser on Linux x86_64", "Linux x86_64")).toEqual({ save: "Ana", forget: false, text: 'Kept: this page is "Ana" from its next connection (reload the page to use it now)', error: false });
    expect(nameEdit("Ana", "Ana", "Linux x86_64")).toEqual({ save: "Ana", forget: false, text: "", error: false });
    expect(nameEdit("a;b", "Ana", "Linux x86_64")).toMatchObject({ save: null, forget: false, error: true, text: expect.stringMatching(/^Not kept: a name is/) });
    expect(nameEdit("  ", "Ana", "Linux x86_64")).toMatchObject({ save: null, forget: true, error: false, text: expect.stringContaining('"browser on Linux x86_64"') });
  });
});

describe("who has control, from the server's events", () => {
  it("reads the name of 'control: NAME (why); …'", () => {
    expect(controllerIn("control: Ana at the bench (taken by 'Ana at the bench')")).toBe("Ana at the bench");
    expect(controllerIn("control: ws 127.0.0.1:51186; E-STOP: pressed")).toBe("ws 127.0.0.1:51186");
    expect(controllerIn("control: task 3")).toBe("task 3");
    expect(controllerIn("control: nobody (released)")).toBeNull();
    expect(controllerIn("RECORDING started: x.mcap")).toBeUndefined();
    expect(controllerIn("READY: initialised")).toBeUndefined();
  });
});
