// The operator station: what the subject sees and touches. Pairing, consent, the pursuit
// display with operator input, the survey after each test, "Stopped" while the E-stop is
// latched. Talks only to /api/station/* with the station's bearer token, and to
// /api/station/ws for input, live samples, changes and the E-stop latch.

import { api, el, wsUrl } from './common.js';

const TOKEN_KEY = 'bdft-station-token';
const CODE_KEY = 'bdft-station-code';
const CODE_AT_KEY = 'bdft-station-code-at';
const PAIRED_KEY = 'bdft-station-paired';
/** The server forgets an unused pairing code after an hour; ask for a new one a bit sooner. */
const CODE_LIFETIME_MS = 55 * 60 * 1000;
const POLL_MS = 1000;
/** After a failed registration, ask again this much later (not every poll). */
const REGISTER_RETRY_MS = 10000;
/** At most 250 input messages a second (the server allows 500). */
const MIN_SEND_MS = 4;
/** Close codes of the station socket (protocol: server_to_browser::station_close). */
const CLOSE_REPLACED = 4001;
const CLOSE_FLOOD = 1008;
const WINDOW_S = 5;          // the strip chart shows the last 5 s
const LONG_FRAME_MS = 25;
const SHAKE_OMEGA = 2 * Math.PI * 4; // the cab's 4 Hz mode (rad/s)
const MAX_INPUT_MM = 1000;   // the server drops anything larger
/** Longest survey comment, in characters (protocol: study::MAX_COMMENT_CHARS). */
const MAX_COMMENT_CHARS = 2000;
const PHASES = ['loading', 'unpaired', 'waiting', 'consent', 'ready', 'running', 'survey', 'move', 'held', 'done'];
/** While a test runs, the display's health goes to the server this often (and at once when
 * the page is hidden or shown): the server stops a test whose display is hidden or stalled. */
const DISPLAY_EVERY_MS = 250;

const $ = (id) => document.getElementById(id);

// ---------------------------------------------------------------------------------------
// Errors: one banner, several sources. Poll and socket problems clear themselves when the
// connection recovers; errors of an action stay until dismissed or the next action works.

const errors = new Map();

function setError(source, message) {
  if (message) errors.set(source, message);
  else errors.delete(source);
  const banner = $('error');
  if (errors.size === 0) {
    banner.hidden = true;
    $('error-text').textContent = '';
  } else {
    $('error-text').textContent = [...errors.values()].join('\n');
    banner.hidden = false;
  }
}

function describe(res) {
  const msg = res.data && typeof res.data.error === 'string' ? res.data.error : '';
  if (res.status === 0) return `Cannot reach the server (${msg || 'network error'}). Please tell the experimenter.`;
  return `${msg || 'The server answered with an error'} (HTTP ${res.status}). Please tell the experimenter.`;
}

// ---------------------------------------------------------------------------------------
// Token and pairing.

let token = localStorage.getItem(TOKEN_KEY);
let registering = false;
let registerAgainAt = 0;
/** Waiting to be paired: the state is not polled (it would answer 401 every second). */
let unpaired = false;

async function register() {
  if (registering || Date.now() < registerAgainAt) return;
  registering = true;
  try {
    const res = await api('POST', '/api/station/register', {});
    if (!res.ok || !res.data || !res.data.token) {
      registerAgainAt = Date.now() + REGISTER_RETRY_MS;
      setError('register', `Could not get a pairing code: ${describe(res)}`);
      return;
    }
    setError('register', null);
    token = res.data.token;
    localStorage.setItem(TOKEN_KEY, token);
    localStorage.setItem(CODE_KEY, res.data.pairing_code);
    localStorage.setItem(CODE_AT_KEY, String(Date.now()));
    localStorage.removeItem(PAIRED_KEY);
    showUnpaired();
  } finally {
    registering = false;
  }
}

function showUnpaired() {
  closeSocket();
  unpaired = true;
  $('pairing-code').textContent = localStorage.getItem(CODE_KEY) || '';
  show({ phase: 'unpaired' });
  waitForPairing();
}

let pairingWait = 0;

/**
 * Waits for the experimenter to pair this station: the server answers as soon as it is
 * paired (or "not yet" after 25 s: ask again), 404 when the code expired (register again).
 * A newer wait (a new code) ends the older.
 */
