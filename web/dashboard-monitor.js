// The live monitor: one panel per paired station, fed by GET /api/stations/{id}/state (every
// second) and the /api/live WebSocket (live samples, trial changes, controller link, the
// E-stop latch: Start stays disabled while it is latched).

import { wsUrl } from './common.js';
import {
  S, act, CONTROLLER_NAME, controllerName, el, emit, errText, get, mmss, num, on, post, validityText, when, SEAT_NAME,
} from './dashboard-core.js';
import { StripChart } from './dashboard-chart.js';

const $ = (id) => document.getElementById(id);

const WINDOW_S = 10;
const KEEP_S = 12;

/** Live samples per trial id: {samples, n, sumE2, sumA2, lastT, seenAt}. */
const live = new Map();
/** Panels by station id. */
const panels = new Map();

let pollTimer = null;
let running = false;
let socket = null;
let socketRetry = null;
let socketDelay = 1000;
let raf = null;
let lastTextUpdate = 0;
/** The E-stop latch: from GET /api/controller when the feed connects, then its `estop` messages. */
let estopLatched = false;

const LATCH_TEXT = 'E-STOP LATCHED: tests cannot start. Press “Reset e-stop” (top right) once it is safe.';

export function init() {
  on('study', () => syncPanels());
  on('stations', () => syncPanels());
  on('assigned', () => pollAll());
  on('trial', () => {
    for (const p of panels.values()) p.lastFetchedFor = null;
  });
  on('controller', () => {
    for (const p of panels.values()) renderPanel(p);
  });
  $('monitors').addEventListener('click', onClick);
  $('monitors').addEventListener('keydown', (e) => {
    if (e.key === 'Enter' && e.target.matches('input[data-abort-reason]')) {
      e.preventDefault();
      const b = $('monitors').querySelector(`button[data-action="abort"][data-station-id="${e.target.dataset.abortReason}"]`);
      if (b && !b.disabled) b.click();
    }
  });
  syncPanels();
}

export function start() {
  running = true;
  connect();
  clearInterval(pollTimer);
  pollTimer = setInterval(pollAll, 1000);
  pollAll();
  if (!raf) raf = requestAnimationFrame(frame);
}

export function stop() {
  running = false;
  clearInterval(pollTimer);
  pollTimer = null;
  clearTimeout(socketRetry);
  if (socket) {
    socket.onclose = null;
    socket.close();
    socket = null;
  }
  if (raf) cancelAnimationFrame(raf);
  raf = null;
  showLive('unknown', 'Live feed: off');
}

// ---- the live socket ----------------------------------------------------------------------

function showLive(kind, text) {
  const pill = $('live-state');
  pill.classList.remove('ok', 'bad', 'unknown');
  pill.classList.add(kind);
  pill.textContent = text;
}

function connect() {
  if (!running || socket) return;
  showLive('unknown', 'Live feed: connecting…');
  let ws;
  try {
    ws = new WebSocket(wsUrl('/api/live'));
  } catch (e) {
    showLive('bad', `Live feed: ${e.message}`);
    return;
  }
  socket = ws;
  ws.onopen = () => {
    socketDelay = 1000;
    showLive('ok', 'Live feed: connected');
    readLatch();
    pollAll();
  };
  ws.onmessage = (ev) => {
    let m;
    try {
      m = JSON.parse(ev.data);
    } catch {
      return;
    }
    if (m.type === 'live' && m.sample) addSample(m.sample);
    else if (m.type === 'trial') onTrialChanged(m.trial_id);
    else if (m.type === 'controller') {
      emit('live-controller', !!m.connected);
      readLatch();
    } else if (m.type === 'estop') {
      setLatch(!!m.latched);
      emit('live-estop', !!m.latched);
    }
  };
  ws.onclose = () => {
    socket = null;
    if (!running) return;
    const s = Math.round(socketDelay / 1000);
    showLive('bad', `Live feed: disconnected — retrying in ${s} s`);
    socketRetry = setTimeout(connect, socketDelay);
    socketDelay = Math.min(socketDelay * 2, 15000);
  };
}

