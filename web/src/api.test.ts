import { describe, expect, expectTypeOf, it, vi } from "vitest";
import { Api, ApiError, LOG_LIMIT, MessageLog, TOKEN_KEY, TOKEN_NEEDED, TRY_KEY, buildRequest, errorText, readToken, saveToken, tokenVerdict, withoutToken, type LogList, type ResponseOf, type Schema } from "./api";

function memoryStorage(init: Record<string, string> = {}) {
  const data = new Map(Object.entries(init));
  return { getItem: (k: string) => data.get(k) ?? null, setItem: (k: string, v: string) => void data.set(k, v), data };
}
const problem = (status: number, code: string, detail: string) => ({ type: `urn:telerobot:error:${code}`, title: code, status, detail });
const json = (body: unknown, status = 200) => new Response(JSON.stringify(body), { status, headers: { "Content-Type": "application/json" } });

describe("the operator token", () => {
  it("comes from ?token=, else from the token field once, else from what was remembered, else is empty", () => {
    const storage = memoryStorage();
    const session = { ...memoryStorage(), removeItem(k: string) { this.data.delete(k); } };
    expect(readToken("", storage, session)).toBe("");
    expect(readToken("?token=secret-1&x=1", storage, session)).toBe("secret-1");
    expect(storage.data.get(TOKEN_KEY)).toBeUndefined(); // not remembered until the server accepts it
    saveToken(storage, "secret-1");
    expect(readToken("?x=1", storage, session)).toBe("secret-1");
    expect(readToken("?token=", storage, session)).toBe("secret-1"); // an empty one changes nothing
    session.setItem(TRY_KEY, "typed");
    expect(readToken("", storage, session)).toBe("typed");
    expect(readToken("", storage, session)).toBe("secret-1"); // tried once
  });
  it("leaves the address once read", () => {
    expect(withoutToken("http://robot:8000/?token=abc&mode=x#h")).toBe("http://robot:8000/?mode=x#h");
    expect(withoutToken("http://robot:8000/?token=abc")).toBe("http://robot:8000/");
  });
  it("is said to be rejected when the server makes the page an observer, and says where one comes from", () => {
    expect(tokenVerdict("good", true, null)).toBeNull();
    expect(tokenVerdict("", false, null)).toBeNull(); // no token: an observer, as asked
    const said = tokenVerdict("wrong", false, "good") ?? "";
    expect(said).toMatch(/^Token rejected/);
    expect(said).toContain("remembered token was kept");
    expect(said).toContain("telerobot serve");
    expect(tokenVerdict("wrong", false, "wrong")).not.toContain("remembered");
  });
});

describe("REST requests", () => {
  it("are JSON, carry the token when there is one, and fill the path and the query", () => {
    const { url, init } = buildRequest("http://robot:8000/", "tok", "put", "/api/v1/video/alignment", {
      query: { viewer: "a b", skip: undefined, none: null },
      body: { dx: 1, dy: -2 },
      headers: { "X-Peer-Id": "p1" },
    });
    expect(url).toBe("http://robot:8000/api/v1/video/alignment?viewer=a+b");
    expect(init.method).toBe("PUT");
    expect(init.headers).toEqual({ "Content-Type": "application/json", Authorization: "Bearer tok", "X-Peer-Id": "p1" });
    expect(init.body).toBe('{"dx":1,"dy":-2}');
    expect(init.keepalive).toBeUndefined();

    const del = buildRequest("http://robot:8000/", "", "delete", "/api/v1/webrtc/{peer_id}", { params: { peer_id: "a/b" }, keepalive: true });
    expect(del.url).toBe("http://robot:8000/api/v1/webrtc/a%2Fb");
    expect(del.init.headers).toEqual({ "Content-Type": "application/json" }); // no token: no Authorization
    expect(del.init.body).toBeUndefined();
    expect(del.init.keepalive).toBe(true);
    expect(() => buildRequest("http://robot/", "", "delete", "/api/v1/webrtc/{peer_id}")).toThrow("no value for {peer_id}");
  });

  it("say what went wrong in the server's words", () => {
    expect(errorText(409, problem(409, "safety_stop", "the e-stop is latched: reset it"), "POST /x", true)).toBe("the e-stop is latched: reset it");
    // No token on this page: how to give it one.
    expect(errorText(403, problem(403, "not_allowed", "this needs the operator token"), "POST /x", false)).toBe(TOKEN_NEEDED);
    expect(errorText(403, problem(403, "not_allowed", "this needs the operator token"), "POST /x", true)).toBe("this needs the operator token");
    expect(errorText(403, problem(403, "not_your_peer", "not your peer"), "PUT /x", false)).toBe("not your peer");
    expect(errorText(422, { detail: [{ msg: "field required" }, { msg: "too long" }] }, "POST /x", true)).toBe("field required; too long");
    expect(errorText(502, undefined, "GET /api/v1/safety", false)).toBe("GET /api/v1/safety: HTTP 502");
    expect(errorText(500, "<html>", "GET /y", false)).toBe("GET /y: HTTP 500");
  });

  it("answer the JSON, or throw an ApiError with the problem", async () => {
    const fetcher = vi.fn(async (url: string, init: RequestInit) => {
      if (url.endsWith("/api/v1/viewer")) return json({ port: 8080, error: null });
      expect(init.body).toBe('{"view":3}');
      return json(problem(409, "not_ready", "the robot is not ready"), 409);
    });
    const api = new Api("http://robot/", "", fetcher);
    expect(await api.request("get", "/api/v1/viewer")).toEqual({ port: 8080, error: null });
    const failed = api.request("post", "/api/v1/calibration/board", { body: { view: 3 } });
    await expect(failed).rejects.toThrow("the robot is not ready");
    await expect(failed).rejects.toBeInstanceOf(ApiError);
    await expect(failed).rejects.toMatchObject({ status: 409 });
    const notJson = new Api("http://robot/", "", async () => new Response("bad gateway", { status: 502 }));
    await expect(notJson.request("get", "/api/v1/safety")).rejects.toThrow("GET /api/v1/safety: HTTP 502");
  });

  it("are typed by the OpenAPI schema", () => {
    expectTypeOf<ResponseOf<"get", "/api/v1/calibration">>().toEqualTypeOf<Schema<"CalibrationState">>();
    expectTypeOf<ResponseOf<"post", "/api/v1/lease">>().toEqualTypeOf<Schema<"LeaseGranted">>();
    expectTypeOf<Schema<"RobotStatus">>().toEqualTypeOf<"NOT_CONNECTED" | "CONNECTED" | "WAITING" | "READY" | "MOVING" | "ERROR">();
    const api = new Api("http://robot/", "", async () => json({}));
    // @ts-expect-error: a body is required
    void api.request("post", "/api/v1/calibration/fit").catch(() => undefined);
    // @ts-expect-error: no such field in BoardRequest
    void api.request("post", "/api/v1/calibration/board", { body: { pose: 1 } }).catch(() => undefined);
    // @ts-expect-error: no such path
    void api.request("get", "/api/v1/nowhere").catch(() => undefined);
  });
});

