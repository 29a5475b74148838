// The power planner: for candidate numbers of subjects, the chance that each pair of
// compensators differs significantly at one seat (or, in a study with cancellation, each
// compensator from itself cancelled with one arm), from whole simulated studies — with the
// study's synthetic population (full trials, minutes) or a pilot's spread. Runs on the
// server in the background (POST /api/studies/{id}/plan-job, progress at GET /api/plan-job).

import { S, act, el, errText, get, post, setStatus } from './dashboard-core.js';

const $ = (id) => document.getElementById(id);

let timer = null;

export function init() {
  $('plan-start').addEventListener('click', start);
  check();
}

/** The form's request, or a message naming the field that is wrong. */
function request() {
  const subjects = $('plan-subjects').value.split(',').map((s) => Number(s.trim()));
  if (!subjects.length || subjects.some((n) => !Number.isInteger(n) || n < 2 || n > 200)) {
    return { error: 'Subjects: whole numbers from 2 to 200, separated by commas (e.g. 8, 12, 16).' };
  }
  const draws = Number($('plan-draws').value);
  const source = $('plan-source').value;
  const [lo, hi] = source === 'population' ? [10, 10000] : [100, 100000];
  if (!Number.isInteger(draws) || draws < lo || draws > hi) {
    return { error: `Simulated studies: a whole number from ${lo} to ${hi} with this model.` };
  }
  const body = {
    source,
    subjects,
    draws,
    station: $('plan-station').value,
    metric: $('plan-metric').value,
    seed: Number($('plan-seed').value) || 0,
  };
  const arm = $('plan-cancellation').value;
  if (arm) body.cancellation = arm;
  return { body };
}

async function start() {
  const id = S.studyId;
  if (!id) {
    setStatus($('plan-status'), 'err', 'Create or select a study first.');
    return;
  }
  const r = request();
  if (r.error) {
    setStatus($('plan-status'), 'err', r.error);
    return;
  }
  $('plan-start').disabled = true;
  const done = await act(`Power plan of study #${id}`, $('plan-status'), () =>
    post(`/api/studies/${id}/plan-job`, r.body), () => 'started');
  if (!done.ok) {
    $('plan-start').disabled = false;
    return;
  }
  follow();
}

function follow() {
  clearTimeout(timer);
  timer = setTimeout(check, 500);
}

/** Shows the state of the last plan, and follows it while it runs. */
async function check() {
  const r = await get('/api/plan-job');
  const bar = $('plan-progress');
  if (!r.ok) {
    if (r.status !== 404 && r.status !== 401) setStatus($('plan-status'), 'err', `Planner state: ${errText(r)}`);
    return;
  }
  const d = r.data;
  if (!d || (!d.running && d.done === undefined)) {
    bar.hidden = true;
    return;
  }
  if (d.running) {
    $('plan-start').disabled = true;
    bar.hidden = false;
    if (d.total) {
      bar.max = d.total;
      bar.value = d.done;
    } else bar.removeAttribute('value');
    setStatus($('plan-status'), 'busy', `Planning study #${d.study_id}: ${d.done} of ${d.total || '?'} simulated trials run…`);
    follow();
    return;
  }
  $('plan-start').disabled = false;
  bar.hidden = true;
  if (d.error) setStatus($('plan-status'), 'err', `The last plan (study #${d.study_id}) failed: ${d.error}`);
  else if (d.report) {
    setStatus($('plan-status'), 'ok', `The last plan, study #${d.study_id} (${d.report.source === 'population' ? 'the synthetic population' : "a pilot's spread"}, seed ${d.report.seed}):`);
    show(d.report);
  }
}

const pct = (p) => `${Math.round(p * 100)} %`;

/** The plan as a table: a row per pair, a column per candidate number of subjects. */
function show(rep) {
  const plans = rep.plans;
  const head = el('tr', {}, el('th', {}, 'Comparison'), ...plans.map((p) => el('th', {}, `n = ${p.subjects}`)));
  const rows = plans[0].pairs.map((pair, i) =>
    el('tr', {},
      el('th', {}, `${pair.a} vs ${pair.b}`),
      ...plans.map((p) => {
        const q = p.pairs[i];
        return el('td', { class: q.possible ? '' : 'muted', title: q.possible ? `${p.draws} simulated studies` : p.note },
          q.possible ? pct(q.power) : 'impossible');
      })));
  const any = el('tr', {}, el('th', {}, 'any pair'), ...plans.map((p) => el('td', {}, p.draws ? pct(p.any) : 'impossible')));
  const notes = plans.filter((p) => p.note).map((p) => el('p', { class: 'status warn' }, `n = ${p.subjects}: ${p.note}.`));
  const m = rep.model;
  const model = el('p', { class: 'muted small' },
    `Model (log scale, ${m.pilot_n} subjects): residual SD ${m.residual_sd.toFixed(3)}; means ${m.compensators.map((c, i) => `${c} ${Math.exp(m.log_means[i]).toPrecision(4)}`).join(', ')}.`);
  $('plan-result').replaceChildren(
    el('table', { class: 'grid numeric' }, el('thead', {}, head), el('tbody', {}, ...rows, any)),
    model,
    ...notes,
  );
}
