// Workbench analysis of the selected study's designs: Bode plots of each part, compensator
// and closed loop, the Nyquist curve of each design with −1 marked and its verdict, the pole
// tables in both views, and the robustness map with its Monte-Carlo pass rate. The server
// computes every number (GET /api/studies/{id}/workbench/…); this file only draws them.

import { S, compensatorName, el, errText, get, num, on, setStatus } from './dashboard-core.js';
import { fitCanvas, frame, niceStep, tickLabel, yGrid } from './dashboard-chart.js';

const $ = (id) => document.getElementById(id);
const COLORS = ['#1f6fb2', '#c0392b', '#2e8b57', '#8e44ad', '#d68910', '#17a2b8', '#555'];

export function init() {
  $('wb-frequency').addEventListener('click', () => loadFrequency());
  $('wb-robust-form').addEventListener('submit', (e) => {
    e.preventDefault();
    loadRobustness();
  });
  on('study', () => {
    for (const id of ['wb-verdicts', 'wb-bode-parts', 'wb-bode-loops', 'wb-bode-compensators', 'wb-nyquist', 'wb-poles', 'wb-robust-result']) {
      $(id).replaceChildren();
    }
    $('wb-kbf').value = S.study ? S.study.params.k_bf : '';
    const pick = $('wb-robust-design');
    const kinds = S.study ? S.study.params.controllers.map((c) => c.kind) : [];
    pick.replaceChildren(...kinds.map((k) => el('option', { value: k }, compensatorName(k))));
  });
}

// ---- frequency domain -----------------------------------------------------------------------

async function loadFrequency() {
  const status = $('wb-frequency-status');
  if (!S.studyId) return setStatus(status, 'err', 'select a study first');
  const kbf = $('wb-kbf').value.trim();
  const q = kbf === '' ? '' : `?kbf=${encodeURIComponent(kbf)}`;
  setStatus(status, 'busy', 'computing (seconds)…');
  const r = await get(`/api/studies/${S.studyId}/workbench/frequency${q}`);
  if (!r.ok) return setStatus(status, 'err', errText(r));
  setStatus(status, 'ok', `K_BF ${r.data.kbf}: ${r.data.compensators.length} designs${r.data.condition ? ` on the machine ${r.data.condition} (the designs made for the stilts)` : ''}`);
  renderFrequency(r.data);
}

function renderFrequency(rep) {
  const f = rep.freqs_hz;
  $('wb-verdicts').replaceChildren(verdictTable(rep));
  // The LQR designs share the cylinder's inner velocity loop (one figure, the first's).
  const inner = rep.compensators.find((c) => c.inner_loop);
  const parts = inner ? [...rep.parts, inner.inner_loop] : rep.parts;
  $('wb-bode-parts').replaceChildren(
    ...parts.map((p) => bodeFigure(p.name, f, [{ label: p.unit, mag: p.mag_db, phase: p.phase_deg }])),
  );
  const loops = (key) => rep.compensators.map((c) => ({ label: c.name, mag: c[key].mag_db, phase: c[key].phase_deg }));
  $('wb-bode-loops').replaceChildren(
    bodeFigure(`on the machine (K_BF ${rep.kbf}): y per reference`, f, loops('closed_loop_on')),
    bodeFigure('off the machine: y per reference', f, loops('closed_loop_off')),
  );
  $('wb-bode-compensators').replaceChildren(
    ...rep.compensators.map((c) =>
      bodeFigure(`${c.name}: valve command`, f, c.compensator.map((b) => ({ label: b.name.replace('valve command ', ''), mag: b.mag_db, phase: b.phase_deg }))),
    ),
  );
  $('wb-nyquist').replaceChildren(...rep.compensators.map((c) => nyquistFigure(c)));
  $('wb-poles').replaceChildren(...rep.compensators.map((c) => poleTable(c.poles)));
}

function verdict(n) {
  return n.stable ? 'stable' : `unstable (${n.closed_loop_unstable} pole${n.closed_loop_unstable === 1 ? '' : 's'} outside)`;
}

function maxKbf(k) {
  return k === null || k === undefined ? '> 20' : num(k);
}

