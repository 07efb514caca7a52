// End-to-end test of the dashboard in headless Debian Chromium, driven by playwright-core.
//
// Starts `stagehand serve` on the simulated rig (fresh data directory, port chosen by the
// daemon), opens the dashboard under a strict Content-Security-Policy with the operator token
// in the URL fragment, runs `quickstart` from the page (answering its prompt), waits for 100 %
// and for every camera's thumbnail; finds the run in the history (date, duration, status),
// browses its frames (filters, paging, thumbnails) and opens raw and HDR frames in the viewer
// (histogram, exposure slider, saturation count equal to the index's); takes a single capture;
// starts a run with parameters typed just before one click on Start, pauses and aborts it and
// resumes it from the history to the end; uploads a script, edits it with the dry run as it is
// typed (violations with line:col), saves and deletes it; then jogs an axis, switches a lamp
// on, arms the laser through the confirmation dialog, presses E-STOP and checks that the rig
// is safe; finally a read-only session sees the controls off and a wrong token sees no E-STOP.
// Screenshots of every stage go to $SCREENSHOT_DIR (default target/e2e-screenshots).
//
// Environment: STAGEHAND_BIN (default target/debug/stagehand), SCREENSHOT_DIR, CHROMIUM
// (default /usr/bin/chromium), E2E_FULL_RIG=1 to use the built-in rig's full-size cameras
// instead of a copy with small cameras (rendering 1024×768 frames is slow on small CI boxes).

import { spawn } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import zlib from 'node:zlib';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const HERE = path.dirname(fileURLToPath(import.meta.url));
const ROOT = path.resolve(HERE, '..', '..');
const BIN = path.resolve(process.env.STAGEHAND_BIN || path.join(ROOT, 'target/debug/stagehand'));
const SHOTS = path.resolve(process.env.SCREENSHOT_DIR || path.join(ROOT, 'target/e2e-screenshots'));
const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
const FULL_RIG = process.env.E2E_FULL_RIG === '1';
const RUN_TIMEOUT_MS = 300_000;
const CSP = "default-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'self'";
const STEP_TIMEOUT_MS = 30_000;

const t0 = Date.now();
const secs = () => ((Date.now() - t0) / 1000).toFixed(1);
const log = (msg) => console.log(`[e2e ${secs().padStart(6)} s] ${msg}`);

class Failure extends Error {}

let daemon = null;
let daemonLog = '';
let browser = null;
let tmp = null;
const pageErrors = [];

/** Kills the daemon (SIGTERM, then SIGKILL) and waits for it. */
async function stopDaemon() {
  if (!daemon || daemon.exitCode !== null || daemon.signalCode !== null) return;
  const exited = new Promise((resolve) => daemon.once('exit', resolve));
  daemon.kill('SIGTERM');
  const timer = setTimeout(() => daemon.kill('SIGKILL'), 10_000);
  await exited;
  clearTimeout(timer);
}

/** A copy of the built-in light stage with small cameras, so frames render fast. */
function smallRig(dir) {
  const src = path.join(ROOT, 'devices/rigs/lightstage.toml');
  let text = fs.readFileSync(src, 'utf8');
  text = text.replace(/^width = \d+$/gm, 'width = 320').replace(/^height = \d+$/gm, 'height = 240');
  const file = path.join(dir, 'lightstage-small.toml');
  fs.writeFileSync(file, text);
  return file;
}

/** Starts the daemon on 127.0.0.1:0 and resolves to its base URL (read from its banner). */
async function startDaemon() {
  if (!fs.existsSync(BIN)) {
    throw new Failure(`no stagehand binary at ${BIN}: run \`cargo build\` first or set STAGEHAND_BIN`);
  }
  const data = path.join(tmp, 'data');
  const args = ['serve', '--data', data, '--listen', '127.0.0.1:0', '--scripts', path.join(ROOT, 'sequences')];
  if (!FULL_RIG) args.push('--rig', smallRig(tmp));
  log(`starting ${BIN} ${args.join(' ')}`);
  daemon = spawn(BIN, args, { cwd: ROOT, stdio: ['ignore', 'pipe', 'pipe'], env: { ...process.env, RUST_LOG: process.env.RUST_LOG || 'info' } });
  const url = await new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Failure(`the daemon did not print its address within 60 s:\n${daemonLog}`)), 60_000);
    const onData = (chunk) => {
      daemonLog += chunk.toString();
      const m = /dashboard:\s+(http:\/\/\S+?)\/?\s/.exec(daemonLog);
      if (m) {
        clearTimeout(timer);
        resolve(m[1]);
      }
    };
    daemon.stdout.on('data', onData);
    daemon.stderr.on('data', onData);
    daemon.once('exit', (code, sig) => {
      clearTimeout(timer);
      reject(new Failure(`the daemon exited early (code ${code}, signal ${sig}):\n${daemonLog}`));
    });
  });
  // Keep collecting its output for the failure report.
  daemon.removeAllListeners('exit');
  const tokens = JSON.parse(fs.readFileSync(path.join(data, 'tokens.json'), 'utf8'));
  return { url, tokens };
}

async function apiGet(base, token, p) {
  const r = await fetch(base + p, { headers: { Authorization: `Bearer ${token}` } });
  if (!r.ok) throw new Failure(`GET ${p}: ${r.status} ${await r.text()}`);
  return r.json();
}

