// Studies: the selector in the top bar, and the parameter form (create, edit until locked,
// read-only with its protocol hash once locked).

import { S, act, el, emit, get, send, setStatus, when, compensatorName } from './dashboard-core.js';

const $ = (id) => document.getElementById(id);

/**
 * Form fields and where they live in StudyParams. `int` fields must be whole numbers, `bool`
 * ones are yes/no selects, `list` ones hold a list separated by commas; `fallback` is shown when the parameters leave the key out (the
 * server leaves the design aids out at their defaults, so old studies keep their hash).
 */
const FIELDS = [
  { id: 'p-trial_s', path: ['trial_s'] },
  { id: 'p-practice_s', path: ['practice_s'] },
  { id: 'p-step_interval_s', path: ['step_interval_s'] },
  { id: 'p-target_range_mm', path: ['target_range_mm'] },
  { id: 'p-target_std_mm', path: ['target_std_mm'] },
  { id: 'p-matched_targets', path: ['matched_targets'], bool: true, fallback: false },
  { id: 'p-order_design', path: ['order_design'], text: true, fallback: 'random' },
  { id: 'p-k_bf', path: ['k_bf'] },
  { id: 'p-survey_scale_points', path: ['survey', 'scale_points'], int: true },
  { id: 'p-display_shake_gain', path: ['display_shake_gain'] },
  { id: 'p-rig', path: ['rig'], text: true },
  { id: 'p-condition', path: ['condition'], text: true, fallback: 'stilts' },
  { id: 'p-conditions', path: ['conditions'], list: true, fallback: [] },
];

/**
 * The texts the station shows (consent form and instructions), each a field of its own in
 * "Texts the station shows". `long` ones are text areas.
 */
const TEXT_FIELDS = [
  { key: 'consent.version', label: 'Consent form version' },
  { key: 'consent.text', label: 'Consent form text', long: 8 },
  { key: 'texts.language', label: 'Language of the texts (a tag such as en, de, fr-CH)' },
  { key: 'texts.instructions', label: 'Instructions before every test', long: 4 },
  { key: 'texts.before_practice', label: 'Before the practice', long: 3 },
  { key: 'texts.before_test', label: 'Before a scored test', long: 2 },
  { key: 'texts.ready', label: 'While waiting for the start' },
  { key: 'texts.move_to_on', label: 'Move to the seat on the machine' },
  { key: 'texts.move_to_off', label: 'Move to the seat at the desk' },
  { key: 'texts.move_note', label: 'Under a move' },
  { key: 'texts.finished_title', label: 'The end, every test done: heading' },
  { key: 'texts.finished', label: 'The end, every test done', long: 2 },
  { key: 'texts.declined_title', label: 'Consent declined: heading' },
  { key: 'texts.declined', label: 'Consent declined', long: 2 },
  { key: 'texts.withdrawn_title', label: 'Withdrawn: heading' },
  { key: 'texts.withdrawn', label: 'Withdrawn', long: 2 },
];

/** The placeholders a text may hold (as the server's `PLACEHOLDERS`). */
const PLACEHOLDERS = ['{tests}', '{tests_per_station}', '{trial_s}', '{practice_s}', '{minutes}'];

/** Adds the texts' fields to the form (after the numeric fields) and to FIELDS. */
function addTextFields() {
  const fields = TEXT_FIELDS.map((t) => {
    const id = `p-${t.key.replace('.', '-')}`;
    FIELDS.push({ id, path: t.key.split('.'), text: true, exact: true });
    const control = t.long
      ? el('textarea', { id, rows: t.long, 'data-param': t.key })
      : el('input', { id, 'data-param': t.key, autocomplete: 'off' });
    return el('label', { class: 'text-field' }, t.label, control);
  });
  const box = el('details', { id: 'p-texts' },
    el('summary', {}, 'Texts the station shows (consent form, instructions) and their language'),
    el('p', { class: 'muted small' },
      `Placeholders the server fills in from the parameters: ${PLACEHOLDERS.join(', ')} (tests in all and at each seat, the test's and the practice's seconds, minutes of tracking in all); {{ and }} for a brace. A blank line starts a new paragraph.`),
    el('div', { class: 'text-fields' }, ...fields));
  $('p-controllers').before(box);
}

