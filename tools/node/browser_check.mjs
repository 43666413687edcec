// Opens a panoman viewer page in headless Chromium over the Chrome DevTools Protocol and checks
// it: no console errors or exceptions, a non-blank canvas, and that moving the frame slider
// changes the rendered image. Saves a screenshot.
// Usage: node --experimental-websocket browser_check.mjs VIEW.html SHOT.png [FRAME]
// (node >= 22 has WebSocket without the flag). Chromium: $CHROMIUM, else `chromium`.
// Prints one JSON line with the measurements; exit 1 if a check fails, 2 on a setup problem.
import { spawn } from 'node:child_process';
import { mkdtempSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join, resolve } from 'node:path';
import { pathToFileURL } from 'node:url';

const [page, shot, frameArg] = process.argv.slice(2);
if (!page || !shot) {
  console.error('usage: node --experimental-websocket browser_check.mjs VIEW.html SHOT.png [FRAME]');
  process.exit(2);
}
if (typeof WebSocket === 'undefined') {
  console.error('no global WebSocket: run node >= 22 or pass --experimental-websocket');
  process.exit(2);
}
const W = 960, H = 720;
const profile = mkdtempSync(join(tmpdir(), 'panoman-chromium-'));
const browser = spawn(process.env.CHROMIUM || 'chromium', [
  '--headless=new', '--no-sandbox', '--no-first-run', '--no-default-browser-check',
  '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist',
  '--disable-background-timer-throttling', '--disable-renderer-backgrounding',
  `--window-size=${W},${H}`, `--user-data-dir=${profile}`, '--remote-debugging-port=0', 'about:blank',
], { stdio: ['ignore', 'ignore', 'pipe'] });
let stderr = '';
const fail = (code, msg) => {
  console.error(msg);
  try { browser.kill('SIGKILL'); } catch {}
  try { rmSync(profile, { recursive: true, force: true }); } catch {}
  process.exit(code);
};
browser.on('error', (e) => fail(2, `cannot start chromium: ${e.message}`));
const guard = setTimeout(() => fail(2, `browser check did not finish in 180 s; chromium stderr:\n${stderr.slice(-4000)}`), 180000);

const wsUrl = await new Promise((res) => {
  browser.stderr.on('data', (d) => {
    stderr += d;
    const m = /DevTools listening on (ws:\/\/\S+)/.exec(stderr);
    if (m) res(m[1]);
  });
});
const ws = new WebSocket(wsUrl);
await new Promise((res, rej) => { ws.onopen = res; ws.onerror = () => rej(new Error('websocket')); });
let nextId = 1;
const pending = new Map();
const problems = [];
ws.onmessage = (ev) => {
  const m = JSON.parse(ev.data);
  if (m.id && pending.has(m.id)) {
    const { res, rej } = pending.get(m.id);
    pending.delete(m.id);
    m.error ? rej(new Error(JSON.stringify(m.error))) : res(m.result);
  } else if (m.method === 'Runtime.consoleAPICalled' && (m.params.type === 'error' || m.params.type === 'assert')) {
    problems.push('console.error: ' + m.params.args.map((a) => a.value ?? a.description ?? '').join(' '));
  } else if (m.method === 'Runtime.exceptionThrown') {
    const d = m.params.exceptionDetails;
    problems.push('exception: ' + (d.exception?.description || d.text));
  } else if (m.method === 'Log.entryAdded' && m.params.entry.level === 'error') {
    problems.push('log error: ' + m.params.entry.text + (m.params.entry.url ? ` (${m.params.entry.url})` : ''));
  }
};
const send = (method, params = {}, sessionId) => new Promise((res, rej) => {
  const id = nextId++;
  pending.set(id, { res, rej });
  ws.send(JSON.stringify({ id, method, params, ...(sessionId ? { sessionId } : {}) }));
});