function verdictTable(rep) {
  const head = el('tr', {}, ...['Design', `Verdict at K_BF ${rep.kbf}`, 'Encirclements of −1 (ccw)', 'Open-loop unstable', 'Largest stable K_BF'].map((h) => el('th', {}, h)));
  const rows = rep.compensators.map((c) => {
    const n = c.nyquist;
    return el('tr', { 'data-design': c.name },
      el('td', {}, compensatorName(c.name)),
      el('td', { class: n.stable ? 'ok' : 'err' }, verdict(n)),
      el('td', {}, String(n.encirclements)),
      el('td', {}, String(n.open_loop_unstable)),
      el('td', {}, maxKbf(n.max_stable_kbf)));
  });
  return el('table', { class: 'grid numeric' }, el('thead', {}, head), el('tbody', {}, ...rows));
}

function figure(title, canvasClass) {
  const canvas = el('canvas', { class: `chart ${canvasClass}` });
  return { node: el('figure', { class: 'wb-figure' }, el('figcaption', {}, title), canvas), canvas };
}

/** Draws after layout (the canvas needs its size), and marks the canvas drawn. */
function afterLayout(canvas, draw) {
  requestAnimationFrame(() => {
    draw(canvas);
    canvas.dataset.drawn = '1';
  });
}

/** A Bode figure: magnitude (dB) above, phase (deg) below, frequency on a log axis. */
function bodeFigure(title, freqs, series) {
  const { node, canvas } = figure(title, 'wb-bode');
  const legend = el('div', { class: 'wb-legend' }, ...series.map((s) => el('span', {}, `— ${s.label}`)));
  legend.querySelectorAll('span').forEach((s, i) => s.classList.add(`wb-c${i % COLORS.length}`));
  node.append(legend);
  afterLayout(canvas, (c) => {
    const { g, W, H } = fitCanvas(c);
    g.fillStyle = '#fff';
    g.fillRect(0, 0, W, H);
    const half = (H - 24) / 2;
    const lx = (f) => Math.log10(f);
    const [x0, x1] = [lx(freqs[0]), lx(freqs[freqs.length - 1])];
    const panel = (top, key, unit) => {
      const vals = series.flatMap((s) => s[key]).filter(Number.isFinite);
      let lo = Math.min(...vals);
      let hi = Math.max(...vals);
      if (key === 'mag') lo = Math.max(lo, hi - 120);
      if (!(hi > lo)) {
        lo -= 1;
        hi += 1;
      }
      axes(g, { left: 52, top, width: W - 64, height: half - 8, lo, hi, x0, x1, unit, log: true });
      const x = (f) => 52 + ((lx(f) - x0) / (x1 - x0)) * (W - 64);
      const y = (v) => top + (half - 8) - ((Math.max(lo, Math.min(hi, v)) - lo) / (hi - lo)) * (half - 8);
      series.forEach((s, i) => polyline(g, COLORS[i % COLORS.length], freqs.map((f, k) => [x(f), y(s[key][k])])));
    };
    panel(6, 'mag', 'dB');
    panel(half + 10, 'phase', 'deg');
    g.fillStyle = '#444';
    g.textAlign = 'center';
    g.fillText('Hz', W / 2, H - 8);
  });
  return node;
}