/** What the form holds: 'draft' (a study not yet created) or 'study' (the selected one). */
let mode = 'draft';
/** The study as the form was filled from it: an edit is based on its `version`. */
let base = null;
let defaults = null;

const STORE_KEY = 'bdft.dashboard.study';

export function init() {
  addTextFields();
  $('study-select').addEventListener('change', () => {
    const id = Number($('study-select').value);
    if (id) select(id);
  });
  $('studies').addEventListener('click', (e) => {
    const b = e.target.closest('button[data-select-study]');
    if (b) select(Number(b.dataset.selectStudy));
  });
  $('study-create').addEventListener('click', create);
  $('study-save').addEventListener('click', save);
  $('study-new').addEventListener('click', newFromDefaults);
  $('study-copy').addEventListener('click', copyToDraft);
  $('study-form').addEventListener('submit', (e) => e.preventDefault());
  $('p-json').addEventListener('input', () => setStatus($('p-json-error'), 'err', ''));
  // Where a refused edit (someone else saved first) is explained, below the save status.
  const conflict = el('div', { id: 'study-conflict', class: 'status err', role: 'alert' });
  conflict.hidden = true;
  $('study-status').after(conflict);
}

async function loadDefaults() {
  if (defaults) return defaults;
  const r = await get('/api/defaults');
  if (!r.ok) {
    setStatus($('study-status'), 'err', `Could not load the default parameters: ${r.data && r.data.error}`);
    return null;
  }
  defaults = r.data;
  return defaults;
}

/** Reloads the list of studies and keeps (or makes) a selection. */
export async function loadStudies(selectId) {
  const r = await get('/api/studies');
  if (!r.ok) {
    setStatus($('study-status'), 'err', `Could not list the studies: ${r.data && r.data.error}`);
    return;
  }
  S.studies = r.data;
  fillSelect();
  let id = selectId ?? S.studyId ?? Number(localStorage.getItem(STORE_KEY));
  if (!S.studies.some((s) => s.id === id)) id = S.studies.length ? S.studies[S.studies.length - 1].id : null;
  $('no-study').hidden = S.studies.length > 0;
  if (id) await select(id);
  else {
    S.studyId = null;
    S.study = null;
    await newFromDefaults();
    emit('study', null);
  }
}

/** A study's name in lists: a dry run says whose pilot it holds, so its synthetic
 * subjects' results are never taken for a study's people. */
function studyLabel(st) {
  if (!st.dry_run) return st.name;
  const of = st.dry_run.of_study === null ? null : S.studies.find((x) => x.id === st.dry_run.of_study);
  const whose = of ? `Pilot of ${of.name}` : st.name;
  return `${whose} — dry run #${st.id}`;
}

function fillSelect() {
  fillTable();
  const sel = $('study-select');
  if (!S.studies.length) {
    sel.replaceChildren(el('option', { value: '' }, 'no study yet'));
    sel.disabled = true;
    return;
  }
  sel.disabled = false;
  sel.replaceChildren(
    ...S.studies.map((s) =>
      el('option', { value: s.id, 'data-dry-run': s.dry_run ? 'yes' : null }, s.dry_run
        ? studyLabel(s)
        : `#${s.id} ${s.name}${s.locked_at ? ' — locked' : ' — not locked'}`),
    ),
  );
  if (S.studyId) sel.value = String(S.studyId);
}

