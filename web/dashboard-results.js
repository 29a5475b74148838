// Results of the selected study: box plots and the learning curve rendered by the server, the
// table of averages per compensator × seat, key comparisons, and the CSV exports.

import { S, COMPENSATOR_NAME, compensatorName, debounce, el, errText, get, num, on, setStatus } from './dashboard-core.js';
import * as downloads from './dashboard-download.js';

const $ = (id) => document.getElementById(id);

export const VARIABLES = [
  ['mse_tracking_mm2', 'Tracking error: mean square (mm²)', 'Tracking MSE (mm²)'],
  ['ms_cab_accel', 'Cab acceleration: mean square ((mm/s²)²)', 'Cab accel MS ((mm/s²)²)'],
  ['rating_accuracy', 'Rating: accuracy', 'Accuracy'],
  ['rating_speed', 'Rating: speed of response', 'Speed'],
  ['rating_smoothness', 'Rating: smoothness', 'Smoothness'],
  ['rating_controllability', 'Rating: overall controllability', 'Controllability'],
];

const SEATS = ['on', 'off'];
const TWINS = [
  ['pid-notch', 'pid'],
  ['pid-shaper', 'pid'],
  ['lqr-cabvel', 'lqr'],
  ['lqr-cabacc', 'lqr'],
  ['pid-notch-adaptive', 'pid'],
  ['pid-shaper-adaptive', 'pid'],
  ['lqr-cabvel-scheduled', 'lqr'],
];

let lastSummary = '';
let statsRows = [];
let stamp = Date.now();

export function init() {
  downloads.init();
  $('results-refresh').addEventListener('click', () => refresh(true));
  const pick = $('stats-metric');
  pick.replaceChildren(...VARIABLES.map(([v, , short]) => el('option', { value: v }, short)));
  pick.addEventListener('change', () => renderStatistics());
  const later = debounce(() => refresh(false), 3000);
  on('trial', later);
  on('subjects', later);
  on('study', () => {
    lastSummary = '';
    stamp = Date.now();
    $('averages').replaceChildren();
    $('comparisons').replaceChildren();
    $('statistics').replaceChildren();
    $('stats-reach').replaceChildren();
    statsRows = [];
    $('plots').replaceChildren();
    $('learning').replaceChildren();
    $('learning-slope').replaceChildren();
    refresh(true);
  });
  on('study-updated', () => refresh(false));
}

/** Reloads the summary; the plots are reloaded when the numbers changed (or `force`). */
export async function refresh(force) {
  const id = S.studyId;
  downloads.setExportLinks(id);
  if (!id) {
    $('averages').replaceChildren(el('tbody', {}, el('tr', {}, el('td', { class: 'muted' }, 'Select or create a study first.'))));
    return;
  }
  const r = await get(`/api/studies/${id}/summary`);
  if (id !== S.studyId) return;
  if (!r.ok) {
    $('averages').replaceChildren(el('tbody', {}, el('tr', {}, el('td', { class: 'status err' }, `Could not load the summary: ${errText(r)}`))));
    return;
  }
  const json = JSON.stringify(r.data);
  const changed = json !== lastSummary;
  lastSummary = json;
  if (changed || force) {
    renderAverages(r.data);
    renderComparisons(r.data);
    loadStatistics(id);
    stamp = Date.now();
    renderPlots();
  }
}

function compensatorOrder(stats) {
  const fromStudy = S.study && Array.isArray(S.study.params.controllers) ? S.study.params.controllers.map((c) => c.kind) : [];
  const seen = [...new Set(stats.map((s) => s.controller))];
  return [...fromStudy, ...seen.filter((c) => !fromStudy.includes(c))];
}

