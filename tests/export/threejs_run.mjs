// Opens a page in headless Chromium and waits, in real time, for it to write <pre id="result">,
// then prints that element's text to stdout. Talks to Chromium over the DevTools protocol on a pipe
// (--remote-debugging-pipe: JSON messages ended by a NUL byte, fd 3 to the browser, fd 4 back), so
// neither a network port nor Chromium's virtual time (which --dump-dom relies on and which runs out
// while the page still waits for WebGL work) is involved. Console messages and exceptions of the
// page go to stderr. Exits 1 when the page writes nothing within the time limit.
// Usage: node threejs_run.mjs CHROMIUM PAGE.html [SECONDS]
import { spawn } from "node:child_process";
import { mkdtempSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";

const [chromium, page, seconds = "300"] = process.argv.slice(2);
if (!chromium || !page) {
  console.error("usage: node threejs_run.mjs CHROMIUM PAGE.html [SECONDS]");
  process.exit(2);
}
const profile = mkdtempSync(join(tmpdir(), "anisocap_chromium_"));
const browser = spawn(chromium, ["--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
  "--allow-file-access-from-files", "--remote-debugging-pipe", `--user-data-dir=${profile}`, "about:blank"],
  { stdio: ["ignore", "ignore", "ignore", "pipe", "pipe"] });
const toBrowser = browser.stdio[3], fromBrowser = browser.stdio[4];

let nextId = 1;
const pending = new Map();
function send(method, params = {}, sessionId) {
  const id = nextId++;
  toBrowser.write(JSON.stringify({ id, method, params, ...(sessionId ? { sessionId } : {}) }) + "\0");
  return new Promise((ok, fail) => pending.set(id, { ok, fail, method }));
}
let buffered = "";
fromBrowser.on("data", (chunk) => {
  buffered += chunk.toString("utf8");
  let end;
  while ((end = buffered.indexOf("\0")) >= 0) {
    const message = JSON.parse(buffered.slice(0, end));
    buffered = buffered.slice(end + 1);
    if (message.id && pending.has(message.id)) {
      const p = pending.get(message.id);
      pending.delete(message.id);
      message.error ? p.fail(new Error(`${p.method}: ${message.error.message}`)) : p.ok(message.result);
    } else if (message.method === "Runtime.consoleAPICalled") {
      console.error("page console:", message.params.args.map((a) => a.value ?? a.description ?? "").join(" "));
    } else if (message.method === "Runtime.exceptionThrown") {
      const d = message.params.exceptionDetails;
      console.error("page exception:", d.exception?.description ?? d.text);
    }
  }
});

// Removes the profile folder. Chromium's helper processes (crash handler, GPU process) can still
// write into it for a moment after the browser has exited, so rmSync retries a removal that finds
// the folder refilled (ENOTEMPTY), waiting 0.1, 0.2, ... 1 s: about 5 s in all. A folder left
// behind after that is reported, never counted as the page's failure.
function removeProfile() {
  try {
    rmSync(profile, { recursive: true, force: true, maxRetries: 10, retryDelay: 100 });
  } catch (e) {
    console.error(`threejs_run: left ${profile} behind (${e.code ?? e.message})`);
  }
}

function finish(code) {
  const done = () => {
    removeProfile();
    process.exit(code);
  };
  if (browser.exitCode !== null || browser.signalCode !== null) return done();
  browser.once("exit", done);
  browser.kill();
}
const timer = setTimeout(() => {
  console.error(`threejs_run: the page wrote no result within ${seconds} s`);
  finish(1);
}, Number(seconds) * 1000);

try {
  const { targetId } = await send("Target.createTarget", { url: "about:blank" });
  const { sessionId } = await send("Target.attachToTarget", { targetId, flatten: true });
  await send("Runtime.enable", {}, sessionId);
  await send("Page.navigate", { url: "file://" + resolve(page) }, sessionId);
  for (;;) {
    const { result } = await send("Runtime.evaluate",
      { expression: "document.getElementById('result')?.textContent ?? null", returnByValue: true }, sessionId);
    if (typeof result.value === "string") {
      clearTimeout(timer);
      process.stdout.write(result.value, () => finish(0));
      break;
    }
    await new Promise((ok) => setTimeout(ok, 200));
  }
} catch (e) {
  console.error("threejs_run:", e.message);
  finish(1);
}