async function waitForPairing() {
  const mine = ++pairingWait;
  const asked = token;
  while (mine === pairingWait) {
    const res = await api('POST', '/api/station/pairing', { token: asked });
    if (mine !== pairingWait) return;
    if (res.ok && res.data && res.data.paired) {
      setError('pairing', null);
      pairingWait++;
      unpaired = false;
      refresh();
      return;
    }
    if (res.ok) {
      setError('pairing', null);
      continue;
    }
    if (res.status === 404) {
      pairingWait++;
      register();
      return;
    }
    setError('pairing', `Waiting for the pairing failed: ${describe(res)}`);
    await new Promise((r) => setTimeout(r, REGISTER_RETRY_MS));
  }
}

/** 401 from the state: not paired (yet), or no longer (the station was removed). */
function onUnauthorized() {
  const code = localStorage.getItem(CODE_KEY);
  const at = Number(localStorage.getItem(CODE_AT_KEY) || 0);
  const revoked = localStorage.getItem(PAIRED_KEY) === '1';
  const stale = at > 0 && Date.now() - at > CODE_LIFETIME_MS;
  if (!token || !code || revoked || stale) {
    register();
    return;
  }
  showUnpaired();
}

// ---------------------------------------------------------------------------------------
// State polling.

let state = null;       // the last state shown
let renderKey = null;
let inflight = false;
let again = false;
let pollTimer = null;

async function refresh() {
  if (replaced) return;
  if (inflight) {
    again = true;
    return;
  }
  inflight = true;
  clearTimeout(pollTimer);
  try {
    if (!token) {
      await register();
      return;
    }
    if (unpaired) return;
    const res = await api('GET', '/api/station/state', undefined, { bearer: token });
    if (res.status === 401) {
      setError('poll', null);
      onUnauthorized();
      return;
    }
    if (!res.ok) {
      setError('poll', describe(res));
      return;
    }
    setError('poll', null);
    setError('register', null);
    unpaired = false;
    localStorage.setItem(PAIRED_KEY, '1');
    ensureSocket();
    show(res.data);
  } finally {
    inflight = false;
    if (again) {
      again = false;
      refresh();
    } else if (!unpaired && !replaced) {
      pollTimer = setTimeout(refresh, POLL_MS);
    }
  }
}

// ---------------------------------------------------------------------------------------
// The socket: live samples, changes and the E-stop latch in, operator input out.

let socket = null;
let socketWanted = false;
let reconnectTimer = null;
/** The E-stop latch as the socket last said (it says so when it opens and on changes). */
let latched = false;
/** Another page of this station took over the socket: this one stays inactive. */
let replaced = false;

function ensureSocket() {
  socketWanted = true;
  if (socket || reconnectTimer) return;
  const ws = new WebSocket(wsUrl('/api/station/ws?token=' + encodeURIComponent(token)));
  socket = ws;
  ws.addEventListener('open', () => {
    setError('socket', null);
  });
  ws.addEventListener('message', (ev) => {
    let msg;
    try {
      msg = JSON.parse(ev.data);
    } catch {
      return;
    }
    if (msg.type === 'changed') refresh();
    else if (msg.type === 'live' && msg.sample) onSample(msg.sample);
    else if (msg.type === 'estop') onLatch(!!msg.latched);
  });
  ws.addEventListener('close', (ev) => {
    if (socket !== ws) return;
    socket = null;
    if (!socketWanted) return;
    if (ev.code === CLOSE_REPLACED) {
      // Reconnecting would take the station back from the other page, and it would do
      // the same: the two would take turns feeding the test.
      replaced = true;
      socketWanted = false;
      clearTimeout(pollTimer);
      setError('socket', null);
      if (state) show(state);
      return;
    }
    if (state && (state.phase === 'ready' || state.phase === 'running')) {
      setError('socket', 'The connection to the server was interrupted; reconnecting…');
    }
    reconnectTimer = setTimeout(() => {
      reconnectTimer = null;
      if (socketWanted) ensureSocket();
    }, ev.code === CLOSE_FLOOD ? 5 * 1000 : 1000);
  });
}

/** The E-stop was pressed or reset: "Stopped" at once, or back to what the state says. */
function onLatch(now) {
  if (now === latched) return;
  latched = now;
  if (state) show(state);
  if (!now) refresh();
}

function closeSocket() {
  socketWanted = false;
  latched = false;
  clearTimeout(reconnectTimer);
  reconnectTimer = null;
  if (socket) {
    const ws = socket;
    socket = null;
    ws.close();
  }
  setError('socket', null);
}

// ---------------------------------------------------------------------------------------
// Showing a phase.