const { targetId } = await send('Target.createTarget', { url: 'about:blank' });
const { sessionId } = await send('Target.attachToTarget', { targetId, flatten: true });
const s = (method, params) => send(method, params, sessionId);
await s('Runtime.enable');
await s('Log.enable');
await s('Page.enable');
await s('Emulation.setDeviceMetricsOverride', { width: W, height: H, deviceScaleFactor: 1, mobile: false });
await s('Page.navigate', { url: pathToFileURL(resolve(page)).href });
const evaluate = async (expression) => {
  const r = await s('Runtime.evaluate', { expression, returnByValue: true, awaitPromise: true });
  if (r.exceptionDetails) throw new Error(`${expression}: ${r.exceptionDetails.exception?.description || r.exceptionDetails.text}`);
  return r.result.value;
};
let state = null;
for (let i = 0; i < 600; i++) {
  state = await evaluate('window.panomanViewer ? {ready: window.panomanViewer.ready, error: window.panomanViewer.error, n: window.panomanViewer.nFrames} : null');
  if (state && (state.ready || state.error)) break;
  await new Promise((r) => setTimeout(r, 200));
}
if (!state || !state.ready) fail(1, `viewer not ready: ${JSON.stringify(state)}; ${problems.join('; ')}`);

const decode = (p) => Buffer.from(p.data, 'base64');
const grab = async (f) => {
  await evaluate(`window.panomanViewer.setFrame(${f})`);
  return evaluate('window.panomanViewer.pixels()');
};
const n = state.n;
const mid = frameArg !== undefined ? Number(frameArg) : Math.floor(n / 2);
const a = await grab(0);
const b = await grab(n > 1 ? mid : 0);
const pa = decode(a), pb = decode(b);
const bg = [pa[0], pa[1], pa[2]]; // a corner pixel is background
let filled = 0, changed = 0;
const total = a.width * a.height;
for (let i = 0; i < pa.length; i += 4) {
  if (Math.abs(pa[i] - bg[0]) + Math.abs(pa[i + 1] - bg[1]) + Math.abs(pa[i + 2] - bg[2]) > 24) filled++;
  if (Math.abs(pa[i] - pb[i]) + Math.abs(pa[i + 1] - pb[i + 1]) + Math.abs(pa[i + 2] - pb[i + 2]) > 24) changed++;
}
// The keypoint toggle: hiding the markers must change the image when there are markers.
const hasMarkers = await evaluate("!document.getElementById('markersBox').classList.contains('hidden')");
let markerToggleChangedFraction = null;
if (hasMarkers) {
  await evaluate('window.panomanViewer.setMarkers(false)');
  const pc = decode(await evaluate('window.panomanViewer.pixels()'));
  await evaluate('window.panomanViewer.setMarkers(true)');
  const pd = decode(await evaluate('window.panomanViewer.pixels()'));
  let m = 0;
  for (let i = 0; i < pc.length; i += 4) {
    if (Math.abs(pc[i] - pd[i]) + Math.abs(pc[i + 1] - pd[i + 1]) + Math.abs(pc[i + 2] - pd[i + 2]) > 24) m++;
  }
  markerToggleChangedFraction = m / total;
}
const shotData = await s('Page.captureScreenshot', { format: 'png' });
writeFileSync(shot, Buffer.from(shotData.data, 'base64'));
const frameShown = await evaluate('window.panomanViewer.frame()');
const result = {
  page, screenshot: shot, width: a.width, height: a.height, nFrames: n, scrubbedTo: mid, frameShown,
  nonBlankFraction: filled / total, scrubChangedFraction: changed / total, markerToggleChangedFraction, consoleErrors: problems,
};
console.log(JSON.stringify(result));
clearTimeout(guard);
ws.close();
const exited = new Promise((r) => browser.once('exit', r));
browser.kill('SIGKILL');
await exited;
try { rmSync(profile, { recursive: true, force: true, maxRetries: 5 }); } catch (e) { console.error(`leaving ${profile}: ${e.message}`); }
const ok = problems.length === 0 && (!hasMarkers || markerToggleChangedFraction > 0) && result.nonBlankFraction > 0.01 && (n < 2 || result.scrubChangedFraction > 0.002) && frameShown === (n > 1 ? mid : 0);
process.exit(ok ? 0 : 1);
