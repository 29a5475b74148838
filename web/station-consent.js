// Consent: the form (its version and text as the study approved them), and the subject's
// decision on it. Apart because it is the one choice the subject makes on this page that
// ends a session for good (declining asks once more), and nothing runs before it.

import { api } from './common.js';
import { onUnauthorized, refresh, token } from './station-connection.js';
import { describe, setError } from './station-errors.js';
import { paragraphs } from './station-instructions.js';
import { show } from './station-phases.js';

const $ = (id) => document.getElementById(id);

/** The consent form, with the choice (not the "are you sure?") showing and enabled. */
export function renderConsent(s) {
  const c = s.consent || {};
  $('consent-version').textContent = c.version || '';
  $('consent-text').replaceChildren(...paragraphs(c.text));
  $('consent-text').scrollTop = 0;
  confirmDecline(false, false);
  setConsentBusy(false);
}

function setConsentBusy(busy) {
  for (const id of ['consent-agree', 'consent-decline', 'decline-confirm', 'decline-back']) $(id).disabled = busy;
}

/**
 * Declining ends the session for good, so it asks once more: the first press shows the
 * confirmation (and hides the choice), "Go back" returns to it.
 */
export function confirmDecline(asking, focus = true) {
  $('consent-choice').hidden = asking;
  $('decline-confirmation').hidden = !asking;
  if (focus) $(asking ? 'decline-confirm' : 'consent-agree').focus({ preventScroll: true });
}

export async function decide(decision) {
  setConsentBusy(true);
  const res = await api('POST', '/api/station/consent', { decision }, { bearer: token });
  setConsentBusy(false);
  if (!res.ok) {
    setError('action', describe(res));
    if (res.status === 401) onUnauthorized();
    else refresh();
    return;
  }
  setError('action', null);
  show(res.data);
}