/** Every study, the selected one marked; a row's button selects it. */
function fillTable() {
  const tbody = $('studies').tBodies[0];
  if (!S.studies.length) {
    tbody.replaceChildren(el('tr', {}, el('td', { colspan: 6, class: 'muted' }, 'No study yet: fill in the form below and press “Create new study”.')));
    return;
  }
  tbody.replaceChildren(
    ...S.studies.map((st) =>
      el(
        'tr',
        { 'data-study-id': st.id, class: [st.id === S.studyId ? 'selected' : '', st.dry_run ? 'dry-run' : ''].join(' ') },
        el('td', { class: 'num' }, st.id),
        el('td', {}, studyLabel(st), st.dry_run ? [' ', el('span', { class: 'tag synthetic', 'data-dry-run-badge': st.id }, 'dry run')] : ''),
        el('td', { class: 'nowrap' }, when(st.created_at)),
        el(
          'td',
          {},
          st.locked_at
            ? [`locked ${when(st.locked_at)} · `, el('code', { title: st.protocol_hash }, `${(st.protocol_hash || '').slice(0, 12)}…`)]
            : el('span', { class: 'muted' }, 'not locked (editable)'),
        ),
        el('td', { class: 'num' }, String(st.seed)),
        el(
          'td',
          {},
          st.id === S.studyId
            ? el('span', { class: 'tag next' }, 'selected')
            : el('button', { type: 'button', class: 'small', 'data-select-study': st.id }, 'Select'),
        ),
      ),
    ),
  );
}

/** Selects a study for every view. */
export async function select(id) {
  const r = await get(`/api/studies/${id}`);
  if (!r.ok) {
    setStatus($('study-status'), 'err', `Could not load study #${id}: ${r.data && r.data.error}`);
    return;
  }
  adopt(r.data);
}

/** Makes `st` (a study as the API returns it) the selected study. */
function adopt(st) {
  const changed = S.studyId !== st.id;
  S.studyId = st.id;
  S.study = st;
  const i = S.studies.findIndex((s) => s.id === st.id);
  if (i >= 0) S.studies[i] = st;
  else S.studies.push(st);
  fillSelect();
  $('study-select').value = String(st.id);
  $('no-study').hidden = true;
  localStorage.setItem(STORE_KEY, String(st.id));
  showStudy(st);
  if (changed) emit('study', st);
}

/** Re-reads the selected study (after enrolment locked it, for one). */
export async function reloadSelected() {
  if (!S.studyId) return;
  const r = await get(`/api/studies/${S.studyId}`);
  if (!r.ok) return;
  const wasLocked = !!(S.study && S.study.locked_at);
  S.study = r.data;
  const i = S.studies.findIndex((s) => s.id === r.data.id);
  if (i >= 0) S.studies[i] = r.data;
  fillSelect();
  if (mode === 'study' && wasLocked !== !!r.data.locked_at) showStudy(r.data);
}

// ---- the form -----------------------------------------------------------------------------

function getPath(obj, path) {
  return path.reduce((o, k) => (o == null ? undefined : o[k]), obj);
}

function setPath(obj, path, v) {
  let o = obj;
  for (const k of path.slice(0, -1)) {
    if (typeof o[k] !== 'object' || o[k] === null) o[k] = {};
    o = o[k];
  }
  o[path[path.length - 1]] = v;
}

function deletePath(obj, path) {
  let o = obj;
  for (const k of path.slice(0, -1)) {
    if (typeof o[k] !== 'object' || o[k] === null) return;
    o = o[k];
  }
  delete o[path[path.length - 1]];
}

/** Fills the form: the named fields, and the rest of the parameters as JSON. */
function fillForm(params) {
  for (const f of FIELDS) {
    const v = getPath(params, f.path) ?? f.fallback;
    $(f.id).value = v === undefined || v === null ? '' : f.list ? v.join(', ') : String(v);
    $(f.id).classList.remove('invalid');
  }
  const rest = structuredClone(params);
  for (const f of FIELDS) deletePath(rest, f.path);
  fillCancellation(params, rest);
  $('p-json').value = JSON.stringify(rest, null, 2);
  setStatus($('p-json-error'), 'err', '');
  const ctl = Array.isArray(params.controllers) ? params.controllers.map((c) => compensatorName(c.kind)) : [];
  $('p-controllers').textContent =
    `Compensators compared (${ctl.length}): ${ctl.join(', ')} · practice: ${compensatorName(params.practice_controller)} ` +
    `· stations: ${(params.stations || []).join(', ')} — edit these in Advanced.`;
}

