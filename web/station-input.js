// The subject's input devices: pointer (mouse, pen, touch) and gamepad. The wanted cylinder
// position in mm is what the subject points at; the device position sent on the socket is
// that / k_bf, at most 250 messages a second and never queued behind a congested socket.
// Apart because it is the page's one real-time duty besides drawing: the controller ends a
// test after 100 ms without input, whatever the display does.

import { socket } from './station-connection.js';
import { state } from './station-phases.js';
import { geom, run } from './station-pursuit.js';

/** At most 250 input messages a second (the server allows 500). */
const MIN_SEND_MS = 4;
const MAX_INPUT_MM = 1000;   // the server drops anything larger

const $ = (id) => document.getElementById(id);

export const input = {
  trialId: null,      // the test the input is for (ready or running), else null
  seqTrial: null,     // the test `seq` counts for
  seq: 0,
  wantedMm: 0,        // where the subject wants the cylinder (chart mm)
  lastSend: 0,
  sentAt: new Map(),  // seq → performance.now() when sent
  source: 'pointer',  // 'pointer' or 'pad': which moved last
  pad: { index: null, axis: null, rest: {}, last: null },
};

function currentTest() {
  return state && state.test && state.test.trial_id === input.trialId ? state.test : null;
}

function clampMm(mm) {
  const t = currentTest();
  const lim = t ? 1.2 * t.target_range_mm : geom.limitMm;
  return Math.max(-lim, Math.min(lim, mm));
}

export function sendInput() {
  const t = currentTest();
  if (!t || !socket || socket.readyState !== WebSocket.OPEN) return;
  const now = performance.now();
  if (now - input.lastSend < MIN_SEND_MS) return;
  // Latest wins: never queue input behind a congested socket.
  if (socket.bufferedAmount > 4096) return;
  if (input.seqTrial !== t.trial_id) {
    input.seqTrial = t.trial_id;
    input.seq = 0;
    input.sentAt.clear();
  }
  const kbf = t.k_bf > 0 ? t.k_bf : 1;
  let pos = input.wantedMm / kbf;
  pos = Math.max(-MAX_INPUT_MM, Math.min(MAX_INPUT_MM, pos));
  const seq = ++input.seq;
  socket.send(JSON.stringify({ type: 'input', trial_id: t.trial_id, seq, position_mm: pos }));
  if (run && run.trialId === t.trial_id) run.inputs++;
  input.lastSend = now;
  input.sentAt.set(seq, now);
  // Forget send times older than 10 s (a sample never answers that late).
  if (input.sentAt.size > 4000) {
    for (const [k, at] of input.sentAt) {
      if (now - at < 10000) break;
      input.sentAt.delete(k);
    }
  }
}

function onPointer(ev) {
  let y = ev.clientY;
  if (typeof ev.getCoalescedEvents === 'function') {
    const all = ev.getCoalescedEvents();
    if (all.length) y = all[all.length - 1].clientY;
  }
  // Measured against the frame, which does not shake (the canvas does).
  const rect = $('track-frame').getBoundingClientRect();
  input.wantedMm = clampMm((geom.centerY - (y - rect.top)) / geom.pxPerMm);
  input.source = 'pointer'; // the pointer takes over from the gamepad
  sendInput();
}

export function setupPointer() {
  const canvas = $('track');
  const move = window.isSecureContext && 'onpointerrawupdate' in window ? 'pointerrawupdate' : 'pointermove';
  canvas.addEventListener(move, onPointer);
  canvas.addEventListener('pointerdown', (ev) => {
    try {
      canvas.setPointerCapture(ev.pointerId);
    } catch {
      // a synthetic pointer cannot be captured; harmless
    }
    onPointer(ev);
  });
  canvas.addEventListener('pointerup', (ev) => {
    if (canvas.hasPointerCapture && canvas.hasPointerCapture(ev.pointerId)) canvas.releasePointerCapture(ev.pointerId);
  });
  // No scrolling, zooming or context menu on the display.
  canvas.addEventListener('contextmenu', (ev) => ev.preventDefault());
}

/**
 * Gamepad: the first axis that moves (more than a quarter of its travel from where it rested
 * when first seen) is used; axes[1] and axes[3] (the sticks' vertical axes, up = −1) are
 * inverted. −1..1 spans the chart's full scale, as the pointer does. Whichever of pointer
 * and gamepad moved last is in control.
 */
export function pollGamepad() {
  if (!navigator.getGamepads) return;
  const pads = navigator.getGamepads();
  const pad = input.pad;
  let gp = pad.index !== null ? pads[pad.index] : null;
  if (!gp || !gp.connected) {
    pad.index = null;
    pad.axis = null;
    gp = null;
    for (const p of pads) {
      if (!p || !p.connected || !p.axes.length) continue;
      if (!pad.rest[p.index] || pad.rest[p.index].id !== p.id) pad.rest[p.index] = { id: p.id, axes: [...p.axes] };
      const rest = pad.rest[p.index].axes;
      const i = p.axes.findIndex((v, k) => Math.abs(v - rest[k]) > 0.25);
      if (i >= 0) {
        pad.index = p.index;
        pad.axis = i;
        pad.last = null;
        gp = p;
        break;
      }
    }
    if (!gp) return;
  }
  let v = gp.axes[pad.axis];
  if (typeof v !== 'number' || !Number.isFinite(v)) return;
  if (pad.axis === 1 || pad.axis === 3) v = -v;
  const moved = pad.last === null || Math.abs(v - pad.last) > 0.01;
  pad.last = v;
  if (moved) input.source = 'pad';
  if (input.source !== 'pad') return;
  const t = currentTest();
  const lim = t ? 1.2 * t.target_range_mm : geom.limitMm;
  input.wantedMm = Math.max(-1, Math.min(1, v)) * lim;
}

// A backstop for frames that stall (a busy tab): the controller ends a test after 100 ms
// without input, so keep input flowing at 25 Hz or more whatever the display does.
setInterval(() => {
  if (input.trialId !== null && performance.now() - input.lastSend > 40) sendInput();
}, 20);
