// A subject's identification tests on their schedule: the Bode plot of the measured
// feedthrough (device position over cab acceleration) with its 95 % bounds, the seated body
// fitted to it, and the band the study's synthetic population spans; and the fitted
// parameters with their intervals. Apart because it is the one figure of the subject view.

import { svg } from './common.js';
import { el, get, num } from './dashboard-core.js';

const W = 560, H = 230, L = 64, R = 12, T = 10, B = 30;
const COLORS = { band: '#cfe3f7', fit: '#c2410c', point: '#1f2937' };

/** The block for subject `id` (fetched now), or an empty fragment when it has no
 * identification test in its schedule. */
export async function identificationBlock(id, trials) {
  if (!trials.some(({ trial }) => trial.phase === 'identification')) return '';
  const r = await get(`/api/subjects/${id}/identification`);
  if (!r.ok) return el('p', { class: 'status err' }, `Could not load the identification: ${r.data && r.data.error}`);
  const v = r.data;
  const box = el('div', { class: 'identification', 'data-identification': v.tests.length ? 'measured' : 'none' },
    el('h4', {}, 'Feedthrough (identification test)'));
  if (!v.tests.length) {
    box.append(el('p', { class: 'muted' }, 'No completed identification test yet.'));
    return box;
  }
  const latest = v.tests[v.tests.length - 1];
  const fitted = [...v.tests].reverse().find((t) => t.fit);
  box.append(
    bode('Magnitude, mm per m/s² (log)', v, latest, 'magnitude'),
    bode('Phase, degrees', v, latest, 'phase'),
    el('p', { class: 'small bode-legend' },
      el('span', { class: 'bode-point' }, '● measured, 95 % bounds  '),
      el('span', { class: 'bode-fit' }, '— fitted body  '),
      el('span', { class: 'bode-band' }, '▮ population 2.5–97.5 %')),
    fitted ? fitTable(fitted.fit) : el('p', { class: 'status err' }, `No body fitted: ${latest.fit_error}`),
  );
  const tuned = [...v.tests].reverse().find((t) => t.designs);
  if (tuned) box.append(designTable(tuned.designs));
  return box;
}

/** A personalized study's designs tuned to the subject: each LQR design's weight, the
 * study's and the subject's, and the margin it keeps for their body (or why none). */
function designTable(designs) {
  if (!designs.length) {
    return el('p', { class: 'status err', 'data-designs': 'none' },
      'No designs tuned: there is no fitted body; the subject runs the study\'s designs.');
  }
  const symbol = { alpha: 'α (tracking)', beta: 'β (cab feedback)' };
  return el('table', { class: 'grid', 'data-designs': 'personal' },
    el('thead', {}, el('tr', {},
      ...['Design', 'Weight', 'Study', 'This subject', 'Stable up to K_BF', ''].map((h) => el('th', {}, h)))),
    el('tbody', {}, ...designs.map((d) => el('tr', { 'data-controller': d.controller },
      el('td', {}, d.controller), el('td', {}, symbol[d.weight] || d.weight),
      el('td', { class: 'num' }, num(d.generic, 3)),
      el('td', { class: 'num' }, d.value == null ? '—' : num(d.value, 3)),
      el('td', { class: 'num' }, d.max_stable_kbf == null ? '> 20' : num(d.max_stable_kbf, 3)),
      el('td', { class: d.reason ? 'status err' : '' }, d.reason || 'runs this subject\'s tests')))),
    el('caption', {}, 'Designs tuned to this subject (k_h at its 95 % upper bound)'));
}

/** The fitted parameters; one the data did not identify says so and why, never a number
 * (its value and bounds are null: an unbounded interval read as a measurement misleads). */
function fitTable(f) {
  const row = (name, e, unit) => el('tr', {},
    el('td', {}, name),
    ...(e.not_identified
      ? [el('td', { colspan: 3, class: 'not-identified' }, `not identified (${e.not_identified})`)]
      : [el('td', { class: 'num' }, num(e.value, 3)),
        el('td', { class: 'num' }, `[${num(e.lo, 3)}, ${num(e.hi, 3)}]`), el('td', {}, unit)]));
  return el('table', { class: 'grid', 'data-fit': 'body' },
    el('thead', {}, el('tr', {}, ...['Parameter', 'Fitted', '95 % interval', ''].map((h) => el('th', {}, h)))),
    el('tbody', {},
      row('k_h', f.k_h, ''),
      row('torso frequency', f.torso_f_hz, 'Hz'),
      row('torso damping', f.torso_zeta, ''),
      row('arm frequency (as gripped)', f.arm_f_hz, 'Hz'),
      row('arm damping', f.arm_zeta, '')),
    el('caption', {}, `Residual r.m.s. ${num(f.residual_rms, 3)} (ln)`));
}