/** The latch as the server holds it now (missed while the feed was down). */
async function readLatch() {
  const r = await get('/api/controller');
  if (r.ok && r.data) setLatch(!!r.data.estop_latched);
}

function setLatch(latched) {
  if (latched === estopLatched) return;
  estopLatched = latched;
  for (const p of panels.values()) renderPanel(p);
}

function addSample(s) {
  let b = live.get(s.trial_id);
  if (!b) {
    b = { samples: [], n: 0, sumE2: 0, sumA2: 0, lastT: 0, seenAt: 0 };
    live.set(s.trial_id, b);
    // Forget old trials.
    for (const [id, o] of live) {
      if (performance.now() - o.seenAt > 300000 && id !== s.trial_id) live.delete(id);
    }
  }
  const e = s.target_mm - s.cylinder_mm;
  b.n += 1;
  b.sumE2 += e * e;
  b.sumA2 += s.cab_accel_mm_s2 * s.cab_accel_mm_s2;
  b.lastT = Math.max(b.lastT, s.t);
  b.seenAt = performance.now();
  b.samples.push(s);
  if (b.samples.length > 4000 || b.samples[0].t < b.lastT - KEEP_S - 2) {
    const cut = b.lastT - KEEP_S;
    let i = 0;
    while (i < b.samples.length && b.samples[i].t < cut) i++;
    b.samples.splice(0, i);
  }
  b.dirty = true;
}

const trialChanged = (() => {
  let t = null;
  return () => {
    clearTimeout(t);
    t = setTimeout(() => emit('trial', null), 250);
  };
})();

function onTrialChanged(trialId) {
  // The last runs' results may have changed (committed, redone elsewhere): read them again.
  for (const p of panels.values()) p.lastFetchedFor = null;
  pollAll();
  trialChanged(trialId);
}

// ---- panels -------------------------------------------------------------------------------

function syncPanels() {
  const box = $('monitors');
  const ids = new Set(S.stations.map((s) => s.id));
  for (const [id, p] of panels) {
    if (!ids.has(id)) {
      p.root.remove();
      panels.delete(id);
    }
  }
  for (const st of S.stations) {
    if (!panels.has(st.id)) {
      const p = makePanel(st);
      panels.set(st.id, p);
      box.append(p.root);
    } else {
      panels.get(st.id).station = st;
    }
  }
  // Keep the panels in the stations' order.
  for (const st of S.stations) box.append(panels.get(st.id).root);
  let empty = box.querySelector('.monitor-empty');
  if (!S.stations.length) {
    if (!empty) {
      empty = el(
        'p',
        { class: 'monitor-empty muted' },
        S.studyId
          ? 'No station paired with this study yet. Open /station on each station’s computer and pair it under Stations.'
          : 'Select or create a study first.',
      );
      box.append(empty);
    }
  } else if (empty) empty.remove();
  for (const p of panels.values()) renderPanel(p);
  pollAll();
}

function fact(label, cls) {
  const v = el('dd', { class: cls });
  return { node: [el('dt', {}, label), v], v };
}