function show(s) {
  const prev = state;
  state = s;
  const phase = PHASES.includes(s.phase) ? s.phase : 'waiting';
  const paired = phase !== 'loading' && phase !== 'unpaired';
  // What the page shows: the phase, unless it is stopped or inactive.
  const displayed = paired && replaced ? 'replaced' : paired && latched ? 'stopped' : phase;
  const active = displayed === phase;
  $('station-name').textContent = s.station && s.station.name ? `Station ${s.station.name}` : '';
  setLanguage(s);

  // Leaving a running test (or a different test now running, or stopped): report the
  // page's timing.
  if (run && (!active || phase !== 'running' || s.test.trial_id !== run.trialId)) finishRun();
  // Input is streamed during ready and running, for the test shown.
  input.trialId = active && (phase === 'ready' || phase === 'running') && s.test ? s.test.trial_id : null;

  // Rebuild a phase's content only when what it shows changed (a poll every second must
  // not wipe a half-filled survey or move the focus).
  const { station: _ignored, ...shown } = s;
  const key = phase === 'survey' ? `survey:${s.trial_id}:${JSON.stringify(s.survey)}:${s.label}` : JSON.stringify(shown);
  if (key !== renderKey || !prev || prev.phase !== phase) {
    renderKey = key;
    const render = renderers[phase];
    if (render) render(s);
  }
  if (active && phase === 'running' && !run) startRun(s.test);
  showStopped(active && ['ready', 'move', 'held'].includes(phase) ? s.stopped : null);

  if (document.body.dataset.phase !== displayed) {
    document.body.dataset.phase = displayed;
    for (const sec of document.querySelectorAll('section.phase')) sec.hidden = sec.dataset.for !== displayed;
    // Move the focus to the new content so that a keyboard or screen reader follows it.
    const target = document.querySelector(`section[data-for="${displayed}"] h1`);
    if (target) {
      target.tabIndex = -1;
      target.focus({ preventScroll: true });
    }
    window.scrollTo(0, 0);
  }
}

/** What the subject is told about a test that was stopped (never a controller's name). */
function showStopped(stopped) {
  const box = $('stopped-notice');
  if (!stopped) {
    box.hidden = true;
    return;
  }
  const why = {
    invalid: 'the display was hidden or stopped updating',
    aborted: 'it was stopped by the experimenter',
    incomplete: 'of a technical problem',
  }[stopped.status] || 'of a problem';
  const then = stopped.repeated ? 'It will be repeated later.' : 'The experimenter will decide how to go on.';
  const text = `${stopped.label} was stopped because ${why}. ${then}`;
  if (box.textContent !== text) box.textContent = text;
  box.hidden = false;
}

const renderers = {
  unpaired() {
    $('pairing-code').textContent = localStorage.getItem(CODE_KEY) || '';
  },
  waiting() {},
  consent(s) {
    const c = s.consent || {};
    $('consent-version').textContent = c.version || '';
    $('consent-text').replaceChildren(...paragraphs(c.text));
    $('consent-text').scrollTop = 0;
    confirmDecline(false, false);
    setConsentBusy(false);
  },
  ready(s) {
    const t = s.test;
    const texts = s.texts || {};
    $('ready-label').textContent = t.label;
    $('ready-progress').textContent = t.practice ? 'Practice run' : `Test ${t.number} of ${t.of}`;
    const before = t.practice ? texts.before_practice : texts.before_test;
    $('ready-instructions').replaceChildren(
      ...paragraphs(texts.instructions),
      ...paragraphs(before, t.practice ? 'strong' : undefined),
    );
    $('ready-note').textContent = texts.ready || '';
  },
  running(s) {
    $('running-label').textContent = s.test.practice ? 'Practice (not scored)' : `${s.test.label} · test ${s.test.number} of ${s.test.of}`;
  },
  survey(s) {
    renderSurvey(s);
  },
  held() {},
  move(s) {
    const texts = s.texts || {};
    $('move-to').textContent = (s.to === 'on' ? texts.move_to_on : texts.move_to_off) || '';
    $('move-note').textContent = texts.move_note || '';
  },
  done(s) {
    const texts = s.texts || {};
    const [title, text] = s.reason === 'finished'
      ? [texts.finished_title, texts.finished]
      : s.reason === 'declined'
        ? [texts.declined_title, texts.declined]
        : [texts.withdrawn_title, texts.withdrawn];
    $('done').replaceChildren(el('h1', {}, title || ''), ...paragraphs(text, 'lead'));
  },
};

/** A study text as paragraphs: a blank line separates them (the server filled it in). */
function paragraphs(text, cls) {
  return (text || '')
    .split(/\n\s*\n/)
    .map((p) => p.trim())
    .filter(Boolean)
    .map((p) => el('p', cls ? { class: cls } : {}, p));
}