/** One panel of the Bode plot: `which` is 'magnitude' (log axis) or 'phase'. */
function bode(title, v, test, which) {
  const mag = which === 'magnitude';
  const pts = test.points;
  const fs = v.population.map((b) => b.f_hz).concat(pts.map((p) => p.f_hz));
  const [f0, f1] = [Math.min(...fs), Math.max(...fs)];
  // The axis spans the band and the estimates; a bound beyond it (a magnitude's lower bound
  // of 0 where the coherence is low) is drawn to the frame's edge.
  const ys = mag
    ? v.population.flatMap((b) => [b.magnitude_lo, b.magnitude_hi]).concat(pts.map((p) => p.magnitude))
    : v.population.flatMap((b) => [b.phase_lo_deg, b.phase_hi_deg]).concat(pts.map((p) => p.phase_deg));
  const fy = (y) => (mag ? Math.log10(Math.max(y, 1e-9)) : y);
  let [y0, y1] = [Math.min(...ys.map(fy)), Math.max(...ys.map(fy))];
  const pad = mag ? 0.15 : 15;
  [y0, y1] = [y0 - pad, y1 + pad];
  const x = (f) => L + (Math.log10(f / f0) / Math.log10(f1 / f0 || 10)) * (W - L - R);
  const y = (val) => T + (1 - Math.min(1, Math.max(0, (fy(val) - y0) / (y1 - y0)))) * (H - T - B);
  const g = svg('svg', { viewBox: `0 0 ${W} ${H}`, role: 'img', 'aria-label': title, class: 'bode-plot', 'data-panel': which });
  g.append(svg('rect', { x: L, y: T, width: W - L - R, height: H - T - B, fill: 'none', stroke: '#bbb' }));
  const lo = mag ? 'magnitude_lo' : 'phase_lo_deg';
  const hi = mag ? 'magnitude_hi' : 'phase_hi_deg';
  const band = v.population.map((b) => `${x(b.f_hz).toFixed(1)},${y(b[hi]).toFixed(1)}`)
    .concat([...v.population].reverse().map((b) => `${x(b.f_hz).toFixed(1)},${y(b[lo]).toFixed(1)}`));
  g.append(svg('polygon', { points: band.join(' '), fill: COLORS.band, stroke: 'none' }, svg('title', {}, 'population 2.5–97.5 %')));
  if (v.fitted.length) {
    const key = mag ? 'magnitude' : 'phase_deg';
    g.append(svg('polyline', {
      points: v.fitted.map((c) => `${x(c.f_hz).toFixed(1)},${y(c[key]).toFixed(1)}`).join(' '),
      fill: 'none', stroke: COLORS.fit, 'stroke-width': 1.6,
    }, svg('title', {}, 'fitted body')));
  }
  for (const p of pts) {
    const [v0, v1, vm] = mag ? [p.magnitude_lo, p.magnitude_hi, p.magnitude] : [p.phase_lo_deg, p.phase_hi_deg, p.phase_deg];
    const px = x(p.f_hz);
    g.append(svg('line', { x1: px, x2: px, y1: y(v0), y2: y(v1), stroke: COLORS.point, 'stroke-width': 1 }));
    g.append(svg('circle', { cx: px, cy: y(vm), r: 2.6, fill: COLORS.point, 'data-f-hz': p.f_hz },
      svg('title', {}, `${num(p.f_hz, 3)} Hz: ${num(vm, 3)} [${num(v0, 3)}, ${num(v1, 3)}], coherence ${num(p.coherence, 2)}`)));
  }
  const label = (val) => (mag ? num(10 ** val, 2) : num(val, 3));
  for (const [val, yy] of [[y1, T + 9], [y0, H - B]]) {
    g.append(svg('text', { x: L - 4, y: yy, 'text-anchor': 'end', 'font-size': 11 }, label(val)));
  }
  g.append(svg('text', { x: L, y: H - 10, 'font-size': 11 }, `${num(f0, 2)} Hz`));
  g.append(svg('text', { x: W - R, y: H - 10, 'text-anchor': 'end', 'font-size': 11 }, `${num(f1, 2)} Hz`));
  return el('figure', {}, el('figcaption', {}, title), g);
}
