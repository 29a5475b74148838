// Calibration: fit the selected study's synthetic population to a table of cell means (CSV
// controller,station,metric,mean[,sd,n[,unit[,use]]]) or to the study's own completed tests,
// with rows held out of the fit (controller:station[:metric], comma-separated), by simulated
// moments on the server, in the background (POST /api/studies/{id}/calibrate, progress at
// GET /api/calibration, cancel at POST /api/calibration/cancel). The result is the study's
// next population version, which its pilots and planner then use.

import { S, act, el, errText, get, post, setStatus } from './dashboard-core.js';

const $ = (id) => document.getElementById(id);

let timer = null;

export function init() {
  $('cal-start').addEventListener('click', start);
  $('cal-cancel').addEventListener('click', cancel);
  check();
}

/** The form's request, or a message naming the field that is wrong. */
function request() {
  const subjects = Number($('cal-subjects').value);
  if (!Number.isInteger(subjects) || subjects < 8 || subjects > 512) {
    return { error: 'Simulated subjects: a whole number from 8 to 512.' };
  }
  const table = $('cal-source').value === 'table' ? $('cal-table').value : null;
  if (table !== null && !table.trim()) {
    return { error: 'Table: paste CSV with the header controller,station,metric,mean (and optionally sd,n,unit,use).' };
  }
  const holdOut = $('cal-hold-out').value.trim();
  if (holdOut && !holdOut.split(',').every((item) => /^\s*[\w-]+:\s*(on|off)\s*(:\s*\w+\s*)?$/.test(item))) {
    return { error: 'Hold out: items controller:station[:metric], comma-separated, e.g. lqr:on,pid:on:ms_cab_accel.' };
  }
  return { body: { table, hold_out: holdOut || null, simulated_subjects: subjects, seed: Number($('cal-seed').value) || 0 } };
}

async function start() {
  const id = S.studyId;
  if (!id) {
    setStatus($('cal-status'), 'err', 'Create or select a study first.');
    return;
  }
  const r = request();
  if (r.error) {
    setStatus($('cal-status'), 'err', r.error);
    return;
  }
  $('cal-start').disabled = true;
  const done = await act(`Calibration of study #${id}`, $('cal-status'), () =>
    post(`/api/studies/${id}/calibrate`, r.body), () => 'started');
  if (!done.ok) {
    $('cal-start').disabled = false;
    return;
  }
  follow();
}

async function cancel() {
  await act('Cancel the calibration', $('cal-status'), () => post('/api/calibration/cancel', {}), () => 'cancelling');
  follow();
}

function follow() {
  clearTimeout(timer);
  timer = setTimeout(check, 500);
}

/** Shows the state of the last calibration, and follows it while it runs. */
async function check() {
  const r = await get('/api/calibration');
  const bar = $('cal-progress');
  if (!r.ok) {
    if (r.status !== 404 && r.status !== 401) setStatus($('cal-status'), 'err', `Calibration state: ${errText(r)}`);
    return;
  }
  const d = r.data;
  if (!d || (!d.running && d.done === undefined)) {
    bar.hidden = true;
    $('cal-cancel').hidden = true;
    return;
  }
  if (d.running) {
    $('cal-start').disabled = true;
    $('cal-cancel').hidden = false;
    bar.hidden = false;
    // The fit runs as many evaluations as it needs: the bar counts simulated trials so far.
    bar.removeAttribute('value');
    setStatus($('cal-status'), 'busy', `Calibrating study #${d.study_id}: ${d.done} simulated trials run…`);
    follow();
    return;
  }
  $('cal-start').disabled = false;
  $('cal-cancel').hidden = true;
  bar.hidden = true;
  if (d.error) setStatus($('cal-status'), 'err', `The last calibration (study #${d.study_id}) ended: ${d.error}`);
  else if (d.report) {
    setStatus($('cal-status'), 'ok', `Study #${d.study_id}: population version ${d.report.population_version} stored (pilots and the planner use it).`);
    show(d.report.fit);
  }
}

const range = (c) => (c.low === null || c.low === undefined ? '—' : `${num(c.low)} – ${num(c.high)}`);

const num = (v) => (v === null || v === undefined || Number.isNaN(v) ? '—' : Number(v).toPrecision(4));

/** The fit: its parameters with intervals, the target cells and the predictions. */
function show(fit) {
  const params = el('table', { class: 'grid numeric' },
    el('thead', {}, el('tr', {}, ...['Parameter (median)', 'before', 'fitted', '95 % interval'].map((h) => el('th', {}, h)))),
    el('tbody', {}, ...fit.parameters.map((p) =>
      el('tr', {}, el('th', {}, p.name), el('td', {}, num(p.before)), el('td', {}, num(p.fitted)), el('td', {}, `${num(p.low)} – ${num(p.high)}`)))));
  // A prediction's "target" column holds what the study's subjects gave (observed, not fitted).
  const inside = (c) => (c.inside === null || c.inside === undefined ? '' : c.inside ? 'inside' : 'OUTSIDE');
  const cellRows = (cells) => cells.map((c) =>
    el('tr', {}, el('th', {}, `${c.controller} ${c.station}`), el('td', {}, c.metric),
      el('td', {}, c.observed === null || c.observed === undefined ? num(c.target) : `${num(c.observed)} (n ${c.observed_n})`),
      el('td', {}, num(c.prediction)), el('td', {}, `± ${num(c.monte_carlo_error)}`),
      el('td', { title: c.note || '' }, `${range(c)}${c.note ? ' *' : ''}`), el('td', {}, inside(c))));
  const heldOut = fit.held_out || [];
  const cells = el('table', { class: 'grid numeric' },
    el('thead', {}, el('tr', {}, ...['Cell', 'metric', 'target', 'prediction', 'Monte-Carlo error', '95 % prediction interval', 'held out'].map((h) => el('th', {}, h)))),
    el('tbody', {}, ...cellRows(fit.cells)),
    ...(heldOut.length ? [el('tbody', {}, el('tr', {}, el('th', { colspan: 7 }, 'Held out of the fit: predicted, beside the target')), ...cellRows(heldOut))] : []),
    el('tbody', {}, el('tr', {}, el('th', { colspan: 7 }, 'Predicted, not in the target (the ratings beside what the subjects gave, never fitted; * the metric was never fitted: its model discrepancy is unknown and left out)')), ...cellRows(fit.predictions)));
  const gof = fit.goodness_of_fit;
  const notes = [
    el('p', { class: gof && gof.verdict.startsWith('fits') ? 'status ok' : 'status warn' }, `Verdict: ${gof ? gof.verdict : '—'}.`),
    el('p', { class: 'muted small' }, `Objective ${num(fit.objective_before)} → ${num(fit.objective)} in ${fit.iterations} iterations, ${fit.simulated_subjects} simulated subjects; intervals: ${fit.intervals}. Prediction intervals: ${fit.prediction_intervals}.`),
  ];
  if (fit.at_bound && fit.at_bound.length) {
    notes.push(el('p', { class: 'status warn' }, `At a bound (the fit wanted to go further): ${fit.at_bound.join(', ')}.`));
  }
  if (fit.not_identified.length) {
    notes.push(el('p', { class: 'status warn' }, `Not identified by this target (left as they were): ${fit.not_identified.join(', ')}.`));
  }
  $('cal-result').replaceChildren(params, cells, ...notes);
}
