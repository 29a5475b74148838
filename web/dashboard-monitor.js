// The live monitor: one panel per paired station, fed by GET /api/stations/{id}/state (every
// second) and the /api/live WebSocket (live samples, trial changes, controller link, the
// E-stop latch: Start stays disabled while it is latched).
//
// This module runs the view (its panels follow the study's stations, the state is read
// every second, the charts are drawn every frame); the parts are in their own modules:
//   dashboard-monitor-live.js     the live feed: socket, samples per trial, the E-stop latch
//   dashboard-monitor-state.js    the panels by station, each station's state, its last run
//   dashboard-monitor-panel.js    one station's panel, built and rendered
//   dashboard-monitor-actions.js  start, abort, redo and accept-as-incomplete

import { S, el, emit, on } from './dashboard-core.js';
import { onClick } from './dashboard-monitor-actions.js';
import * as feed from './dashboard-monitor-live.js';
import { drawPanel, makePanel, renderPanel } from './dashboard-monitor-panel.js';
import { panels, poll } from './dashboard-monitor-state.js';

const $ = (id) => document.getElementById(id);

let pollTimer = null;
let running = false;
let raf = null;
let lastTextUpdate = 0;

export function init() {
  feed.listen({
    connected: pollAll,
    trialChanged: onTrialChanged,
    latchChanged() {
      for (const p of panels.values()) renderPanel(p);
    },
  });
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
  feed.open();
  clearInterval(pollTimer);
  pollTimer = setInterval(pollAll, 1000);
  pollAll();
  if (!raf) raf = requestAnimationFrame(frame);
}

export function stop() {
  running = false;
  clearInterval(pollTimer);
  pollTimer = null;
  feed.close();
  if (raf) cancelAnimationFrame(raf);
  raf = null;
}

// ---- news from the feed -------------------------------------------------------------------

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

// ---- the panels follow the study's stations -----------------------------------------------

/** One panel per station of the selected study, in the stations' order. */
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
      empty = el('p', { class: 'monitor-empty muted' });
      box.append(empty);
    }
    // The note made before a study was selected stays: its words follow the selection.
    empty.textContent = S.studyId
      ? 'No station paired with this study yet. Open /station on each station’s computer and pair it under Stations.'
      : 'Select or create a study first.';
  } else if (empty) empty.remove();
  for (const p of panels.values()) renderPanel(p);
  pollAll();
}

async function pollAll() {
  if (!running) return;
  await Promise.all([...panels.values()].map(poll));
}

function frame(now) {
  raf = running ? requestAnimationFrame(frame) : null;
  const textDue = now - lastTextUpdate > 250;
  if (textDue) lastTextUpdate = now;
  for (const p of panels.values()) drawPanel(p, textDue);
}
