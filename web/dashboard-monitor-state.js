// What the monitor knows of each station: its panel (by station id), the station's state
// read from GET /api/stations/{id}/state, which trial ran last there (a short test may
// start and end between two reads: its live samples tell), and that trial's official
// result from the subject's schedule. Apart because it is the monitor's one reader of the
// stations: the panels draw what it keeps, the actions read it again after each change.

import { errText, get } from './dashboard-core.js';
import { live } from './dashboard-monitor-live.js';
import { renderPanel } from './dashboard-monitor-panel.js';

/** Panels by station id. */
export const panels = new Map();

/** Reads the station's state again, notes the trial that ran last, and renders the panel. */
export async function poll(p) {
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