function setReadOnly(ro) {
  for (const f of FIELDS) {
    const n = $(f.id);
    if (n.tagName === 'SELECT') n.disabled = ro;
    else n.readOnly = ro;
  }
  $('p-json').readOnly = ro;
  $('p-seed').readOnly = ro;
  $('p-cancellation').disabled = ro;
  $('p-wrong-gain').readOnly = ro;
  $('p-wrong-lag').readOnly = ro;
  $('study-form').classList.toggle('locked', ro);
}

function showHash(hash) {
  $('protocol-hash').textContent = hash || '';
  $('protocol-hash').hidden = !hash;
  $('protocol-hash-none').hidden = !!hash;
}

function showStudy(st) {
  mode = 'study';
  base = st;
  $('study-conflict').hidden = true;
  fillForm(st.params);
  const locked = !!st.locked_at;
  setReadOnly(locked);
  $('p-seed').value = String(st.seed);
  $('p-seed').readOnly = true;
  showHash(st.protocol_hash);
  const m = $('study-mode');
  m.className = `mode ${locked ? 'locked' : 'editing'}`;
  if (locked) {
    m.textContent =
      `Study #${st.id} “${st.name}” is LOCKED since ${when(st.locked_at)} (a subject was enrolled): its parameters are read-only. ` +
      'To vary them, type a name and create a new study from these parameters, or copy them into a new draft.';
    $('study-name').value = '';
    $('study-name').placeholder = 'name of a new study with these parameters';
  } else {
    m.textContent =
      `Editing study #${st.id} “${st.name}” (seed ${st.seed}), created ${when(st.created_at)}. ` +
      'Editable until the first subject is enrolled. “Create new study” makes a new study from the form instead.';
    $('study-name').value = st.name;
    $('study-name').placeholder = '';
  }
  $('study-save').disabled = locked;
  $('study-save').textContent = `Save changes to study #${st.id}`;
  $('study-copy').disabled = false;
  showStability(st);
}