/** The Nyquist curve K_BF·G(e^{jωT}) (solid, and its mirror dashed), −1 marked. */
function nyquistFigure(c) {
  const n = c.nyquist;
  const { node, canvas } = figure(`${c.name}: ${verdict(n)}, ${n.encirclements} encirclement(s) of −1, P = ${n.open_loop_unstable}`, 'wb-nyquist');
  node.dataset.verdict = n.stable ? 'stable' : 'unstable';
  afterLayout(canvas, (cv) => {
    const { g, W, H } = fitCanvas(cv);
    g.fillStyle = '#fff';
    g.fillRect(0, 0, W, H);
    // Fit the curve, but keep −1 in view and cut far excursions (the verdict is computed, not read).
    let m = 1.5;
    for (let i = 0; i < n.re.length; i++) m = Math.max(m, Math.min(6, Math.hypot(n.re[i], n.im[i])));
    m *= 1.1;
    const size = Math.min(W - 60, H - 30);
    const box = { left: 52, top: 6, width: size, height: size, lo: -m, hi: m, x0: -m, x1: m, unit: 'Im' };
    axes(g, box);
    const x = (v) => box.left + ((v + m) / (2 * m)) * size;
    const y = (v) => box.top + size - ((v + m) / (2 * m)) * size;
    g.save();
    g.beginPath();
    g.rect(box.left, box.top, size, size);
    g.clip();
    g.strokeStyle = '#bbb';
    g.beginPath();
    g.moveTo(x(-m), y(0));
    g.lineTo(x(m), y(0));
    g.moveTo(x(0), y(-m));
    g.lineTo(x(0), y(m));
    g.stroke();
    polyline(g, COLORS[0], n.re.map((r, i) => [x(r), y(n.im[i])]));
    polyline(g, COLORS[0], n.re.map((r, i) => [x(r), y(-n.im[i])]), [4, 3]);
    g.restore();
    g.strokeStyle = '#c0392b';
    g.lineWidth = 2;
    const [cx, cy] = [x(-1), y(0)];
    g.beginPath();
    g.moveTo(cx - 6, cy - 6);
    g.lineTo(cx + 6, cy + 6);
    g.moveTo(cx + 6, cy - 6);
    g.lineTo(cx - 6, cy + 6);
    g.stroke();
    g.fillStyle = '#c0392b';
    g.textAlign = 'left';
    g.fillText('−1', cx + 8, cy - 8);
    g.fillStyle = '#444';
    g.textAlign = 'center';
    g.fillText('Re', box.left + size / 2, box.top + size + 18);
  });
  return node;
}

function axes(g, { left, top, width, height, lo, hi, x0, x1, unit, log }) {
  g.strokeStyle = '#e3e6ea';
  g.fillStyle = '#444';
  g.lineWidth = 1;
  g.textAlign = 'right';
  g.textBaseline = 'middle';
  yGrid(g, { left, width, lo, hi, y: (v) => top + height - ((v - lo) / (hi - lo)) * height, n: 4 });
  g.textAlign = 'center';
  g.textBaseline = 'top';
  const xs = log ? 1 : niceStep(x1 - x0, 4);
  for (let v = Math.ceil(x0 / xs) * xs; v <= x1 + 1e-9; v += xs) {
    const xx = Math.round(left + ((v - x0) / (x1 - x0)) * width) + 0.5;
    g.beginPath();
    g.moveTo(xx, top);
    g.lineTo(xx, top + height);
    g.stroke();
    g.fillText(log ? tickLabel(10 ** v, 10 ** v) : tickLabel(v, xs), xx, top + height + 2);
  }
  frame(g, { left, top, width, height, unit });
}

function polyline(g, color, pts, dash = []) {
  g.strokeStyle = color;
  g.lineWidth = 1.5;
  g.setLineDash(dash);
  g.beginPath();
  let first = true;
  for (const [px, py] of pts) {
    if (!Number.isFinite(px) || !Number.isFinite(py)) {
      first = true;
      continue;
    }
    if (first) g.moveTo(px, py);
    else g.lineTo(px, py);
    first = false;
  }
  g.stroke();
  g.setLineDash([]);
}

// ---- poles ----------------------------------------------------------------------------------

function pole(p) {
  if (!p) return '—';
  const [re, im] = p;
  return im === 0 ? num(re) : `${num(re)} ${im < 0 ? '−' : '+'} ${num(Math.abs(im))}j`;
}

/** Both views side by side; each difference with the element that causes it. */
function poleTable(cmp) {
  const d = cmp.design.poles;
  const i = cmp.implemented.poles;
  const rows = [];
  for (let k = 0; k < Math.max(d.length, i.length); k++) {
    rows.push(el('tr', {}, el('td', {}, pole(d[k])), el('td', {}, pole(i[k]))));
  }
  const both = el('table', { class: 'grid numeric' },
    el('thead', {}, el('tr', {}, el('th', {}, 'design view (rad/s)'), el('th', {}, 'implemented view (rad/s)'))),
    el('tbody', {}, ...rows));
  const diffs = cmp.differences.length
    ? el('table', { class: 'grid' },
      el('thead', {}, el('tr', {}, ...['design', 'implemented', 'moved (rad/s)', 'cause'].map((h) => el('th', {}, h)))),
      el('tbody', {}, ...cmp.differences.map((x) => el('tr', {},
        el('td', {}, pole(x.design)), el('td', {}, pole(x.implemented)), el('td', {}, num(x.moved)), el('td', {}, x.cause)))))
    : el('p', { class: 'muted small' }, 'no differences');
  const empty = !d.length && !i.length ? el('p', { class: 'muted small' }, 'the shaper’s delays are not poles of a rational system: see its Nyquist verdict') : '';
  return el('details', { class: 'wb-poles', 'data-design': cmp.name },
    el('summary', {}, `${compensatorName(cmp.name)} — ${cmp.differences.length} difference(s)`),
    el('p', { class: 'muted small' }, cmp.note), empty, both, diffs);
}