function makePanel(st) {
  const f = {
    subject: fact('Subject'),
    test: fact('Test'),
    controller: fact('Controller', 'big'),
    label: fact('Subject sees'),
    where: fact('Where'),
    time: fact('Time left', 'big'),
    page: fact('Station page'),
    mse: fact('MSE (live)'),
    cab: fact('Cab MS (live)'),
  };
  const title = el('h3');
  const phase = el('span', { class: 'phase' });
  const hint = el('p', { class: 'mon-hint' });
  const latch = el('p', { class: 'mon-latch status err', role: 'alert', hidden: true });
  const timeBar = el('progress', { class: 'time-bar', max: 1, value: 0 });
  const posCanvas = el('canvas', { class: 'chart chart-pos', 'aria-label': 'Target and cylinder position, last 10 s' });
  const accCanvas = el('canvas', { class: 'chart chart-acc', 'aria-label': 'Cab acceleration, last 10 s' });
  const startBtn = el('button', { type: 'button', class: 'primary big', 'data-action': 'start', 'data-station-id': st.id }, 'Start test');
  const abortReason = el('input', {
    'data-abort-reason': st.id,
    placeholder: 'abort reason (optional)',
    title: 'Recorded with the abort; if empty: “aborted by the experimenter”',
    maxlength: 500,
    'aria-label': 'Reason for aborting',
  });
  const abortBtn = el('button', { type: 'button', class: 'danger', 'data-action': 'abort', 'data-station-id': st.id }, 'Abort test');
  const result = el('p', { class: 'mon-result', role: 'status', 'aria-live': 'polite', hidden: true });
  const error = el('p', { class: 'mon-error status err', role: 'alert', hidden: true });
  const last = el('div', { class: 'mon-last', hidden: true });
  const root = el(
    'section',
    { class: 'monitor phase-unknown', 'data-station-id': st.id },
    el('header', { class: 'mon-head' }, title, phase),
    hint,
    latch,
    el(
      'div',
      { class: 'mon-grid' },
      el('dl', { class: 'facts' }, ...Object.values(f).map((x) => x.node)),
      el(
        'div',
        { class: 'charts' },
        el(
          'div',
          { class: 'legend' },
          el('span', { class: 'sw sw-target' }), 'target ',
          el('span', { class: 'sw sw-cyl' }), 'cylinder ',
          el('span', { class: 'sw sw-dev' }), 'input device (mm)',
        ),
        posCanvas,
        el('div', { class: 'legend' }, el('span', { class: 'sw sw-acc' }), 'cab acceleration (mm/s²)'),
        accCanvas,
      ),
    ),
    timeBar,
    el('div', { class: 'mon-actions' }, startBtn, abortReason, abortBtn),
    result,
    error,
    last,
  );
  return {
    id: st.id,
    station: st,
    root,
    title,
    phase,
    hint,
    latch,
    f,
    timeBar,
    startBtn,
    abortBtn,
    abortReason,
    result,
    error,
    last,
    pos: new StripChart(
      posCanvas,
      [
        { key: 'target_mm', color: '#222', width: 2, dash: [6, 3] },
        { key: 'device_mm', color: '#9aa5b1', width: 1 },
        { key: 'cylinder_mm', color: '#0072B2', width: 2 },
      ],
      { window_s: WINDOW_S, unit: 'mm', minSpan: 20 },
    ),
    acc: new StripChart(accCanvas, [{ key: 'cab_accel_mm_s2', color: '#D55E00', width: 1.2 }], {
      window_s: WINDOW_S,
      unit: 'mm/s²',
      minSpan: 200,
    }),
    state: null,
    stateError: null,
    polling: false,
    busy: false,
    /** The trial whose chart and result are shown once it is no longer running. */
    lastTrial: null,
    lastTrialInfo: null,
    lastFetchedFor: null,
  };
}

async function pollAll() {
  if (!running) return;
  await Promise.all([...panels.values()].map(poll));
}

async function poll(p) {
  if (p.polling) return;
  p.polling = true;
  const r = await get(`/api/stations/${p.id}/state`);
  p.polling = false;
  if (!panels.has(p.id)) return;
  if (!r.ok) {
    p.stateError = `Could not read the station's state: ${errText(r)}`;
    renderPanel(p);
    return;
  }
  p.stateError = null;
  let prev = p.state;
  p.state = r.data;
  // Another subject at the station: nothing of the previous one's last run is theirs.
  const subjectOf = (x) => (x && x.station ? x.station.subject_id : null);
  if (prev && subjectOf(prev) !== subjectOf(p.state)) {
    p.lastTrial = null;
    p.lastTrialInfo = null;
    p.lastFetchedFor = null;
    p.dirtyChart = true;
    prev = null;
  }
  const prevRunning = prev && prev.phase === 'running' && prev.test ? prev.test.trial_id : null;
  const nowRunning = p.state.phase === 'running' && p.state.test ? p.state.test.trial_id : null;
  const prevTest = prev && prev.test ? prev.test.trial_id : null;
  const nowTest = p.state.test ? p.state.test.trial_id : null;
  // The test shown before has run (a short one may start and end between two polls: its
  // live samples tell).
  const ran = prevRunning || (prevTest && prevTest !== nowTest && live.has(prevTest) ? prevTest : null);
  if (ran && ran !== nowRunning) {
    p.lastTrial = ran;
    p.lastTrialInfo = null;
  }
  if (!prevRunning && !nowRunning && p.state.phase === 'survey' && !p.lastTrial) p.lastTrial = p.state.trial_id;
  if (nowRunning) p.dirtyChart = true;
  if (p.lastTrial && p.lastFetchedFor !== p.lastTrial && p.state.station && p.state.station.subject_id) {
    p.lastFetchedFor = p.lastTrial;
    fetchLast(p, p.state.station.subject_id, p.lastTrial);
  }
  renderPanel(p);
}

