// The stagehand dashboard: plain modern JavaScript, no framework, no build step, nothing fetched
// from outside the daemon (it must work on a lab laptop without internet).
//
// State flows one way: GET /api/status (and the SSE `resync` event, which carries the same
// Status) is the truth; the other live events update the page at once and schedule a throttled
// status refresh, so whatever shape a device event has, the page converges on the daemon's state.
'use strict';

const TOKEN_KEY = 'stagehand.token';
const LOG_MAX = 200;
const THUMB_SIZE = 256;
const ARM_PHRASE = 'I confirm the enclosure is closed and eye protection is worn';

const S = {
  token: null,
  role: 'unknown', // 'operator' | 'read_only' | 'unknown'
  status: null,
  run: null, // RunState of the active run, or null
  lastRun: null, // what the run panel shows once the run has ended
  prompt: null, // {run_id, step, message}
  interlock: null, // GET /api/interlock body, or null when unknown
  scripts: [],
  dryrun: null,
  dryrunFor: null,
  es: null,
  sseOpen: false,
  cams: new Map(),
  log: [], // newest first: {seq, kind, unix_s, data, key, count, li}
  logSeqs: new Set(),
  logReady: false,
  logBuffer: [],
  statusTimer: null,
  statusInFlight: false,
  statusAgain: false,
  runsTimer: null,
  started: false,
  sseWasOpen: false,
  lastEventUnix: 0,
  runEnds: new Map(), // run id → Unix time of its run_finished event seen by this page
  lastFrameAt: new Map(), // run id → capture time of its last frame (null while looked up)
};

const $ = (id) => document.getElementById(id);

/** Creates an element: h('div', {class: 'x', onclick: f}, 'text', child). */
function h(tag, attrs, ...children) {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith('on')) el.addEventListener(k.slice(2), v);
    else if (k === 'class') el.className = v;
    else if (k === 'dataset') Object.assign(el.dataset, v);
    // CSSOM, not a style attribute: the page runs under a strict Content-Security-Policy.
    else if (k === 'style') Object.assign(el.style, v);
    else el.setAttribute(k, v === true ? '' : v);
  }
  for (const c of children.flat()) {
    if (c === undefined || c === null || c === false) continue;
    el.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return el;
}

// ---------------------------------------------------------------- formatting

function fmtDuration(s) {
  if (s === undefined || s === null || !Number.isFinite(s)) return '–';
  s = Math.max(0, s);
  if (s < 10) return `${s.toFixed(1)} s`;
  if (s < 60) return `${Math.round(s)} s`;
  if (s < 3600) {
    const m = Math.floor(s / 60);
    return `${m} min ${String(Math.round(s - m * 60)).padStart(2, '0')} s`;
  }
  const hrs = Math.floor(s / 3600);
  const m = Math.round((s - hrs * 3600) / 60);
  return `${hrs} h ${String(m).padStart(2, '0')} min`;
}

/** Binary units, as the dry-run report prints them. */
function fmtBytes(b) {
  if (b === undefined || b === null || !Number.isFinite(b)) return '–';
  const units = ['B', 'KiB', 'MiB', 'GiB', 'TiB'];
  let i = 0;
  while (b >= 1024 && i < units.length - 1) {
    b /= 1024;
    i++;
  }
  return `${b >= 100 || i === 0 ? Math.round(b) : b.toFixed(1)} ${units[i]}`;
}

function fmtDeg(d) {
  return Number.isFinite(d) ? `${d.toFixed(2)}°` : '–';
}

function fmtClock(unix_s) {
  const d = unix_s ? new Date(unix_s * 1000) : new Date();
  return d.toLocaleTimeString([], { hour12: false });
}

function shortJson(v, max = 160) {
  let s;
  if (v && typeof v === 'object' && !Array.isArray(v)) {
    s = Object.entries(v)
      .map(([k, x]) => `${k}=${typeof x === 'object' && x !== null ? JSON.stringify(x) : x}`)
      .join(' ');
  } else {
    s = JSON.stringify(v);
  }
  return s && s.length > max ? `${s.slice(0, max - 1)}…` : s || '';
}

// ---------------------------------------------------------------- API

class ApiError extends Error {
  constructor(status, message, hint, method, path) {
    super(message);
    this.status = status;
    this.hint = hint;
    this.method = method;
    this.path = path;
  }
}

/**
 * fetch with the bearer token; resolves to the JSON (or text) body, rejects with ApiError.
 * `body` is sent as JSON, or as it is with `contentType` when that is given.
 */
async function api(method, path, body, contentType) {
  const opts = { method, headers: { Authorization: `Bearer ${S.token}` } };
  if (body !== undefined && contentType) {
    opts.headers['Content-Type'] = contentType;
    opts.body = body;
  } else if (body !== undefined) {
    opts.headers['Content-Type'] = 'application/json';
    opts.body = JSON.stringify(body);
  }
  let res;
  try {
    res = await fetch(path, opts);
  } catch (e) {
    throw new ApiError(0, `cannot reach the daemon (${e.message})`,
      'check that `stagehand serve` is running and reachable', method, path);
  }
  const type = res.headers.get('content-type') || '';
  let data = null;
  if (res.status !== 204) {
    data = type.includes('json') ? await res.json().catch(() => null) : await res.text().catch(() => '');
  }
  if (!res.ok) {
    const message = (data && data.error) || (typeof data === 'string' && data.trim()) || res.statusText || 'request failed';
    const err = new ApiError(res.status, message, data && data.hint, method, path);
    if (res.status === 401) unauthorized(err);
    if (res.status === 403 && S.role !== 'read_only') {
      S.role = 'read_only';
      renderRole();
      applyEnables();
    }
    throw err;
  }
  return data;
}

/** Withtoken: a URL for <img>/EventSource, which cannot send headers. */
function withToken(path, params = {}) {
  const u = new URL(path, location.origin);
  for (const [k, v] of Object.entries(params)) if (!u.searchParams.has(k)) u.searchParams.set(k, v);
  u.searchParams.set('access_token', S.token);
  return u.pathname + u.search;
}

/** Runs an operator action from a button: disables it meanwhile, shows any error. */
async function act(btn, method, path, body, what) {
  if (btn) {
    btn.dataset.busy = '1';
    btn.disabled = true;
  }
  try {
    const r = await api(method, path, body);
    scheduleStatus(50);
    return r;
  } catch (e) {
    showError(e, what);
    scheduleStatus(50);
    return undefined;
  } finally {
    if (btn) delete btn.dataset.busy;
    applyEnables();
  }
}

// ---------------------------------------------------------------- errors and toasts

function showError(e, what) {
  const status = e && e.status ? `${e.status} ` : '';
  const where = e && e.method ? `${e.method} ${e.path}` : '';
  const title = what ? `${what} failed` : 'Error';
  const msg = (e && e.message) || String(e);
  const toast = h('div', { class: 'toast toast-error', role: 'alert' },
    h('button', { class: 'toast-close', type: 'button', 'aria-label': 'Dismiss', onclick: () => toast.remove() }, '×'),
    h('div', { class: 'toast-title' }, title),
    h('div', {}, msg),
    e && e.hint ? h('div', { class: 'toast-hint' }, e.hint) : null,
    where ? h('div', { class: 'toast-where' }, `${status}${where}`) : null);
  $('toasts').prepend(toast);
  while ($('toasts').children.length > 5) $('toasts').lastChild.remove();
  // Errors stay in the event log; the toast goes after a while (or when dismissed).
  setTimeout(() => toast.remove(), 30000);
  addLocalLog('error', `${title}: ${msg}${e && e.hint ? ` (${e.hint})` : ''}`);
}

function showInfo(text) {
  const toast = h('div', { class: 'toast toast-info', role: 'status' }, text);
  $('toasts').prepend(toast);
  setTimeout(() => toast.remove(), 5000);
}

// ---------------------------------------------------------------- token and login

