// The pursuit display of a running test: the live samples it is fed, the strip chart of
// target and cylinder drawn every frame, the countdown, and the shake of the on-machine
// station (the cab's displacement at its 4 Hz mode). Apart because it is the page's frame
// loop: it draws what has arrived and never waits on the server. The display's timing is
// measured and reported by station-timing.js, the input it sends by station-input.js.

import { input, pollGamepad, sendInput } from './station-input.js';
import { countFrame, reportTiming, sendDisplay } from './station-timing.js';

const WINDOW_S = 5;          // the strip chart shows the last 5 s
const SHAKE_OMEGA = 2 * Math.PI * 4; // the cab's 4 Hz mode (rad/s)

const $ = (id) => document.getElementById(id);

/** Chart geometry in CSS pixels (set by the drawing code, used by the pointer). */
export const geom = { centerY: 0, pxPerMm: 1, limitMm: 48 };

export let run = null;

export function startRun(test) {
  run = {
    trialId: test.trial_id,
    test,
    samples: [],          // {t, target, cyl, accel}, the last few seconds
    latest: null,
    latestAt: 0,          // performance.now() when the latest sample arrived
    frames: 0,
    longFrames: 0,
    lastFrame: null,
    longestGap: 0,        // ms between two frames, or since the start before the first
    startedAt: performance.now(),
    hiddenMs: 0,          // hidden time before the current hidden spell
    hiddenSince: document.hidden ? performance.now() : null,
    inputs: 0,            // input messages sent for this test
    rtts: [],
    seenSeq: new Set(),
  };
  resizeCanvas();
  sendDisplay();
}

export function onSample(sample) {
  if (!run || sample.trial_id !== run.trialId) return;
  const now = performance.now();
  // In an identification test the subject holds the pointer (the device) still at the
  // centre; the multisine that moves the boom is not theirs to follow, so it is not drawn.
  const identification = run.test.phase === 'identification';
  const s = {
    t: sample.t,
    target: identification ? 0 : sample.target_mm,
    cyl: identification ? sample.device_mm : sample.cylinder_mm,
    accel: sample.cab_accel_mm_s2,
  };
  if (run.latest && s.t < run.latest.t) run.samples = [];
  run.samples.push(s);
  run.latest = s;
  run.latestAt = now;
  // Drop what has scrolled off (keep a little more than the window).
  const cut = s.t - WINDOW_S - 1;
  let drop = 0;
  while (drop < run.samples.length && run.samples[drop].t < cut) drop++;
  if (drop > 0) run.samples.splice(0, drop);
  const seq = sample.input_seq;
  if (seq > 0 && !run.seenSeq.has(seq)) {
    run.seenSeq.add(seq);
    const sent = input.sentAt.get(seq);
    if (sent !== undefined) run.rtts.push(now - sent);
  }
}

/** The test shown is no longer running: stop shaking and report the page's timing. */
export function finishRun() {
  const r = run;
  run = null;
  const canvas = $('track');
  canvas.style.transform = '';
  reportTiming(r);
}

let canvasSize = { w: 0, h: 0, dpr: 1 };

export function resizeCanvas() {
  const canvas = $('track');
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth;
  const h = canvas.clientHeight;
  if (w === canvasSize.w && h === canvasSize.h && dpr === canvasSize.dpr) return;
  canvasSize = { w, h, dpr };
  canvas.width = Math.max(1, Math.round(w * dpr));
  canvas.height = Math.max(1, Math.round(h * dpr));
}

function cssVar(name, fallback) {
  const v = getComputedStyle(document.documentElement).getPropertyValue(name).trim();
  return v || fallback;
}

const colors = { target: '#ffd33d', cylinder: '#33c3ff' };

/** The chart's colours from the stylesheet (the defaults above if it sets none). */
export function readColors() {
  colors.target = cssVar('--target', colors.target);
  colors.cylinder = cssVar('--cylinder', colors.cylinder);
}

/**
 * The axis's gridlines for a target range of ±`range` mm: zero, the multiples of the
 * largest step of 1, 2 or 5 × 10ⁿ that fits twice into the range, and ±range itself;
 * symmetric, so the two halves read alike (±12.5 rounded two ways gave +13 and −12).
 */
export function axisTicks(range) {
  const half = range / 2;
  const decade = 10 ** Math.floor(Math.log10(half));
  const step = [5, 2, 1].map((m) => m * decade).find((s) => s <= half);
  const ticks = [0];
  for (let k = 1; k * step < range - 1e-9 * range; k += 1) ticks.push(k * step, -k * step);
  ticks.push(range, -range);
  return ticks.sort((a, b) => a - b);
}

