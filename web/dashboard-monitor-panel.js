// A station's panel on the live monitor: built once (facts, strip charts of position and
// cab acceleration, Start and Abort), then rendered from the station's state: what the
// experimenter should do next, the test and its blinded label, the time left, the live
// estimates, the E-stop latch, and the result of the last run. Apart because it only draws:
// it reads the state and the live samples, and never asks the server anything.

import {
  S, COMPENSATOR_NAME, compensatorName, el, mmss, num, validityText, when, SEAT_NAME,
} from './dashboard-core.js';
import { StripChart } from './dashboard-chart.js';
import { estopLatched, live } from './dashboard-monitor-live.js';

const WINDOW_S = 10;
/** How the panel names a test that is not scored, by phase. */
const UNSCORED = { practice: 'Practice', identification: 'Identification' };

const LATCH_TEXT = 'E-STOP LATCHED: tests cannot start. Press “Reset e-stop” (top right) once it is safe.';

function fact(label, cls) {
  const v = el('dd', { class: cls });
  return { node: [el('dt', {}, label), v], v };
}

export function makePanel(st) {
  const f = {
    subject: fact('Subject'),
    test: fact('Test'),
    controller: fact('Compensator', 'big'),
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
      return st.test && st.test.phase === 'practice'
        ? `${who} is ready for the practice run (not scored). Press Start when they are.`
        : st.test && st.test.phase === 'identification'
          ? `${who} is ready for the identification test (the seat moves by itself; not scored). Press Start when they are.`
          : `${who} is ready for the next test. Press Start when they are.`;
    case 'running':
      return `${who} is tracking. Abort only if needed (a reason is recorded); the e-stop is at the top right.`;
    case 'held': {
      const f = st.failed;
      if (f && f.phase === 'practice') {
        return `${who}'s practice failed ${f.attempts} time${f.attempts === 1 ? '' : 's'} (trial ${f.trial_id}) and holds every scored test: repeat it (Schedule a redo) or accept it as incomplete with a reason, under Subjects.`;
      }
      const which = f ? `“${f.label}” (trial ${f.trial_id})` : 'remaining test';
      return `${who}'s ${which} failed as often as it is repeated by itself: repeat it (Schedule a redo) or accept it as incomplete with a reason, under Subjects.`;
    }
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

export function renderPanel(p) {
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
  p.f.test.v.textContent = test ? (UNSCORED[test.phase] ? `${UNSCORED[test.phase]} (not scored), trial ${test.trial_id}` : `Test ${test.number} of ${test.of}, trial ${test.trial_id}`) : '—';
  if (test) p.f.controller.v.replaceChildren(COMPENSATOR_NAME[test.controller] || test.controller, el('span', { class: 'sub' }, test.controller));
  else p.f.controller.v.textContent = '—';
  p.f.label.v.textContent = test ? test.label : st && st.phase === 'survey' ? st.label : '—';
  p.f.where.v.textContent = test ? `${SEAT_NAME[test.station] || test.station}, ${mmss(test.duration_s)} long` : '—';
  updateLiveText(p);

  p.f.page.v.textContent = pageText(st && st.station ? st.station.socket : undefined);

  const ready = phase === 'ready' && test;
  p.startBtn.disabled = !ready || p.busy || estopLatched;
  p.startBtn.textContent = ready ? (UNSCORED[test.phase] ? `Start ${UNSCORED[test.phase].toLowerCase()}` : `Start test ${test.number}`) : 'Start test';
  p.startBtn.title = estopLatched
    ? 'The E-stop is latched: reset it first'
    : ready ? `Start trial ${test.trial_id} (${compensatorName(test.controller)})` : 'Only when the station is ready';
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
    `Last run: trial ${li.id} (${li.code}, ${li.phase === 'test' ? li.blinded_label : li.phase}, ${compensatorName(li.controller)}) — ${li.status}` +
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

/** One animation frame: the live text when due, and the charts when something new came. */
export function drawPanel(p, textDue) {
  const id = chartTrial(p);
  const b = id ? live.get(id) : null;
  if (textDue) updateLiveText(p);
  if (!(b && b.dirty) && !p.dirtyChart) return;
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