/** The page's language follows the study's texts (screen readers, hyphenation). */
function setLanguage(s) {
  const lang = s.texts && s.texts.language;
  if (lang && document.documentElement.lang !== lang) document.documentElement.lang = lang;
}

// ---------------------------------------------------------------------------------------
// Consent.

function setConsentBusy(busy) {
  for (const id of ['consent-agree', 'consent-decline', 'decline-confirm', 'decline-back']) $(id).disabled = busy;
}

/**
 * Declining ends the session for good, so it asks once more: the first press shows the
 * confirmation (and hides the choice), "Go back" returns to it.
 */
function confirmDecline(asking, focus = true) {
  $('consent-choice').hidden = asking;
  $('decline-confirmation').hidden = !asking;
  if (focus) $(asking ? 'decline-confirm' : 'consent-agree').focus({ preventScroll: true });
}

async function decide(decision) {
  setConsentBusy(true);
  const res = await api('POST', '/api/station/consent', { decision }, { bearer: token });
  setConsentBusy(false);
  if (!res.ok) {
    setError('action', describe(res));
    if (res.status === 401) onUnauthorized();
    else refresh();
    return;
  }
  setError('action', null);
  show(res.data);
}

// ---------------------------------------------------------------------------------------
// Survey.

function renderSurvey(s) {
  const sv = s.survey;
  const form = $('survey');
  $('survey-label').textContent = s.label || 'this test';
  const points = Array.from({ length: sv.scale_points }, (_, i) => i + 1);
  const groups = sv.items.map((item) => {
    const lowId = `${item.key}-low`;
    const highId = `${item.key}-high`;
    return el('fieldset', { dataset: { field: item.key } },
      el('legend', { id: `${item.key}-legend` }, item.label),
      el('div', { class: 'scale' },
        el('span', { class: 'anchor low', id: lowId }, `1 = ${item.low_anchor}`),
        el('div', { class: 'points' }, points.map((p) => {
          const ends = p === 1 ? lowId : p === sv.scale_points ? highId : undefined;
          return el('label', { class: 'point' },
            el('input', { type: 'radio', name: item.key, value: p, 'aria-describedby': ends }),
            el('span', {}, p));
        })),
        el('span', { class: 'anchor high', id: highId }, `${sv.scale_points} = ${item.high_anchor}`)));
  });
  const box = el('textarea', { id: 'comment', name: 'comment', maxlength: MAX_COMMENT_CHARS, rows: 4, 'aria-describedby': 'comment-count' });
  const count = el('p', { id: 'comment-count', class: 'counter', 'aria-live': 'polite' });
  const recount = () => {
    // Counted as maxlength counts (UTF-16 units): the counter says what the box allows,
    // and never more than the server's limit in characters.
    const n = box.value.length;
    count.textContent = `${n} / ${MAX_COMMENT_CHARS}`;
    count.classList.toggle('full', n >= MAX_COMMENT_CHARS);
  };
  box.addEventListener('input', recount);
  recount();
  const comment = el('div', { class: 'comment-block', dataset: { field: 'comment' } },
    el('label', { for: 'comment' }, sv.open_question), box, count);
  const submit = el('div', { class: 'survey-actions' },
    el('button', { type: 'submit', id: 'survey-submit', class: 'primary' }, 'Submit answers'));
  form.replaceChildren(...groups, comment, submit);
}

function clearFieldErrors(form) {
  for (const e of form.querySelectorAll('.field-error')) e.remove();
  for (const e of form.querySelectorAll('[aria-invalid]')) e.removeAttribute('aria-invalid');
  for (const i of form.querySelectorAll('input[type=radio], textarea')) {
    const keep = (i.getAttribute('aria-describedby') || '').split(' ').filter((id) => id && !id.endsWith('-error'));
    if (keep.length) i.setAttribute('aria-describedby', keep.join(' '));
    else i.removeAttribute('aria-describedby');
  }
}

function showFieldErrors(form, fields) {
  let first = null;
  const other = [];
  for (const f of fields) {
    const block = form.querySelector(`[data-field="${CSS.escape(f.field)}"]`);
    if (!block) {
      other.push(`${f.field}: ${f.message}`);
      continue;
    }
    const id = `${f.field}-error`;
    let msg = form.querySelector(`.field-error[data-field="${CSS.escape(f.field)}"]`);
    if (!msg) {
      msg = el('p', { class: 'field-error', id, dataset: { field: f.field } });
      block.append(msg);
    }
    msg.textContent = msg.textContent ? `${msg.textContent} ${f.message}` : f.message;
    const controls = block.querySelectorAll('input[type=radio], textarea');
    if (block.tagName === 'FIELDSET') block.setAttribute('aria-invalid', 'true');
    for (const c of controls) {
      if (c.tagName === 'TEXTAREA') c.setAttribute('aria-invalid', 'true');
      const by = (c.getAttribute('aria-describedby') || '').split(' ').filter(Boolean);
      if (!by.includes(id)) c.setAttribute('aria-describedby', [...by, id].join(' '));
    }
    if (!first) first = [...controls].find((c) => c.checked) || controls[0];
  }
  if (other.length) setError('action', other.join('\n'));
  if (first) first.focus();
}