/** The official result of the panel's last trial (status, metrics) from the subject's schedule. */
async function fetchLast(p, subjectId, trialId) {
  const r = await get(`/api/subjects/${subjectId}`);
  if (!r.ok || p.lastTrial !== trialId) return;
  const t = r.data.trials.map((x) => x.trial).find((x) => x.id === trialId);
  if (!t) return;
  if (t.status === 'running') {
    // Not committed yet: look again shortly.
    setTimeout(() => {
      if (p.lastTrial === trialId) {
        p.lastFetchedFor = null;
      }
    }, 1000);
    return;
  }
  const later = r.data.trials.map((x) => x.trial).filter((x) => x.slot === t.slot && x.attempt > t.attempt);
  const newest = later.length ? later[later.length - 1] : null;
  p.lastTrialInfo = {
    ...t,
    code: r.data.subject.code,
    isLatest: !newest,
    redone: newest ? newest.id : null,
    redoneScheduled: !!newest && newest.status === 'scheduled',
    accepted_reason: newest && newest.accepted_reason ? newest.accepted_reason : t.accepted_reason,
  };
  renderPanel(p);
}

const PHASE_TEXT = {
  waiting: 'waiting',
  consent: 'consent',
  survey: 'survey',
  move: 'move',
  ready: 'ready',
  running: 'RUNNING',
  held: 'held',
  done: 'done',
};

function hintText(st) {
  const who = st.subject || 'The subject';
  switch (st.phase) {
    case 'waiting':
      return 'No subject is assigned to this station: assign one under Stations.';
    case 'consent':
      return `${who} is reading the consent form (v${st.consent ? st.consent.version : '?'}) on this station. Nothing runs until they agree.`;
    case 'survey':
      return `${who} is answering the survey on “${st.label}” (trial ${st.trial_id}). The next test can start once it is submitted.`;
    case 'move': {
      const subjectId = st.station && st.station.subject_id;
      const there = S.stations.filter((x) => x.role === st.to || x.role === 'both');
      const assigned = there.filter((x) => x.subject_id === subjectId);
      const where = assigned.length
        ? `they are assigned to “${assigned.map((x) => x.name).join('”, “')}” there already`
        : there.length
          ? `assign them to “${there.map((x) => x.name).join('” or “')}” under Stations`
          : 'no station of this study serves it yet: pair one';
      return `${who}'s next test is ${SEAT_NAME[st.to] || st.to}: move the subject there; ${where}.`;
    }
    case 'ready':
      return st.test && st.test.practice
        ? `${who} is ready for the practice run (not scored). Press Start when they are.`
        : `${who} is ready for the next test. Press Start when they are.`;
    case 'running':
      return `${who} is tracking. Abort only if needed (a reason is recorded); the e-stop is at the top right.`;
    case 'held':
      return `${who}'s remaining test failed as often as it is repeated by itself: repeat it (Schedule a redo) or accept it as incomplete with a reason.`;
    case 'done':
      return st.reason === 'finished'
        ? `${who} has finished every test.`
        : st.reason === 'declined'
          ? `${who} declined consent: nothing will run.`
          : st.reason === 'withdrawn'
            ? `${who} has withdrawn.`
            : `Done (${st.reason || ''}).`;
    default:
      return '';
  }
}