function renderAverages(stats) {
  const t = $('averages');
  // A study with a condition factor has a row per condition (the summary's groups).
  const conditions = [...new Set(stats.map((x) => x.condition))];
  const find = (c, s, v, k) => stats.find((x) => x.controller === c && x.station === s && x.variable === v && x.condition === k);
  const head = el(
    'thead',
    {},
    el(
      'tr',
      {},
      el('th', { rowspan: 2 }, 'Controller'),
      el('th', { rowspan: 2 }, 'Seat'),
      el('th', { colspan: 2, class: 'group' }, 'Metrics (lower is better)'),
      el('th', { colspan: 4, class: 'group' }, `Ratings 1–${(S.study && S.study.params.survey.scale_points) || '?'} (higher is better)`),
    ),
    el('tr', {}, ...VARIABLES.map(([v, label, short]) => el('th', { title: `${label} — ${v}` }, short))),
  );
  const body = el('tbody');
  if (!stats.length) {
    body.append(el('tr', {}, el('td', { colspan: 2 + VARIABLES.length, class: 'muted' }, 'No completed test yet.')));
  }
  for (const c of stats.length ? compensatorOrder(stats) : []) {
    for (const [k, s] of conditions.flatMap((k) => SEATS.map((s) => [k, s]))) {
      const cells = VARIABLES.map(([v]) => {
        const x = find(c, s, v, k);
        if (!x) return el('td', { class: 'muted' }, '—');
        return el(
          'td',
          {
            'data-variable': v,
            title: `n ${x.n} · mean ${x.mean} · median ${x.median} · q1 ${x.q1} · q3 ${x.q3} · min ${x.min} · max ${x.max}`,
          },
          num(x.mean),
          el('span', { class: 'n' }, ` n=${x.n}`),
        );
      });
      body.append(
        el(
          'tr',
          { 'data-controller': c, 'data-station': s, 'data-condition': k, class: `station-${s}` },
          el('th', { scope: 'row', class: 'nowrap', title: c }, COMPENSATOR_NAME[c] || c),
          el('td', { class: 'nowrap' }, (s === 'on' ? 'on machine' : 'off (desk)') + (conditions.length > 1 ? ` · ${k}` : '')),
          ...cells,
        ),
      );
    }
  }
  t.replaceChildren(el('caption', {}, 'Mean and number of completed tests (hover a cell for median, quartiles, range)'), head, body);
}

function renderComparisons(stats) {
  // Within the first condition a study's summary lists (its only one without the factor).
  const first = stats.length ? stats[0].condition : null;
  const mean = (c, v) => {
    const x = stats.find((s) => s.controller === c && s.station === 'on' && s.variable === v && s.condition === first);
    return x ? x : null;
  };
  const rows = [];
  for (const [comp, twin] of TWINS) {
    for (const v of ['mse_tracking_mm2', 'ms_cab_accel']) {
      const a = mean(comp, v);
      const b = mean(twin, v);
      if (!a || !b) continue;
      const change = b.mean !== 0 ? ((a.mean - b.mean) / b.mean) * 100 : NaN;
      rows.push(
        el(
          'tr',
          {},
          el('td', {}, `${compensatorName(comp)} vs ${compensatorName(twin)}`),
          el('td', {}, v === 'mse_tracking_mm2' ? 'tracking MSE (mm²)' : 'cab accel MS ((mm/s²)²)'),
          el('td', { class: 'num' }, `${num(a.mean)} (n=${a.n})`),
          el('td', { class: 'num' }, `${num(b.mean)} (n=${b.n})`),
          el('td', { class: `num ${change < 0 ? 'better' : change > 0 ? 'worse' : ''}` }, Number.isFinite(change) ? `${change > 0 ? '+' : ''}${change.toFixed(1)} %` : '—'),
        ),
      );
    }
  }
  $('comparisons').replaceChildren(
    rows.length
      ? el(
          'table',
          { class: 'grid numeric' },
          el('thead', {}, el('tr', {}, ...['Comparison (on the machine)', 'Metric', 'Compensated', 'Uncompensated twin', 'Change'].map((h) => el('th', {}, h)))),
          el('tbody', {}, ...rows),
        )
      : el('p', { class: 'muted' }, 'Needs completed tests on the machine of a compensator and its uncompensated twin.'),
  );
}

async function loadStatistics(id) {
  const r = await get(`/api/studies/${id}/stats`);
  if (id !== S.studyId) return;
  if (!r.ok) {
    setStatus($('stats-reach'), 'err', `Could not load the statistics: ${errText(r)}`);
    return;
  }
  statsRows = r.data;
  renderStatistics();
}

const TEST_NAME = {
  friedman: 'Friedman',
  wilcoxon: 'Wilcoxon (exact)',
  wilcoxon_on_off: 'Wilcoxon on vs off',
  rm_anova: 'RM-ANOVA (GG)',
  kruskal_condition: 'Kruskal–Wallis across conditions',
};

const fmtP = (p) => (p === null || p === undefined ? '—' : p < 0.001 ? p.toExponential(2) : p.toFixed(4));

