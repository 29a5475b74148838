// The workbench's machine-conditions table: each of the selected study's designs, made for
// its rig, on the machine on tires, outriggers down, with a loaded bucket, driving the stick,
// …: its bench cab-acceleration reduction against its twin and its largest stable K_BF with
// the body (GET /api/studies/{id}/workbench/conditions; `bdft-controller conditions`).

import { S, compensatorName, el, errText, get, on, setStatus } from './dashboard-core.js';

const $ = (id) => document.getElementById(id);

export function init() {
  $('wb-conditions-form').addEventListener('submit', (e) => {
    e.preventDefault();
    load();
  });
  on('study', () => $('wb-conditions-result').replaceChildren());
}

async function load() {
  const status = $('wb-conditions-status');
  if (!S.studyId) return setStatus(status, 'err', 'select a study first');
  const list = $('wb-conditions').value.trim();
  const q = list === '' ? '' : `?conditions=${encodeURIComponent(list)}`;
  setStatus(status, 'busy', 'computing (seconds)…');
  const r = await get(`/api/studies/${S.studyId}/workbench/conditions${q}`);
  if (!r.ok) return setStatus(status, 'err', errText(r));
  const t = r.data;
  setStatus(status, 'ok', `${t.rows.length} rows`);
  const fmt = (v, d) => (v === null || v === undefined ? '—' : v.toFixed(d));
  $('wb-conditions-result').replaceChildren(
    el('p', { class: 'muted small' },
      `Bench: ${t.signal}, ${t.duration_s} s, seed ${t.seed}, no operator; margin: the largest stable K_BF with the body, verdict at the study's K_BF ${t.k_bf}.`),
    el('div', { class: 'table-wrap' },
      el('table', { id: 'wb-conditions-table', class: 'grid numeric' },
        el('thead', {}, el('tr', {}, ...['Design', 'Condition', 'f₁ (Hz)', '± rule', 'Cab-acceleration reduction', 'Largest stable K_BF', `Stable at ${t.k_bf}`]
          .map((h) => el('th', {}, h)))),
        el('tbody', {}, ...t.rows.map((row) => el('tr', { class: row.stable ? '' : 'bad' },
          el('td', {}, compensatorName(row.design.split(':')[0]) + (row.design.includes(':') ? ` (${row.design.split(':')[1]})` : '')),
          el('td', {}, row.condition),
          el('td', {}, fmt(row.f1_hz, 2)),
          el('td', {}, `${fmt(100 * row.f1_uncertainty, 0)} %`),
          el('td', {}, row.cab_accel_reduction_pct === null ? '— (no twin)' : `${fmt(row.cab_accel_reduction_pct, 1)} %`),
          el('td', {}, row.max_stable_kbf === null ? '≥ 20' : fmt(row.max_stable_kbf, 3)),
          el('td', {}, row.stable ? 'yes' : 'NO'),
        ))))),
  );
}