function renderPanel(p) {
  const st = p.state;
  const station = p.station;
  p.title.textContent = `${station.name} `;
  p.title.append(el('span', { class: 'muted small' }, `station #${station.id} · serves ${SEAT_NAME[station.role] || station.role}`));
  const phase = st ? st.phase : 'unknown';
  p.root.className = `monitor phase-${phase}`;
  p.phase.textContent = st ? PHASE_TEXT[phase] || phase : '…';
  p.hint.textContent = st ? hintText(st) : 'Reading the station’s state…';
  const test = st && st.test;
  p.f.subject.v.textContent = st && st.subject ? st.subject : '—';
  p.f.test.v.textContent = test ? (test.practice ? `Practice (not scored), trial ${test.trial_id}` : `Test ${test.number} of ${test.of}, trial ${test.trial_id}`) : '—';
  if (test) p.f.controller.v.replaceChildren(CONTROLLER_NAME[test.controller] || test.controller, el('span', { class: 'sub' }, test.controller));
  else p.f.controller.v.textContent = '—';
  p.f.label.v.textContent = test ? test.label : st && st.phase === 'survey' ? st.label : '—';
  p.f.where.v.textContent = test ? `${SEAT_NAME[test.station] || test.station}, ${mmss(test.duration_s)} long` : '—';
  updateLiveText(p);

  p.f.page.v.textContent = pageText(st && st.station ? st.station.socket : undefined);

  const ready = phase === 'ready' && test;
  p.startBtn.disabled = !ready || p.busy || estopLatched;
  p.startBtn.textContent = ready ? (test.practice ? 'Start practice' : `Start test ${test.number}`) : 'Start test';
  p.startBtn.title = estopLatched
    ? 'The E-stop is latched: reset it first'
    : ready ? `Start trial ${test.trial_id} (${controllerName(test.controller)})` : 'Only when the station is ready';
  p.latch.textContent = estopLatched ? LATCH_TEXT : '';
  p.latch.hidden = !estopLatched;
  p.abortBtn.disabled = phase !== 'running' || p.busy;
  p.abortReason.disabled = phase !== 'running';
  if (ready && S.controller.connected === false) {
    p.startBtn.title = 'The controller is not connected: the start will be refused';
  }

  const errs = [];
  if (p.stateError) errs.push(p.stateError);
  if (p.actionError) errs.push(p.actionError);
  if (ready && S.controller.connected === false) errs.push('The controller is not connected: tests cannot start.');
  p.error.textContent = errs.join(' · ');
  p.error.hidden = errs.length === 0;

  renderLast(p);
  p.dirtyChart = true;
}

/** The station page's live socket: open or not, its input, why the server closed it. */
function pageText(socket) {
  if (socket === undefined) return '—';
  if (socket === null) return 'not connected since the server started';
  const input = `${socket.accepted} messages${socket.dropped ? `, ${socket.dropped} dropped over the rate limit` : ''}`;
  if (socket.connected) return `connected · ${input}`;
  return `disconnected${socket.closed_by_server ? ` by the server (${socket.closed_by_server})` : ''} · ${input}`;
}

const FAILED = ['aborted', 'incomplete', 'invalid'];


/** The result of the panel's last run; a failed test is re-queued by itself, and can be
 * redone by hand or accepted as incomplete from here. */