/** The stability gate: each compensator analysed at the study's K_BF, on and off the machine. */
async function showStability(st) {
  const box = $('stability');
  box.replaceChildren(el('p', { class: 'muted' }, 'Analysing every compensator at the study’s K_BF, on and off the machine…'));
  const r = await get(`/api/studies/${st.id}/stability`);
  if (!S.study || S.study.id !== st.id) return;
  if (!r.ok) {
    box.replaceChildren(el('p', { class: 'status err' }, `Stability analysis failed: ${r.data && r.data.error}`));
    return;
  }
  const rep = r.data;
  const yes = (ok) => el('td', { class: ok ? 'ok' : 'err' }, ok ? 'stable' : 'UNSTABLE');
  const rows = rep.verdicts.map((v) =>
    el('tr', { class: v.stable_on && v.stable_off ? '' : 'unstable' },
      el('td', {}, compensatorName(v.controller)),
      yes(v.stable_on),
      yes(v.stable_off),
      el('td', {}, v.max_stable_kbf == null ? 'above 20' : v.max_stable_kbf.toFixed(2)),
      el('td', { class: v.has_margin ? 'ok' : 'err' }, v.has_margin ? 'yes' : 'no')));
  const table = el('table', { class: 'grid numeric' },
    el('thead', {}, el('tr', {}, ...[`Compensator`, `On the machine at K_BF ${rep.k_bf}`, 'Off the machine', 'Largest stable K_BF', `Margin ≥ ${rep.margin}× K_BF`].map((h) => el('th', {}, h)))),
    el('tbody', {}, ...rows));
  const parts = [el('h3', {}, 'Stability with the feedthrough loop closed'), table];
  const unstable = rep.verdicts.filter((v) => !v.stable_on || !v.stable_off);
  if (unstable.length && !st.locked_at) {
    if (st.params.rig === 'real') {
      parts.push(el('p', { class: 'status err' }, 'This study runs on the real machine: it cannot be locked (no subject can be enrolled) while a design is unstable. Change the design or K_BF.'));
    } else if (st.instability_ack) {
      parts.push(el('p', { class: 'status info' }, `Acknowledged by ${st.instability_ack.by} ${when(st.instability_ack.at)}: “${st.instability_ack.reason}”. It runs in simulation only.`));
    } else {
      const reason = el('input', { id: 'ack-reason', maxlength: 500, size: 40, placeholder: 'why run it anyway (kept in the audit log)' });
      const out = el('span', { class: 'status', role: 'status' });
      const btn = el('button', { type: 'button', class: 'danger' }, 'Acknowledge and allow in simulation');
      btn.addEventListener('click', async () => {
        const r2 = await act('Acknowledge instability', out, () => send('POST', `/api/studies/${st.id}/acknowledge-instability`, { reason: reason.value }));
        if (r2.ok) reloadSelected().then(() => S.study && showStudy(S.study));
      });
      parts.push(el('p', { class: 'status err' }, 'A design is unstable on the machine: subjects can be enrolled only after you acknowledge it (simulation only).'),
        el('div', { class: 'toolbar' }, reason, btn, out));
    }
  }
  box.replaceChildren(...parts);
}

async function showDraft(params, name, why) {
  mode = 'draft';
  fillForm(params);
  setReadOnly(false);
  $('p-seed').value = '';
  showHash(null);
  $('study-name').value = name;
  $('study-name').placeholder = 'name of the new study';
  const m = $('study-mode');
  m.className = 'mode draft';
  m.textContent = `New study (draft, not created yet): ${why}. Nothing is saved until you press “Create new study”.`;
  $('study-save').disabled = true;
  $('study-save').textContent = 'Save changes';
  $('study-copy').disabled = true;
}

async function newFromDefaults() {
  const d = await loadDefaults();
  if (!d) return;
  await showDraft(d, '', 'parameters of the published protocol');
  setStatus($('study-status'), 'info', 'The form holds the default parameters.');
}

function copyToDraft() {
  if (!S.study) return;
  showDraft(S.study.params, `${S.study.name} (copy)`, `copied from study #${S.study.id}`);
  setStatus($('study-status'), 'info', `The form holds a copy of study #${S.study.id}'s parameters.`);
}

/** The choices of the cancellation select (its arms, comma-separated). */
const CANCELLATION_CHOICES = ['', 'personal', 'personal,generic', 'personal,generic,wrong'];

/**
 * Fills the cancellation fields from `params`, taking what they show out of `rest` (the
 * advanced JSON): the arms and the wrong model's error; a `limit_mm` stays in the JSON. Arms
 * the select does not offer stay in the JSON, the select saying so.
 */
function fillCancellation(params, rest) {
  const c = params.cancellation;
  const arms = c && Array.isArray(c.arms) ? c.arms.join(',') : '';
  const offered = CANCELLATION_CHOICES.includes(arms);
  $('p-cancellation').value = offered ? arms : 'json';
  $('p-wrong-gain').value = c && c.wrong ? String(c.wrong.gain) : '';
  $('p-wrong-lag').value = c && c.wrong ? String(c.wrong.phase_lag_deg ?? 0) : '';
  if (c && offered) {
    delete rest.cancellation.arms;
    delete rest.cancellation.wrong;
    if (Object.keys(rest.cancellation).length === 0) delete rest.cancellation;
  }
}