/** A 16-bit RGB PNG of `samples` (filter 0), with an sBIT chunk and a stagehand iTXt. */
function png16(w, h, samples, sbit, meta) {
  const crcTable = Array.from({ length: 256 }, (_, n) => {
    let c = n;
    for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
    return c >>> 0;
  });
  const crc = (buf) => {
    let c = 0xffffffff;
    for (const b of buf) c = crcTable[(c ^ b) & 0xff] ^ (c >>> 8);
    return (c ^ 0xffffffff) >>> 0;
  };
  const chunk = (type, data) => {
    const len = Buffer.alloc(4);
    len.writeUInt32BE(data.length);
    const body = Buffer.concat([Buffer.from(type, 'latin1'), data]);
    const c = Buffer.alloc(4);
    c.writeUInt32BE(crc(body));
    return Buffer.concat([len, body, c]);
  };
  const ihdr = Buffer.alloc(13);
  ihdr.writeUInt32BE(w, 0);
  ihdr.writeUInt32BE(h, 4);
  ihdr.set([16, 2, 0, 0, 0], 8);
  const raw = Buffer.alloc(h * (1 + w * 6));
  for (let y = 0; y < h; y++) {
    for (let i = 0; i < w * 3; i++) raw.writeUInt16BE(samples[y * w * 3 + i], y * (1 + w * 6) + 1 + i * 2);
  }
  return Buffer.concat([
    Buffer.from([137, 80, 78, 71, 13, 10, 26, 10]),
    chunk('IHDR', ihdr),
    ...(sbit ? [chunk('sBIT', Buffer.from([sbit, sbit, sbit]))] : []),
    chunk('iTXt', Buffer.concat([Buffer.from('stagehand\0\0\0\0\0', 'latin1'), Buffer.from(meta, 'utf8')])),
    chunk('IDAT', zlib.deflateSync(raw)),
    chunk('IEND', Buffer.alloc(0)),
  ]);
}

let shotNo = 0;
async function shot(page, name) {
  shotNo += 1;
  const file = path.join(SHOTS, `${String(shotNo).padStart(2, '0')}-${name}.png`);
  // Sticky elements land mid-page in a full-page shot of a scrolled page.
  await page.evaluate(() => window.scrollTo(0, 0));
  await page.screenshot({ path: file, fullPage: true });
  log(`screenshot ${path.relative(ROOT, file)}`);
  return file;
}

/** Fails if the page shows an error toast (the dashboard reports every API error that way). */
async function noErrorToasts(page, stage) {
  const errors = await page.locator('.toast-error').allInnerTexts();
  if (errors.length) throw new Failure(`${stage}: the page shows an error:\n  ${errors.join('\n  ').replace(/\n/g, ' | ')}`);
  if (pageErrors.length) throw new Failure(`${stage}: JavaScript error on the page: ${pageErrors.join('; ')}`);
}

async function stage(name, fn) {
  const s = Date.now();
  log(`▶ ${name}`);
  try {
    await fn();
  } catch (e) {
    e.stage = e.stage || name;
    throw e;
  }
  log(`✓ ${name} (${((Date.now() - s) / 1000).toFixed(1)} s)`);
}

