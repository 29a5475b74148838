// The display's timing: while a test runs, its health (frames, the longest gap between two,
// time hidden, input sent) goes to the server every 250 ms and at once when the page is
// hidden or shown, and when the test ends a summary (long frames, input rate, the input's
// round trip) is filed with the trial. Apart because the server judges a test on these
// figures, not on what the page draws.

import { api } from './common.js';
import { socket, token } from './station-connection.js';
import { describe, setError } from './station-errors.js';
import { run } from './station-pursuit.js';

/** A frame this much later than the one before counts as long. */
const LONG_FRAME_MS = 25;
/** While a test runs, the display's health goes to the server this often (and at once when
 * the page is hidden or shown): the server stops a test whose display is hidden or stalled. */
const DISPLAY_EVERY_MS = 250;

/** One frame drawn: counts it, and the gap since the last (or since the start). */
export function countFrame(r, now) {
  const gap = now - (r.lastFrame === null ? r.startedAt : r.lastFrame);
  if (r.lastFrame !== null && gap > LONG_FRAME_MS) r.longFrames++;
  if (gap > r.longestGap) r.longestGap = gap;
  r.lastFrame = now;
  r.frames++;
}

/** The display's figures so far; the gap still open and the hidden spell still running
 * count (a stalled or hidden page draws no frame that would close them). */
function displayFigures(r, now) {
  const gap = now - (r.lastFrame === null ? r.startedAt : r.lastFrame);
  return {
    hidden: document.hidden,
    frames: r.frames,
    longest_gap_ms: Math.round(Math.max(r.longestGap, gap) * 10) / 10,
    hidden_ms: Math.round((r.hiddenMs + (r.hiddenSince === null ? 0 : now - r.hiddenSince)) * 10) / 10,
    inputs: r.inputs,
  };
}

export function sendDisplay() {
  const r = run;
  if (!r || !socket || socket.readyState !== WebSocket.OPEN) return;
  socket.send(JSON.stringify({ type: 'display', trial_id: r.trialId, ...displayFigures(r, performance.now()) }));
}

export function onVisibility() {
  const r = run;
  if (r) {
    const now = performance.now();
    if (document.hidden && r.hiddenSince === null) r.hiddenSince = now;
    if (!document.hidden && r.hiddenSince !== null) {
      r.hiddenMs += now - r.hiddenSince;
      r.hiddenSince = null;
    }
  }
  sendDisplay();
}

function percentile(sorted, p) {
  if (!sorted.length) return 0;
  const i = Math.min(sorted.length - 1, Math.max(0, Math.ceil(p * sorted.length) - 1));
  return sorted[i];
}

/** The timing of a run that has ended, filed with its trial. */
export async function reportTiming(r) {
  const sorted = [...r.rtts].sort((a, b) => a - b);
  const round = (x) => Math.round(Math.min(600000, Math.max(0, x)) * 100) / 100;
  const now = performance.now();
  const figures = displayFigures(r, now);
  const secs = Math.max(1e-3, (now - r.startedAt) / 1000);
  const body = {
    trial_id: r.trialId,
    frames: r.frames,
    long_frames: Math.min(r.longFrames, r.frames),
    longest_gap_ms: round(figures.longest_gap_ms),
    hidden_ms: round(figures.hidden_ms),
    input_hz: Math.round(Math.min(1000, r.inputs / secs) * 10) / 10,
    rtt_ms: {
      p50: round(percentile(sorted, 0.5)),
      p95: round(percentile(sorted, 0.95)),
      max: round(sorted.length ? sorted[sorted.length - 1] : 0),
    },
  };
  const res = await api('POST', '/api/station/timing', body, { bearer: token });
  if (!res.ok) setError('action', `Could not save the display timing: ${describe(res)}`);
}

setInterval(sendDisplay, DISPLAY_EVERY_MS);