/**
 * Puts the cancellation fields into `params` (and the identification test the factor needs,
 * when the study has none); a field that is not a number goes into `bad`.
 */
function readCancellation(params, bad) {
  const arms = $('p-cancellation').value;
  if (arms === 'json') return;
  if (!arms) {
    delete params.cancellation;
    return;
  }
  const c = { ...(params.cancellation || {}), arms: arms.split(',') };
  delete c.wrong;
  if (c.arms.includes('wrong')) {
    const gain = Number($('p-wrong-gain').value.trim() || '1.3');
    const lag = Number($('p-wrong-lag').value.trim() || '0');
    if (!Number.isFinite(gain) || !Number.isFinite(lag)) {
      $('p-wrong-gain').classList.add('invalid');
      bad.push('cancellation.wrong: a number is required for the gain and the phase lag');
      return;
    }
    c.wrong = { gain, phase_lag_deg: lag, phase_ref_hz: 2 };
  }
  params.cancellation = c;
  if (!params.identification) params.identification = {};
}

/** The parameters in the form: the JSON, then the fields over it. Null (and errors shown) if invalid. */
function readParams() {
  let params;
  try {
    params = JSON.parse($('p-json').value || '{}');
  } catch (e) {
    $('p-advanced').open = true;
    setStatus($('p-json-error'), 'err', `The advanced JSON is not valid JSON: ${e.message}`);
    return null;
  }
  if (typeof params !== 'object' || params === null || Array.isArray(params)) {
    $('p-advanced').open = true;
    setStatus($('p-json-error'), 'err', 'The advanced JSON must be an object {…}.');
    return null;
  }
  const overridden = [];
  const bad = [];
  for (const f of FIELDS) {
    const n = $(f.id);
    n.classList.remove('invalid');
    if (getPath(params, f.path) !== undefined) overridden.push(f.path.join('.'));
    if (f.text) {
      setPath(params, f.path, n.value);
      continue;
    }
    if (f.bool) {
      setPath(params, f.path, n.value === 'true');
      continue;
    }
    if (f.list) {
      setPath(params, f.path, n.value.split(',').map((x) => x.trim()).filter((x) => x));
      continue;
    }
    const v = Number(n.value);
    if (n.value.trim() === '' || !Number.isFinite(v) || (f.int && !Number.isInteger(v))) {
      n.classList.add('invalid');
      bad.push(`${f.path.join('.')}: ${f.int ? 'a whole number' : 'a number'} is required`);
      continue;
    }
    setPath(params, f.path, v);
  }
  $('p-wrong-gain').classList.remove('invalid');
  $('p-cancellation').classList.remove('invalid');
  readCancellation(params, bad);
  if (bad.length) {
    setStatus($('study-status'), 'err', bad.join('; '));
    return null;
  }
  lastOverridden = overridden;
  setStatus($('p-json-error'), 'info', overridden.length ? ignoredText() : '');
  return params;
}

/** Keys of the advanced JSON that the form's fields replaced in the last read. */
let lastOverridden = [];

function ignoredText() {
  return lastOverridden.length ? `ignored in the JSON, the form's fields win: ${lastOverridden.join(', ')}` : '';
}

/** Marks the field an error message names (e.g. "trial_s: …"). */
function markField(message) {
  if (message.includes('cancellation.wrong')) $('p-wrong-gain').classList.add('invalid');
  else if (message.includes('cancellation')) $('p-cancellation').classList.add('invalid');
  for (const f of FIELDS) {
    const key = f.path.join('.');
    if (message.includes(key) || (!f.exact && message.includes(f.path[f.path.length - 1]))) {
      $(f.id).classList.add('invalid');
      if (f.exact) $('p-texts').open = true;
    }
  }
}