async function main() {
  fs.mkdirSync(SHOTS, { recursive: true });
  for (const f of fs.readdirSync(SHOTS)) if (f.endsWith('.png')) fs.rmSync(path.join(SHOTS, f));
  tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'stagehand-e2e-'));
  const { url: base, tokens } = await startDaemon();
  log(`daemon at ${base}`);

  if (!fs.existsSync(CHROMIUM)) {
    throw new Failure(`no Chromium at ${CHROMIUM}: install it (\`apt-get install -y chromium\`) or set CHROMIUM`);
  }
  const userDataDir = path.join(tmp, 'chromium-profile');
  browser = await chromium.launchPersistentContext(userDataDir, {
    executablePath: CHROMIUM,
    headless: true,
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync'],
    viewport: { width: 1440, height: 1000 },
  });
  // The dashboard must work under the strict policy the daemon sends: no inline script, style
  // attribute, handler or eval. The daemon's header must be at least as strict as CSP above; any
  // violation fails the test.
  {
    const res = await fetch(`${base}/`);
    const policy = res.headers.get('content-security-policy') || '';
    for (const directive of CSP.split(';').map((d) => d.trim())) {
      if (!policy.includes(directive)) throw new Error(`the daemon's CSP lacks "${directive}": ${policy}`);
    }
    if (/unsafe-inline|unsafe-eval/.test(policy)) throw new Error(`the daemon's CSP allows inline code: ${policy}`);
    if (res.headers.get('x-frame-options') !== 'DENY') throw new Error('no X-Frame-Options: DENY on the dashboard');
    if (res.headers.get('x-content-type-options') !== 'nosniff') throw new Error('no nosniff on the dashboard');
  }
  await browser.addInitScript(() => {
    document.addEventListener('securitypolicyviolation', (e) => {
      console.error(`CSP violation: ${e.violatedDirective} blocked ${e.blockedURI || 'inline'} at ${e.sourceFile || '?'}:${e.lineNumber}`);
    });
  });
  const page = browser.pages()[0] || (await browser.newPage());
  page.setDefaultTimeout(STEP_TIMEOUT_MS);
  page.on('pageerror', (e) => pageErrors.push(e.message));
  page.on('console', (m) => {
    if (/CSP violation|Content Security Policy/.test(m.text())) pageErrors.push(m.text());
    if (m.type() === 'error' && !/status of 404/.test(m.text())) log(`browser console: ${m.text()}`);
  });
  // confirm() before aborting a run or deleting a script: the operator says yes.
  page.on('dialog', (d) => {
    log(`confirm: ${d.message()}`);
    d.accept();
  });
  const op = tokens.operator;
  const status = () => apiGet(base, op, '/api/status');

  await stage('open the dashboard with the token in the URL fragment', async () => {
    await page.goto(`${base}/#token=${op}`);
    await page.locator('#conn', { hasText: 'live' }).waitFor();
    await page.locator('#role', { hasText: 'operator' }).waitFor();
    if (page.url().includes(op)) throw new Failure(`the token is still in the address bar: ${page.url()}`);
    await page.locator('#axes .axis').first().waitFor();
    await page.locator('#cameras .cam').first().waitFor();
    await page.locator('#estop').waitFor({ state: 'visible' });
    await noErrorToasts(page, 'load');
    await shot(page, 'loaded');
  });

  await stage('select quickstart and see its dry-run estimate', async () => {
    await page.locator('#script-select option[value="quickstart"]').waitFor({ state: 'attached' });
    await page.selectOption('#script-select', 'quickstart');
    await page.locator('#dryrun .dryrun-head').waitFor();
    const time = await page.locator('#est-time').innerText();
    const frames = await page.locator('#est-frames').innerText();
    const bytes = await page.locator('#est-bytes').innerText();
    log(`estimate: rig time ${time}, frames ${frames}, data ${bytes}`);
    if (!/\d/.test(time) || !/\d/.test(frames) || !/\d/.test(bytes)) {
      throw new Failure(`the estimate is incomplete: time "${time}", frames "${frames}", bytes "${bytes}"`);
    }
    if (await page.locator('#run-start').isDisabled()) {
      throw new Failure(`Start is disabled: ${await page.locator('#run-start-note').innerText()}`);
    }
    await noErrorToasts(page, 'dry run');
    await shot(page, 'dry-run');
  });

  let runId = null;
  await stage('start the run and answer its prompt from the page', async () => {
    await page.click('#run-start');
    const banner = page.locator('#prompt-banner');
    await banner.waitFor({ state: 'visible' });
    const msg = await page.locator('#prompt-message').innerText();
    log(`prompt: ${msg}`);
    if (!/sample/i.test(msg)) throw new Failure(`unexpected prompt text: ${msg}`);
    const st = await status();
    if (!st.run || !st.run.prompt) throw new Failure(`status shows no prompt: ${JSON.stringify(st.run)}`);
    runId = st.run.run_id;
    await shot(page, 'prompt');
    await page.click('#prompt-continue');
    await banner.waitFor({ state: 'hidden' });
    await noErrorToasts(page, 'prompt');
  });

  await stage('watch the run progress to 100 %', async () => {
    const pct = async () => Number(await page.locator('#run-progress').getAttribute('aria-valuenow'));
    await page.waitForFunction(() => Number(document.querySelector('#run-progress').getAttribute('aria-valuenow')) >= 25,
      null, { timeout: RUN_TIMEOUT_MS, polling: 250 });
    log(`progress ${await pct()} %: ${await page.locator('#run-details').innerText()}`);
    await shot(page, 'running');
    await page.waitForFunction(() => Number(document.querySelector('#run-progress').getAttribute('aria-valuenow')) >= 100,
      null, { timeout: RUN_TIMEOUT_MS, polling: 250 });
    const text = await page.locator('#run-progress-text').innerText();
    if (!/100\s*%/.test(text)) throw new Failure(`progress text is "${text}", not 100 %`);
    await page.locator('#run-badge', { hasText: 'finished' }).waitFor();
    const st = await status();
    if (st.run) throw new Failure(`the daemon still has an active run: ${JSON.stringify(st.run)}`);
    const runs = await apiGet(base, op, '/api/runs');
    const mine = runs.find((r) => r.run_id === runId);
    if (!mine || mine.status !== 'done') throw new Failure(`run ${runId} did not finish as done: ${JSON.stringify(mine)}`);
    log(`run ${runId}: ${mine.steps_done}/${mine.steps_total} steps, ${mine.frames} frames`);
    await noErrorToasts(page, 'run');
  });

  await stage('see a frame from every camera', async () => {
    const n = (await status()).devices.cameras.length;
    await page.waitForFunction((count) => {
      const tiles = [...document.querySelectorAll('#cameras .cam')];
      return tiles.length === count && tiles.every((t) => {
        const img = t.querySelector('img.cam-img');
        return img && !img.hidden && img.complete && img.naturalWidth > 0;
      });
    }, n, { timeout: 60_000, polling: 250 });
    // Each tile ends on its camera's newest frame (thumbnails load a few at a time).
    const cams = (await status()).devices.cameras.map((c) => c.id);
    for (const cam of cams) {
      const latest = await apiGet(base, op, `/api/cameras/${cam}/latest`);
      if (latest.run_id !== runId) throw new Failure(`the latest frame of ${cam} is from run ${latest.run_id}, not ${runId}`);
      await page.locator(`#cameras .cam[data-camera="${cam}"][data-frame="${latest.frame_id}"]`).waitFor({ timeout: 60_000 });
    }
    // A camera tile opens its frame in the viewer (not a download).
    await page.locator(`#cameras .cam[data-camera="${cams[0]}"] .cam-link`).click();
    await page.locator('#viewer-canvas[data-ev]').waitFor();
    const title = await page.locator('#viewer-title').innerText();
    if (!title.startsWith(cams[0])) throw new Failure(`the viewer opened from ${cams[0]}'s tile shows "${title}"`);
    await page.click('#viewer-close');
    const sizes = await page.$$eval('#cameras img.cam-img', (imgs) => imgs.map((i) => `${i.naturalWidth}x${i.naturalHeight}`));
    log(`${n} camera thumbnails loaded: ${sizes.join(' ')}`);
    const logLines = await page.locator('#log li').count();
    if (logLines < 10) throw new Failure(`the event log has only ${logLines} lines after a run`);
    await page.locator('#log li', { hasText: `run ${runId} finished` }).first().waitFor();
    await shot(page, 'finished');
  });

  await stage('the history lists the run with its date, duration and status', async () => {
    const row = page.locator(`#runs-body tr[data-run="${runId}"]`);
    await row.waitFor();
    await row.locator('.run-status', { hasText: 'done' }).waitFor();
    const cells = await row.locator('td').allInnerTexts();
    log(`history row: ${cells.join(' | ')}`);
    if (!/\d{4}-\d\d-\d\d \d\d:\d\d:\d\d/.test(cells[2])) throw new Failure(`no start date in the history row: "${cells[2]}"`);
    if (!/\d/.test(cells[3])) throw new Failure(`no duration in the history row: "${cells[3]}"`);
    if (await row.locator('.resume-btn').count()) throw new Failure('a finished run offers Resume');
  });

  let rawFrame = null;
  let hdrFrame = null;
  await stage('browse the frames of the run: filters, paging, thumbnails', async () => {
    const all = await apiGet(base, op, `/api/runs/${runId}/frames?limit=1000`);
    rawFrame = all.frames.find((f) => f.kind === 'raw' && f.saturated_samples > 0) || all.frames.find((f) => f.kind === 'raw');
    hdrFrame = all.frames.find((f) => f.kind === 'hdr');
    await page.locator(`#runs-body tr[data-run="${runId}"] .browse-btn`).click();
    await page.locator('#frames-card').waitFor({ state: 'visible' });
    const countIs = async (n) => page.locator('#frames-count', { hasText: new RegExp(`^${n} frames? match`) }).waitFor();
    await countIs(all.total);
    const tiles = page.locator('#frames-grid .frame-tile');
    const pageSize = await tiles.count();
    if (pageSize !== Math.min(24, all.total)) throw new Failure(`${pageSize} tiles on the first page of ${all.total} frames`);
    await page.waitForFunction(() => [...document.querySelectorAll('#frames-grid .frame-tile img')]
      .every((i) => i.complete && i.naturalWidth > 0), null, { timeout: 60_000, polling: 250 });
    await shot(page, 'frame-browser');
    // Paging.
    await page.click('#frames-next');
    await page.locator('#frames-page', { hasText: `25–${Math.min(48, all.total)} of ${all.total}` }).waitFor();
    await page.click('#frames-prev');
    await page.locator('#frames-page', { hasText: `1–${pageSize} of ${all.total}` }).waitFor();
    // Each filter gives what the API gives.
    const checks = [
      ['camera', '#f-camera', all.frames[0].camera, 'select'],
      ['lamp', '#f-lamp', 'lamp1', 'select'],
      ['step', '#f-step', String(hdrFrame ? hdrFrame.step : all.frames[0].step), 'fill'],
      ['block', '#f-block', hdrFrame ? hdrFrame.block : all.frames[0].block, 'fill'],
    ];
    for (const [name, sel, value, how] of checks) {
      await page.click('#f-clear');
      await countIs(all.total);
      const want = (await apiGet(base, op, `/api/runs/${runId}/frames?${name}=${encodeURIComponent(value)}&limit=0`)).total;
      if (how === 'select') await page.selectOption(sel, value);
      else await page.fill(sel, value);
      await countIs(want);
      const shown = await tiles.count();
      if (shown !== Math.min(24, want)) throw new Failure(`${name}=${value}: ${shown} tiles for ${want} frames`);
      if (name === 'camera') {
        const cams = await tiles.evaluateAll((ts) => ts.map((t) => t.dataset.camera));
        if (cams.some((c) => c !== value)) throw new Failure(`camera filter ${value} shows frames of ${[...new Set(cams)].join(', ')}`);
      }
      log(`filter ${name}=${value}: ${want} frames`);
    }
    await page.click('#f-clear');
    await countIs(all.total);
  });

  await stage('open a raw frame in the viewer: histogram, saturation, exposure slider', async () => {
    await page.fill('#f-step', String(rawFrame.step));
    await page.selectOption('#f-camera', rawFrame.camera);
    await page.locator(`#frames-grid .frame-tile[data-frame="${rawFrame.frame_id}"]`).click();
    await page.locator('#viewer').waitFor({ state: 'visible' });
    await page.locator('#viewer-canvas[data-ev]').waitFor();
    await page.locator('#viewer-hist[data-drawn]').waitFor();
    const info = await page.evaluate(() => {
      const c = document.getElementById('viewer-canvas');
      const hist = document.getElementById('viewer-hist');
      const hd = hist.getContext('2d').getImageData(0, 0, hist.width, hist.height).data;
      let lit = 0;
      for (let i = 0; i < hd.length; i += 4) if (hd[i] + hd[i + 1] + hd[i + 2] > 60) lit++;
      return { w: c.width, h: c.height, ev: c.dataset.ev, histLit: lit, sat: V.img.satSamples, shift: V.img.shift, maxDN: V.img.maxDN };
    });
    log(`viewer: ${info.w}×${info.h}, auto ${info.ev} EV, max DN ${info.maxDN}, shift ${info.shift}, ${info.sat} saturated samples, histogram ${info.histLit} lit pixels`);
    if (info.w !== rawFrame.width || info.h !== rawFrame.height) throw new Failure(`the viewer shows ${info.w}×${info.h}, the frame is ${rawFrame.width}×${rawFrame.height}`);
    if (info.histLit < 200) throw new Failure(`the histogram is (nearly) empty: ${info.histLit} lit pixels`);
    if (info.sat !== rawFrame.saturated_samples) {
      throw new Failure(`the viewer counts ${info.sat} saturated samples, the index ${rawFrame.saturated_samples}: the DN are not read exactly`);
    }
    const digest = () => page.evaluate(() => {
      const c = document.getElementById('viewer-canvas');
      const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
      let hsh = 0;
      let sum = 0;
      for (let i = 0; i < d.length; i += 4) {
        hsh = (hsh * 31 + d[i] + 7 * d[i + 1] + 13 * d[i + 2]) | 0;
        sum += d[i] + d[i + 1] + d[i + 2];
      }
      return { hsh, mean: sum / (d.length * 0.75) };
    });
    const before = await digest();
    await shot(page, 'viewer-raw');
    const target = Number(info.ev) >= 6 ? Number(info.ev) - 2 : Number(info.ev) + 2;
    await page.locator('#viewer-exposure').fill(String(target));
    await page.locator(`#viewer-canvas[data-ev="${target.toFixed(1)}"]`).waitFor();
    const after = await digest();
    log(`exposure ${info.ev} → ${target.toFixed(1)} EV: mean level ${before.mean.toFixed(1)} → ${after.mean.toFixed(1)}`);
    if (after.hsh === before.hsh) throw new Failure('the exposure slider did not change the image');
    if ((target > Number(info.ev)) !== (after.mean > before.mean)) throw new Failure('more exposure did not brighten the image');
    await noErrorToasts(page, 'viewer');
    await page.click('#viewer-close');
    await page.locator('#viewer').waitFor({ state: 'hidden' });
  });

  await stage('the viewer reads DN exactly from low-bit and MSB-aligned (sBIT) PNGs', async () => {
    // 12-bit DN stored as they are (today) or shifted to the top bits with sBIT and/or a
    // sample_shift in the metadata (the storage change under way): the same DN either way.
    const w = 19;
    const hgt = 7;
    const dn = Array.from({ length: w * hgt * 3 }, (_, i) => (i * 977 + 13) % 4096);
    dn[0] = 4095;
    dn[4] = 4095;
    const variants = [
      { name: 'low bits', shift: 0, sbit: false, info: { bit_depth: 12 } },
      { name: 'MSB + sBIT', shift: 4, sbit: true, info: { bit_depth: 12 } },
      { name: 'MSB + sample_shift', shift: 4, sbit: false, info: { bit_depth: 12, sample_shift: 4 } },
      { name: 'MSB, no hint', shift: 4, sbit: false, info: { bit_depth: 12 } },
    ];
    for (const v of variants) {
      const png = png16(w, hgt, dn.map((x) => x << v.shift), v.sbit ? 12 : null, JSON.stringify({ bit_depth: 12 }));
      const got = await page.evaluate(async ({ b64, info }) => {
        const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
        const im = prepareImage(info, await decodePng(bytes.buffer));
        return { dn: Array.from(im.data), sat: im.satSamples, shift: im.shift };
      }, { b64: png.toString('base64'), info: v.info });
      const bad = got.dn.findIndex((x, i) => x !== dn[i]);
      if (bad >= 0) throw new Failure(`${v.name}: sample ${bad} reads as DN ${got.dn[bad]}, stored DN ${dn[bad]}`);
      const sat = dn.filter((x) => x === 4095).length;
      if (got.sat !== sat) throw new Failure(`${v.name}: ${got.sat} saturated samples, expected ${sat}`);
      log(`${v.name}: DN exact, shift ${got.shift}, ${got.sat} saturated`);
    }
  });

  await stage('open an HDR frame in the viewer (tone-mapped)', async () => {
    if (!hdrFrame) throw new Failure('quickstart recorded no HDR frame');
    await page.click('#f-clear');
    await page.selectOption('#f-kind', 'hdr');
    await page.locator(`#frames-grid .frame-tile[data-frame="${hdrFrame.frame_id}"]`).click();
    await page.locator('#viewer-canvas[data-ev]').waitFor();
    await page.locator('#viewer-hist[data-drawn]').waitFor();
    const mean = await page.evaluate(() => {
      const c = document.getElementById('viewer-canvas');
      const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
      let s = 0;
      for (let i = 0; i < d.length; i += 4) s += d[i] + d[i + 1] + d[i + 2];
      return s / (d.length * 0.75);
    });
    log(`HDR frame ${hdrFrame.frame_id}: mean display level ${mean.toFixed(1)} of 255`);
    if (!(mean > 3 && mean < 250)) throw new Failure(`the tone-mapped HDR frame is ${mean < 3 ? 'black' : 'white'} (mean ${mean.toFixed(1)})`);
    await shot(page, 'viewer-hdr');
    await page.keyboard.press('Escape');
    await page.locator('#viewer').waitFor({ state: 'hidden' });
    await page.click('#frames-close');
  });

  await stage('a single capture from the page', async () => {
    await page.fill('#capture-exposure', '5');
    await page.click('#capture-btn');
    const note = page.locator('#capture-note', { hasText: /frame\(s\) in run/ });
    await note.waitFor({ timeout: 120_000 });
    const capRun = await note.getAttribute('data-run');
    const detail = await apiGet(base, op, `/api/runs/${capRun}`);
    const cams = (await status()).devices.cameras.length;
    if (detail.frames !== cams) throw new Failure(`the capture run ${capRun} has ${detail.frames} frames for ${cams} cameras`);
    await page.locator(`#runs-body tr[data-run="${capRun}"] .run-status`, { hasText: 'done' }).waitFor();
    log(`capture: run ${capRun}, ${detail.frames} frames: ${await page.locator('#capture-note').innerText()}`);
    await noErrorToasts(page, 'capture');
  });

  let run2 = null;
  await stage('a parameter fixed just before Start needs one click', async () => {
    await page.selectOption('#script-select', 'quickstart');
    await page.locator('#dryrun .dryrun-head').waitFor();
    // A mistake in the parameters is shown as it is typed and keeps Start off...
    await page.fill('#script-set', 'lamp_count=1 sweep_lines');
    await page.locator('#dryrun .error-text', { hasText: 'sweep_lines' }).waitFor();
    if (!(await page.locator('#run-start').isDisabled())) throw new Failure('Start is enabled with a malformed parameter');
    // ...and once fixed, one click starts the run, though its dry run is still on its way.
    await page.fill('#script-set', 'lamp_count=1 sweep_lines=2');
    await page.click('#run-start');
    await page.locator('#prompt-banner').waitFor({ state: 'visible' });
    run2 = (await status()).run.run_id;
    const detail = await apiGet(base, op, `/api/runs/${run2}`);
    if (detail.manifest.params.lamp_count !== 1 || detail.manifest.params.sweep_lines !== 2) {
      throw new Failure(`run ${run2} started with ${JSON.stringify(detail.manifest.params)}, not the typed parameters`);
    }
    await page.click('#prompt-continue');
    await page.locator('#prompt-banner').waitFor({ state: 'hidden' });
  });

  await stage('pause and abort the run, resume it from the history to the end', async () => {
    await page.waitForFunction(() => Number(document.querySelector('#run-progress').getAttribute('aria-valuenow')) >= 20,
      null, { timeout: RUN_TIMEOUT_MS, polling: 100 });
    await page.click('#run-pause');
    await page.locator('#run-badge', { hasText: 'paused' }).waitFor();
    await page.click('#run-abort');
    await page.locator('#run-badge', { hasText: 'aborted' }).waitFor();
    const row = page.locator(`#runs-body tr[data-run="${run2}"]`);
    await row.locator('.run-status', { hasText: 'aborted' }).waitFor();
    // The daemon's `warning` event about the stop shows in the banner until the run runs again.
    await page.locator('#warning-banner', { hasText: `run ${run2} aborted` }).waitFor();
    const stopped = (await apiGet(base, op, '/api/runs')).find((r) => r.run_id === run2);
    log(`aborted at ${stopped.steps_done}/${stopped.steps_total} steps`);
    await shot(page, 'aborted');
    await row.locator('.resume-btn').click();
    await page.locator('#warning-banner').waitFor({ state: 'hidden' });
    await page.locator('#run-badge', { hasText: 'finished' }).waitFor({ timeout: RUN_TIMEOUT_MS });
    const done = (await apiGet(base, op, '/api/runs')).find((r) => r.run_id === run2);
    if (done.status !== 'done' || done.steps_done !== done.steps_total) throw new Failure(`after resume: ${JSON.stringify(done)}`);
    await row.locator('.run-status', { hasText: 'done' }).waitFor();
    log(`resumed to ${done.steps_done}/${done.steps_total} steps, ${done.frames} frames`);
    await noErrorToasts(page, 'resume');
    await shot(page, 'resumed');
  });

  await stage('the interlock opened mid-sweep pauses the run; resumed, no dark laser frame is kept', async () => {
    await page.selectOption('#script-select', 'quickstart');
    // One tour position and one lamp: the shortest quickstart that still sweeps the laser.
    await page.fill('#script-set', 'lamp_count=1 turntable_deg=[0.0] light_arc_deg=[30.0]');
    await page.locator('#dryrun .dryrun-head').waitFor();
    await page.click('#run-start');
    await page.locator('#prompt-banner').waitFor({ state: 'visible' });
    const run3 = (await status()).run.run_id;
    await page.click('#prompt-continue');
    // Open the door from the page once the laser emits (the sweep).
    for (;;) {
      const st = await status();
      if (st.devices?.laser?.on) break;
      if (!st.run) throw new Failure('the run ended before the laser switched on');
      await new Promise((r) => setTimeout(r, 20));
    }
    await page.click('#interlock-toggle');
    await page.locator('#warning-banner', { hasText: 'interlock' }).waitFor({ timeout: RUN_TIMEOUT_MS });
    await page.locator('#run-badge', { hasText: 'paused' }).waitFor();
    await shot(page, 'interlock-paused');
    const paused = (await status()).run;
    if (!paused || !/interlock/.test(paused.pause_reason || '')) throw new Failure(`the paused run gives no reason: ${JSON.stringify(paused)}`);
    await page.click('#interlock-toggle');
    await page.locator('.l-interlock', { hasText: 'interlock closed' }).waitFor();
    await page.click('#run-resume');
    await page.locator('#run-badge', { hasText: 'finished' }).waitFor({ timeout: RUN_TIMEOUT_MS });
    const done = (await apiGet(base, op, '/api/runs')).find((r) => r.run_id === run3);
    if (done.status !== 'done') throw new Failure(`after the interlock resume: ${JSON.stringify(done)}`);
    const frames = (await apiGet(base, op, `/api/runs/${run3}/frames?limit=1000`)).frames;
    const dark = frames.filter((f) => f.laser_armed && !f.laser_on);
    if (dark.length) throw new Failure(`${dark.length} laser frames were recorded with the laser off`);
    log(`interlock: paused, resumed, ${frames.length} frames, none dark`);
  });

  await stage('upload a script, edit it with the dry run as it is typed, save, delete', async () => {
    const good = 'home();\nonly_lamp(lamps()[0]);\ncapture(0.01);\nlamps_off();\n';
    await page.fill('#script-set', ''); // quickstart's parameters do not apply to this script
    await page.setInputFiles('#script-upload', { name: 'e2e tour.rhai', mimeType: 'text/plain', buffer: Buffer.from(good) });
    await page.locator('#editor').waitFor({ state: 'visible' });
    const name = await page.inputValue('#editor-name');
    if (name !== 'e2e_tour') throw new Failure(`the uploaded script is named "${name}"`);
    await page.locator('#script-select option[value="e2e_tour"]').waitFor({ state: 'attached' });
    if ((await page.inputValue('#script-select')) !== 'e2e_tour') throw new Failure('the uploaded script is not selected');
    await page.locator('#editor-dryrun .dryrun-head', { hasText: 'ready to run' }).waitFor();
    // Type a move outside the turntable's travel: the violation appears while typing.
    await page.click('#editor-text');
    await page.keyboard.press('Control+End');
    await page.keyboard.type('move_to(#{turntable: 400.0});\n');
    const v = page.locator('#editor-dryrun .violations li.sev-error', { hasText: 'turntable' });
    await v.waitFor();
    const vt = await v.innerText();
    log(`violation while typing: ${vt}`);
    if (!/^5:1\b/.test(vt)) throw new Failure(`the violation does not say line 5, column 1: "${vt}"`);
    await page.locator('#editor-dryrun .dryrun-head', { hasText: 'cannot run' }).waitFor();
    await shot(page, 'editor-violation');
    // A syntax error names its place too.
    await page.keyboard.type('captur(0.01);');
    await page.locator('#editor-dryrun .error-text', { hasText: /6:1/ }).waitFor();
    // Fix it and save.
    await page.fill('#editor-text', `${good}move_to(#{turntable: 40.0});\ncapture(0.01);\n`);
    await page.locator('#editor-dryrun .dryrun-head', { hasText: 'ready to run' }).waitFor();
    await page.click('#editor-save');
    await page.locator('#editor-status', { hasText: 'Saved as e2e_tour' }).waitFor();
    const res = await fetch(`${base}/api/scripts/e2e_tour`, { headers: { Authorization: `Bearer ${op}` } });
    if (!(await res.text()).includes('turntable: 40.0')) throw new Failure('the saved script does not hold the edit');
    await page.locator('#dryrun .dryrun-head', { hasText: 'ready to run' }).waitFor();
    await noErrorToasts(page, 'editor');
    await page.click('#script-delete');
    await page.locator('#script-select option[value="e2e_tour"]').waitFor({ state: 'detached' });
    const left = await apiGet(base, op, '/api/scripts');
    if (left.some((x) => x.name === 'e2e_tour')) throw new Failure('the script is still listed after Delete');
    if (!(await page.locator('#editor').isHidden())) throw new Failure('the editor still shows the deleted script');
    await noErrorToasts(page, 'delete');
    // A new script starts from a template that is ready to run on this rig.
    await page.click('#script-new');
    await page.locator('#editor').waitFor({ state: 'visible' });
    await page.locator('#editor-dryrun .dryrun-head', { hasText: 'ready to run' }).waitFor();
    await page.click('#editor-close');
    await page.locator('#editor').waitFor({ state: 'hidden' });
  });

  await stage('jog an axis', async () => {
    const before = (await status()).devices.axes.find((a) => a.id === 'turntable');
    const row = page.locator('[data-axis="turntable"]');
    await row.locator('button[data-jog="10"]').click();
    const want = before.position_deg + 10;
    await page.waitForFunction((w) => {
      const t = document.querySelector('[data-axis="turntable"] .axis-pos').textContent;
      return Math.abs(parseFloat(t) - w) < 0.05 && !document.querySelector('[data-axis="turntable"]').classList.contains('moving');
    }, want, { timeout: STEP_TIMEOUT_MS, polling: 100 });
    const after = (await status()).devices.axes.find((a) => a.id === 'turntable');
    if (Math.abs(after.position_deg - want) > 0.05) {
      throw new Failure(`turntable at ${after.position_deg}° after a +10° jog from ${before.position_deg}°`);
    }
    log(`turntable ${before.position_deg}° → ${after.position_deg}°`);
    await noErrorToasts(page, 'jog');
  });

  await stage('switch a lamp on', async () => {
    await page.click('[data-lamp="lamp1"]');
    await page.locator('[data-lamp="lamp1"].on').waitFor();
    const lamp = (await status()).devices.lamps.find((l) => l.id === 'lamp1');
    if (!lamp.on) throw new Failure('lamp1 is off in the status after switching it on');
    await noErrorToasts(page, 'lamp');
  });

  await stage('arm the laser through the confirmation dialog', async () => {
    await page.click('#laser-arm');
    const dlg = page.locator('#arm-dialog');
    await dlg.waitFor({ state: 'visible' });
    if (!(await page.locator('#arm-confirm').isDisabled())) throw new Failure('Arm is enabled before the confirmation is ticked');
    await page.getByLabel('I confirm the enclosure is closed and eye protection is worn').check();
    await shot(page, 'arm-dialog');
    await page.click('#arm-confirm');
    await dlg.waitFor({ state: 'hidden' });
    // A string `hasText` matches case-insensitively, and "disarmed" contains "armed": only
    // the exact badge proves the arm went through before the status is read.
    await page.locator('#laser .l-armed', { hasText: /^ARMED$/ }).waitFor();
    const laser = (await status()).devices.laser;
    if (!laser.armed) throw new Failure(`the laser is not armed in the status: ${JSON.stringify(laser)}`);
    await noErrorToasts(page, 'arm');
    await shot(page, 'armed');
  });

  await stage('press E-STOP', async () => {
    await page.click('#estop');
    await page.locator('#estop-banner').waitFor({ state: 'visible' });
    await page.locator('#laser .l-armed', { hasText: 'disarmed' }).waitFor();
    await page.locator('[data-lamp="lamp1"]:not(.on)').waitFor();
    const st = await status();
    const lampsOn = st.devices.lamps.filter((l) => l.on).map((l) => l.id);
    const problems = [];
    if (!st.estop) problems.push('estop is not latched');
    if (lampsOn.length) problems.push(`lamps still on: ${lampsOn.join(', ')}`);
    if (st.devices.laser && (st.devices.laser.armed || st.devices.laser.on)) problems.push(`laser ${JSON.stringify(st.devices.laser)}`);
    if (st.devices.axes.some((a) => a.moving)) problems.push('an axis is still moving');
    if (problems.length) throw new Failure(`after E-STOP: ${problems.join('; ')}`);
    if (!(await page.locator('[data-axis="turntable"] button[data-jog="1"]').isDisabled())) {
      throw new Failure('jog buttons are still enabled while the e-stop is latched');
    }
    await noErrorToasts(page, 'e-stop');
    await shot(page, 'estop');
  });

  await stage('reset the e-stop', async () => {
    await page.click('#estop-reset');
    await page.locator('#estop-banner').waitFor({ state: 'hidden' });
    if ((await status()).estop) throw new Failure('the e-stop is still latched after Reset');
    await noErrorToasts(page, 'reset');
  });

  await stage('a read-only session sees the rig but cannot control it', async () => {
    const ro = await browser.newPage();
    ro.on('pageerror', (e) => pageErrors.push(`read-only page: ${e.message}`));
    await ro.goto(`${base}/#token=${tokens.read_only}`);
    await ro.locator('#role', { hasText: 'read-only' }).waitFor();
    await ro.locator('#readonly-banner').waitFor({ state: 'visible' });
    await ro.locator('#axes .axis').first().waitFor();
    // Thumbnails load with the read-only token too (as ?access_token=).
    await ro.waitForFunction(() => [...document.querySelectorAll('#cameras .cam')].every((t) => {
      const img = t.querySelector('img.cam-img');
      return img && !img.hidden && img.complete && img.naturalWidth > 0;
    }), null, { timeout: 60_000, polling: 250 });
    for (const sel of ['#run-start', '[data-axis="turntable"] button[data-jog="1"]', '[data-lamp="lamp1"]', '#laser-arm']) {
      if (!(await ro.locator(sel).isDisabled())) throw new Failure(`${sel} is enabled for a read-only token`);
    }
    await shot(ro, 'read-only');
    await ro.close();
  });

  await stage('a wrong token gets the sign-in box with a message', async () => {
    const bad = await browser.newPage();
    await bad.goto(`${base}/#token=not-a-valid-token-0000000000`);
    await bad.locator('#login').waitFor({ state: 'visible' });
    const msg = await bad.locator('#login-error').innerText();
    if (!/token/i.test(msg)) throw new Failure(`the sign-in box says "${msg}" for a wrong token`);
    if (await bad.locator('#estop').isVisible()) throw new Failure('E-STOP is shown before signing in');
    await bad.close();
  });
}