async function submitSurvey(ev) {
  ev.preventDefault();
  const form = $('survey');
  const s = state;
  if (!s || s.phase !== 'survey') return;
  const body = { trial_id: s.trial_id };
  for (const item of s.survey.items) {
    const checked = form.querySelector(`input[name="${CSS.escape(item.key)}"]:checked`);
    body[item.key] = checked ? Number(checked.value) : null;
  }
  body.comment = $('comment').value;
  const button = $('survey-submit');
  button.disabled = true;
  const res = await api('POST', '/api/station/survey', body, { bearer: token });
  button.disabled = false;
  clearFieldErrors(form);
  if (res.ok) {
    setError('action', null);
    show(res.data);
    return;
  }
  if (res.status === 422 && res.data && Array.isArray(res.data.fields)) {
    setError('action', null);
    showFieldErrors(form, res.data.fields);
    return;
  }
  setError('action', describe(res));
  if (res.status === 401) onUnauthorized();
  else if (res.status === 409) refresh();
}

// ---------------------------------------------------------------------------------------
// Operator input: pointer (mouse, pen, touch) and gamepad. The wanted cylinder position in
// mm is what the subject points at; the device position sent is that / k_bf.

const input = {
  trialId: null,      // the test the input is for (ready or running), else null
  seqTrial: null,     // the test `seq` counts for
  seq: 0,
  wantedMm: 0,        // where the subject wants the cylinder (chart mm)
  lastSend: 0,
  sentAt: new Map(),  // seq → performance.now() when sent
  source: 'pointer',  // 'pointer' or 'pad': which moved last
  pad: { index: null, axis: null, rest: {}, last: null },
};

/** Chart geometry in CSS pixels (set by the drawing code, used by the pointer). */
const geom = { centerY: 0, pxPerMm: 1, limitMm: 48 };

function currentTest() {
  return state && state.test && state.test.trial_id === input.trialId ? state.test : null;
}

function clampMm(mm) {
  const t = currentTest();
  const lim = t ? 1.2 * t.target_range_mm : geom.limitMm;
  return Math.max(-lim, Math.min(lim, mm));
}

function sendInput() {
  const t = currentTest();
  if (!t || !socket || socket.readyState !== WebSocket.OPEN) return;
  const now = performance.now();
  if (now - input.lastSend < MIN_SEND_MS) return;
  // Latest wins: never queue input behind a congested socket.
  if (socket.bufferedAmount > 4096) return;
  if (input.seqTrial !== t.trial_id) {
    input.seqTrial = t.trial_id;
    input.seq = 0;
    input.sentAt.clear();
  }
  const kbf = t.k_bf > 0 ? t.k_bf : 1;
  let pos = input.wantedMm / kbf;
  pos = Math.max(-MAX_INPUT_MM, Math.min(MAX_INPUT_MM, pos));
  const seq = ++input.seq;
  socket.send(JSON.stringify({ type: 'input', trial_id: t.trial_id, seq, position_mm: pos }));
  if (run && run.trialId === t.trial_id) run.inputs++;
  input.lastSend = now;
  input.sentAt.set(seq, now);
  // Forget send times older than 10 s (a sample never answers that late).
  if (input.sentAt.size > 4000) {
    for (const [k, at] of input.sentAt) {
      if (now - at < 10000) break;
      input.sentAt.delete(k);
    }
  }
}

function onPointer(ev) {
  let y = ev.clientY;
  if (typeof ev.getCoalescedEvents === 'function') {
    const all = ev.getCoalescedEvents();
    if (all.length) y = all[all.length - 1].clientY;
  }
  // Measured against the frame, which does not shake (the canvas does).
  const rect = $('track-frame').getBoundingClientRect();
  input.wantedMm = clampMm((geom.centerY - (y - rect.top)) / geom.pxPerMm);
  input.source = 'pointer'; // the pointer takes over from the gamepad
  sendInput();
}

