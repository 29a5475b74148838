// What the experimenter does from a station's panel: start the test the station is ready
// for, abort the running one (with a reason), and for a failed run schedule a redo or
// accept it as incomplete (a reason is required). Apart because these are the monitor's
// only state-changing requests: each shows its outcome in the panel, then the station is read
// again and the other views are told a trial changed.

import { act, compensatorName, emit, errText, post } from './dashboard-core.js';
import { renderPanel } from './dashboard-monitor-panel.js';
import { panels, poll } from './dashboard-monitor-state.js';

/** A click in the monitor: the panel's action button, if it is one. */
export async function onClick(e) {
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
    `Start trial ${test.trial_id} at “${p.station.name}” (${p.state.subject}, ${test.phase === 'test' ? test.label : test.phase}, ${compensatorName(test.controller)})`,
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

