// Pilot runs: the whole protocol for N synthetic subjects of the selected study, run by the
// server faster than real time (POST /api/studies/{id}/pilot, progress at GET /api/pilot).

import { S, act, emit, errText, get, post, setStatus } from './dashboard-core.js';
import { loadStudies } from './dashboard-study.js';

const $ = (id) => document.getElementById(id);

let timer = null;

export function init() {
  $('pilot-start').addEventListener('click', start);
  check();
}

async function start() {
  const id = S.studyId;
  if (!id) {
    setStatus($('pilot-status'), 'err', 'Create or select a study first.');
    return;
  }
  const n = Number($('pilot-subjects').value);
  if (!Number.isInteger(n) || n < 1 || n > 50) {
    setStatus($('pilot-status'), 'err', 'Subjects: a whole number from 1 to 50.');
    return;
  }
  $('pilot-start').disabled = true;
  const r = await act(`Pilot run of ${n} synthetic subjects in study #${id}`, $('pilot-status'), () =>
    post(`/api/studies/${id}/pilot`, { subjects: n }),
  () => 'started');
  if (!r.ok) {
    $('pilot-start').disabled = false;
    return;
  }
  follow();
}

function follow() {
  clearTimeout(timer);
  timer = setTimeout(check, 1000);
}

/** Shows the state of the last pilot run (and follows it while it runs). */
async function check() {
  const r = await get('/api/pilot');
  const bar = $('pilot-progress');
  if (!r.ok) {
    if (r.status !== 404 && r.status !== 401) setStatus($('pilot-status'), 'err', `Pilot state: ${errText(r)}`);
    return;
  }
  const d = r.data;
  if (!d || (!d.running && d.done === undefined)) {
    bar.hidden = true;
    $('pilot-start').disabled = false;
    return;
  }
  if (d.running) {
    $('pilot-start').disabled = true;
    bar.hidden = false;
    if (d.total) {
      bar.max = d.total;
      bar.value = d.done;
    } else bar.removeAttribute('value');
    setStatus($('pilot-status'), 'busy', `Pilot run in dry run #${d.study_id}: ${d.done} of ${d.total || '?'} trials run…`);
    emit('trial', null);
    follow();
    return;
  }
  $('pilot-start').disabled = false;
  bar.hidden = true;
  if (d.error) setStatus($('pilot-status'), 'err', `Last pilot run (dry run #${d.study_id}) failed: ${d.error}`);
  else if (d.report) {
    const rep = d.report;
    setStatus(
      $('pilot-status'),
      'ok',
      `Last pilot run (dry run #${rep.study_id}, apart from the study's people; select it under Studies to see its results): ${rep.subjects.length} synthetic subjects (${rep.subjects.join(', ')}), ${rep.complete} of ${rep.trials} trials complete.`,
    );
  }
  if (timer) {
    // It just finished: every view reloads, and the study list shows the dry run it made
    // (selectable, so its results can be looked at).
    timer = null;
    await loadStudies();
    emit('trial', null);
  }
}
