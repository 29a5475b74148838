// Bench runs: pick designs or configuration versions and a signal, run them on the rig with
// no operator (POST /api/bench; progress at GET /api/bench), then the stored run: the table of
// mean-squared tracking error and cab acceleration with each compensated design's reduction
// against its uncompensated twin, and overlaid plots of cylinder tracking and cab
// acceleration (SVG, drawn here from the stored 100 Hz traces).

import { svg } from './common.js';
import { S, act, el, errText, get, num, on, post, setStatus, when } from './dashboard-core.js';

const $ = (id) => document.getElementById(id);

/** The designs the server knows by name (as `robustness` takes them). */
const DESIGNS = [
  'pid', 'pid-notch', 'pid-shaper', 'lqr', 'lqr-cabvel', 'lqr-cabacc',
  'pid-notch-adaptive', 'pid-shaper-adaptive', 'lqr-cabvel-scheduled',
  'pid-shaper:zvd', 'pid-shaper:ei', 'pid-shaper:two-hump-ei', 'lqr:kalman', 'lqr-cabvel:kalman', 'lqr-cabacc:kalman',
];
const COLORS = ['#1f77b4', '#d62728', '#2ca02c', '#9467bd', '#ff7f0e', '#8c564b', '#e377c2', '#17becf'];

let timer = null;
/** A run started here is being followed: its end shows it. */
let following = false;

export function init() {
  $('bench-designs').append(
    ...DESIGNS.map((d) => el('label', {}, el('input', { type: 'checkbox', value: d }), ' ', d)),
  );
  $('bench-signal').addEventListener('change', () => {
    $('bench-csv-box').hidden = $('bench-signal').value !== 'csv';
  });
  $('bench-run').addEventListener('click', start);
  $('bench-runs').addEventListener('change', () => show(Number($('bench-runs').value)));
  on('configs', showVersions);
  loadRuns();
  check();
}

function showVersions(list) {
  $('bench-configs').replaceChildren(
    el('legend', {}, 'Configuration versions'),
    ...list.map((v) => el('label', {}, el('input', { type: 'checkbox', value: v.id }), ` ${v.name} v${v.version}`)),
  );
}

async function start() {
  const compensators = [
    ...[...$('bench-designs').querySelectorAll('input:checked')].map((c) => ({ design: c.value })),
    ...[...$('bench-configs').querySelectorAll('input:checked')].map((c) => ({ config_id: Number(c.value) })),
  ];
  const kind = $('bench-signal').value;
  const signal = { kind };
  if (kind === 'csv') {
    const file = $('bench-csv').files[0];
    if (!file) {
      setStatus($('bench-status'), 'err', 'Choose a CSV file: one column of mm, one line per sample.');
      return;
    }
    signal.csv = await file.text();
    signal.sample_rate_hz = Number($('bench-rate').value);
  }
  const body = { compensators, signal };
  const d = $('bench-duration').value.trim();
  if (d && kind !== 'csv') body.duration_s = Number(d);
  if ($('bench-on-study').checked && S.studyId) body.study_id = S.studyId;
  const condition = $('bench-condition').value.trim();
  if (condition) body.condition = condition;
  $('bench-run').disabled = true;
  const r = await act(`Bench run of ${compensators.length} compensator(s)`, $('bench-status'), () => post('/api/bench', body),
    (v) => `run #${v.run_id} started`);
  if (!r.ok) {
    $('bench-run').disabled = false;
    return;
  }
  following = true;
  check();
}

/** Follows the running run; shows the newest when it ends. */
async function check() {
  clearTimeout(timer);
  const r = await get('/api/bench');
  if (!r.ok) return;
  const s = r.data;
  const bar = $('bench-progress');
  if (s.running) {
    $('bench-run').disabled = true;
    bar.hidden = false;
    bar.max = s.total || 1;
    bar.value = s.done;
    setStatus($('bench-status'), 'busy', `Bench run #${s.run_id}: ${s.done} of ${s.total} compensators run…`);
    timer = setTimeout(check, 500);
    return;
  }
  bar.hidden = true;
  $('bench-run').disabled = false;
  if (following) {
    following = false;
    setStatus($('bench-status'), 'ok', `Bench run #${s.run_id} finished.`);
    await loadRuns();
  }
}

