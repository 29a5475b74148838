// The station's error banner: one banner, several sources (registration, pairing, the state
// poll, the socket, the subject's actions). Apart because every other part of the page
// reports through it, and it needs none of them.
//
// Poll and socket problems clear themselves when the connection recovers; errors of an
// action stay until dismissed or the next action works.

const $ = (id) => document.getElementById(id);

const errors = new Map();

export function setError(source, message) {
  if (message) errors.set(source, message);
  else errors.delete(source);
  const banner = $('error');
  if (errors.size === 0) {
    banner.hidden = true;
    $('error-text').textContent = '';
  } else {
    $('error-text').textContent = [...errors.values()].join('\n');
    banner.hidden = false;
  }
}

export function describe(res) {
  const msg = res.data && typeof res.data.error === 'string' ? res.data.error : '';
  if (res.status === 0) return `Cannot reach the server (${msg || 'network error'}). Please tell the experimenter.`;
  return `${msg || 'The server answered with an error'} (HTTP ${res.status}). Please tell the experimenter.`;
}