describe("the message log", () => {
  function fakeList() {
    const items: { textContent: string; style: { color: string }; remove(): void }[] = [];
    const list = {
      ownerDocument: {
        createElement: () => {
          const li = { textContent: "", style: { color: "" }, remove: () => void items.splice(items.indexOf(li), 1) };
          return li;
        },
      },
      prepend: (li: (typeof items)[number]) => void items.unshift(li),
      get childElementCount() {
        return items.length;
      },
      get lastElementChild() {
        return items[items.length - 1] ?? null;
      },
    };
    return { items, list: list as unknown as LogList };
  }

  it("keeps the newest lines, at most its limit, here and on the page", () => {
    const { items, list } = fakeList();
    const log = new MessageLog(list, 3, () => new Date(2020, 0, 1, 12, 0, 0));
    for (let i = 1; i <= 5; i++) log.add(`line ${i}`, i === 5);
    expect(log.entries.map((e) => e.text)).toEqual(["line 5", "line 4", "line 3"]);
    const time = new Date(2020, 0, 1, 12, 0, 0).toLocaleTimeString();
    expect(items.map((li) => li.textContent)).toEqual([`${time} line 5`, `${time} line 4`, `${time} line 3`]);
    expect(items[0]!.style.color).toBe("#f88"); // an error
    expect(items[1]!.style.color).toBe("");
    expect(new MessageLog(null).limit).toBe(LOG_LIMIT);
  });

  it("folds a message repeated in a row into one line with a count", () => {
    const { items, list } = fakeList();
    const log = new MessageLog(list, 3, () => new Date(2020, 0, 1, 12, 0, 0));
    log.add("first");
    for (let i = 0; i < 11; i++) log.add("E-STOP: e-stop pressed", true);
    log.add("E-STOP: e-stop pressed"); // the same words said as news: the same line, its colour now
    expect(log.entries.map((e) => [e.text, e.count, e.error])).toEqual([
      ["E-STOP: e-stop pressed", 12, false],
      ["first", 1, false],
    ]);
    const time = new Date(2020, 0, 1, 12, 0, 0).toLocaleTimeString();
    expect(items.map((li) => li.textContent)).toEqual([`${time} E-STOP: e-stop pressed ×12`, `${time} first`]);
    expect(items[0]!.style.color).toBe("");
  });

  it("folds a message that comes back among the newest lines, and moves it to the top", () => {
    const { items, list } = fakeList();
    const log = new MessageLog(list, 10, () => new Date(2020, 0, 1, 12, 0, 0));
    for (let i = 0; i < 3; i++) {
      log.add("link lost: reconnecting", true);
      log.add("link back");
    }
    log.add("something else");
    log.add("video: no video", false);
    log.add("video: no video", true); // one thing said by two layers
    const time = new Date(2020, 0, 1, 12, 0, 0).toLocaleTimeString();
    expect(items.map((li) => li.textContent)).toEqual([
      `${time} video: no video ×2`,
      `${time} something else`,
      `${time} link back ×3`,
      `${time} link lost: reconnecting ×3`,
    ]);
    expect(items[0]!.style.color).toBe("#f88");
    // Beyond the window a message is news again: its own line
    for (const t of ["a", "b", "c"]) log.add(t);
    log.add("something else");
    expect(items.filter((li) => li.textContent.endsWith("something else"))).toHaveLength(2);
  });
});