async function loadRuns() {
  const r = await get('/api/bench/runs');
  if (!r.ok) return;
  $('bench-runs').replaceChildren(
    ...r.data.map((run) => el('option', { value: run.id }, `#${run.id} ${JSON.parse(run.signal_json).kind} ${run.duration_s} s, ${run.rig} (${run.condition}), ${run.status} (${when(run.created_at)})`)),
  );
  if (r.data.length) show(r.data[0].id);
}

const pct = (x) => (x === null || x === undefined ? '' : `${x.toFixed(1)} %`);

async function show(id) {
  $('bench-export').href = `/api/bench/runs/${id}/export`;
  $('bench-export').setAttribute('download', `bdft-bench${id}.csv`);
  const r = await get(`/api/bench/runs/${id}`);
  if (!r.ok) {
    setStatus($('bench-status'), 'err', `Bench run #${id}: ${errText(r)}`);
    return;
  }
  const v = r.data;
  if (v.run.error) setStatus($('bench-status'), 'err', `Bench run #${id} failed: ${v.run.error}`);
  $('bench-table').tBodies[0].replaceChildren(
    ...v.results.map((x) =>
      el('tr', {},
        el('td', {}, x.label),
        el('td', {}, x.outcome),
        el('td', {}, num(x.mse_tracking_mm2)),
        el('td', {}, num(x.ms_cab_accel)),
        el('td', {}, x.twin || '—'),
        el('td', {}, pct(x.tracking_reduction_pct)),
        el('td', {}, pct(x.cab_accel_reduction_pct)),
      )),
  );
  const labels = v.results.map((x) => x.label);
  const track = [{ label: 'reference', color: '#000', dash: true, trace: v.traces[0], key: 'target_mm' }]
    .concat(v.traces.map((t, i) => ({ label: labels[i], color: COLORS[i % COLORS.length], trace: t, key: 'cyl_pos_mm' })));
  const cab = v.traces.map((t, i) => ({ label: labels[i], color: COLORS[i % COLORS.length], trace: t, key: 'cab_accel_mm_s2' }));
  $('bench-plots').replaceChildren(
    plot('Cylinder tracking: reference and position (mm)', v.traces.length ? track : []),
    plot('Cab acceleration (mm/s²)', cab),
  );
}

/** An overlay plot of `lines` [{label, color, dash?, trace, key}] over time. */
function plot(title, lines) {
  const W = 640, H = 260, L = 60, R = 10, T = 10, B = 28;
  let lo = Infinity, hi = -Infinity, tEnd = 0;
  for (const l of lines) {
    const ys = l.trace[l.key];
    for (const y of ys) { lo = Math.min(lo, y); hi = Math.max(hi, y); }
    tEnd = Math.max(tEnd, (ys.length - 1) * l.trace.dt_s);
  }
  if (!(hi > lo)) { lo -= 1; hi += 1; }
  const x = (t) => L + (t / (tEnd || 1)) * (W - L - R);
  const y = (v) => T + (1 - (v - lo) / (hi - lo)) * (H - T - B);
  const g = svg('svg', { viewBox: `0 0 ${W} ${H}`, role: 'img', 'aria-label': title, class: 'bench-plot' });
  g.append(svg('rect', { x: L, y: T, width: W - L - R, height: H - T - B, fill: 'none', stroke: '#bbb' }));
  for (const [v, yy] of [[hi, T + 4], [lo, H - B]]) {
    g.append(svg('text', { x: L - 4, y: yy, 'text-anchor': 'end', 'font-size': 11 }, num(v, 3)));
  }
  g.append(svg('text', { x: W - R, y: H - 8, 'text-anchor': 'end', 'font-size': 11 }, `${num(tEnd, 3)} s`));
  g.append(svg('text', { x: L, y: H - 8, 'font-size': 11 }, '0 s'));
  for (const l of lines) {
    const ys = l.trace[l.key];
    const pts = ys.map((v, k) => `${x(k * l.trace.dt_s).toFixed(1)},${y(v).toFixed(1)}`).join(' ');
    const attrs = { points: pts, fill: 'none', stroke: l.color, 'stroke-width': 1.2 };
    if (l.dash) attrs['stroke-dasharray'] = '4 3';
    g.append(svg('polyline', attrs, svg('title', {}, l.label)));
  }
  const legend = el('p', { class: 'small' }, ...lines.map((l) => el('span', { class: 'legend-item', title: l.label }, `■ ${l.label}  `)));
  lines.forEach((l, i) => { legend.children[i].style.color = l.color; });
  return el('figure', {}, el('figcaption', {}, title), g, legend);
}
