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

/** fetch with the bearer token; resolves to the JSON (or text) body, rejects with ApiError. */
async function api(method, path, body) {
  const opts = { method, headers: { Authorization: `Bearer ${S.token}` } };
  if (body !== undefined) {
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
    script: !!$('script-select').value && !!S.dryrun && S.dryrun.ok !== false && S.dryrunFor === $('script-select').value,
    laserarmed: !!(S.status && S.status.devices.laser && S.status.devices.laser.armed),
    laserdisarmed: !(S.status && S.status.devices.laser && S.status.devices.laser.armed),
  };
  for (const el of document.querySelectorAll('[data-need]')) {
    const needs = el.dataset.need.split(/\s+/).filter(Boolean);
    el.disabled = !!el.dataset.busy || !needs.every((n) => ok[n]);
  }
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
  else if (S.dryrunFor !== $('script-select').value) startWhy = 'checking the script…';
  else if (S.dryrun && S.dryrun.ok === false) startWhy = 'fix the errors first';
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
    const link = h('a', { class: 'cam-link', target: '_blank', rel: 'noopener noreferrer', title: 'Open the full frame (PNG)' }, img, empty);
    const caption = h('span', { class: 'cam-caption muted small' }, `${c.width}×${c.height}`);
    const fig = h('figure', { class: 'cam', dataset: { camera: c.id } },
      h('div', { class: 'cam-frame', style: `aspect-ratio: ${c.width} / ${c.height}` }, link),
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

/** The frame itself for a new tab: raw frames as PNG; HDR frames (EXR/TIFF only, which
 * browsers cannot show) as a large tone-mapped preview. */
function fullUrl(fi) {
  if (fi.kind === 'hdr') return withToken(thumbUrl(fi).split('?')[0], { size: 1024 });
  const base = fi.url || `/api/runs/${encodeURIComponent(fi.run_id)}/frames/${fi.frame_id}`;
  return withToken(base, { format: 'png' });
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
    tile.link.href = fullUrl(fi);
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

async function validateSelected() {
  const name = $('script-select').value;
  const box = $('dryrun');
  S.dryrun = null;
  S.dryrunFor = null;
  applyEnables();
  if (!name) {
    box.className = 'dryrun muted';
    box.textContent = 'Select a script to see its dry run.';
    return;
  }
  let set;
  try {
    set = parseSet($('script-set').value);
  } catch (e) {
    box.className = 'dryrun';
    box.replaceChildren(h('p', { class: 'error-text' }, `Parameters: ${e.message}`));
    return;
  }
  const my = ++dryrunSeq;
  box.className = 'dryrun muted';
  box.textContent = `Checking ${name}…`;
  let dr;
  try {
    dr = await api('POST', `/api/scripts/${encodeURIComponent(name)}/validate`, Object.keys(set).length ? { set } : {});
  } catch (e) {
    if (my !== dryrunSeq) return;
    box.className = 'dryrun';
    box.replaceChildren(h('p', { class: 'error-text' }, `Dry run failed: ${e.message}`), e.hint ? h('p', { class: 'muted' }, e.hint) : '');
    showError(e, `Dry run of ${name}`);
    return;
  }
  if (my !== dryrunSeq) return;
  S.dryrun = dr;
  S.dryrunFor = name;
  renderDryrun(dr);
  applyEnables();
}

function renderDryrun(dr) {
  const box = $('dryrun');
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
    dr.error ? h('p', { class: 'error-text' }, dr.error) : null,
    violations.length ? h('ul', { class: 'violations' }, violations.map((v) => h('li', { class: `sev-${v.severity}` },
      h('span', { class: 'mono' }, `${v.line}:${v.col}`), ' ',
      h('span', { class: `badge ${v.severity === 'error' ? 'badge-danger' : 'badge-warn'}` }, v.severity), ' ',
      v.message, v.step !== undefined && v.step !== null ? h('span', { class: 'muted' }, ` (step ${v.step})`) : null))) : null,
    dr.report ? h('details', {}, h('summary', {}, 'Full dry-run report'), h('pre', { class: 'report' }, dr.report)) : null,
  ].filter(Boolean));
}

async function startRun(ev) {
  const name = $('script-select').value;
  if (!name) return;
  let set;
  try {
    set = parseSet($('script-set').value);
  } catch (e) {
    showError(e, 'Start run');
    return;
  }
  const body = { script: name };
  if (Object.keys(set).length) body.set = set;
  const r = await act(ev.currentTarget, 'POST', '/api/runs', body, `Start ${name}`);
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
    if (e.status !== 404 && e.status !== 401) showError(e, 'Listing runs');
    return;
  }
  if (!Array.isArray(runs)) return;
  runs.sort((a, b) => (b.created_unix_s || 0) - (a.created_unix_s || 0));
  $('runs-body').replaceChildren(...runs.slice(0, 10).map((r) => h('tr', {},
    h('td', { class: 'mono' }, r.run_id), h('td', {}, r.script), h('td', {}, h('span', { class: `badge ${statusClass(r.status)}` }, r.status)),
    h('td', {}, `${r.steps_done ?? '–'}/${r.steps_total ?? '–'}`), h('td', {}, r.frames ?? '–'))));
  if (!runs.length) $('runs-body').append(h('tr', {}, h('td', { colspan: 5, class: 'muted' }, 'no runs yet')));
  // Before any run this session: show the newest run's outcome.
  if (!S.run && !S.lastRun && runs[0]) {
    const r = runs[0];
    S.lastRun = {
      run_id: r.run_id, script: r.script, steps_done: r.steps_done, total_steps: r.steps_total,
      frames_written: r.frames, progress: r.steps_total ? r.steps_done / r.steps_total : 0,
      finished: { status: r.status },
    };
    renderRun();
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
  if (!fin && r.state === 'paused') bits.push('paused: no new step starts until Resume');
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
  } else if (mine && e === 'resumed') {
    S.run.state = 'running';
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
  for (const kind of ['device', 'run', 'frame', 'prompt', 'warning', 'estop']) {
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
  switch (ev.kind) {
    case 'run':
      onRunEvent(d);
      if (d.event === 'step_finished' || d.event === 'run_started' || d.event === 'run_finished' || d.event === 'prompt') scheduleStatus(300);
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
      showInfo(`Warning: ${d.message || shortJson(d)}`);
      break;
    default:
      break;
  }
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
  $('script-select').addEventListener('change', validateSelected);
  $('script-set').addEventListener('change', validateSelected);
  $('script-refresh').addEventListener('click', () => loadScripts().then(validateSelected));
  $('run-start').setAttribute('data-need', 'operator noestop norun script');
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