for (const sig of ['SIGINT', 'SIGTERM']) {
  process.on(sig, () => {
    log(`${sig}: stopping the daemon`);
    stopDaemon().finally(() => process.exit(130));
  });
}

let failed = false;
try {
  await main();
  log(`PASS: dashboard end-to-end test (${secs()} s); screenshots in ${SHOTS}`);
} catch (e) {
  failed = true;
  console.error(`\n[e2e] FAIL${e.stage ? ` at "${e.stage}"` : ''}: ${e.message}`);
  if (!(e instanceof Failure) && e.stack) console.error(e.stack);
  try {
    const page = browser && browser.pages()[0];
    if (page) {
      const file = path.join(SHOTS, 'FAILED.png');
      await page.screenshot({ path: file, fullPage: true });
      console.error(`[e2e] screenshot of the failure: ${file}`);
      const toasts = await page.locator('.toast').allInnerTexts();
      if (toasts.length) console.error(`[e2e] messages on the page:\n  ${toasts.join('\n  ').replace(/\n(?!  )/g, ' | ')}`);
      const lines = await page.locator('#log li').allInnerTexts();
      if (lines.length) console.error(`[e2e] event log (newest first):\n  ${lines.slice(0, 25).join('\n  ').replace(/\t/g, ' ')}`);
    }
  } catch (_) { /* the browser may be gone */ }
  const tail = daemonLog.split('\n').slice(-40).join('\n');
  console.error(`[e2e] daemon output (last 40 lines):\n${tail}`);
} finally {
  if (browser) await browser.close().catch(() => {});
  await stopDaemon().catch((e) => console.error(`[e2e] cannot stop the daemon: ${e.message}`));
  if (tmp && !failed) fs.rmSync(tmp, { recursive: true, force: true });
  else if (tmp) console.error(`[e2e] data directory kept for inspection: ${tmp}`);
}
process.exit(failed ? 1 : 0);