function renderLast(p) {
  const li = p.lastTrialInfo;
  const b = li ? live.get(li.id) : null;
  const key = li ? JSON.stringify([li, b ? b.n : 0, p.busy]) : '';
  if (key === p.lastKey) return;
  p.lastKey = key;
  if (!li) {
    p.last.hidden = true;
    return;
  }
  p.last.hidden = false;
  p.last.className = `mon-last st-${li.status}`;
  const text =
    `Last run: trial ${li.id} (${li.code}, ${li.practice ? 'practice' : li.blinded_label}, ${controllerName(li.controller)}) — ${li.status}` +
    (li.status_reason ? ` (${li.status_reason})` : '') +
    (li.mse_tracking_mm2 !== null ? ` · MSE ${num(li.mse_tracking_mm2)} mm²` : '') +
    (li.ms_cab_accel !== null ? ` · cab accel MS ${num(li.ms_cab_accel)} (mm/s²)²` : '') +
    (b && b.n ? ` · live estimate ${num(b.sumE2 / b.n)} mm² from ${b.n} samples` : '') +
    (li.finished_at ? ` · ended ${when(li.finished_at)}` : '');
  const failed = FAILED.includes(li.status);
  const canRedo = li.isLatest && !li.redone && failed && !li.accepted_reason;
  // Accepting names the failed attempt; the server accepts the test's latest attempt (its
  // re-queued successor while that has not run).
  const canAccept = failed && !li.accepted_reason && (li.isLatest || li.redoneScheduled);
  const validity = validityText(li);
  p.last.replaceChildren(
    ...[
    text,
    validity ? el('div', { class: 'small mon-validity' }, validity) : null,
    canRedo
      ? el(
          'button',
          { type: 'button', class: 'small redo-last', 'data-action': 'redo-last', 'data-station-id': p.id, 'data-trial-id': li.id, disabled: p.busy },
          'Schedule a redo of this test',
        )
      : null,
    li.redone ? el('span', {}, ` · ${li.redoneScheduled ? 're-queued at the end of its block' : 'redone'}: new attempt is trial ${li.redone}`) : null,
    li.accepted_reason ? el('span', {}, ` · accepted as incomplete (${li.accepted_reason})`) : null,
    canAccept
      ? el('span', { class: 'accept-last' },
          ' ',
          el('input', { 'data-accept-reason': p.id, placeholder: 'reason (required)', maxlength: 500, 'aria-label': 'Reason for accepting the test as incomplete' }),
          el('button', { type: 'button', class: 'small', 'data-action': 'accept-last', 'data-station-id': p.id, 'data-trial-id': li.id, disabled: p.busy },
            'Accept as incomplete (no repeat)'))
      : null,
    ].filter(Boolean),
  );
}

/** The trial whose samples the panel shows: the running one, else the last one. */
function chartTrial(p) {
  const st = p.state;
  if (st && st.phase === 'running' && st.test) return st.test.trial_id;
  return p.lastTrial;
}

function updateLiveText(p) {
  const st = p.state;
  const test = st && st.test;
  const isRunning = st && st.phase === 'running' && test;
  const b = isRunning ? live.get(test.trial_id) : null;
  if (isRunning) {
    const fresh = b && performance.now() - b.seenAt < 2000;
    const elapsed = fresh ? b.lastT : test.started_at ? (Date.now() - test.started_at) / 1000 : 0;
    const left = Math.max(0, test.duration_s - elapsed);
    p.f.time.v.textContent = `${mmss(left)} left (${mmss(elapsed)} of ${mmss(test.duration_s)})${fresh ? '' : ' — no live samples'}`;
    p.timeBar.max = test.duration_s;
    p.timeBar.value = Math.min(elapsed, test.duration_s);
    p.timeBar.hidden = false;
  } else {
    p.f.time.v.textContent = test ? `${mmss(test.duration_s)} — not started` : '—';
    p.timeBar.hidden = true;
  }
  const cb = live.get(chartTrial(p));
  if (cb && cb.n) {
    const suffix = isRunning ? '' : ' (last run)';
    p.f.mse.v.textContent = `${num(cb.sumE2 / cb.n)} mm²${suffix}`;
    p.f.cab.v.textContent = `${num(cb.sumA2 / cb.n)} (mm/s²)²${suffix}`;
    p.f.mse.v.title = `from ${cb.n} live samples (about 100 per second; the stored metric uses every 1 kHz sample)`;
  } else {
    p.f.mse.v.textContent = isRunning ? 'waiting for samples…' : '—';
    p.f.cab.v.textContent = '—';
    p.f.mse.v.title = '';
  }
}