function setupPointer() {
  const canvas = $('track');
  const move = window.isSecureContext && 'onpointerrawupdate' in window ? 'pointerrawupdate' : 'pointermove';
  canvas.addEventListener(move, onPointer);
  canvas.addEventListener('pointerdown', (ev) => {
    try {
      canvas.setPointerCapture(ev.pointerId);
    } catch {
      // a synthetic pointer cannot be captured; harmless
    }
    onPointer(ev);
  });
  canvas.addEventListener('pointerup', (ev) => {
    if (canvas.hasPointerCapture && canvas.hasPointerCapture(ev.pointerId)) canvas.releasePointerCapture(ev.pointerId);
  });
  // No scrolling, zooming or context menu on the display.
  canvas.addEventListener('contextmenu', (ev) => ev.preventDefault());
}

/**
 * Gamepad: the first axis that moves (more than a quarter of its travel from where it rested
 * when first seen) is used; axes[1] and axes[3] (the sticks' vertical axes, up = −1) are
 * inverted. −1..1 spans the chart's full scale, as the pointer does. Whichever of pointer
 * and gamepad moved last is in control.
 */
function pollGamepad() {
  if (!navigator.getGamepads) return;
  const pads = navigator.getGamepads();
  const pad = input.pad;
  let gp = pad.index !== null ? pads[pad.index] : null;
  if (!gp || !gp.connected) {
    pad.index = null;
    pad.axis = null;
    gp = null;
    for (const p of pads) {
      if (!p || !p.connected || !p.axes.length) continue;
      if (!pad.rest[p.index] || pad.rest[p.index].id !== p.id) pad.rest[p.index] = { id: p.id, axes: [...p.axes] };
      const rest = pad.rest[p.index].axes;
      const i = p.axes.findIndex((v, k) => Math.abs(v - rest[k]) > 0.25);
      if (i >= 0) {
        pad.index = p.index;
        pad.axis = i;
        pad.last = null;
        gp = p;
        break;
      }
    }
    if (!gp) return;
  }
  let v = gp.axes[pad.axis];
  if (typeof v !== 'number' || !Number.isFinite(v)) return;
  if (pad.axis === 1 || pad.axis === 3) v = -v;
  const moved = pad.last === null || Math.abs(v - pad.last) > 0.01;
  pad.last = v;
  if (moved) input.source = 'pad';
  if (input.source !== 'pad') return;
  const t = currentTest();
  const lim = t ? 1.2 * t.target_range_mm : geom.limitMm;
  input.wantedMm = Math.max(-1, Math.min(1, v)) * lim;
}

// ---------------------------------------------------------------------------------------
// The running test: samples, drawing, shaking, timing.

let run = null;

function startRun(test) {
  run = {
    trialId: test.trial_id,
    test,
    samples: [],          // {t, target, cyl, accel}, the last few seconds
    latest: null,
    latestAt: 0,          // performance.now() when the latest sample arrived
    frames: 0,
    longFrames: 0,
    lastFrame: null,
    longestGap: 0,        // ms between two frames, or since the start before the first
    startedAt: performance.now(),
    hiddenMs: 0,          // hidden time before the current hidden spell
    hiddenSince: document.hidden ? performance.now() : null,
    inputs: 0,            // input messages sent for this test
    rtts: [],
    seenSeq: new Set(),
  };
  resizeCanvas();
  sendDisplay();
}

/** The display's figures so far; the gap still open and the hidden spell still running
 * count (a stalled or hidden page draws no frame that would close them). */
function displayFigures(r, now) {
  const gap = now - (r.lastFrame === null ? r.startedAt : r.lastFrame);
  return {
    hidden: document.hidden,
    frames: r.frames,
    longest_gap_ms: Math.round(Math.max(r.longestGap, gap) * 10) / 10,
    hidden_ms: Math.round((r.hiddenMs + (r.hiddenSince === null ? 0 : now - r.hiddenSince)) * 10) / 10,
    inputs: r.inputs,
  };
}

function sendDisplay() {
  const r = run;
  if (!r || !socket || socket.readyState !== WebSocket.OPEN) return;
  socket.send(JSON.stringify({ type: 'display', trial_id: r.trialId, ...displayFigures(r, performance.now()) }));
}

function onVisibility() {
  const r = run;
  if (r) {
    const now = performance.now();
    if (document.hidden && r.hiddenSince === null) r.hiddenSince = now;
    if (!document.hidden && r.hiddenSince !== null) {
      r.hiddenMs += now - r.hiddenSince;
      r.hiddenSince = null;
    }
  }
  sendDisplay();
}