function readToken() {
  const m = /(?:^#|&)token=([^&]+)/.exec(location.hash);
  if (m) {
    const t = decodeURIComponent(m[1]);
    try {
      localStorage.setItem(TOKEN_KEY, t);
    } catch (_) { /* private mode: keep it in memory */ }
    // Strip the token from the address bar (and history) so it is not shared by accident.
    history.replaceState(null, '', location.pathname + location.search);
    return t;
  }
  try {
    return localStorage.getItem(TOKEN_KEY);
  } catch (_) {
    return null;
  }
}

function showLogin(message) {
  stopEvents();
  $('estop').hidden = true;
  $('main').hidden = true;
  $('login').hidden = false;
  $('signout').hidden = true;
  $('login-error').hidden = !message;
  $('login-error').textContent = message || '';
  $('conn').textContent = 'signed out';
  $('conn').className = 'badge badge-warn';
  $('login-token').focus();
}

function unauthorized(err) {
  try {
    localStorage.removeItem(TOKEN_KEY);
  } catch (_) { /* ignore */ }
  S.token = null;
  S.started = false;
  showLogin(`The daemon refused the token: ${err.message}. ${err.hint || ''}`);
}

/** The token's role, from GET /api/whoami (`operator` or `read_only`). */
async function detectRole() {
  try {
    const r = await fetch('/api/whoami', { headers: { Authorization: `Bearer ${S.token}` } });
    if (r.status === 401) return 'invalid';
    if (r.ok) {
      const j = await r.json();
      if (j && j.role) return j.role;
    }
  } catch (_) { /* unknown below */ }
  return 'unknown';
}

function renderRole() {
  const el = $('role');
  el.hidden = S.role === 'unknown';
  el.textContent = S.role === 'read_only' ? 'read-only' : 'operator';
  el.className = `badge ${S.role === 'read_only' ? 'badge-warn' : 'badge-ok'}`;
  $('readonly-banner').hidden = S.role !== 'read_only';
}

// ---------------------------------------------------------------- status

function scheduleStatus(delay = 250) {
  if (S.statusTimer) return;
  S.statusTimer = setTimeout(() => {
    S.statusTimer = null;
    refreshStatus();
  }, delay);
}

async function refreshStatus() {
  if (!S.token) return;
  if (S.statusInFlight) {
    S.statusAgain = true;
    return;
  }
  S.statusInFlight = true;
  try {
    const st = await api('GET', '/api/status');
    applyStatus(st);
    if (st.devices && st.devices.laser) refreshInterlock();
  } catch (e) {
    if (e.status !== 401) showError(e, 'Reading the rig status');
  } finally {
    S.statusInFlight = false;
    if (S.statusAgain) {
      S.statusAgain = false;
      scheduleStatus(100);
    }
  }
}

async function refreshInterlock() {
  try {
    S.interlock = await api('GET', '/api/interlock');
  } catch (e) {
    S.interlock = e.status === 404 ? null : { error: e.message };
  }
  renderLaser();
}

function applyStatus(st) {
  const prevRun = S.run;
  S.status = st;
  S.run = st.run || null;
  if (S.run && S.run.state === 'paused' && pauseReason(S.run)) {
    showWarning(`Run ${S.run.run_id} paused: ${pauseReason(S.run)}`, S.run);
  }
  if (S.run) {
    S.lastRun = { ...S.run, finished: null };
    S.prompt = S.run.prompt ? { run_id: S.run.run_id, ...S.run.prompt } : null;
  } else {
    S.prompt = null;
    if (prevRun && S.lastRun && !S.lastRun.finished) {
      // The run ended between two status reads; its run_finished event says how.
      S.lastRun.finished = S.lastRun.finished || { status: 'ended' };
      scheduleRuns();
    }
  }
  renderAll();
}

function runActive() {
  return !!S.run;
}

/** The daemon refuses manual device commands while a run is active (paused too). */
function runBusy() {
  return !!S.run;
}

// ---------------------------------------------------------------- enables

/**
 * Every control says what it needs in data-need (space separated): `operator` (not read-only),
 * `noestop`, `manual` (no run driving the rig), `run`, `running`, `paused`, `script`.
 */
function applyEnables() {
  const estop = !!(S.status && S.status.estop);
  const ok = {
    operator: S.role !== 'read_only',
    noestop: !estop,
    manual: !runBusy(),
    run: runActive(),
    running: !!S.run && (S.run.state === 'running' || S.run.state === 'prompt'),
    paused: !!S.run && S.run.state === 'paused',
    norun: !runActive(),
    script: scriptStartable(),
    uploaded: selectedScriptUploaded(),
    selected: !!$('script-select').value,
    laserarmed: !!(S.status && S.status.devices.laser && S.status.devices.laser.armed),
    laserdisarmed: !(S.status && S.status.devices.laser && S.status.devices.laser.armed),
  };
  for (const el of document.querySelectorAll('[data-need]')) {
    const needs = el.dataset.need.split(/\s+/).filter(Boolean);
    el.disabled = !!el.dataset.busy || !needs.every((n) => ok[n]);
  }
  $('script-upload-label').classList.toggle('disabled', $('script-upload').disabled);
  // Why the device controls are off.
  const note = $('device-note');
  let why = '';
  if (S.role === 'read_only') why = 'Read-only token: device controls are disabled.';
  else if (estop) why = 'E-stop latched: reset it before moving anything or switching lamps or the laser on.';
  else if (runBusy()) why = `Run ${S.run.run_id} is active: manual controls are off until it ends or is aborted (Stop and E-STOP always work).`;
  note.hidden = !why;
  note.textContent = why;
  // Why Start is off.
  let startWhy = '';
  if (S.role === 'read_only') startWhy = 'read-only token';
  else if (estop) startWhy = 'e-stop latched';
  else if (runActive()) startWhy = 'a run is active';
  else if (!$('script-select').value) startWhy = 'select a script';
  else if (S.setError) startWhy = 'fix the parameters first';
  else if (S.dryrunFor === dryrunKey() && S.dryrun && S.dryrun.ok === false) startWhy = 'fix the errors first';
  else if (S.dryrunFor !== dryrunKey()) startWhy = 'checking the script…';
  $('run-start-note').textContent = startWhy;
}

// ---------------------------------------------------------------- render

function renderAll() {
  const st = S.status;
  if (!st) return;
  $('rig-name').textContent = `${st.rig.name}${st.rig.simulated ? ' (simulated)' : st.rig.emulated ? ' (emulated)' : ''}`;
  document.title = `stagehand · ${st.rig.name}`;
  $('estop-banner').hidden = !st.estop;
  document.body.classList.toggle('estopped', !!st.estop);
  renderAxes();
  renderLamps();
  renderLaser();
  renderCart();
  renderCameraTiles();
  renderRun();
  renderPrompt();
  applyEnables();
}

function renderAxes() {
  const box = $('axes');
  const axes = S.status.devices.axes || [];
  const ids = axes.map((a) => a.id).join(',');
  if (box.dataset.ids !== ids) {
    box.dataset.ids = ids;
    box.replaceChildren(...axes.map(axisRow));
    if (!axes.length) box.append(h('p', { class: 'muted' }, 'This rig has no axes.'));
  }
  for (const a of axes) {
    const row = box.querySelector(`[data-axis="${CSS.escape(a.id)}"]`);
    if (!row) continue;
    row.querySelector('.axis-pos').textContent = fmtDeg(a.position_deg);
    const homed = row.querySelector('.b-homed');
    homed.textContent = a.homed ? 'homed' : 'not homed';
    homed.className = `badge b-homed ${a.homed ? 'badge-ok' : 'badge-warn'}`;
    row.querySelector('.b-moving').hidden = !a.moving;
    row.classList.toggle('moving', !!a.moving);
  }
}

function axisRow(a) {
  const id = a.id;
  const base = `/api/axes/${encodeURIComponent(id)}`;
  const jog = (d) => h('button', {
    type: 'button', class: 'btn btn-small jog', 'data-need': 'operator noestop manual',
    'data-jog': String(d), title: `Jog ${id} by ${d > 0 ? '+' : ''}${d}°`,
    onclick: (ev) => act(ev.currentTarget, 'POST', `${base}/jog`, { delta_deg: d }, `Jog ${id}`),
  }, `${d > 0 ? '+' : '−'}${Math.abs(d)}°`);
  const input = h('input', {
    type: 'number', step: 'any', min: a.min_deg, max: a.max_deg, class: 'move-input',
    'aria-label': `${id} target in degrees`, placeholder: 'deg', 'data-need': 'operator noestop manual',
  });
  const move = (ev) => {
    ev.preventDefault();
    const v = parseFloat(input.value);
    if (!Number.isFinite(v)) {
      showError(new Error(`type a target angle in degrees (${a.min_deg}…${a.max_deg})`), `Move ${id}`);
      return;
    }
    act(form.querySelector('button'), 'POST', `${base}/move`, { target_deg: v }, `Move ${id}`);
  };
  // novalidate: an out-of-range target goes to the daemon, whose answer says what is wrong.
  const form = h('form', { class: 'row move-form', novalidate: true, onsubmit: move }, input,
    h('button', { type: 'submit', class: 'btn btn-small', 'data-need': 'operator noestop manual' }, 'Move'));
  return h('div', { class: 'axis', dataset: { axis: id } },
    h('div', { class: 'axis-head' },
      h('span', { class: 'axis-id' }, id),
      h('span', { class: 'axis-pos', 'aria-live': 'off' }, fmtDeg(a.position_deg)),
      h('span', { class: 'badge b-homed' }, ''),
      h('span', { class: 'badge badge-info b-moving', hidden: true }, 'moving'),
      h('span', { class: 'axis-spacer' }),
      h('button', {
        type: 'button', class: 'btn btn-small', 'data-need': 'operator noestop manual',
        onclick: (ev) => act(ev.currentTarget, 'POST', `${base}/home`, undefined, `Home ${id}`),
      }, 'Home'),
      h('button', {
        type: 'button', class: 'btn btn-small btn-stop', 'data-need': 'operator',
        onclick: (ev) => act(ev.currentTarget, 'POST', `${base}/stop`, undefined, `Stop ${id}`),
      }, 'Stop')),
    h('div', { class: 'row axis-ctl' },
      jog(-10), jog(-1), jog(1), jog(10), form,
      h('span', { class: 'muted small axis-range', title: 'travel limits' }, `${a.min_deg}…${a.max_deg}°`)));
}

function renderLamps() {
  const box = $('lamps');
  const lamps = S.status.devices.lamps || [];
  const ids = lamps.map((l) => l.id).join(',');
  if (box.dataset.ids !== ids) {
    box.dataset.ids = ids;
    box.replaceChildren(...lamps.map((l) => h('button', {
      type: 'button', class: 'lamp', dataset: { lamp: l.id }, 'data-need': 'operator manual',
      title: `${l.id}: bank ${l.bank}, channel ${l.channel}`,
      onclick: (ev) => {
        const cur = (S.status.devices.lamps || []).find((x) => x.id === l.id);
        const on = !(cur && cur.on);
        if (on && S.status.estop) {
          showError(new Error('the e-stop is latched'), `Switch ${l.id} on`);
          return;
        }
        act(ev.currentTarget, 'POST', `/api/lamps/${encodeURIComponent(l.id)}`, { on }, `Switch ${l.id} ${on ? 'on' : 'off'}`);
      },
    }, h('span', { class: 'lamp-dot' }), l.id)));
    if (!lamps.length) box.append(h('p', { class: 'muted' }, 'This rig has no lamps.'));
  }
  for (const l of lamps) {
    const b = box.querySelector(`[data-lamp="${CSS.escape(l.id)}"]`);
    if (!b) continue;
    b.classList.toggle('on', !!l.on);
    b.setAttribute('aria-pressed', l.on ? 'true' : 'false');
  }
  $('lamps-off').setAttribute('data-need', 'operator manual');
}

function renderLaser() {
  const box = $('laser');
  const laser = S.status && S.status.devices.laser;
  $('laser-section').hidden = !laser;
  if (!laser) return;
  if (!box.dataset.built) {
    box.dataset.built = '1';
    box.append(
      h('div', { class: 'row laser-state' },
        h('span', { class: 'laser-id' }),
        h('span', { class: 'badge l-armed' }),
        h('span', { class: 'badge l-on' }),
        h('span', { class: 'badge l-interlock' }),
        h('span', { class: 'badge l-watchdog' })),
      h('div', { class: 'row' },
        h('button', { type: 'button', id: 'laser-arm', class: 'btn btn-warn', 'data-need': 'operator noestop manual laserdisarmed', onclick: openArmDialog }, 'Arm…'),
        h('button', {
          type: 'button', id: 'laser-disarm', class: 'btn', 'data-need': 'operator',
          onclick: (ev) => act(ev.currentTarget, 'POST', '/api/laser/disarm', undefined, 'Disarm the laser'),
        }, 'Disarm'),
        h('button', {
          type: 'button', id: 'laser-on', class: 'btn btn-danger', 'data-need': 'operator noestop manual laserarmed',
          onclick: (ev) => act(ev.currentTarget, 'POST', '/api/laser/on', {}, 'Switch the laser on'),
        }, 'Laser on'),
        h('button', {
          type: 'button', id: 'laser-off', class: 'btn', 'data-need': 'operator',
          onclick: (ev) => act(ev.currentTarget, 'POST', '/api/laser/off', undefined, 'Switch the laser off'),
        }, 'Laser off'),
        h('button', { type: 'button', id: 'interlock-toggle', class: 'btn btn-small', hidden: true, 'data-need': 'operator', onclick: toggleInterlock }, '')));
  }
  box.querySelector('.laser-id').textContent = `${laser.id} · ${laser.fitted_nm} nm fitted`;
  const armed = box.querySelector('.l-armed');
  armed.textContent = laser.armed ? 'ARMED' : 'disarmed';
  armed.className = `badge l-armed ${laser.armed ? 'badge-danger' : 'badge-ok'}`;
  const on = box.querySelector('.l-on');
  on.textContent = laser.on ? 'EMITTING' : 'off';
  on.className = `badge l-on ${laser.on ? 'badge-danger' : 'badge-ok'}`;
  const il = box.querySelector('.l-interlock');
  const closed = interlockClosed();
  il.textContent = closed === true ? 'interlock closed' : closed === false ? 'interlock OPEN' : 'interlock ?';
  il.className = `badge l-interlock ${closed === true ? 'badge-ok' : closed === false ? 'badge-danger' : ''}`;
  il.title = S.interlock && S.interlock.error ? `cannot read the interlock: ${S.interlock.error}` : 'The enclosure interlock: the laser fires only when it is closed';
  // What switches the laser off if stagehand dies: a relay board's watchdog, or nothing (GRBL).
  const wd = box.querySelector('.l-watchdog');
  const noWatchdog = (laser.watchdog || '').startsWith('no watchdog');
  wd.textContent = noWatchdog ? 'NO WATCHDOG' : laser.watchdog_s != null ? `watchdog ${laser.watchdog_s} s` : 'simulated';
  wd.className = `badge l-watchdog ${noWatchdog ? 'badge-warn' : 'badge-ok'}`;
  wd.title = laser.watchdog || '';
  const tog = $('interlock-toggle');
  const canSet = !!(S.interlock && S.interlock.settable);
  tog.hidden = !(canSet && closed !== null);
  tog.textContent = closed ? 'Open interlock' : 'Close interlock';
  tog.title = `The interlock is ${S.interlock && S.interlock.source}: this opens or closes it (simulated and emulated rigs only)`;
}

function interlockClosed() {
  const il = S.interlock;
  if (!il || il.error) return null;
  if (typeof il.closed === 'boolean') return il.closed;
  return null;
}

function toggleInterlock(ev) {
  const closed = interlockClosed();
  act(ev.currentTarget, 'POST', '/api/interlock', { closed: !closed }, `${closed ? 'Open' : 'Close'} the interlock`)
    .then(refreshInterlock);
}

function openArmDialog() {
  const dlg = $('arm-dialog');
  const laser = S.status.devices.laser;
  $('arm-nm').textContent = laser ? laser.fitted_nm : '?';
  $('arm-check').checked = false;
  $('arm-confirm').disabled = true;
  dlg.returnValue = '';
  dlg.showModal();
}

function renderCart() {
  const cart = S.status.devices.cart;
  $('cart-section').hidden = !cart;
  if (cart) $('cart').textContent = `${cart.id} at ${cart.position_mm.toFixed(1)} mm`;
}

// ---------------------------------------------------------------- cameras

function renderCameraTiles() {
  const box = $('cameras');
  const cams = S.status.devices.cameras || [];
  const ids = cams.map((c) => c.id).join(',');
  if (box.dataset.ids === ids) return;
  box.dataset.ids = ids;
  S.cams.clear();
  box.replaceChildren();
  if (!cams.length) box.append(h('p', { class: 'muted' }, 'This rig has no cameras.'));
  for (const c of cams) {
    const img = h('img', { alt: `latest frame of ${c.id}`, class: 'cam-img', hidden: true });
    const empty = h('span', { class: 'cam-empty' }, 'no frame yet');
    const link = h('a', {
      class: 'cam-link', href: '#', title: 'Open the frame in the viewer',
      onclick: (ev) => {
        ev.preventDefault();
        const t = S.cams.get(c.id);
        if (t && t.shown) openViewer(t.shown, null);
      },
    }, img, empty);
    const caption = h('span', { class: 'cam-caption muted small' }, `${c.width}×${c.height}`);
    const fig = h('figure', { class: 'cam', dataset: { camera: c.id } },
      h('div', { class: 'cam-frame', style: { aspectRatio: `${c.width} / ${c.height}` } }, link),
      h('figcaption', {}, h('strong', {}, c.id), ' ', caption));
    box.append(fig);
    S.cams.set(c.id, { fig, img, empty, link, caption, loading: false, pending: null, shown: null, spec: c });
    loadLatest(c.id);
  }
}

async function loadLatest(id) {
  try {
    const fi = await api('GET', `/api/cameras/${encodeURIComponent(id)}/latest`);
    if (fi) showFrame(fi);
  } catch (e) {
    if (e.status !== 404 && e.status !== 401) showError(e, `Latest frame of ${id}`);
  }
}

function thumbUrl(fi) {
  const base = fi.thumbnail_url || `/api/runs/${encodeURIComponent(fi.run_id)}/frames/${fi.frame_id}/thumbnail`;
  return withToken(base, { size: THUMB_SIZE });
}

/** Shows a frame on its camera's tile; while a thumbnail loads, only the newest waits. */
function showFrame(fi) {
  const tile = S.cams.get(fi.camera);
  if (!tile) return;
  if (tile.shown && tile.shown.run_id === fi.run_id && tile.shown.frame_id >= fi.frame_id) return;
  if (tile.loading) {
    tile.pending = fi;
    return;
  }
  tile.loading = true;
  const im = new Image();
  im.alt = `latest frame of ${fi.camera}`;
  im.className = 'cam-img';
  const done = () => {
    tile.loading = false;
    const next = tile.pending;
    tile.pending = null;
    if (next) showFrame(next);
  };
  im.onload = () => {
    tile.img.replaceWith(im);
    tile.img = im;
    tile.empty.hidden = true;
    tile.shown = fi;
    const bits = [`step ${fi.step}`, fi.kind];
    if (fi.label) bits.push(fi.label);
    if (Number.isFinite(fi.exposure_s)) bits.push(`${fi.exposure_s < 1 ? `${+(fi.exposure_s * 1000).toFixed(2)} ms` : `${fi.exposure_s} s`}`);
    if (Array.isArray(fi.lamps_on) && fi.lamps_on.length) bits.push(fi.lamps_on.join('+'));
    if (fi.laser_on) bits.push('laser');
    tile.caption.textContent = bits.join(' · ');
    tile.caption.title = bits.join(' · ');
    tile.fig.title = `run ${fi.run_id}, frame ${fi.frame_id}`;
    tile.fig.dataset.run = fi.run_id;
    tile.fig.dataset.frame = String(fi.frame_id);
    tile.fig.classList.add('fresh');
    setTimeout(() => tile.fig.classList.remove('fresh'), 600);
    done();
  };
  im.onerror = () => {
    tile.empty.hidden = false;
    tile.empty.textContent = `thumbnail of frame ${fi.frame_id} failed to load`;
    done();
  };
  im.src = thumbUrl(fi);
}

// ---------------------------------------------------------------- scripts

async function loadScripts() {
  const sel = $('script-select');
  try {
    S.scripts = await api('GET', '/api/scripts');
  } catch (e) {
    sel.replaceChildren(h('option', { value: '' }, 'cannot list scripts'));
    if (e.status !== 401) showError(e, 'Listing the scripts');
    return;
  }
  const prev = sel.value;
  sel.replaceChildren(h('option', { value: '' }, S.scripts.length ? '— choose a script —' : 'no scripts (start the daemon with --scripts DIR)'),
    ...S.scripts.map((s) => h('option', { value: s.name }, `${s.name}${s.source === 'uploaded' ? ' (uploaded)' : ''}`)));
  if (prev && S.scripts.some((s) => s.name === prev)) sel.value = prev;
  applyEnables();
}

/** Parses "a=1 b=[1,2] c=text" into {a: 1, b: [1, 2], c: "text"}; values are JSON when they parse. */
function parseSet(text) {
  const set = {};
  for (const tok of text.trim().split(/\s+/).filter(Boolean)) {
    const i = tok.indexOf('=');
    if (i <= 0) throw new Error(`parameter \`${tok}\` is not name=value`);
    const k = tok.slice(0, i);
    const raw = tok.slice(i + 1);
    try {
      set[k] = JSON.parse(raw);
    } catch (_) {
      set[k] = raw;
    }
  }
  return set;
}

let dryrunSeq = 0;
let dryrunTimer = null;

/** What the dry run depends on: the script and the parameter text. */
function dryrunKey() {
  return `${$('script-select').value}\n${$('script-set').value.trim()}`;
}

/**
 * Start needs a script whose dry run (for the parameters as typed) is not known to fail.
 * A dry run still on its way does not disable Start: Start waits for it (see startRun), so a
 * parameter typed just before the click needs one click, not two.
 */
function scriptStartable() {
  if (!$('script-select').value || S.setError) return false;
  return !(S.dryrunFor === dryrunKey() && S.dryrun && S.dryrun.ok === false);
}

function selectedScriptUploaded() {
  const name = $('script-select').value;
  const entry = S.scripts.find((x) => x.name === name);
  return !!entry && entry.source === 'uploaded';
}

/** Validates the selection as the operator types (debounced); nothing happens if unchanged. */
function scheduleValidate(delay = 300) {
  clearTimeout(dryrunTimer);
  S.setError = null;
  try {
    parseSet($('script-set').value);
  } catch (e) {
    S.setError = e.message;
  }
  if (S.dryrunFor === dryrunKey() && !S.setError) {
    applyEnables();
    return;
  }
  if (S.setError) {
    const box = $('dryrun');
    box.className = 'dryrun dryrun-bad';
    box.replaceChildren(h('p', { class: 'error-text' }, `Parameters: ${S.setError}`),
      h('p', { class: 'muted small' }, 'Write parameters as name=value separated by spaces, e.g. lamp_count=1 sweep_lines=2.'));
    applyEnables();
    return;
  }
  $('dryrun').classList.add('checking');
  applyEnables();
  dryrunTimer = setTimeout(validateSelected, delay);
}

/** The dry run of the selected script with the typed parameters; resolves when shown. */
async function validateSelected() {
  clearTimeout(dryrunTimer);
  const name = $('script-select').value;
  const key = dryrunKey();
  const box = $('dryrun');
  applyEnables();
  if (!name) {
    S.dryrun = null;
    S.dryrunFor = key;
    box.className = 'dryrun muted';
    box.textContent = 'Select a script to see its dry run.';
    applyEnables();
    return;
  }
  let set;
  try {
    set = parseSet($('script-set').value);
    S.setError = null;
  } catch (e) {
    S.setError = e.message;
    scheduleValidate();
    return;
  }
  const my = ++dryrunSeq;
  if (S.dryrunFor === null || !S.dryrunFor.startsWith(`${name}\n`)) {
    box.className = 'dryrun muted';
    box.textContent = `Checking ${name}…`;
  } else {
    box.classList.add('checking');
  }
  let dr;
  try {
    dr = await api('POST', `/api/scripts/${encodeURIComponent(name)}/validate`, Object.keys(set).length ? { set } : {});
  } catch (e) {
    if (my !== dryrunSeq) return;
    // A 422 is the daemon refusing the parameters: show it in place, it is not a failure.
    S.dryrun = { ok: false, error: e.message };
    S.dryrunFor = key;
    box.className = 'dryrun dryrun-bad';
    box.replaceChildren(h('p', { class: 'error-text' }, e.status === 422 ? `Parameters: ${e.message}` : `Dry run failed: ${e.message}`),
      e.hint ? h('p', { class: 'muted' }, e.hint) : '');
    if (e.status !== 422) showError(e, `Dry run of ${name}`);
    applyEnables();
    return;
  }
  if (my !== dryrunSeq) return;
  S.dryrun = dr;
  S.dryrunFor = key;
  renderDryrun(dr, box);
  applyEnables();
}

/** Shows a dry run in `box`; `onJump(line, col)` makes the violations clickable. */
function renderDryrun(dr, box, onJump) {
  box.className = `dryrun ${dr.ok === false ? 'dryrun-bad' : 'dryrun-ok'}`;
  const est = dr.estimate || {};
  const frames = est.frames !== undefined ? est.frames
    : (est.raw_frames !== undefined ? est.raw_frames + (est.hdr_frames || 0) : undefined);
  const framesDetail = est.raw_frames !== undefined ? ` (${est.raw_frames} raw + ${est.hdr_frames || 0} HDR)` : '';
  const kv = (k, v, id) => [h('dt', {}, k), h('dd', { id }, v)];
  const violations = dr.violations || [];
  const nErr = violations.filter((v) => v.severity === 'error').length;
  box.replaceChildren(...[
    h('div', { class: 'dryrun-head' },
      h('span', { class: `badge ${dr.ok === false ? 'badge-danger' : 'badge-ok'}` }, dr.ok === false ? 'cannot run' : 'ready to run'),
      ' ', h('span', { class: 'muted small' }, dr.error ? 'the script has an error'
        : violations.length ? `${nErr} error(s), ${violations.length - nErr} warning(s)` : 'no problems found')),
    dr.error && !dr.steps ? null : h('dl', { class: 'kv' },
      kv('Rig time', `${fmtDuration(est.rig_time_s)}${est.prompts ? ` + ${est.prompts} prompt(s)` : ''}`, 'est-time'),
      kv('Steps', dr.steps !== undefined ? String(dr.steps) : '–', 'est-steps'),
      kv('Frames', frames !== undefined ? `${frames}${framesDetail}` : '–', 'est-frames'),
      kv('Data', fmtBytes(est.bytes), 'est-bytes')),
    dr.error ? h('p', { class: `error-text${onJump && dr.error_line ? ' jump' : ''}`, onclick: onJump && dr.error_line ? () => onJump(dr.error_line, dr.error_col || 1) : null },
      dr.error_line && !/:\d+:\d+/.test(dr.error) ? `${dr.error_line}:${dr.error_col || 1} ` : '', dr.error) : null,
    violations.length ? h('ul', { class: 'violations' }, violations.map((v) => h('li', {
      class: `sev-${v.severity}${onJump ? ' jump' : ''}`,
      title: onJump ? 'Go to this line' : null,
      onclick: onJump ? () => onJump(v.line, v.col) : null,
    },
      h('span', { class: 'mono' }, `${v.line}:${v.col}`), ' ',
      h('span', { class: `badge ${v.severity === 'error' ? 'badge-danger' : 'badge-warn'}` }, v.severity), ' ',
      v.message, v.step !== undefined && v.step !== null ? h('span', { class: 'muted' }, ` (step ${v.step})`) : null))) : null,
    dr.report ? h('details', {}, h('summary', {}, 'Full dry-run report'), h('pre', { class: 'report' }, dr.report)) : null,
  ].filter(Boolean));
}

async function startRun(ev) {
  const name = $('script-select').value;
  if (!name) return;
  const btn = ev.currentTarget;
  if (S.dryrunFor !== dryrunKey()) {
    // Typed just before the click: check first, then start (one click).
    btn.dataset.busy = '1';
    applyEnables();
    try {
      await validateSelected();
    } finally {
      delete btn.dataset.busy;
      applyEnables();
    }
    if (S.dryrun && S.dryrun.ok === false) {
      showError(new Error('the dry run found errors; they are listed under the script'), `Start ${name}`);
      return;
    }
  }
  let set;
  try {
    set = parseSet($('script-set').value);
  } catch (e) {
    showError(e, 'Start run');
    return;
  }
  const body = { script: name };
  if (Object.keys(set).length) body.set = set;
  const r = await act(btn, 'POST', '/api/runs', body, `Start ${name}`);
  if (r && r.run_id) {
    S.lastRun = { run_id: r.run_id, script: name, state: 'starting', progress: 0, finished: null };
    renderRun();
    showInfo(`Run ${r.run_id} started`);
  }
}

// ---------------------------------------------------------------- runs

function scheduleRuns() {
  if (S.runsTimer) return;
  S.runsTimer = setTimeout(() => {
    S.runsTimer = null;
    loadRuns();
  }, 300);
}

async function loadRuns() {
  let runs;
  try {
    runs = await api('GET', '/api/runs');
  } catch (e) {
    if (e.status !== 401) {
      $('runs-body').replaceChildren(h('tr', {}, h('td', { colspan: 8, class: 'error-text' },
        `Cannot list the runs: ${e.message}. Press ↻ to try again.`)));
      showError(e, 'Listing runs');
    }
    return;
  }
  if (!Array.isArray(runs)) return;
  runs.sort((a, b) => (b.created_unix_s || 0) - (a.created_unix_s || 0));
  S.runs = runs;
  renderHistory();
  // Before any run this session: show the newest run's outcome.
  if (!S.run && !S.lastRun && runs[0]) {
    const r = runs[0];
    S.lastRun = {
      run_id: r.run_id, script: r.script, steps_done: r.steps_done, total_steps: r.steps_total,
      frames_written: r.frames, progress: r.steps_total ? r.steps_done / r.steps_total : 0,
      finished: { status: r.status, message: r.message },
    };
    renderRun();
  }
  // A run whose end was seen only as its absence from the status (a status read that left
  // before its run_finished event and arrived after it): the run list has how it ended.
  if (!S.run && S.lastRun && S.lastRun.finished && S.lastRun.finished.status === 'ended') {
    const r = runs.find((x) => x.run_id === S.lastRun.run_id);
    if (r && r.status && r.status !== 'running') {
      S.lastRun.finished = { status: r.status, message: r.message };
      if (r.status === 'done') S.lastRun.progress = 1;
      renderRun();
    }
  }
}

/** Local date and time of a Unix time: `2026-12-01 20:31:07`. */
function fmtDateTime(unix_s) {
  if (!Number.isFinite(unix_s) || unix_s <= 0) return '–';
  const d = new Date(unix_s * 1000);
  const p2 = (n) => String(n).padStart(2, '0');
  return `${d.getFullYear()}-${p2(d.getMonth() + 1)}-${p2(d.getDate())} ${p2(d.getHours())}:${p2(d.getMinutes())}:${p2(d.getSeconds())}`;
}

/**
 * How long a run took: the listing's duration or end time when the daemon gives them; else
 * the end this page saw (its run_finished event); else, approximately, from the start to its
 * last frame (looked up once per run, see runEndFromFrames). The stored `rig_time_s` is the
 * rig's clock, not a duration, so it is not used.
 */
function runDuration(r) {
  const num = (...keys) => keys.map((k) => r[k]).find((v) => Number.isFinite(v));
  const dur = num('duration_s', 'wall_time_s', 'elapsed_s');
  if (dur !== undefined) return { text: fmtDuration(dur), title: 'wall-clock time from start to end' };
  const start = num('started_unix_s', 'start_unix_s', 'created_unix_s');
  const end = num('ended_unix_s', 'end_unix_s', 'finished_unix_s');
  if (start !== undefined && end !== undefined && end >= start) {
    return { text: fmtDuration(end - start), title: `${fmtDateTime(start)} → ${fmtDateTime(end)}` };
  }
  if (r.active) {
    const since = S.run && S.run.run_id === r.run_id && Number.isFinite(S.run.started_unix_s) ? S.run.started_unix_s : start;
    return { text: since ? `${fmtDuration(Date.now() / 1000 - since)} so far` : 'running', title: 'running now' };
  }
  const seen = S.runEnds.get(r.run_id);
  if (start !== undefined && Number.isFinite(seen) && seen >= start) {
    return { text: fmtDuration(seen - start), title: `${fmtDateTime(start)} → ${fmtDateTime(seen)}` };
  }
  const last = S.lastFrameAt.get(r.run_id);
  if (start !== undefined && Number.isFinite(last) && last >= start) {
    return { text: `≈ ${fmtDuration(last - start)}`, title: `from the start to the last frame (${fmtDateTime(last)}); the daemon does not list when runs end` };
  }
  if (last === undefined && r.frames > 0) runEndFromFrames(r);
  return { text: '–', title: r.frames ? 'looking up the last frame…' : 'no frames: the daemon does not list when runs end' };
}

/** Looks up when a run's last frame was captured (once per run; the history redraws). */
async function runEndFromFrames(r) {
  S.lastFrameAt.set(r.run_id, null);
  try {
    const page = await api('GET', `/api/runs/${encodeURIComponent(r.run_id)}/frames?limit=1&offset=${Math.max(0, r.frames - 1)}`);
    const f = page && page.frames && page.frames[0];
    S.lastFrameAt.set(r.run_id, f && Number.isFinite(f.wall_time_unix_s) ? f.wall_time_unix_s : NaN);
  } catch (_) {
    S.lastFrameAt.set(r.run_id, NaN);
  }
  clearTimeout(S.historyRedraw);
  S.historyRedraw = setTimeout(renderHistory, 50);
}

const HISTORY_SHORT = 15;

function renderHistory() {
  const runs = S.runs || [];
  const body = $('runs-body');
  const shown = S.historyAll ? runs : runs.slice(0, HISTORY_SHORT);
  body.replaceChildren(...shown.map((r) => {
    const dur = runDuration(r);
    const canResume = !!r.resumable || (r.resumable === undefined && ['aborted', 'failed', 'interrupted'].includes(r.status));
    const why = r.error || r.message;
    return h('tr', { dataset: { run: r.run_id }, class: S.browse && S.browse.run === r.run_id ? 'selected' : null },
      h('td', { class: 'mono' }, r.run_id),
      h('td', {}, (r.script || '').replace(/\.rhai$/, '') || '–'),
      h('td', { class: 'when' }, fmtDateTime(r.created_unix_s)),
      h('td', { class: 'when', title: dur.title }, dur.text),
      h('td', {}, h('span', { class: `badge run-status ${statusClass(r.status)}` }, r.status),
        why ? h('span', { class: 'msg muted small', title: why }, why) : null),
      h('td', { class: 'num' }, `${r.steps_done ?? '–'}/${r.steps_total ?? '–'}`),
      h('td', { class: 'num' }, r.frames ?? '–'),
      h('td', { class: 'actions' },
        h('button', {
          type: 'button', class: 'btn btn-small browse-btn', disabled: !r.frames,
          title: r.frames ? 'Browse the frames of this run' : 'This run has no frames',
          onclick: () => openBrowser(r),
        }, 'Frames'),
        canResume ? ' ' : null,
        canResume ? h('button', {
          type: 'button', class: 'btn btn-small btn-primary resume-btn', 'data-need': 'operator noestop norun',
          title: 'Continue this run: steps already on disk are skipped',
          onclick: (ev) => resumeStored(ev, r),
        }, 'Resume') : null));
  }));
  if (!runs.length) body.append(h('tr', {}, h('td', { colspan: 8, class: 'muted' }, 'No runs yet: start one above, or press "Capture now".')));
  $('history-more').hidden = runs.length <= HISTORY_SHORT;
  $('history-more').textContent = S.historyAll ? `Show the newest ${HISTORY_SHORT}` : `Show all ${runs.length} runs`;
  applyEnables();
}

async function resumeStored(ev, r) {
  const st = await act(ev.currentTarget, 'POST', `/api/runs/${encodeURIComponent(r.run_id)}/resume`, undefined, `Resume run ${r.run_id}`);
  if (st && st.run_id) {
    S.run = { ...st };
    S.lastRun = { ...st, finished: null };
    renderRun();
    showInfo(`Run ${r.run_id} resumed: ${Math.max(0, (st.total_steps || 0) - (st.steps_done || 0))} step(s) to do`);
    scheduleRuns();
  }
}

function statusClass(s) {
  if (s === 'done' || s === 'running') return 'badge-ok';
  if (s === 'aborted' || s === 'paused' || s === 'prompt' || s === 'stopping') return 'badge-warn';
  if (s === 'failed') return 'badge-danger';
  return '';
}

function renderRun() {
  const r = S.run || S.lastRun;
  const bar = $('run-progress');
  if (!r) {
    $('run-title').textContent = 'No run yet';
    $('run-badge').hidden = true;
    setProgress(0);
    $('run-details').textContent = '';
    return;
  }
  const fin = !S.run && r.finished;
  const state = fin ? r.finished.status : r.state || 'starting';
  $('run-title').replaceChildren(h('span', { class: 'mono' }, r.run_id || '…'), ` · ${r.script || ''}`);
  const badge = $('run-badge');
  badge.hidden = false;
  badge.textContent = state === 'done' ? 'finished' : state;
  badge.className = `badge ${statusClass(state)}`;
  let p = Number.isFinite(r.progress) ? r.progress : (r.total_steps ? (r.steps_done || 0) / r.total_steps : 0);
  if (fin && state === 'done') p = 1;
  setProgress(p);
  bar.classList.toggle('done', fin && state === 'done');
  bar.classList.toggle('stopped', fin && state !== 'done');
  const bits = [];
  if (r.total_steps) bits.push(`${r.steps_done ?? 0} of ${r.total_steps} steps`);
  if (!fin && r.step !== undefined && r.step !== null) bits.push(`current step ${r.step}${r.step_kind ? ` (${r.step_kind}${r.block ? ` in ${r.block}` : ''})` : ''}`);
  if (r.frames_written !== undefined) bits.push(`${r.frames_written} frames written`);
  if (Number.isFinite(r.rig_time_s)) bits.push(`rig time ${fmtDuration(r.rig_time_s)}${Number.isFinite(r.estimated_rig_time_s) ? ` of ≈${fmtDuration(r.estimated_rig_time_s)}` : ''}`);
  if (!fin && r.state === 'paused') bits.push(`paused${pauseReason(r) ? ` (${pauseReason(r)})` : ''}: no new step starts until Resume`);
  else if (!fin && Number.isFinite(r.eta_s)) {
    const at = new Date(Date.now() + r.eta_s * 1000).toLocaleTimeString([], { hour12: false, hour: '2-digit', minute: '2-digit' });
    bits.push(`ETA ${fmtDuration(r.eta_s)} (≈${at})`);
  }
  if (fin && r.finished.message) bits.push(r.finished.message);
  $('run-details').textContent = bits.join(' · ');
}

function setProgress(p) {
  const pct = Math.max(0, Math.min(100, Math.round(p * 1000) / 10));
  const shown = pct >= 100 ? '100' : pct.toFixed(pct < 10 ? 1 : 0);
  $('run-progress-bar').style.width = `${pct}%`;
  $('run-progress-text').textContent = `${shown} %`;
  $('run-progress').setAttribute('aria-valuenow', String(pct));
}

function onRunEvent(d) {
  const e = d.event;
  const mine = S.run && S.run.run_id === d.run_id;
  if (e === 'run_started') {
    // A warning about this run (why it stopped or paused) is over once it runs again.
    if (S.warningRun === d.run_id) {
      $('warning-banner').hidden = true;
      S.warningText = null;
      S.warningDismissed = null;
    }
    S.run = { ...(mine ? S.run : {}), run_id: d.run_id, script: (S.run && S.run.script) || (S.lastRun && S.lastRun.run_id === d.run_id && S.lastRun.script) || '', state: 'running', total_steps: d.total_steps, steps_done: d.total_steps - d.steps_to_do, estimated_rig_time_s: d.estimated_rig_time_s, progress: d.total_steps ? (d.total_steps - d.steps_to_do) / d.total_steps : 0 };
    S.lastRun = { ...S.run, finished: null };
  } else if (mine && e === 'step_started') {
    S.run.step = d.step;
    S.run.step_kind = d.kind;
    S.run.block = d.block;
  } else if (mine && e === 'step_finished') {
    S.run.steps_done = Math.max(S.run.steps_done || 0, d.step + 1);
    S.run.total_steps = d.total_steps;
    S.run.eta_s = d.eta_s;
    if (d.total_steps) S.run.progress = Math.max(S.run.progress || 0, S.run.steps_done / d.total_steps);
  } else if (mine && e === 'paused') {
    S.run.state = 'paused';
    const why = pauseReason(d);
    if (why) {
      S.run.reason = why;
      showWarning(`Run ${d.run_id} paused: ${why}`, d);
    }
  } else if (mine && e === 'resumed') {
    S.run.state = 'running';
    delete S.run.reason;
    if (S.warningRun === d.run_id && /paused/.test(S.warningText || '')) {
      $('warning-banner').hidden = true;
      S.warningText = null;
      S.warningDismissed = null;
    }
  } else if (e === 'run_finished') {
    const r = (S.run && S.run.run_id === d.run_id ? S.run : null) || (S.lastRun && S.lastRun.run_id === d.run_id ? S.lastRun : { run_id: d.run_id });
    S.lastRun = { ...r, finished: { status: d.status, message: d.message } };
    if (d.status === 'done') S.lastRun.progress = 1;
    S.run = null;
    S.prompt = null;
    renderPrompt();
    scheduleRuns();
  }
  if (S.run) S.lastRun = { ...S.run, finished: null };
  renderRun();
  applyEnables();
}

// ---------------------------------------------------------------- warnings

/** Why a run paused, from whatever field the daemon puts it in (none for a plain Pause). */
function pauseReason(r) {
  if (!r) return '';
  const v = r.reason ?? r.pause_reason ?? r.paused_reason ?? (r.state === 'paused' || r.event === 'paused' ? r.message : undefined);
  if (v === undefined || v === null || v === '') return '';
  return typeof v === 'string' ? v : (v.message || shortJson(v));
}

/**
 * Shows a warning in the banner under the header until it is dismissed. The same message
 * again (a resync repeating a paused run's reason) does not reopen a dismissed banner.
 */
function showWarning(message, d) {
  const text = String(message || 'warning');
  if (S.warningDismissed === text) return;
  const same = S.warningText === text;
  S.warningText = text;
  S.warningCount = same ? (S.warningCount || 1) + 1 : 1;
  $('warning-title').textContent = d && (d.device || d.source) ? `Warning from ${d.device || d.source}:` : 'Warning:';
  $('warning-message').textContent = text;
  $('warning-more').textContent = `${fmtClock(d && d.unix_s)}${S.warningCount > 1 ? ` · ×${S.warningCount}` : ''}${d && d.run_id ? ` · run ${d.run_id}` : ''}`;
  $('warning-banner').hidden = false;
  S.warningRun = d && d.run_id ? d.run_id : null;
}

function dismissWarning() {
  S.warningDismissed = S.warningText;
  $('warning-banner').hidden = true;
}

// ---------------------------------------------------------------- prompts

function onPromptEvent(d) {
  if (d.answered) {
    if (S.prompt && S.prompt.step === d.step) S.prompt = null;
  } else {
    S.prompt = { run_id: d.run_id, step: d.step, message: d.message };
    if (S.run) S.run.state = 'prompt';
  }
  renderPrompt();
}

function renderPrompt() {
  const p = S.prompt;
  const banner = $('prompt-banner');
  const wasHidden = banner.hidden;
  banner.hidden = !p;
  document.body.classList.toggle('prompting', !!p);
  if (!p) return;
  $('prompt-message').textContent = p.message || '(no message)';
  $('prompt-where').textContent = `(run ${p.run_id}, step ${p.step})`;
  if (wasHidden) {
    banner.scrollIntoView({ block: 'nearest' });
    $('prompt-continue').focus({ preventScroll: true });
  }
}

async function answerPrompt(ev, answer) {
  const p = S.prompt;
  if (!p) return;
  const r = await act(ev.currentTarget, 'POST', `/api/runs/${encodeURIComponent(p.run_id)}/prompt`, { answer }, `Answer the prompt (${answer})`);
  if (r !== undefined) {
    S.prompt = null;
    renderPrompt();
  }
}

// ---------------------------------------------------------------- events (SSE)

function startEvents() {
  stopEvents();
  const es = new EventSource(withToken('/api/events'));
  S.es = es;
  setConn('connecting');
  es.onopen = () => {
    S.sseOpen = true;
    setConn('live');
    if (S.sseWasOpen && S.logReady) {
      // Reconnected (maybe to a restarted daemon, whose sequence numbers start again):
      // catch up on what the log missed from the daemon's recent events.
      S.logSeqs.clear();
      addLocalLog('info', 'event stream reconnected');
      S.logReady = false;
      loadRecent(S.lastEventUnix);
      if (!S.scripts.length) loadScripts();
      loadRuns();
    }
    S.sseWasOpen = true;
  };
  es.onerror = () => {
    S.sseOpen = false;
    if (es.readyState === EventSource.CLOSED) {
      setConn('disconnected');
      // EventSource gives up on HTTP errors (401, 5xx): find out why, then retry.
      refreshStatus();
      setTimeout(() => {
        if (S.es === es && S.token) startEvents();
      }, 3000);
    } else {
      setConn('reconnecting');
    }
  };
  es.addEventListener('resync', (m) => {
    try {
      applyStatus(JSON.parse(m.data));
    } catch (e) {
      showError(e, 'Reading a resync event');
    }
  });
  // Named events the page knows; `interlock` and unnamed messages are taken too (a newer daemon
  // may send them), logged, and shown in the banner when they say they are warnings.
  for (const kind of ['device', 'run', 'frame', 'prompt', 'warning', 'estop', 'interlock', 'message']) {
    es.addEventListener(kind, (m) => {
      let ev;
      try {
        ev = JSON.parse(m.data);
      } catch (e) {
        showError(e, `Reading a ${kind} event`);
        return;
      }
      onHubEvent(ev);
    });
  }
}

function stopEvents() {
  if (S.es) S.es.close();
  S.es = null;
  S.sseOpen = false;
}

function setConn(state) {
  const el = $('conn');
  el.textContent = state;
  el.className = `badge ${state === 'live' ? 'badge-ok' : state === 'disconnected' ? 'badge-danger' : 'badge-warn'}`;
  el.title = state === 'live' ? 'Receiving live events' : 'The live event stream is not connected; the page may be stale';
}

function onHubEvent(ev) {
  addLog(ev);
  const d = ev.data || {};
  if (ev.kind === 'run' && d.run_id) {
    if (d.event === 'run_finished' && Number.isFinite(ev.unix_s)) S.runEnds.set(d.run_id, ev.unix_s);
    if (d.event === 'run_started') {
      S.runEnds.delete(d.run_id);
      S.lastFrameAt.delete(d.run_id);
    }
  }
  switch (ev.kind) {
    case 'run':
      onRunEvent(d);
      if (d.event === 'step_finished' || d.event === 'run_started' || d.event === 'run_finished' || d.event === 'prompt') scheduleStatus(300);
      // The history's steps and frames of the active run, a few times a minute.
      if (d.event === 'step_durable' && !S.runsSoon) {
        S.runsSoon = setTimeout(() => {
          S.runsSoon = null;
          scheduleRuns();
        }, 3000);
      }
      break;
    case 'frame':
      showFrame(d);
      break;
    case 'prompt':
      onPromptEvent(d);
      break;
    case 'device':
      applyDeviceEvent(d);
      scheduleStatus(400);
      break;
    case 'estop':
      if (S.status && d.active !== undefined) {
        S.status.estop = !!d.active;
        renderAll();
      }
      scheduleStatus(50);
      break;
    case 'warning':
      showWarning(d.message || shortJson(d), d);
      break;
    default:
      if (ev.kind === 'interlock') refreshInterlock();
      break;
  }
  // Any other event that says it is a warning (a run's own `warning` events come as a
  // `warning` event too, shown above).
  const saysWarning = d.type === 'warning' || d.level === 'warning' || d.severity === 'warning';
  if (saysWarning && ev.kind !== 'warning' && !(ev.kind === 'run' && d.event === 'warning')) showWarning(d.message || shortJson(d), d);
}

/** Applies what a `device` event says when its shape is recognisable (axis, lamp, laser). */
function applyDeviceEvent(d) {
  if (!S.status) return;
  const dev = S.status.devices;
  if (Array.isArray(d.axes)) {
    Object.assign(dev, d);
    renderAll();
    return;
  }
  const target = d.state && typeof d.state === 'object' ? d.state : d;
  const id = d.id || d.axis || d.lamp || d.device;
  const axis = (dev.axes || []).find((a) => a.id === id);
  if (axis) {
    for (const k of ['position_deg', 'homed', 'moving']) if (target[k] !== undefined) axis[k] = target[k];
    renderAxes();
    return;
  }
  const lamp = (dev.lamps || []).find((l) => l.id === id);
  if (lamp && target.on !== undefined) {
    lamp.on = !!target.on;
    renderLamps();
    return;
  }
  if (dev.laser && (id === dev.laser.id || d.kind === 'laser')) {
    for (const k of ['armed', 'on']) if (target[k] !== undefined) dev.laser[k] = !!target[k];
    renderLaser();
    applyEnables();
  }
  if (d.interlock !== undefined || d.closed !== undefined) refreshInterlock();
}

// ---------------------------------------------------------------- event log

function logKey(ev) {
  if (ev.kind !== 'device' || !ev.data) return null;
  if (ev.devKey !== undefined) return ev.devKey;
  const d = ev.data;
  return `device:${d.id || d.axis || d.lamp || d.device || ''}:${d.event || d.kind || ''}`;
}

/**
 * A `device` event carries the whole DevicesState: the log says what changed since the one
 * before (e.g. "turntable 12.30° moving · lamp1 on"), and the key groups a moving axis's
 * updates into one line.
 */
function describeSnapshot(ev) {
  const d = ev.data;
  const prev = S.logDevPrev;
  S.logDevPrev = d;
  const changes = [];
  const ids = [];
  const old = (list, id) => (prev && Array.isArray(list) ? list.find((x) => x.id === id) : null);
  for (const a of d.axes || []) {
    const p = old(prev && prev.axes, a.id);
    if (p && p.position_deg === a.position_deg && p.moving === a.moving && p.homed === a.homed) continue;
    ids.push(a.id);
    changes.push(`${a.id} ${fmtDeg(a.position_deg)}${a.moving ? ' moving' : ''}${p && !p.homed && a.homed ? ' homed' : ''}${p && p.homed && !a.homed ? ' NOT homed' : ''}`);
  }
  for (const l of d.lamps || []) {
    const p = old(prev && prev.lamps, l.id);
    if (p && p.on === l.on) continue;
    if (!p && !l.on) continue;
    ids.push(l.id);
    changes.push(`${l.id} ${l.on ? 'on' : 'off'}`);
  }
  if (d.laser) {
    const p = prev && prev.laser;
    if (!p || p.armed !== d.laser.armed || p.on !== d.laser.on) {
      ids.push(d.laser.id);
      changes.push(`${d.laser.id} ${d.laser.armed ? 'ARMED' : 'disarmed'}, ${d.laser.on ? 'EMITTING' : 'off'}`);
    }
  }
  if (d.cart) {
    const p = prev && prev.cart;
    if (!p || p.position_mm !== d.cart.position_mm) {
      ids.push(d.cart.id);
      changes.push(`${d.cart.id} ${d.cart.position_mm.toFixed(1)} mm`);
    }
  }
  // Only axis motion collapses into one line; lamp and laser switches stay separate lines.
  const onlyAxes = ids.length && ids.every((id) => (d.axes || []).some((a) => a.id === id));
  ev.devKey = onlyAxes ? `device:axes:${ids.join(',')}` : null;
  return changes.length ? changes.join(' · ') : 'no visible change';
}

function describe(kind, d) {
  d = d || {};
  switch (kind) {
    case 'run': return describeRun(d);
    case 'frame': return `${d.camera}: frame ${d.frame_id} of step ${d.step} (${d.kind}${d.label ? `, ${d.label}` : ''})`;
    case 'prompt': return d.answered ? `prompt at step ${d.step} answered: ${d.answered}` : `prompt at step ${d.step}: ${d.message}`;
    case 'warning': return d.message || shortJson(d);
    case 'estop':
      if (d.active === false) return 'e-stop reset';
      return `E-STOP latched: rig safe in ${Number.isFinite(d.elapsed_ms) ? `${d.elapsed_ms.toFixed(1)} ms` : '?'}${d.aborted_run ? `, run ${d.aborted_run} aborted` : ''}${d.errors && d.errors.length ? `; FAILED: ${d.errors.join('; ')}` : ''}`;
    case 'device': return describeDevice(d);
    default: return d.message || shortJson(d);
  }
}

function describeDevice(d) {
  const id = d.id || d.axis || d.lamp || d.device;
  const s = d.state && typeof d.state === 'object' ? d.state : d;
  if (id && s.position_deg !== undefined) {
    return `${id}${d.event ? ` ${d.event}` : ''} at ${fmtDeg(s.position_deg)}${s.moving ? ' (moving)' : ''}${s.homed === false ? ' (not homed)' : ''}`;
  }
  if (id && s.on !== undefined && s.armed === undefined) return `${id} ${s.on ? 'on' : 'off'}`;
  if (id && s.armed !== undefined) return `${id} ${s.armed ? 'armed' : 'disarmed'}, ${s.on ? 'emitting' : 'off'}`;
  if (d.message) return `${id ? `${id}: ` : ''}${d.message}`;
  return shortJson(d);
}

function describeRun(d) {
  const step = (n) => `step ${n}`;
  switch (d.event) {
    case 'run_started': return `run ${d.run_id} started: ${d.total_steps} steps${d.steps_to_do !== d.total_steps ? ` (${d.steps_to_do} to do)` : ''}, ≈${fmtDuration(d.estimated_rig_time_s)} rig time`;
    case 'step_started': return `${step(d.step)} started: ${d.kind}${d.block ? ` in ${d.block}` : ''}`;
    case 'step_finished': return `${step(d.step)} of ${d.total_steps} done: ${d.kind}${d.frames ? `, ${d.frames} frames` : ''}; ETA ${fmtDuration(d.eta_s)}`;
    case 'step_durable': return `${step(d.step)} on disk (${d.files} files)`;
    case 'prompt': return `${step(d.step)} asks: ${d.message}`;
    case 'paused': return `paused before ${step(d.before_step)}`;
    case 'resumed': return `resumed before ${step(d.before_step)}`;
    case 'warning': return `warning: ${d.message}`;
    case 'device_fault': return `${d.device} failed at ${step(d.step)} (attempt ${d.attempt}): ${d.message}`;
    case 'recovered': return `${d.device} recovered; ${step(d.step)} runs again`;
    case 'run_finished': return `run ${d.run_id} ${d.status === 'done' ? 'finished' : d.status}${d.message ? `: ${d.message}` : ''} (rig time ${fmtDuration(d.elapsed_rig_s)})`;
    default: return shortJson(d);
  }
}

function logClass(kind, d) {
  if (kind === 'estop' && d.active === false) return 'log-good';
  if (kind === 'estop' || kind === 'error') return 'log-bad';
  if (kind === 'warning' || (kind === 'run' && (d.event === 'warning' || d.event === 'device_fault'))) return 'log-warn';
  if (kind === 'prompt' || (kind === 'run' && d.event === 'prompt')) return 'log-prompt';
  if (kind === 'run' && d.event === 'run_finished') return d.status === 'done' ? 'log-good' : 'log-warn';
  return '';
}

function addLog(ev) {
  if (!S.logReady) {
    S.logBuffer.push(ev);
    return;
  }
  if (ev.seq !== undefined && ev.seq !== null) {
    if (S.logSeqs.has(ev.seq)) return;
    S.logSeqs.add(ev.seq);
  }
  if (ev.seq !== null && ev.seq !== undefined && ev.unix_s) S.lastEventUnix = Math.max(S.lastEventUnix || 0, ev.unix_s);
  const text = ev.kind === 'device' && ev.data && Array.isArray(ev.data.axes) ? describeSnapshot(ev) : describe(ev.kind, ev.data);
  const key = logKey(ev);
  const top = S.log[0];
  if (key && top && top.key === key) {
    top.count += 1;
    top.li.querySelector('.log-text').textContent = `${text} (×${top.count})`;
    top.li.querySelector('time').textContent = fmtClock(ev.unix_s);
    return;
  }
  const li = h('li', { class: `log-${ev.kind} ${logClass(ev.kind, ev.data || {})}`, dataset: { kind: ev.kind } },
    h('time', {}, fmtClock(ev.unix_s)),
    h('span', { class: 'log-kind' }, ev.kind),
    h('span', { class: 'log-text' }, text));
  $('log').prepend(li);
  S.log.unshift({ seq: ev.seq, kind: ev.kind, key, count: 1, li });
  while (S.log.length > LOG_MAX) {
    const old = S.log.pop();
    old.li.remove();
    if (old.seq !== undefined) S.logSeqs.delete(old.seq);
  }
}

function addLocalLog(kind, text) {
  addLog({ seq: null, kind, unix_s: Date.now() / 1000, data: { message: text } });
}

/** Fills the log from GET /api/events/recent (only events after `since`, Unix seconds, if given). */
async function loadRecent(since) {
  let recent = [];
  try {
    recent = await api('GET', '/api/events/recent');
  } catch (e) {
    if (e.status !== 401) showError(e, 'Reading the recent events');
  }
  const older = Array.isArray(recent) ? recent.filter((e) => since === undefined || e.unix_s > since) : [];
  const all = [...older, ...S.logBuffer];
  S.logBuffer = [];
  const seen = new Set();
  const live = all.filter((e) => e.seq === null || e.seq === undefined || (!seen.has(e.seq) && seen.add(e.seq)));
  live.sort((a, b) => (a.seq ?? Infinity) - (b.seq ?? Infinity));
  S.logReady = true;
  for (const e of live) addLog(e);
}

// ---------------------------------------------------------------- script editor, upload, delete

const ED = { builtinOf: null, timer: null, seq: 0, lastKey: null };
const NEW_SCRIPT = `// A new capture script (Rhai). See sequences/README.md in the stagehand sources for the API.
let exposure_s = param("exposure_s", 0.02);

home();
lamps_off();
block("one lamp", || {
    only_lamp(lamps()[0]);
    capture(exposure_s);
    lamps_off();
});
`;

function validScriptName(name) {
  const stem = name.replace(/\.rhai$/, '');
  if (!stem) return 'type a name for the script';
  if (stem.length > 64) return 'the name is longer than 64 characters';
  if (stem.startsWith('.') || stem.includes('..')) return 'the name must not start with a dot or contain `..`';
  const bad = /[^A-Za-z0-9_.-]/.exec(stem);
  if (bad) return `the character "${bad[0]}" is not allowed (letters, digits, _ - . only)`;
  return '';
}

/** Opens the editor on the selected script (`edit`) or a new one (`new`). */
async function openEditor(mode) {
  const name = $('script-select').value;
  let text = NEW_SCRIPT;
  let target = '';
  let note = 'New script: Save uploads it to the daemon.';
  ED.builtinOf = null;
  if (mode === 'edit') {
    if (!name) {
      showError(new Error('select a script in the list first'), 'Edit a script');
      return;
    }
    try {
      text = await api('GET', `/api/scripts/${encodeURIComponent(name)}`);
    } catch (e) {
      showError(e, `Reading script ${name}`);
      return;
    }
    const entry = S.scripts.find((x) => x.name === name);
    if (entry && entry.source === 'builtin') {
      ED.builtinOf = name;
      target = `${name}_edited`;
      note = `${name} is built in and read-only: Save stores your version under the name above.`;
    } else {
      target = name;
      note = 'Uploaded script: Save replaces it on the daemon.';
    }
  }
  showEditor(target, String(text), note);
}

function showEditor(name, text, note) {
  $('editor').hidden = false;
  $('editor-name').value = name;
  $('editor-text').value = text;
  $('editor-note').textContent = note;
  $('editor-status').textContent = '';
  ED.lastKey = null;
  validateEditor();
  $('editor').scrollIntoView({ block: 'nearest' });
  $('editor-text').focus({ preventScroll: true });
}

function closeEditor() {
  clearTimeout(ED.timer);
  ED.seq++;
  $('editor').hidden = true;
}

function scheduleEditorValidate() {
  clearTimeout(ED.timer);
  $('editor-dryrun').classList.add('checking');
  ED.timer = setTimeout(validateEditor, 350);
}

/** Dry run of the text in the editor (POST /api/validate, nothing stored). */
async function validateEditor() {
  clearTimeout(ED.timer);
  const box = $('editor-dryrun');
  const text = $('editor-text').value;
  const name = $('editor-name').value.trim();
  const nameProblem = validScriptName(name);
  // The script's own defaults: the run's parameters field belongs to the selected script.
  const body = { text };
  if (!nameProblem) body.name = name.replace(/\.rhai$/, '');
  const key = JSON.stringify(body);
  if (key === ED.lastKey) {
    box.classList.remove('checking');
    return;
  }
  const my = ++ED.seq;
  box.classList.add('checking');
  let dr;
  try {
    dr = await api('POST', '/api/validate', body);
  } catch (e) {
    if (my !== ED.seq) return;
    box.className = 'dryrun dryrun-bad';
    box.replaceChildren(h('p', { class: 'error-text' }, `Dry run failed: ${e.message}`), e.hint ? h('p', { class: 'muted' }, e.hint) : '');
    return;
  }
  if (my !== ED.seq) return;
  ED.lastKey = key;
  renderDryrun(dr, box, jumpTo);
  box.dataset.ok = String(dr.ok !== false);
}

/** Puts the editor's caret at line:col (1-based) and scrolls it into view. */
function jumpTo(line, col) {
  const ta = $('editor-text');
  const lines = ta.value.split('\n');
  const l = Math.max(1, Math.min(line, lines.length));
  let pos = 0;
  for (let i = 0; i < l - 1; i++) pos += lines[i].length + 1;
  pos += Math.max(0, Math.min((col || 1) - 1, lines[l - 1].length));
  ta.focus();
  ta.setSelectionRange(pos, pos);
  const lh = parseFloat(getComputedStyle(ta).lineHeight) || 18;
  ta.scrollTop = Math.max(0, (l - 4) * lh);
}

/** PUT /api/scripts/{name} with the text; selects the stored script and shows its dry run. */
async function storeScript(name, text, btn, what) {
  const stem = name.replace(/\.rhai$/, '');
  if (btn) {
    btn.dataset.busy = '1';
    applyEnables();
  }
  try {
    const dr = await api('PUT', `/api/scripts/${encodeURIComponent(stem)}`, text, 'text/plain; charset=utf-8');
    await loadScripts();
    $('script-select').value = stem;
    S.dryrunFor = null;
    scheduleValidate(0);
    return { stem, dr };
  } catch (e) {
    showError(e.status === 409
      ? new ApiError(409, e.message, 'choose another name: built-in scripts cannot be replaced', e.method, e.path)
      : e, what);
    return null;
  } finally {
    if (btn) delete btn.dataset.busy;
    applyEnables();
  }
}

async function saveEditor(ev) {
  const name = $('editor-name').value.trim();
  const problem = validScriptName(name);
  if (problem) {
    showError(new Error(problem), 'Save the script');
    $('editor-name').focus();
    return;
  }
  const r = await storeScript(name, $('editor-text').value, ev.currentTarget, `Save script ${name}`);
  if (!r) return;
  ED.builtinOf = null;
  $('editor-name').value = r.stem;
  $('editor-note').textContent = 'Uploaded script: Save replaces it on the daemon.';
  $('editor-status').textContent = `Saved as ${r.stem} at ${fmtClock()}${r.dr && r.dr.ok === false ? ' (it has errors: runs refuse it until they are fixed)' : ''}`;
  renderDryrun(r.dr, $('editor-dryrun'), jumpTo);
}

async function uploadScript(ev) {
  const input = ev.currentTarget;
  const file = input.files && input.files[0];
  input.value = '';
  if (!file) return;
  if (file.size > 256 * 1024) {
    showError(new Error(`${file.name} is ${fmtBytes(file.size)}; scripts may be at most 256 KiB`), 'Upload a script');
    return;
  }
  let text;
  try {
    text = await file.text();
  } catch (e) {
    showError(new Error(`cannot read ${file.name}: ${e.message}`), 'Upload a script');
    return;
  }
  const stem = file.name.replace(/\.rhai$/i, '').replace(/[^A-Za-z0-9_.-]/g, '_').replace(/^\.+/, '').slice(0, 64) || 'uploaded';
  const builtin = S.scripts.find((x) => x.name === stem && x.source === 'builtin');
  const target = builtin ? `${stem}_uploaded` : stem;
  const r = await storeScript(target, text, null, `Upload ${file.name}`);
  if (!r) return;
  showInfo(`Uploaded ${file.name} as ${r.stem}${r.dr && r.dr.ok === false ? ': it has errors, see the editor' : ''}`);
  showEditor(r.stem, text, 'Uploaded script: Save replaces it on the daemon.');
  $('editor-status').textContent = `Uploaded from ${file.name} at ${fmtClock()}`;
}

async function deleteScript(ev) {
  const name = $('script-select').value;
  if (!name || !selectedScriptUploaded()) return;
  if (!confirm(`Delete the uploaded script ${name}? Runs recorded with it keep their copy.`)) return;
  const r = await act(ev.currentTarget, 'DELETE', `/api/scripts/${encodeURIComponent(name)}`, undefined, `Delete script ${name}`);
  if (r === undefined) return;
  showInfo(`Deleted script ${name}`);
  if (!$('editor').hidden && $('editor-name').value.trim().replace(/\.rhai$/, '') === name) closeEditor();
  await loadScripts();
  $('script-select').value = '';
  S.dryrunFor = null;
  scheduleValidate(0);
}

// ---------------------------------------------------------------- single capture

async function singleCapture(ev) {
  ev.preventDefault();
  const ms = parseFloat($('capture-exposure').value);
  const gain = parseFloat($('capture-gain').value);
  if (!Number.isFinite(ms) || ms <= 0) {
    showError(new Error('type an exposure time in milliseconds, greater than 0'), 'Single capture');
    return;
  }
  if (!Number.isFinite(gain) || gain <= 0) {
    showError(new Error('type an analogue gain greater than 0 (1 is unity)'), 'Single capture');
    return;
  }
  const note = $('capture-note');
  note.textContent = 'capturing…';
  const r = await act($('capture-btn'), 'POST', '/api/capture', { exposure_s: ms / 1000, gain }, 'Single capture');
  if (!r) {
    note.textContent = '';
    return;
  }
  const frames = Array.isArray(r.frames) ? r.frames : [];
  note.textContent = `${frames.length} frame(s) in run ${r.run_id} at ${fmtClock()}`;
  note.dataset.run = r.run_id;
  for (const fi of frames) showFrame(fi);
  showInfo(`Captured ${frames.length} frame(s): run ${r.run_id}`);
  scheduleRuns();
}

// ---------------------------------------------------------------- frame browser

const PAGE_SIZE = 24;

function openBrowser(r) {
  S.browse = { run: r.run_id, summary: r, offset: 0, total: 0, frames: [], seq: 0 };
  const st = S.status && S.status.devices;
  const fill = (sel, ids) => {
    const prev = sel.value;
    sel.replaceChildren(h('option', { value: '' }, 'any'), ...ids.map((id) => h('option', { value: id }, id)));
    if (ids.includes(prev)) sel.value = prev;
  };
  fill($('f-camera'), st ? (st.cameras || []).map((c) => c.id) : []);
  fill($('f-lamp'), st ? (st.lamps || []).map((l) => l.id) : []);
  $('frames-run').textContent = r.run_id;
  $('frames-run-info').textContent = `${(r.script || '').replace(/\.rhai$/, '')} · ${fmtDateTime(r.created_unix_s)} · ${r.status}`;
  $('frames-card').hidden = false;
  for (const tr of document.querySelectorAll('#runs-body tr')) tr.classList.toggle('selected', tr.dataset.run === r.run_id);
  $('frames-card').scrollIntoView({ block: 'start' });
  loadFrames();
}

function frameFilters() {
  const q = new URLSearchParams();
  const cam = $('f-camera').value;
  const lamp = $('f-lamp').value;
  const kind = $('f-kind').value;
  const block = $('f-block').value.trim();
  const step = $('f-step').value.trim();
  if (cam) q.set('camera', cam);
  if (lamp) q.set('lamp', lamp);
  if (kind) q.set('kind', kind);
  if (block) q.set('block', block);
  if (step !== '') {
    if (!/^\d+$/.test(step)) throw new Error(`step "${step}" is not a whole number ≥ 0`);
    q.set('step', step);
  }
  return q;
}

let filterTimer = null;
function onFilterChange(delay) {
  clearTimeout(filterTimer);
  filterTimer = setTimeout(() => {
    if (!S.browse) return;
    S.browse.offset = 0;
    loadFrames();
  }, delay);
}

async function loadFrames() {
  const b = S.browse;
  if (!b) return;
  const grid = $('frames-grid');
  let q;
  try {
    q = frameFilters();
  } catch (e) {
    grid.replaceChildren(h('p', { class: 'error-text' }, `Filter: ${e.message}`));
    return;
  }
  q.set('limit', String(PAGE_SIZE));
  q.set('offset', String(b.offset));
  const my = ++b.seq;
  $('frames-count').textContent = 'loading…';
  let page;
  try {
    page = await api('GET', `/api/runs/${encodeURIComponent(b.run)}/frames?${q}`);
  } catch (e) {
    if (my !== b.seq || S.browse !== b) return;
    $('frames-count').textContent = '';
    grid.replaceChildren(h('p', { class: 'error-text' }, `Cannot list the frames of run ${b.run}: ${e.message}`),
      e.hint ? h('p', { class: 'muted' }, e.hint) : '');
    return;
  }
  if (my !== b.seq || S.browse !== b) return;
  b.total = page.total || 0;
  b.frames = page.frames || [];
  const n = b.frames.length;
  $('frames-count').textContent = `${b.total} frame${b.total === 1 ? '' : 's'} match${b.total === 1 ? 'es' : ''}`;
  $('frames-page').textContent = n ? `${b.offset + 1}–${b.offset + n} of ${b.total}` : '';
  $('frames-prev').disabled = b.offset <= 0;
  $('frames-next').disabled = b.offset + n >= b.total;
  if (!n) {
    grid.replaceChildren(h('p', { class: 'empty-note' }, b.total
      ? 'No frames on this page.'
      : 'No frame matches these filters. The block filter matches the block path as listed under each frame; Clear filters shows every frame.'));
    return;
  }
  grid.replaceChildren(...b.frames.map((fi, i) => frameTile(fi, i)));
}

function frameBits(fi) {
  const bits = [fi.kind === 'hdr' ? 'HDR' : 'raw'];
  if (Number.isFinite(fi.exposure_s)) bits.push(fmtExposure(fi.exposure_s));
  if (Array.isArray(fi.lamps_on) && fi.lamps_on.length) bits.push(fi.lamps_on.join('+'));
  if (fi.laser_on) bits.push('laser');
  if (fi.label) bits.push(fi.label);
  return bits;
}

function fmtExposure(s) {
  return s < 1 ? `${+(s * 1000).toFixed(3)} ms` : `${+s.toFixed(3)} s`;
}

function frameTile(fi, i) {
  const img = h('img', { alt: `${fi.camera}, step ${fi.step}`, loading: 'lazy', decoding: 'async' });
  img.addEventListener('error', () => {
    img.replaceWith(h('span', { class: 'cam-empty' }, 'thumbnail failed: open the frame to see why'));
  });
  img.src = thumbUrl(fi);
  return h('button', {
    type: 'button', class: 'frame-tile', dataset: { frame: String(fi.frame_id), camera: fi.camera },
    title: `frame ${fi.frame_id}: open in the viewer`, onclick: () => openViewer(fi, i),
  },
  h('span', { class: 'frame-thumb' }, img),
  h('span', { class: 'frame-cap' },
    h('strong', {}, fi.camera), ` · step ${fi.step}`,
    h('span', { class: 'muted' }, frameBits(fi).join(' · ')),
    h('span', { class: 'muted' }, fi.block || '(no block)')));
}

// ---------------------------------------------------------------- frame viewer

const V = { fi: null, idx: null, img: null, seq: 0, raf: 0 };

/** Opens `fi` in the viewer; `idx` is its place on the browser's page (for ‹ ›), or null. */
function openViewer(fi, idx) {
  const dlg = $('viewer');
  V.fi = fi;
  V.idx = idx;
  V.img = null;
  if (!dlg.open) dlg.showModal();
  $('viewer-title').textContent = `${fi.camera} · step ${fi.step} · frame ${fi.frame_id} · run ${fi.run_id}`;
  const status = $('viewer-status');
  status.hidden = false;
  status.className = 'muted';
  status.textContent = `Loading frame ${fi.frame_id} (${fi.width}×${fi.height}, ${fi.kind === 'hdr' ? '32-bit float' : `${fi.bit_depth}-bit`})…`;
  const canvas = $('viewer-canvas');
  canvas.hidden = true;
  delete canvas.dataset.ev;
  $('viewer-stats').textContent = '';
  clearHistogram();
  const list = S.browse && idx !== null ? S.browse.frames : null;
  $('viewer-prev').disabled = !list || idx <= 0;
  $('viewer-next').disabled = !list || idx >= list.length - 1;
  renderViewerMeta(fi);
  loadViewerImage(fi);
}

function renderViewerMeta(fi) {
  const kv = (k, v) => (v === undefined || v === null || v === '' ? [] : [h('dt', {}, k), h('dd', {}, v)]);
  const axes = fi.axes_deg && typeof fi.axes_deg === 'object'
    ? Object.entries(fi.axes_deg).map(([k, v]) => `${k} ${fmtDeg(v)}`).join(', ') : '';
  $('viewer-meta').replaceChildren(
    ...kv('Kind', fi.kind === 'hdr' ? `HDR (bracket ${(fi.exposures_s || []).map(fmtExposure).join(', ')})` : 'raw'),
    ...kv('Exposure', Number.isFinite(fi.exposure_s) ? `${fmtExposure(fi.exposure_s)}, gain ${fi.gain}` : ''),
    ...kv('Lamps on', Array.isArray(fi.lamps_on) ? (fi.lamps_on.join(', ') || 'none') : ''),
    ...kv('Laser', fi.laser_on ? `on, ${fi.laser_colour_nm} nm` : fi.laser_armed ? 'armed, off' : 'off'),
    ...kv('Axes', axes),
    ...kv('Block', fi.block || '–'),
    ...kv('Captured', fmtDateTime(fi.wall_time_unix_s)),
    ...kv('Size', `${fi.width}×${fi.height}, ${fmtBytes(fi.size_bytes)}`),
    ...kv('File', fi.path));
  const base = fi.url || `/api/runs/${encodeURIComponent(fi.run_id)}/frames/${fi.frame_id}`;
  const formats = fi.kind === 'hdr' ? ['exr', 'tiff'] : ['png', 'tiff', 'exr'];
  $('viewer-downloads').replaceChildren('Download: ', ...formats.flatMap((f, i) => [
    i ? ' · ' : '', h('a', { href: withToken(base, { format: f }), download: '' }, f.toUpperCase())]));
}

/** Fetches the frame's pixels: raw frames as the stored 16-bit PNG, HDR frames as float TIFF. */
async function loadViewerImage(fi) {
  const my = ++V.seq;
  const base = fi.url || `/api/runs/${encodeURIComponent(fi.run_id)}/frames/${fi.frame_id}`;
  const hdr = fi.kind === 'hdr';
  const path = hdr ? `${base.split('?')[0]}?format=tiff` : base;
  let img;
  try {
    let res;
    try {
      res = await fetch(path, { headers: { Authorization: `Bearer ${S.token}` } });
    } catch (e) {
      throw new Error(`cannot reach the daemon (${e.message})`);
    }
    if (!res.ok) {
      let msg = `${res.status} ${res.statusText}`;
      try {
        const j = await res.json();
        msg = `${j.error || msg}${j.hint ? ` (${j.hint})` : ''}`;
      } catch (_) { /* not JSON */ }
      throw new Error(msg);
    }
    const buf = await res.arrayBuffer();
    img = hdr ? await decodeTiff(buf) : await decodePng(buf);
  } catch (e) {
    if (my !== V.seq) return;
    const status = $('viewer-status');
    status.className = 'error-text';
    status.textContent = `Cannot show frame ${fi.frame_id} of run ${fi.run_id}: ${e.message}. `
      + 'Try the download links on the right; if they fail too, the file is damaged or missing on the daemon\'s disk.';
    return;
  }
  if (my !== V.seq) return;
  V.img = prepareImage(fi, img);
  const slider = $('viewer-exposure');
  slider.value = String(V.img.autoEv);
  $('viewer-status').hidden = true;
  const canvas = $('viewer-canvas');
  canvas.width = V.img.w;
  canvas.height = V.img.h;
  canvas.hidden = false;
  drawHistogram(V.img);
  renderViewerStats(V.img);
  drawViewer();
}

/** Finds the stagehand metadata embedded in the file (PNG iTXt / TIFF ImageDescription). */
function embeddedMeta(text) {
  if (!text) return {};
  try {
    const j = JSON.parse(text);
    return j && typeof j === 'object' ? j : {};
  } catch (_) {
    return {};
  }
}

/** Looks `key` up in the frame info, then anywhere in the embedded metadata. */
function metaValue(fi, meta, key) {
  if (fi[key] !== undefined && fi[key] !== null) return fi[key];
  const seen = new Set();
  const walk = (o, depth) => {
    if (!o || typeof o !== 'object' || depth > 4 || seen.has(o)) return undefined;
    seen.add(o);
    if (o[key] !== undefined && o[key] !== null) return o[key];
    for (const v of Object.values(o)) {
      const r = walk(v, depth + 1);
      if (r !== undefined) return r;
    }
    return undefined;
  };
  return walk(meta, 0);
}

/**
 * Turns decoded samples into what the viewer draws. Raw: DN = sample >> shift, where the shift
 * is the metadata's `sample_shift`, else 16 − sBIT when the PNG has an sBIT chunk, else 0 (DN
 * stored in the low bits); a sample at the sensor's maximum (2^bit_depth − 1) is saturated.
 */
function prepareImage(fi, d) {
  const meta = embeddedMeta(d.text);
  const n = d.w * d.h;
  if (d.float) {
    const v = d.data;
    let nonFinite = 0;
    const sample = [];
    const stride = Math.max(1, Math.floor((n * 3) / 200000));
    for (let i = 0; i < n * 3; i++) {
      if (!Number.isFinite(v[i])) nonFinite++;
      else if (i % stride === 0 && v[i] > 0) sample.push(v[i]);
    }
    sample.sort((a, b) => a - b);
    const q = (p) => (sample.length ? sample[Math.min(sample.length - 1, Math.round((sample.length - 1) * p))] : 1);
    const max = sample.length ? sample[sample.length - 1] : 1;
    const white = Math.max(q(0.995), max / 4, 1e-12);
    return { w: d.w, h: d.h, hdr: true, data: v, white, max, nonFinite, autoEv: 0, saturated: fi.saturated_samples };
  }
  const bitDepth = Number(metaValue(fi, meta, 'bit_depth')) || (d.sbit ? d.sbit : d.bitDepth);
  let shift = metaValue(fi, meta, 'sample_shift');
  shift = Number.isFinite(Number(shift)) && shift !== '' && shift !== null ? Number(shift)
    : (d.sbit && d.bitDepth === 16 ? 16 - d.sbit : 0);
  shift = Math.max(0, Math.min(15, shift | 0));
  const maxDN = 2 ** Math.min(16, bitDepth) - 1;
  if (!shift && d.bitDepth === 16 && bitDepth < 16) {
    // Neither metadata nor sBIT names a shift, but samples beyond the sensor's range mean
    // MSB-aligned storage: the shift is the low bits that are zero in every sample.
    let or = 0;
    let top = 0;
    for (let i = 0; i < d.data.length; i++) {
      or |= d.data[i];
      if (d.data[i] > top) top = d.data[i];
    }
    if (top > maxDN) {
      let tz = 0;
      while (tz < 16 - bitDepth && !(or & (1 << tz))) tz++;
      shift = tz;
    }
  }
  const black = Math.max(0, Math.min(maxDN - 1, Number(metaValue(fi, meta, 'black_level_dn')) || 0));
  const dn = shift ? new Uint16Array(d.data.length) : d.data;
  if (shift) for (let i = 0; i < dn.length; i++) dn[i] = d.data[i] >> shift;
  // Histograms: 256 bins per channel for the plot, a finer one for the percentile.
  const bins = 256;
  const hist = [new Uint32Array(bins), new Uint32Array(bins), new Uint32Array(bins)];
  const fine = new Uint32Array(maxDN + 1);
  const sum = [0, 0, 0];
  const lo = [Infinity, Infinity, Infinity];
  const hi = [0, 0, 0];
  let satPixels = 0;
  let satSamples = 0;
  for (let p = 0; p < n; p++) {
    let sat = false;
    for (let c = 0; c < 3; c++) {
      const x = Math.min(dn[p * 3 + c], maxDN);
      hist[c][Math.min(bins - 1, Math.floor((x * bins) / (maxDN + 1)))]++;
      fine[x]++;
      sum[c] += x;
      if (x < lo[c]) lo[c] = x;
      if (x > hi[c]) hi[c] = x;
      if (x >= maxDN) {
        sat = true;
        satSamples++;
      }
    }
    if (sat) satPixels++;
  }
  // White point: the 99.5th percentile, but at least a quarter of the way to the brightest.
  const target = 0.995 * n * 3;
  let acc = 0;
  let p995 = maxDN;
  for (let x = 0; x <= maxDN; x++) {
    acc += fine[x];
    if (acc >= target) {
      p995 = x;
      break;
    }
  }
  const brightest = Math.max(hi[0], hi[1], hi[2]);
  const white = Math.max(p995, black + (brightest - black) / 4, black + 1);
  const autoEv = Math.round(Math.log2((maxDN - black) / (white - black)) * 10) / 10;
  return {
    w: d.w, h: d.h, hdr: false, data: dn, maxDN, black, bitDepth, shift, sbit: d.sbit, hist,
    mean: sum.map((s) => s / n), lo, hi, satPixels, satSamples, autoEv: Math.max(-4, Math.min(8, autoEv)),
  };
}

function srgb8(x) {
  if (!(x > 0)) return 0;
  if (x >= 1) return 255;
  const y = x <= 0.0031308 ? 12.92 * x : 1.055 * x ** (1 / 2.4) - 0.055;
  return Math.round(y * 255);
}

function scheduleViewerDraw() {
  const ev = Number($('viewer-exposure').value);
  $('viewer-ev').textContent = `${ev >= 0 ? '+' : '−'}${Math.abs(ev).toFixed(1)} EV${V.img && Math.abs(ev - V.img.autoEv) < 0.05 ? ' (auto)' : ''}`;
  if (V.raf) return;
  V.raf = requestAnimationFrame(() => {
    V.raf = 0;
    drawViewer();
  });
}

/** Draws the frame at the slider's exposure: raw linear × 2^EV, HDR Reinhard-tone-mapped. */
function drawViewer() {
  const im = V.img;
  if (!im) return;
  const ev = Number($('viewer-exposure').value);
  const gain = 2 ** ev;
  const mark = $('viewer-sat').checked;
  $('viewer-ev').textContent = `${ev >= 0 ? '+' : '−'}${Math.abs(ev).toFixed(1)} EV${Math.abs(ev - im.autoEv) < 0.05 ? ' (auto)' : ''}`;
  const canvas = $('viewer-canvas');
  const ctx = canvas.getContext('2d');
  const out = ctx.createImageData(im.w, im.h);
  const o = out.data;
  const n = im.w * im.h;
  const src = im.data;
  if (!im.hdr) {
    const lut = new Uint8ClampedArray(im.maxDN + 1);
    const range = im.maxDN - im.black;
    for (let x = 0; x <= im.maxDN; x++) lut[x] = srgb8(((x - im.black) / range) * gain);
    const max = im.maxDN;
    for (let p = 0, i = 0, j = 0; p < n; p++, i += 3, j += 4) {
      const r = src[i] > max ? max : src[i];
      const g = src[i + 1] > max ? max : src[i + 1];
      const b = src[i + 2] > max ? max : src[i + 2];
      if (mark && (r >= max || g >= max || b >= max)) {
        o[j] = 255; o[j + 1] = 0; o[j + 2] = 255;
      } else {
        o[j] = lut[r]; o[j + 1] = lut[g]; o[j + 2] = lut[b];
      }
      o[j + 3] = 255;
    }
  } else {
    const k = (2 * gain) / im.white;
    const tm = (v) => {
      const x = v > 0 ? v * k : 0;
      return srgb8((x * (1 + x / 4)) / (1 + x));
    };
    for (let p = 0, i = 0, j = 0; p < n; p++, i += 3, j += 4) {
      const r = src[i];
      const g = src[i + 1];
      const b = src[i + 2];
      if (mark && !(Number.isFinite(r) && Number.isFinite(g) && Number.isFinite(b))) {
        o[j] = 255; o[j + 1] = 0; o[j + 2] = 255;
      } else {
        o[j] = tm(r); o[j + 1] = tm(g); o[j + 2] = tm(b);
      }
      o[j + 3] = 255;
    }
  }
  ctx.putImageData(out, 0, 0);
  canvas.dataset.ev = ev.toFixed(1);
}

function clearHistogram() {
  const c = $('viewer-hist');
  const ctx = c.getContext('2d');
  ctx.clearRect(0, 0, c.width, c.height);
  delete c.dataset.drawn;
  $('viewer-hist-scale').textContent = '';
}

/** Per-channel histogram (log counts): raw over 0..max DN, HDR over log2 radiance. */
function drawHistogram(im) {
  const c = $('viewer-hist');
  const ctx = c.getContext('2d');
  const W = c.width;
  const H = c.height;
  ctx.clearRect(0, 0, W, H);
  let hist = im.hist;
  let scale;
  if (im.hdr) {
    // 16 stops up to 2 stops above the white point.
    const top = Math.log2(im.white) + 2;
    const bottom = top - 16;
    hist = [new Uint32Array(256), new Uint32Array(256), new Uint32Array(256)];
    const v = im.data;
    for (let i = 0; i < v.length; i++) {
      const x = v[i];
      if (!(x > 0) || !Number.isFinite(x)) continue;
      const b = Math.floor(((Math.log2(x) - bottom) / 16) * 256);
      hist[i % 3][b < 0 ? 0 : b > 255 ? 255 : b]++;
    }
    scale = `log₂ radiance, ${(2 ** bottom).toPrecision(2)}…${(2 ** top).toPrecision(2)} DN/s; log count`;
  } else {
    scale = `DN 0…${im.maxDN} (${im.bitDepth}-bit${im.shift ? `, stored << ${im.shift}` : ''}); log count`;
  }
  let peak = 1;
  for (const hc of hist) for (const x of hc) if (x > peak) peak = x;
  const lp = Math.log1p(peak);
  ctx.globalCompositeOperation = 'lighter';
  const colours = ['rgba(255,70,70,0.75)', 'rgba(70,230,90,0.75)', 'rgba(80,140,255,0.85)'];
  hist.forEach((hc, ch) => {
    ctx.fillStyle = colours[ch];
    ctx.beginPath();
    ctx.moveTo(0, H);
    for (let b = 0; b < hc.length; b++) {
      const y = H - (Math.log1p(hc[b]) / lp) * (H - 4);
      ctx.lineTo((b / hc.length) * W, y);
      ctx.lineTo(((b + 1) / hc.length) * W, y);
    }
    ctx.lineTo(W, H);
    ctx.closePath();
    ctx.fill();
  });
  ctx.globalCompositeOperation = 'source-over';
  if (!im.hdr && im.satSamples) {
    ctx.fillStyle = '#ff00ff';
    ctx.fillRect(W - 3, 0, 3, H);
  }
  $('viewer-hist-scale').textContent = scale;
  c.dataset.drawn = '1';
}

function renderViewerStats(im) {
  const box = $('viewer-stats');
  if (im.hdr) {
    box.replaceChildren(
      h('div', {}, `Radiance (DN/s at gain 1): white point ${im.white.toPrecision(4)}, brightest ${im.max.toPrecision(4)}`),
      h('div', {}, `Saturated in every exposure of the bracket: ${Number.isFinite(im.saturated) ? im.saturated : '?'} samples`),
      im.nonFinite ? h('div', { class: 'error-text' }, `${im.nonFinite} non-finite samples (marked)`) : '');
    return;
  }
  const pct = (100 * im.satPixels) / (im.w * im.h);
  box.replaceChildren(
    h('div', {}, `Mean DN R ${im.mean[0].toFixed(1)} · G ${im.mean[1].toFixed(1)} · B ${im.mean[2].toFixed(1)}`),
    h('div', {}, `Range DN ${Math.min(...im.lo)}…${Math.max(...im.hi)} of ${im.maxDN}${im.black ? `, black level ${im.black}` : ''}`),
    h('div', { class: im.satPixels ? 'sat-count warn-text' : 'sat-count' },
      im.satPixels ? `Saturated: ${im.satPixels} pixels (${pct < 0.01 ? '<0.01' : pct.toFixed(2)} %), ${im.satSamples} samples at ${im.maxDN}` : 'No saturated pixels'));
}

function viewerStep(d) {
  if (!S.browse || V.idx === null) return;
  const i = V.idx + d;
  if (i < 0 || i >= S.browse.frames.length) return;
  openViewer(S.browse.frames[i], i);
}

// ---------------------------------------------------------------- image decoders

/** zlib-inflates bytes with the browser's DecompressionStream. */
async function inflate(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

/**
 * Decodes a PNG (greyscale or RGB, with or without alpha, 8 or 16 bits, not interlaced) to
 * interleaved RGB samples; returns the sBIT of the first channel and the `stagehand` text.
 */
async function decodePng(buf) {
  const u8 = new Uint8Array(buf);
  const dv = new DataView(buf);
  const sig = [137, 80, 78, 71, 13, 10, 26, 10];
  if (u8.length < 8 || sig.some((b, i) => u8[i] !== b)) throw new Error('the file is not a PNG');
  let pos = 8;
  let w = 0;
  let hgt = 0;
  let depth = 0;
  let ctype = 0;
  let interlace = 0;
  let sbit = null;
  let text = null;
  const idat = [];
  const latin1 = new TextDecoder('latin1');
  const utf8 = new TextDecoder('utf-8');
  while (pos + 8 <= u8.length) {
    const len = dv.getUint32(pos);
    const type = latin1.decode(u8.subarray(pos + 4, pos + 8));
    const data = u8.subarray(pos + 8, pos + 8 + len);
    if (data.length < len) throw new Error(`the PNG is truncated in its ${type} chunk`);
    pos += 12 + len;
    if (type === 'IHDR') {
      const d = new DataView(buf, data.byteOffset, len);
      w = d.getUint32(0);
      hgt = d.getUint32(4);
      depth = data[8];
      ctype = data[9];
      interlace = data[12];
    } else if (type === 'sBIT') {
      sbit = data[0];
    } else if (type === 'IDAT') {
      idat.push(data);
    } else if (type === 'iTXt' || type === 'tEXt') {
      const z = data.indexOf(0);
      const key = latin1.decode(data.subarray(0, z));
      if (key === 'stagehand') {
        if (type === 'tEXt') text = latin1.decode(data.subarray(z + 1));
        else {
          const compressed = data[z + 1] === 1;
          let p = z + 3;
          p = data.indexOf(0, p) + 1; // language tag
          p = data.indexOf(0, p) + 1; // translated keyword
          const body = data.subarray(p);
          text = utf8.decode(compressed ? await inflate(body) : body);
        }
      }
    } else if (type === 'IEND') break;
  }
  const channels = { 0: 1, 2: 3, 4: 2, 6: 4 }[ctype];
  if (!w || !hgt || !channels) throw new Error(`unsupported PNG colour type ${ctype}`);
  if (depth !== 8 && depth !== 16) throw new Error(`unsupported PNG bit depth ${depth}`);
  if (interlace) throw new Error('interlaced PNGs are not supported by the viewer');
  let total = 0;
  for (const c of idat) total += c.length;
  const z = new Uint8Array(total);
  let o = 0;
  for (const c of idat) {
    z.set(c, o);
    o += c.length;
  }
  const raw = await inflate(z);
  const bpp = (channels * depth) / 8;
  const stride = w * bpp;
  if (raw.length < hgt * (stride + 1)) throw new Error('the PNG image data is shorter than its size says');
  const px = new Uint8Array(hgt * stride);
  for (let y = 0; y < hgt; y++) {
    const f = raw[y * (stride + 1)];
    const line = y * (stride + 1) + 1;
    const row = y * stride;
    const up = row - stride;
    for (let i = 0; i < stride; i++) {
      const x = raw[line + i];
      const a = i >= bpp ? px[row + i - bpp] : 0;
      const b = y ? px[up + i] : 0;
      let v;
      switch (f) {
        case 0: v = x; break;
        case 1: v = x + a; break;
        case 2: v = x + b; break;
        case 3: v = x + ((a + b) >> 1); break;
        case 4: {
          const c = i >= bpp && y ? px[up + i - bpp] : 0;
          const p = a + b - c;
          const pa = Math.abs(p - a);
          const pb = Math.abs(p - b);
          const pc = Math.abs(p - c);
          v = x + (pa <= pb && pa <= pc ? a : pb <= pc ? b : c);
          break;
        }
        default: throw new Error(`bad PNG filter type ${f} in row ${y}`);
      }
      px[row + i] = v;
    }
  }
  const n = w * hgt;
  const out = new Uint16Array(n * 3);
  const sample = depth === 16 ? (k) => (px[2 * k] << 8) | px[2 * k + 1] : (k) => px[k];
  for (let p = 0; p < n; p++) {
    for (let c = 0; c < 3; c++) out[p * 3 + c] = sample(p * channels + (channels >= 3 ? c : 0));
  }
  return { w, h: hgt, bitDepth: depth, sbit, text, data: out, float: false };
}

/** Decodes a baseline TIFF strip image (uncompressed or deflate; 16-bit or 32-bit float RGB). */
async function decodeTiff(buf) {
  const dv = new DataView(buf);
  const u8 = new Uint8Array(buf);
  const order = dv.getUint16(0);
  const le = order === 0x4949;
  if (!le && order !== 0x4d4d) throw new Error('the file is not a TIFF');
  if (dv.getUint16(2, le) !== 42) throw new Error('not a classic TIFF (BigTIFF is not supported)');
  const ifd = dv.getUint32(4, le);
  const count = dv.getUint16(ifd, le);
  const tags = {};
  const sizes = { 1: 1, 2: 1, 3: 2, 4: 4, 16: 8 };
  for (let i = 0; i < count; i++) {
    const e = ifd + 2 + i * 12;
    const tag = dv.getUint16(e, le);
    const type = dv.getUint16(e + 2, le);
    const n = dv.getUint32(e + 4, le);
    const size = sizes[type];
    if (!size) continue;
    const at = n * size <= 4 ? e + 8 : dv.getUint32(e + 8, le);
    if (type === 2) {
      tags[tag] = new TextDecoder('latin1').decode(u8.subarray(at, at + n)).replace(/\0+$/, '');
      continue;
    }
    const vals = [];
    for (let k = 0; k < n; k++) {
      const p = at + k * size;
      vals.push(type === 1 ? dv.getUint8(p) : type === 3 ? dv.getUint16(p, le) : type === 4 ? dv.getUint32(p, le) : Number(dv.getBigUint64(p, le)));
    }
    tags[tag] = vals;
  }
  const w = tags[256][0];
  const hgt = tags[257][0];
  const bps = (tags[258] || [1])[0];
  const comp = (tags[259] || [1])[0];
  const spp = (tags[277] || [1])[0];
  const pred = (tags[317] || [1])[0];
  const fmt = (tags[339] || [1])[0];
  if (tags[322]) throw new Error('tiled TIFFs are not supported by the viewer');
  if ((tags[284] || [1])[0] !== 1) throw new Error('planar TIFFs are not supported by the viewer');
  if (comp !== 1 && comp !== 8 && comp !== 32946) throw new Error(`TIFF compression ${comp} is not supported`);
  if (!((fmt === 3 && bps === 32) || (fmt === 1 && bps === 16))) throw new Error(`TIFF samples of ${bps} bits (format ${fmt}) are not supported`);
  const offsets = tags[273];
  const counts = tags[279];
  const bytes = new Uint8Array(w * hgt * spp * (bps / 8));
  let o = 0;
  for (let s = 0; s < offsets.length; s++) {
    let chunk = u8.subarray(offsets[s], offsets[s] + counts[s]);
    if (comp !== 1) chunk = await inflate(chunk);
    bytes.set(chunk.subarray(0, Math.min(chunk.length, bytes.length - o)), o);
    o += chunk.length;
  }
  if (o < bytes.length) throw new Error('the TIFF image data is shorter than its size says');
  const bd = new DataView(bytes.buffer);
  const n = w * hgt;
  const floatOut = fmt === 3;
  const vals = floatOut ? new Float32Array(n * spp) : new Uint16Array(n * spp);
  for (let i = 0; i < n * spp; i++) vals[i] = floatOut ? bd.getFloat32(i * 4, le) : bd.getUint16(i * 2, le);
  if (pred === 2 && !floatOut) {
    for (let y = 0; y < hgt; y++) {
      for (let i = spp; i < w * spp; i++) vals[y * w * spp + i] = (vals[y * w * spp + i] + vals[y * w * spp + i - spp]) & 0xffff;
    }
  } else if (pred !== 1 && !(pred === 2 && !floatOut)) {
    throw new Error(`TIFF predictor ${pred} is not supported`);
  }
  const out = floatOut ? new Float32Array(n * 3) : new Uint16Array(n * 3);
  for (let p = 0; p < n; p++) for (let c = 0; c < 3; c++) out[p * 3 + c] = vals[p * spp + (spp >= 3 ? c : 0)];
  return { w, h: hgt, bitDepth: bps, sbit: null, text: tags[270] || null, data: out, float: floatOut };
}

// ---------------------------------------------------------------- start

async function start() {
  $('login').hidden = true;
  $('signout').hidden = false;
  S.logReady = false;
  S.logBuffer = [];
  S.log = [];
  S.logSeqs.clear();
  S.sseWasOpen = false;
  S.logDevPrev = null;
  $('log').replaceChildren();
  // Check the token before showing anything.
  try {
    const st = await api('GET', '/api/status');
    S.started = true;
    $('main').hidden = false;
    $('estop').hidden = false;
    applyStatus(st);
  } catch (e) {
    if (e.status !== 401) {
      showLogin(`Cannot read the rig status: ${e.message}. ${e.hint || ''}`);
      $('login-token').value = S.token || '';
    }
    return;
  }
  startEvents();
  if (S.status.devices.laser) refreshInterlock();
  const loads = Promise.all([loadScripts(), loadRecent(), loadRuns()]);
  const role = await detectRole();
  if (role === 'invalid') {
    unauthorized(new ApiError(401, 'the bearer token is not valid'));
    return;
  }
  S.role = role;
  renderRole();
  applyEnables();
  await loads;
}

function wire() {
  $('login-form').addEventListener('submit', (ev) => {
    ev.preventDefault();
    const t = $('login-token').value.trim();
    if (!t) return;
    S.token = t;
    try {
      localStorage.setItem(TOKEN_KEY, t);
    } catch (_) { /* ignore */ }
    $('login-token').value = '';
    start();
  });
  $('signout').addEventListener('click', () => {
    try {
      localStorage.removeItem(TOKEN_KEY);
    } catch (_) { /* ignore */ }
    S.token = null;
    S.role = 'unknown';
    renderRole();
    showLogin('');
  });
  $('estop').addEventListener('click', async (ev) => {
    const btn = ev.currentTarget;
    try {
      await api('POST', '/api/estop');
      if (S.status) {
        S.status.estop = true;
        renderAll();
      }
    } catch (e) {
      showError(e.status === 403
        ? new ApiError(403, 'this read-only token cannot e-stop the rig', 'use the rig\'s hardware emergency stop, or sign in with the operator token', e.method, e.path)
        : e, 'E-STOP');
    }
    btn.blur();
    scheduleStatus(50);
  });
  $('estop-reset').setAttribute('data-need', 'operator');
  $('estop-reset').addEventListener('click', (ev) => act(ev.currentTarget, 'POST', '/api/estop/reset', undefined, 'Reset the e-stop'));
  $('prompt-continue').setAttribute('data-need', 'operator');
  $('prompt-abort').setAttribute('data-need', 'operator');
  $('prompt-continue').addEventListener('click', (ev) => answerPrompt(ev, 'continue'));
  $('prompt-abort').addEventListener('click', (ev) => answerPrompt(ev, 'abort'));
  $('lamps-off').addEventListener('click', (ev) => act(ev.currentTarget, 'POST', '/api/lamps/off', undefined, 'Switch all lamps off'));
  $('script-select').addEventListener('change', () => scheduleValidate(0));
  $('script-set').addEventListener('input', () => scheduleValidate(300));
  $('script-set').addEventListener('change', () => scheduleValidate(0));
  $('script-refresh').addEventListener('click', () => loadScripts().then(() => {
    S.dryrunFor = null;
    scheduleValidate(0);
  }));
  $('run-start').setAttribute('data-need', 'operator noestop norun script');
  $('script-edit').setAttribute('data-need', 'selected');
  $('script-edit').addEventListener('click', () => openEditor('edit'));
  $('script-new').setAttribute('data-need', 'operator');
  $('script-new').addEventListener('click', () => openEditor('new'));
  $('script-upload').setAttribute('data-need', 'operator');
  $('script-upload').addEventListener('change', uploadScript);
  $('script-delete').setAttribute('data-need', 'operator uploaded');
  $('script-delete').addEventListener('click', deleteScript);
  $('editor-text').addEventListener('input', scheduleEditorValidate);
  $('editor-text').addEventListener('keydown', (ev) => {
    if (ev.key === 'Tab' && !ev.shiftKey && !ev.ctrlKey && !ev.altKey && !ev.metaKey) {
      // A tab key indents (4 spaces) instead of leaving the editor.
      ev.preventDefault();
      const ta = ev.currentTarget;
      ta.setRangeText('    ', ta.selectionStart, ta.selectionEnd, 'end');
      scheduleEditorValidate();
    } else if ((ev.ctrlKey || ev.metaKey) && ev.key === 's') {
      ev.preventDefault();
      if (!$('editor-save').disabled) $('editor-save').click();
    }
  });
  $('editor-name').addEventListener('input', scheduleEditorValidate);
  $('editor-save').setAttribute('data-need', 'operator');
  $('editor-save').addEventListener('click', saveEditor);
  $('editor-close').addEventListener('click', closeEditor);
  $('capture-btn').setAttribute('data-need', 'operator noestop norun');
  $('capture-form').addEventListener('submit', singleCapture);
  $('history-refresh').addEventListener('click', loadRuns);
  $('history-more').addEventListener('click', () => {
    S.historyAll = !S.historyAll;
    renderHistory();
  });
  $('frames-close').addEventListener('click', () => {
    $('frames-card').hidden = true;
    S.browse = null;
    for (const tr of document.querySelectorAll('#runs-body tr.selected')) tr.classList.remove('selected');
  });
  for (const id of ['f-camera', 'f-lamp', 'f-kind']) $(id).addEventListener('change', () => onFilterChange(0));
  for (const id of ['f-step', 'f-block']) $(id).addEventListener('input', () => onFilterChange(350));
  $('frames-filters').addEventListener('submit', (ev) => {
    ev.preventDefault();
    onFilterChange(0);
  });
  $('f-clear').addEventListener('click', () => {
    for (const id of ['f-camera', 'f-lamp', 'f-kind', 'f-step', 'f-block']) $(id).value = '';
    onFilterChange(0);
  });
  $('frames-refresh').addEventListener('click', loadFrames);
  $('frames-prev').addEventListener('click', () => {
    if (!S.browse) return;
    S.browse.offset = Math.max(0, S.browse.offset - PAGE_SIZE);
    loadFrames();
  });
  $('frames-next').addEventListener('click', () => {
    if (!S.browse) return;
    S.browse.offset += PAGE_SIZE;
    loadFrames();
  });
  $('viewer-exposure').addEventListener('input', scheduleViewerDraw);
  $('viewer-auto').addEventListener('click', () => {
    if (!V.img) return;
    $('viewer-exposure').value = String(V.img.autoEv);
    scheduleViewerDraw();
  });
  $('viewer-sat').addEventListener('change', scheduleViewerDraw);
  $('viewer-close').addEventListener('click', () => $('viewer').close());
  $('viewer-prev').addEventListener('click', () => viewerStep(-1));
  $('viewer-next').addEventListener('click', () => viewerStep(1));
  $('viewer').addEventListener('keydown', (ev) => {
    if (ev.target instanceof HTMLInputElement) return;
    if (ev.key === 'ArrowLeft') viewerStep(-1);
    else if (ev.key === 'ArrowRight') viewerStep(1);
  });
  $('viewer').addEventListener('close', () => {
    V.seq++;
    V.img = null;
  });
  $('warning-dismiss').addEventListener('click', dismissWarning);
  $('run-start').addEventListener('click', startRun);
  const runAct = (path, what) => (ev) => S.run && act(ev.currentTarget, 'POST', `/api/runs/${encodeURIComponent(S.run.run_id)}/${path}`, undefined, what);
  $('run-pause').setAttribute('data-need', 'operator running');
  $('run-resume').setAttribute('data-need', 'operator paused');
  $('run-abort').setAttribute('data-need', 'operator run');
  $('run-pause').addEventListener('click', runAct('pause', 'Pause the run'));
  $('run-resume').addEventListener('click', runAct('resume', 'Resume the run'));
  $('run-abort').addEventListener('click', (ev) => {
    if (!S.run) return;
    if (!confirm(`Abort run ${S.run.run_id}? Frames written so far are kept.`)) return;
    runAct('abort', 'Abort the run')(ev);
  });
  const check = $('arm-check');
  check.parentElement.title = ARM_PHRASE;
  check.addEventListener('change', () => {
    $('arm-confirm').disabled = !check.checked;
  });
  $('arm-dialog').addEventListener('close', () => {
    const dlg = $('arm-dialog');
    if (dlg.returnValue === 'arm' && check.checked) {
      act($('laser-arm'), 'POST', '/api/laser/arm', { confirm: true }, 'Arm the laser');
    }
  });
  // While an axis moves and no events say so, poll (e.g. the event stream is down).
  setInterval(() => {
    if (!S.started || !S.status) return;
    const moving = (S.status.devices.axes || []).some((a) => a.moving);
    if ((moving || S.run) && !S.sseOpen) refreshStatus();
    else if (moving) scheduleStatus(500);
  }, 1000);
  renderRole();
}

wire();
S.token = readToken();
if (S.token) start();
else showLogin('');