function renderStatistics() {
  const metric = $('stats-metric').value;
  const rows = statsRows.filter((r) => r.metric === metric || r.metric === `log_${metric}`);
  // One plain statement per family that cannot reach significance at this n.
  const unreachable = [...new Set(rows.filter((r) => !r.reachable).map((r) => `${TEST_NAME[r.test]} at ${r.station}: ${r.note}`))];
  $('stats-reach').replaceChildren(
    ...unreachable.map((t) => el('p', { class: 'status warn' }, `No planned comparison can be significant here — ${t}. More subjects are needed (see the power planner).`)),
  );
  if (!rows.length) {
    $('statistics').replaceChildren(el('p', { class: 'muted' }, 'Needs at least two subjects with complete tests.'));
    return;
  }
  const body = rows.map((r) =>
    el(
      'tr',
      { 'data-test': r.test, class: r.reachable ? '' : 'unreachable' },
      el('td', {}, TEST_NAME[r.test] || r.test),
      el('td', {}, r.station),
      el('td', {}, r.test === 'rm_anova' || r.test === 'kruskal_condition' ? r.a : r.b && r.a !== r.b ? `${compensatorName(r.a)} vs ${compensatorName(r.b)}` : compensatorName(r.a) || 'all'),
      el('td', { class: 'num' }, String(r.n)),
      el('td', { class: 'num' }, num(r.statistic)),
      el('td', { class: 'num' }, fmtP(r.p_value)),
      el('td', { class: 'num' }, fmtP(r.p_adjusted)),
      el('td', { class: 'num', title: r.effect }, `${num(r.effect_size)} (${r.effect})`),
      el('td', { class: 'num' }, r.median_diff === null ? '—' : `${num(r.median_diff)} [${num(r.ci_low)}, ${num(r.ci_high)}]`),
      el('td', { class: 'small' }, r.note),
    ),
  );
  $('statistics').replaceChildren(
    el(
      'table',
      { class: 'grid numeric' },
      el('thead', {}, el('tr', {}, ...['Test', 'Seat', 'Comparison', 'n', 'Statistic', 'p', 'p (Holm)', 'Effect size', 'Median a − b [95 % CI]', 'Note'].map((h) => el('th', {}, h)))),
      el('tbody', {}, ...body),
    ),
  );
}

/** A server-drawn figure `name` (.svg shown, .svg and .png to download) with its caption. */
function figure(id, name, label, alt) {
  const base = `/api/studies/${id}/plots/${name}`;
  const status = el('p', { class: 'plot-missing', hidden: true });
  const img = el('img', { src: `${base}.svg?v=${stamp}`, alt, 'data-variable': name });
  img.addEventListener('error', async () => {
    img.hidden = true;
    status.hidden = false;
    setStatus(status, 'info', 'No plot yet…');
    const r = await get(`${base}.svg`);
    setStatus(
      status,
      r.status === 404 ? 'info' : 'err',
      r.status === 404
        ? `No plot (HTTP 404: ${(r.data && r.data.error) || 'not found'}). It appears once tests are complete and the server draws plots.`
        : `The plot could not be loaded: ${errText(r)}`,
    );
  });
  img.addEventListener('load', () => {
    img.hidden = false;
    status.hidden = true;
  });
  return el(
    'figure',
    { class: 'plot', 'data-variable': name },
    el('figcaption', {}, label),
    img,
    status,
    el(
      'div',
      { class: 'plot-links' },
      'Download: ',
      el('a', { href: `${base}.svg`, download: `study${id}-${name}.svg`, 'data-progress-download': '', 'data-label': `${name}.svg` }, 'SVG'),
      ' · ',
      el('a', { href: `${base}.png`, download: `study${id}-${name}.png`, 'data-progress-download': '', 'data-label': `${name}.png` }, 'PNG'),
    ),
  );
}

function renderPlots() {
  const id = S.studyId;
  $('plots').replaceChildren(
    ...VARIABLES.map(([v, label]) => figure(id, v, label, `Box plot: ${label}, per compensator and seat`)),
  );
  $('learning').replaceChildren(
    figure(id, 'learning_curve', 'Tracking error by test position', 'Learning curve: tracking error against test position, a line per subject and the median, by seat'),
  );
  loadLearning(id);
}

/** The learning slope under the curve: the median over subjects of each one's slope. */
async function loadLearning(id) {
  const box = $('learning-slope');
  const r = await get(`/api/studies/${id}/learning`);
  if (id !== S.studyId) return;
  if (!r.ok) {
    setStatus(box, 'err', `Could not load the learning curve: ${errText(r)}`);
    return;
  }
  const c = r.data;
  box.className = 'status info';
  box.hidden = false;
  box.textContent = c.slope == null
    ? 'Learning slope: needs a subject with two completed tests.'
    : `Learning slope: ${num(c.slope, 3)} ${c.slope_unit} (error ${c.slope_percent_per_test >= 0 ? '+' : ''}${num(c.slope_percent_per_test, 1)} % per test), ` +
      `the median over ${c.slope_n} subject${c.slope_n === 1 ? '' : 's'} of each one's least-squares slope of ln MSE on position; negative: error falls with practice.`;
}