function onSample(sample) {
  if (!run || sample.trial_id !== run.trialId) return;
  const now = performance.now();
  const s = {
    t: sample.t,
    target: sample.target_mm,
    cyl: sample.cylinder_mm,
    accel: sample.cab_accel_mm_s2,
  };
  if (run.latest && s.t < run.latest.t) run.samples = [];
  run.samples.push(s);
  run.latest = s;
  run.latestAt = now;
  // Drop what has scrolled off (keep a little more than the window).
  const cut = s.t - WINDOW_S - 1;
  let drop = 0;
  while (drop < run.samples.length && run.samples[drop].t < cut) drop++;
  if (drop > 0) run.samples.splice(0, drop);
  const seq = sample.input_seq;
  if (seq > 0 && !run.seenSeq.has(seq)) {
    run.seenSeq.add(seq);
    const sent = input.sentAt.get(seq);
    if (sent !== undefined) run.rtts.push(now - sent);
  }
}

function percentile(sorted, p) {
  if (!sorted.length) return 0;
  const i = Math.min(sorted.length - 1, Math.max(0, Math.ceil(p * sorted.length) - 1));
  return sorted[i];
}

async function finishRun() {
  const r = run;
  run = null;
  const canvas = $('track');
  canvas.style.transform = '';
  const sorted = [...r.rtts].sort((a, b) => a - b);
  const round = (x) => Math.round(Math.min(600000, Math.max(0, x)) * 100) / 100;
  const now = performance.now();
  const figures = displayFigures(r, now);
  const secs = Math.max(1e-3, (now - r.startedAt) / 1000);
  const body = {
    trial_id: r.trialId,
    frames: r.frames,
    long_frames: Math.min(r.longFrames, r.frames),
    longest_gap_ms: round(figures.longest_gap_ms),
    hidden_ms: round(figures.hidden_ms),
    input_hz: Math.round(Math.min(1000, r.inputs / secs) * 10) / 10,
    rtt_ms: {
      p50: round(percentile(sorted, 0.5)),
      p95: round(percentile(sorted, 0.95)),
      max: round(sorted.length ? sorted[sorted.length - 1] : 0),
    },
  };
  const res = await api('POST', '/api/station/timing', body, { bearer: token });
  if (!res.ok) setError('action', `Could not save the display timing: ${describe(res)}`);
}

let canvasSize = { w: 0, h: 0, dpr: 1 };

function resizeCanvas() {
  const canvas = $('track');
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth;
  const h = canvas.clientHeight;
  if (w === canvasSize.w && h === canvasSize.h && dpr === canvasSize.dpr) return;
  canvasSize = { w, h, dpr };
  canvas.width = Math.max(1, Math.round(w * dpr));
  canvas.height = Math.max(1, Math.round(h * dpr));
}

function cssVar(name, fallback) {
  const v = getComputedStyle(document.documentElement).getPropertyValue(name).trim();
  return v || fallback;
}

const colors = { target: '#ffd33d', cylinder: '#33c3ff' };