function frame(now) {
  raf = running ? requestAnimationFrame(frame) : null;
  const textDue = now - lastTextUpdate > 250;
  if (textDue) lastTextUpdate = now;
  for (const p of panels.values()) {
    const id = chartTrial(p);
    const b = id ? live.get(id) : null;
    if (textDue) updateLiveText(p);
    if (!(b && b.dirty) && !p.dirtyChart) continue;
    if (b) b.dirty = false;
    p.dirtyChart = false;
    const test = p.state && p.state.test;
    const range = test ? test.target_range_mm * 1.25 : 50;
    const samples = b ? b.samples : [];
    const tEnd = b ? Math.max(b.lastT, WINDOW_S) : WINDOW_S;
    const isRunning = p.state && p.state.phase === 'running';
    const note = !b ? (isRunning ? 'waiting for live samples…' : 'no test running') : '';
    p.pos.draw(samples, tEnd, [-range, range], note);
    p.acc.draw(samples, tEnd, null, note);
  }
}

// ---- start and abort ----------------------------------------------------------------------

async function onClick(e) {
  const btn = e.target.closest('button[data-action][data-station-id]');
  if (!btn || btn.disabled) return;
  const p = panels.get(Number(btn.dataset.stationId));
  if (!p || !p.state) return;
  if (btn.dataset.action === 'start') await startTest(p);
  else if (btn.dataset.action === 'abort') await abortTest(p);
  else if (btn.dataset.action === 'redo-last') await redoLast(p, Number(btn.dataset.trialId));
  else if (btn.dataset.action === 'accept-last') await acceptLast(p, Number(btn.dataset.trialId));
}

async function acceptLast(p, trialId) {
  const input = p.last.querySelector(`input[data-accept-reason="${p.id}"]`);
  const reason = input ? input.value.trim() : '';
  if (!reason) {
    p.actionError = 'Accepting a test as incomplete needs a reason.';
    renderPanel(p);
    return;
  }
  p.busy = true;
  renderPanel(p);
  const r = await act(`Accept trial ${trialId}'s test as incomplete`, p.result, () => post(`/api/trials/${trialId}/incomplete`, { reason }), () =>
    'accepted as incomplete: it will not be repeated',
  );
  p.busy = false;
  p.actionError = r.ok ? null : `Accept refused: ${errText(r)}`;
  p.lastFetchedFor = null;
  await poll(p);
  renderPanel(p);
  emit('trial', null);
}

async function redoLast(p, trialId) {
  p.busy = true;
  renderPanel(p);
  const r = await act(`Redo trial ${trialId}`, p.result, () => post(`/api/trials/${trialId}/redo`), (d) =>
    `new attempt ${d.attempt} scheduled as trial ${d.id}; it is now the subject's next test`,
  );
  p.busy = false;
  p.actionError = r.ok ? null : `Redo refused: ${errText(r)}`;
  if (r.ok && p.lastTrialInfo && p.lastTrialInfo.id === trialId) p.lastTrialInfo.redone = r.data.id;
  await poll(p);
  renderPanel(p);
  emit('trial', null);
}

async function startTest(p) {
  const test = p.state.test;
  if (!test) return;
  p.busy = true;
  renderPanel(p);
  const r = await act(
    `Start trial ${test.trial_id} at “${p.station.name}” (${p.state.subject}, ${test.practice ? 'practice' : test.label}, ${controllerName(test.controller)})`,
    p.result,
    () => post(`/api/trials/${test.trial_id}/start`),
    () => 'started',
  );
  p.busy = false;
  p.actionError = r.ok ? null : `Start refused: ${errText(r)}`;
  if (r.ok) {
    p.lastTrial = null;
    p.lastTrialInfo = null;
  }
  await poll(p);
  renderPanel(p);
  emit('trial', null);
}

async function abortTest(p) {
  const test = p.state.test;
  if (!test) return;
  const reason = p.abortReason.value.trim() || 'aborted by the experimenter';
  p.busy = true;
  renderPanel(p);
  const r = await act(`Abort trial ${test.trial_id} at “${p.station.name}”`, p.result, () => post(`/api/trials/${test.trial_id}/abort`, { reason }), () =>
    `abort sent (reason: ${reason})`,
  );
  p.busy = false;
  p.actionError = r.ok ? null : `Abort refused: ${errText(r)}`;
  if (r.ok) p.abortReason.value = '';
  await poll(p);
  renderPanel(p);
  emit('trial', null);
}