async function create() {
  const name = $('study-name').value.trim();
  if (!name) {
    $('study-name').classList.add('invalid');
    setStatus($('study-status'), 'err', 'Type a name for the new study.');
    $('study-name').focus();
    return;
  }
  $('study-name').classList.remove('invalid');
  const params = readParams();
  if (!params) return;
  const body = { name, params };
  const seedText = mode === 'draft' ? $('p-seed').value.trim() : '';
  if (seedText) {
    const seed = Number(seedText);
    if (!Number.isSafeInteger(seed) || seed < 0) {
      setStatus($('study-status'), 'err', 'seed: a whole number from 0 to 2^53 − 1, or empty for a random seed');
      return;
    }
    body.seed = seed;
  }
  const btn = $('study-create');
  btn.disabled = true;
  const r = await act('Create study', $('study-status'), () => send('POST', '/api/studies', body), (d) =>
    `study #${d.id} “${d.name}” created (seed ${d.seed}) and selected${lastOverridden.length ? ` (${ignoredText()})` : ''}`,
  );
  btn.disabled = false;
  // The answer is the new study: select it at once (every view follows).
  if (r.ok) adopt(r.data);
  else markField(r.data && r.data.error ? r.data.error : '');
}

async function save() {
  if (mode !== 'study' || !S.study) return;
  const name = $('study-name').value.trim();
  if (!name) {
    $('study-name').classList.add('invalid');
    setStatus($('study-status'), 'err', 'The study needs a name.');
    return;
  }
  const params = readParams();
  if (!params) return;
  const id = S.study.id;
  const btn = $('study-save');
  btn.disabled = true;
  const version = base && base.id === id ? base.version : S.study.version;
  const r = await act(`Save study #${id}`, $('study-status'), () => send('PUT', `/api/studies/${id}`, { name, params, version }), (d) =>
    `saved as version ${d.version}${lastOverridden.length ? ` (${ignoredText()})` : ''}`,
  );
  btn.disabled = false;
  if (r.ok) {
    S.study = r.data;
    const i = S.studies.findIndex((s) => s.id === id);
    if (i >= 0) S.studies[i] = r.data;
    fillSelect();
    showStudy(r.data);
    emit('study-updated', r.data);
  } else {
    markField(r.data && r.data.error ? r.data.error : '');
    if (r.status === 409 && r.data && r.data.current) showConflict(r.data.current);
    else if (r.status === 409) reloadSelected().then(() => S.study && showStudy(S.study));
  }
}

/** What differs between two versions of a study: its name and the top-level parameters. */
function differences(a, b) {
  const out = a.name === b.name ? [] : [`name (“${a.name}” → “${b.name}”)`];
  const keys = new Set([...Object.keys(a.params), ...Object.keys(b.params)]);
  for (const k of keys) {
    if (JSON.stringify(a.params[k]) !== JSON.stringify(b.params[k])) out.push(k);
  }
  return out;
}

/**
 * Someone else saved the study after the version this form was based on: nothing of ours
 * was saved. The edits stay in the form; the experimenter sees what the other change was
 * and chooses to take the current version or to save the form over it.
 */
function showConflict(current) {
  const i = S.studies.findIndex((s) => s.id === current.id);
  if (i >= 0) S.studies[i] = current;
  S.study = current;
  const changed = base ? differences(base, current) : [];
  const box = $('study-conflict');
  const take = el('button', { type: 'button' }, `Show version ${current.version} (drop my edits)`);
  take.addEventListener('click', () => showStudy(current));
  const over = el('button', { type: 'button', class: 'danger' }, `Save my form over version ${current.version}`);
  over.addEventListener('click', () => {
    base = current;
    box.hidden = true;
    save();
  });
  box.replaceChildren(
    el('strong', {}, `Not saved: study #${current.id} was changed by someone else`),
    ` (now version ${current.version}, your form was based on version ${base ? base.version : '?'}). `,
    changed.length ? `Their change: ${changed.join(', ')}. ` : '',
    'Your edits are still in the form.',
    el('div', { class: 'toolbar' }, take, over),
  );
  box.hidden = false;
}

