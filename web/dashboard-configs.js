// Versioned compensator configurations: the list of versions, a new version from a design
// (each save is a new version; a version never changes), and the selected study's pick of
// versions (PUT /api/studies/{id}/configs, refused once the study is locked).

import { S, act, el, emit, get, on, post, send, setStatus, when } from './dashboard-core.js';
import { reloadSelected } from './dashboard-study.js';

const $ = (id) => document.getElementById(id);

/** Every version, as GET /api/configs lists it (the bench offers them too). */
export let versions = [];

export function init() {
  $('config-load').addEventListener('click', loadBase);
  $('config-save').addEventListener('click', save);
  $('config-pick').addEventListener('click', pick);
  on('study', showPicked);
  load();
}

/** The designs to start from: the selected study's (or the published defaults), then versions. */
async function bases() {
  const study = S.study ? S.study.params : (await get('/api/defaults')).data;
  const out = (study?.controllers || []).map((spec) => ({ label: `${spec.kind} (study design)`, spec }));
  for (const v of versions) out.push({ label: `${v.name} v${v.version}`, spec: v.spec });
  return out;
}

let baseList = [];

export async function load() {
  const r = await get('/api/configs');
  if (!r.ok) return;
  versions = r.data;
  const tbody = $('config-table').tBodies[0];
  tbody.replaceChildren(
    ...versions.map((v) =>
      el(
        'tr',
        { dataset: { configId: v.id } },
        el('td', {}, el('label', {}, el('input', { type: 'checkbox', class: 'config-check', value: v.id }), ' ', v.name)),
        el('td', {}, `v${v.version}`),
        el('td', {}, v.kind),
        el('td', {}, when(v.created_at)),
        el('td', {}, el('code', { class: 'small' }, JSON.stringify(v.spec))),
      ),
    ),
  );
  if (!versions.length) tbody.append(el('tr', {}, el('td', { colspan: 5, class: 'muted' }, 'No configuration versions yet.')));
  baseList = await bases();
  $('config-base').replaceChildren(...baseList.map((b, i) => el('option', { value: i }, b.label)));
  showPicked();
  emit('configs', versions);
}

function loadBase() {
  const b = baseList[Number($('config-base').value)];
  if (!b) return;
  $('config-spec').value = JSON.stringify(b.spec, null, 2);
  if (!$('config-name').value) $('config-name').value = b.label.replace(/ \(study design\)$/, '').replace(/ v\d+$/, '');
}

async function save() {
  let spec;
  try {
    spec = JSON.parse($('config-spec').value);
  } catch (e) {
    setStatus($('config-status'), 'err', `Design: not valid JSON (${e.message}).`);
    return;
  }
  const name = $('config-name').value.trim();
  const r = await act(`Save configuration ${name}`, $('config-status'), () => post('/api/configs', { name, spec }), (v) => `version ${v.version}`);
  if (r.ok) load();
}

async function pick() {
  if (!S.studyId) {
    setStatus($('config-status'), 'err', 'Create or select a study first.');
    return;
  }
  const ids = [...document.querySelectorAll('.config-check:checked')].map((c) => Number(c.value));
  if (!ids.length) {
    setStatus($('config-status'), 'err', 'Check the versions the study should use.');
    return;
  }
  const r = await act(`Use ${ids.length} version(s) in study #${S.studyId}`, $('config-status'), () =>
    send('PUT', `/api/studies/${S.studyId}/configs`, { config_ids: ids }));
  // The study's parameters (and version) changed: the form shows them anew.
  if (r.ok) await reloadSelected();
  showPicked();
}

async function showPicked() {
  if (!S.studyId) {
    $('config-picked').textContent = '';
    return;
  }
  const r = await get(`/api/studies/${S.studyId}/configs`);
  if (!r.ok) return;
  $('config-picked').textContent = r.data.length
    ? `Study #${S.studyId} uses: ${r.data.map((v) => `${v.name} v${v.version} (${v.kind})`).join(', ')}.`
    : `Study #${S.studyId} uses no configuration versions (its own designs).`;
}