function draw(now) {
  const r = run;
  const canvas = $('track');
  resizeCanvas();
  const { w, h, dpr } = canvasSize;
  const ctx = canvas.getContext('2d');
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.fillStyle = '#000';
  ctx.fillRect(0, 0, w, h);

  const range = r.test.target_range_mm;
  const limit = 1.2 * range;
  const left = Math.min(110, w * 0.12);
  const right = w - 16;
  const top = 80;
  const bottom = h - 24;
  const centerY = (top + bottom) / 2;
  const pxPerMm = Math.max(1e-6, (bottom - top) / 2 / limit);
  geom.centerY = centerY;
  geom.pxPerMm = pxPerMm;
  geom.limitMm = limit;
  const yOf = (mm) => centerY - Math.max(-limit, Math.min(limit, mm)) * pxPerMm;

  // Grid: zero and ±range, labelled in mm.
  ctx.font = '600 20px system-ui, sans-serif';
  ctx.textAlign = 'right';
  ctx.textBaseline = 'middle';
  for (const mm of [-range, -range / 2, 0, range / 2, range]) {
    const y = Math.round(yOf(mm)) + 0.5;
    ctx.strokeStyle = mm === 0 ? '#8b949e' : '#30363d';
    ctx.lineWidth = mm === 0 ? 2 : 1;
    ctx.beginPath();
    ctx.moveTo(left, y);
    ctx.lineTo(right, y);
    ctx.stroke();
    ctx.fillStyle = '#c9d1d9';
    ctx.fillText(`${mm > 0 ? '+' : ''}${Math.round(mm)} mm`, left - 10, y);
  }

  // Time: the newest sample at the right edge, extrapolated between samples for a smooth
  // scroll (at most 0.1 s ahead, so a stalled feed stops the chart).
  let tNow = 0;
  if (r.latest) tNow = r.latest.t + Math.min(0.1, Math.max(0, (now - r.latestAt) / 1000));
  const t0 = tNow - WINDOW_S;
  const xOf = (t) => right - ((tNow - t) / WINDOW_S) * (right - left);

  ctx.save();
  ctx.beginPath();
  ctx.rect(left, top - 10, right - left, bottom - top + 20);
  ctx.clip();
  const line = (key, color, width) => {
    ctx.strokeStyle = color;
    ctx.lineWidth = width;
    ctx.lineJoin = 'round';
    ctx.lineCap = 'round';
    ctx.beginPath();
    let started = false;
    for (const s of r.samples) {
      if (s.t < t0 - 0.05) continue;
      const x = xOf(s.t);
      const y = yOf(s[key]);
      if (started) ctx.lineTo(x, y);
      else {
        ctx.moveTo(x, y);
        started = true;
      }
    }
    ctx.stroke();
  };
  line('target', colors.target, 8);
  line('cyl', colors.cylinder, 4);
  // The newest positions, as dots at the right edge.
  if (r.latest) {
    for (const [key, color, rad] of [['target', colors.target, 9], ['cyl', colors.cylinder, 7]]) {
      ctx.fillStyle = color;
      ctx.beginPath();
      ctx.arc(xOf(r.latest.t), yOf(r.latest[key]), rad, 0, 2 * Math.PI);
      ctx.fill();
    }
  }
  ctx.restore();

  // Countdown.
  const left_s = Math.max(0, r.test.duration_s - (r.latest ? r.latest.t : 0));
  const text = `${Math.ceil(left_s)} s`;
  const cd = $('countdown');
  if (cd.textContent !== text) {
    cd.textContent = text;
    cd.dataset.seconds = String(Math.ceil(left_s));
  }

  // Shake (on-machine station only): the cab's displacement at its 4 Hz mode.
  const gain = r.test.shake_gain || 0;
  if (gain > 0 && r.latest) {
    const mm = gain * (-r.latest.accel / (SHAKE_OMEGA * SHAKE_OMEGA));
    // A safety bound: a violent transient (or a large gain) never throws the chart more than
    // a quarter of the screen.
    const bound = 0.25 * h;
    const px = Math.max(-bound, Math.min(bound, mm * pxPerMm));
    // Up on the chart is up on the screen: a cab moving up moves the display up.
    canvas.style.transform = `translate3d(0, ${(-px).toFixed(2)}px, 0)`;
  } else if (canvas.style.transform) {
    canvas.style.transform = '';
  }
}

function frame(now) {
  requestAnimationFrame(frame);
  if (run) {
    const gap = now - (run.lastFrame === null ? run.startedAt : run.lastFrame);
    if (run.lastFrame !== null && gap > LONG_FRAME_MS) run.longFrames++;
    if (gap > run.longestGap) run.longestGap = gap;
    run.lastFrame = now;
    run.frames++;
    draw(now);
  }
  if (input.trialId !== null) {
    pollGamepad();
    sendInput();
  }
}

// A backstop for frames that stall (a busy tab): the controller ends a test after 100 ms
// without input, so keep input flowing at 25 Hz or more whatever the display does.
setInterval(() => {
  if (input.trialId !== null && performance.now() - input.lastSend > 40) sendInput();
}, 20);

setInterval(sendDisplay, DISPLAY_EVERY_MS);

// ---------------------------------------------------------------------------------------
// Start.

function init() {
  $('error-dismiss').addEventListener('click', () => {
    setError('action', null);
    setError('register', null);
  });
  $('consent-agree').addEventListener('click', () => decide('agreed'));
  $('consent-decline').addEventListener('click', () => confirmDecline(true));
  $('decline-back').addEventListener('click', () => confirmDecline(false));
  $('decline-confirm').addEventListener('click', () => decide('declined'));
  $('survey').addEventListener('submit', submitSurvey);
  $('use-here').addEventListener('click', () => location.reload());
  $('new-code').addEventListener('click', () => {
    localStorage.removeItem(CODE_KEY);
    token = null;
    localStorage.removeItem(TOKEN_KEY);
    register();
  });
  setupPointer();
  window.addEventListener('resize', resizeCanvas);
  document.addEventListener('visibilitychange', onVisibility);
  window.addEventListener('gamepadconnected', (ev) => {
    delete input.pad.rest[ev.gamepad.index];
  });
  colors.target = cssVar('--target', colors.target);
  colors.cylinder = cssVar('--cylinder', colors.cylinder);
  requestAnimationFrame(frame);
  refresh();
}

init();