/** A gridline's label: signed, with as many decimals as the value has (at most one). */
export function tickLabel(mm) {
  const text = Number.isInteger(mm) ? String(Math.abs(mm)) : Math.abs(mm).toFixed(1);
  return `${mm > 0 ? '+' : mm < 0 ? '−' : ''}${text} mm`;
}

function draw(now) {
  const r = run;
  const canvas = $('track');
  resizeCanvas();
  const { w, h, dpr } = canvasSize;
  const ctx = canvas.getContext('2d');
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.fillStyle = '#000';
  ctx.fillRect(0, 0, w, h);

  const range = r.test.target_range_mm;
  const limit = 1.2 * range;
  const left = Math.min(110, w * 0.12);
  const right = w - 16;
  const top = 80;
  const bottom = h - 24;
  const centerY = (top + bottom) / 2;
  const pxPerMm = Math.max(1e-6, (bottom - top) / 2 / limit);
  geom.centerY = centerY;
  geom.pxPerMm = pxPerMm;
  geom.limitMm = limit;
  const yOf = (mm) => centerY - Math.max(-limit, Math.min(limit, mm)) * pxPerMm;

  // Grid: zero, round ticks and ±range, labelled in mm.
  ctx.font = '600 20px system-ui, sans-serif';
  ctx.textAlign = 'right';
  ctx.textBaseline = 'middle';
  for (const mm of axisTicks(range)) {
    const y = Math.round(yOf(mm)) + 0.5;
    ctx.strokeStyle = mm === 0 ? '#8b949e' : '#30363d';
    ctx.lineWidth = mm === 0 ? 2 : 1;
    ctx.beginPath();
    ctx.moveTo(left, y);
    ctx.lineTo(right, y);
    ctx.stroke();
    ctx.fillStyle = '#c9d1d9';
    ctx.fillText(tickLabel(mm), left - 10, y);
  }

  // Time: the newest sample at the right edge, extrapolated between samples for a smooth
  // scroll (at most 0.1 s ahead, so a stalled feed stops the chart).
  let tNow = 0;
  if (r.latest) tNow = r.latest.t + Math.min(0.1, Math.max(0, (now - r.latestAt) / 1000));
  const t0 = tNow - WINDOW_S;
  const xOf = (t) => right - ((tNow - t) / WINDOW_S) * (right - left);

  ctx.save();
  ctx.beginPath();
  ctx.rect(left, top - 10, right - left, bottom - top + 20);
  ctx.clip();
  const line = (key, color, width) => {
    ctx.strokeStyle = color;
    ctx.lineWidth = width;
    ctx.lineJoin = 'round';
    ctx.lineCap = 'round';
    ctx.beginPath();
    let started = false;
    for (const s of r.samples) {
      if (s.t < t0 - 0.05) continue;
      const x = xOf(s.t);
      const y = yOf(s[key]);
      if (started) ctx.lineTo(x, y);
      else {
        ctx.moveTo(x, y);
        started = true;
      }
    }
    ctx.stroke();
  };
  line('target', colors.target, 8);
  line('cyl', colors.cylinder, 4);
  // The newest positions, as dots at the right edge.
  if (r.latest) {
    for (const [key, color, rad] of [['target', colors.target, 9], ['cyl', colors.cylinder, 7]]) {
      ctx.fillStyle = color;
      ctx.beginPath();
      ctx.arc(xOf(r.latest.t), yOf(r.latest[key]), rad, 0, 2 * Math.PI);
      ctx.fill();
    }
  }
  ctx.restore();

  // Countdown.
  const left_s = Math.max(0, r.test.duration_s - (r.latest ? r.latest.t : 0));
  const text = `${Math.ceil(left_s)} s`;
  const cd = $('countdown');
  if (cd.textContent !== text) {
    cd.textContent = text;
    cd.dataset.seconds = String(Math.ceil(left_s));
  }

  // Shake (on-machine station only): the cab's displacement at its 4 Hz mode.
  const gain = r.test.shake_gain || 0;
  if (gain > 0 && r.latest) {
    const mm = gain * (-r.latest.accel / (SHAKE_OMEGA * SHAKE_OMEGA));
    // A safety bound: a violent transient (or a large gain) never throws the chart more than
    // a quarter of the screen.
    const bound = 0.25 * h;
    const px = Math.max(-bound, Math.min(bound, mm * pxPerMm));
    // Up on the chart is up on the screen: a cab moving up moves the display up.
    canvas.style.transform = `translate3d(0, ${(-px).toFixed(2)}px, 0)`;
  } else if (canvas.style.transform) {
    canvas.style.transform = '';
  }
}

export function frame(now) {
  requestAnimationFrame(frame);
  if (run) {
    countFrame(run, now);
    draw(now);
  }
  if (input.trialId !== null) {
    pollGamepad();
    sendInput();
  }
}
