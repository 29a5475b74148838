// The operator station: what the subject sees and touches. Pairing, consent, the pursuit
// display with operator input, the survey after each test, "Stopped" while the E-stop is
// latched. Talks only to /api/station/* with the station's bearer token, and to
// /api/station/ws for input, live samples, changes and the E-stop latch.
//
// This module starts the page; the parts are in their own modules:
//   station-connection.js   one tab per browser, token and pairing, polling the state, the socket
//   station-phases.js       which phase shows, and when a test's run starts and ends
//   station-instructions.js the study's texts: before a test, moving seats, the end
//   station-consent.js      the consent form and the subject's decision
//   station-survey.js       the survey after each test
//   station-pursuit.js      the pursuit display: live samples, drawing, shaking
//   station-input.js        pointer and gamepad input sent to the controller
//   station-timing.js       the display's health and timing, reported to the server
//   station-errors.js       the error banner
// They import each other, which ES modules allow: none calls another while they load, and
// init() below runs once all have loaded. A variable they share (the state shown, the
// token, the socket, the run) is assigned only in the module that declares it; the others
// read it live.

import { claimTab, newCode, refresh } from './station-connection.js';
import { confirmDecline, decide } from './station-consent.js';
import { setError } from './station-errors.js';
import { input, setupPointer } from './station-input.js';
import { frame, readColors, resizeCanvas } from './station-pursuit.js';
import { submitSurvey } from './station-survey.js';
import { onVisibility } from './station-timing.js';

const $ = (id) => document.getElementById(id);

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
  $('new-code').addEventListener('click', newCode);
  setupPointer();
  window.addEventListener('resize', resizeCanvas);
  document.addEventListener('visibilitychange', onVisibility);
  window.addEventListener('gamepadconnected', (ev) => {
    delete input.pad.rest[ev.gamepad.index];
  });
  readColors();
  requestAnimationFrame(frame);
  claimTab(refresh);
}

init();