// ---- robustness -----------------------------------------------------------------------------

async function loadRobustness() {
  const status = $('wb-robust-status');
  if (!S.studyId) return setStatus(status, 'err', 'select a study first');
  const params = new URLSearchParams({ design: $('wb-robust-design').value });
  for (const k of ['kh_lo', 'kh_hi', 'freq_lo', 'freq_hi', 'grid', 'draws']) {
    const v = $(`wb-${k.replace('_', '-')}`).value.trim();
    if (v !== '') params.set(k, v);
  }
  setStatus(status, 'busy', 'computing…');
  const r = await get(`/api/studies/${S.studyId}/workbench/robustness?${params}`);
  if (!r.ok) return setStatus(status, 'err', errText(r));
  setStatus(status, 'ok', `${r.data.design}: done`);
  renderRobustness(r.data);
}

function renderRobustness(rep) {
  const kbf = rep.spec.kbf;
  const rate = rep.pass_rate === null ? 'no draws' : `${(100 * rep.pass_rate).toFixed(1)} % of ${rep.spec.draws} draws stable at K_BF ${kbf}`;
  const { node, canvas } = figure(`${rep.design}: largest stable K_BF over K_H × structure frequency`, 'wb-map');
  afterLayout(canvas, (c) => heatMap(c, rep));
  $('wb-robust-result').replaceChildren(
    el('p', { id: 'wb-pass-rate' }, `Monte-Carlo pass rate: ${rate}`),
    node,
    el('p', { class: 'muted small' }, `Red: unstable at the study's K_BF ${kbf}; green, darker with more margin (white: stable beyond K_BF 20).`),
  );
}

function heatMap(c, rep) {
  const { g, W, H } = fitCanvas(c);
  g.fillStyle = '#fff';
  g.fillRect(0, 0, W, H);
  const rows = rep.kh_scales.length;
  const cols = rep.freq_scales.length;
  const box = { left: 52, top: 6, width: W - 64, height: H - 30 };
  const kbf = rep.spec.kbf;
  for (let i = 0; i < rows; i++) {
    for (let j = 0; j < cols; j++) {
      const v = rep.max_stable_kbf[i][j];
      let color = '#ffffff';
      if (v !== null && v < kbf) color = '#d9534f';
      else if (v !== null) {
        const t = Math.min(1, Math.log(v / Math.max(kbf, 1e-3)) / Math.log(20 / Math.max(kbf, 1e-3)));
        color = `rgb(${Math.round(200 - 160 * t)}, ${Math.round(235 - 90 * t)}, ${Math.round(200 - 150 * t)})`;
      }
      g.fillStyle = color;
      const x = box.left + (j / cols) * box.width;
      const y = box.top + box.height - ((i + 1) / rows) * box.height;
      g.fillRect(x, y, box.width / cols + 0.5, box.height / rows + 0.5);
    }
  }
  const pct = (s) => (s - 1) * 100;
  axes(g, {
    ...box,
    lo: pct(rep.kh_scales[0]),
    hi: pct(rep.kh_scales[rows - 1]) || pct(rep.kh_scales[0]) + 1,
    x0: pct(rep.freq_scales[0]),
    x1: pct(rep.freq_scales[cols - 1]) || pct(rep.freq_scales[0]) + 1,
    unit: 'K_H %',
  });
  g.fillStyle = '#444';
  g.textAlign = 'center';
  g.fillText('structure frequencies %', box.left + box.width / 2, H - 8);
}
