// Showing a phase: the station's state decides which section of the page shows (or
// "Stopped" while the E-stop is latched, or "open in another window"), which phase's
// content is rebuilt, and when a test's run starts and ends. Apart because it is the one
// switch every state goes through; what each phase shows is in its own module.

import { latched, replaced, showPairingCode } from './station-connection.js';
import { renderConsent } from './station-consent.js';
import { input } from './station-input.js';
import { renderDone, renderMove, renderReady, setLanguage } from './station-instructions.js';
import { finishRun, run, startRun } from './station-pursuit.js';
import { renderSurvey } from './station-survey.js';

const PHASES = ['loading', 'unpaired', 'waiting', 'consent', 'ready', 'running', 'survey', 'move', 'held', 'done'];

const $ = (id) => document.getElementById(id);

export let state = null; // the last state shown
let renderKey = null;

export function show(s) {
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

  showSection(displayed);
}

/** Shows the section of `displayed` (a phase, or what the page shows instead of one) alone. */
export function showSection(displayed) {
  if (document.body.dataset.phase === displayed) return;
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

/** What the subject is told about a test that was stopped (never a controller's name). */
function showStopped(stopped) {
  const box = $('stopped-notice');
  if (!stopped) {
    box.hidden = true;
    return;
  }
  // Each status a whole sentence of its own, so that every one reads well after the label.
  const what = {
    invalid: 'was stopped because the display was hidden or stopped updating',
    aborted: 'was stopped by the experimenter',
    incomplete: 'was stopped by a technical problem',
  }[stopped.status] || 'was stopped by a problem';
  const then = !stopped.repeated
    ? 'The experimenter will decide how to go on.'
    : stopped.repeated_next ? 'It will be repeated next.' : 'It will be repeated later.';
  const text = `${stopped.label} ${what}. ${then}`;
  if (box.textContent !== text) box.textContent = text;
  box.hidden = false;
}

const renderers = {
  unpaired() {
    showPairingCode();
  },
  waiting() {},
  consent(s) {
    renderConsent(s);
  },
  ready(s) {
    renderReady(s);
  },
  running(s) {
    $('running-label').textContent = s.test.phase === 'practice'
      ? 'Practice (not scored)'
      : s.test.phase === 'identification'
        ? 'Measurement (not scored): you do not steer'
        : `${s.test.label} · test ${s.test.number} of ${s.test.of}`;
  },
  survey(s) {
    renderSurvey(s);
  },
  held() {},
  move(s) {
    renderMove(s);
  },
  done(s) {
    renderDone(s);
  },
};
