// Downloads with a visible progress: a click on an <a data-progress-download> is fetched with
// the session cookie and read chunk by chunk (a <progress> appears when it takes more than a
// second: bytes received, indeterminate without a length), then saved from a Blob URL under
// the server's file name. The plain href stays on the anchor for use without JavaScript.

import { el, errText, logActivity } from './dashboard-core.js';

const inFlight = new Map();

export function init() {
  document.addEventListener('click', (e) => {
    const a = e.target.closest('a[data-progress-download]');
    if (!a || e.defaultPrevented || e.button !== 0 || e.metaKey || e.ctrlKey || e.shiftKey || e.altKey) return;
    const href = a.getAttribute('href');
    if (!href || href === '#') {
      e.preventDefault();
      return;
    }
    e.preventDefault();
    download(a);
  });
}

/**
 * Points every export link (`a[data-export]`, `data-format` csv — the default — or parquet;
 * `bids` with zip) at study `id`, or disables them without a study.
 */
export function setExportLinks(id) {
  for (const a of document.querySelectorAll('a[data-export]')) {
    const kind = a.dataset.export;
    const format = a.dataset.format || 'csv';
    if (id) {
      // The BIDS dataset is a folder of files, served as one zip.
      a.href =
        kind === 'bids'
          ? `/api/studies/${id}/bids.zip`
          : `/api/studies/${id}/export/${kind}${format === 'csv' ? '' : `?format=${format}`}`;
      a.setAttribute('download', `bdft-study${id}-${kind}.${format}`);
      a.removeAttribute('aria-disabled');
    } else {
      a.href = '#';
      a.setAttribute('aria-disabled', 'true');
    }
    a.dataset.progressDownload = '';
    a.dataset.label = `${kind}.${format}`;
  }
}

function bytes(n) {
  if (n < 1024) return `${n} B`;
  if (n < 1024 * 1024) return `${(n / 1024).toFixed(1)} kB`;
  if (n < 1024 ** 3) return `${(n / 1024 / 1024).toFixed(1)} MB`;
  return `${(n / 1024 ** 3).toFixed(2)} GB`;
}

/** The file name from Content-Disposition (filename*=UTF-8''… or filename="…"). */
export function dispositionName(header) {
  if (!header) return null;
  const star = /filename\*\s*=\s*(?:UTF-8|utf-8)''([^;]+)/.exec(header);
  if (star) {
    try {
      return decodeURIComponent(star[1].trim().replace(/^"|"$/g, ''));
    } catch {
      // Fall through to the plain name.
    }
  }
  const plain = /filename\s*=\s*("((?:[^"\\]|\\.)*)"|[^;]+)/.exec(header);
  if (plain) return (plain[2] !== undefined ? plain[2].replace(/\\(.)/g, '$1') : plain[1]).trim();
  return null;
}

async function download(a) {
  const url = a.href;
  const label = a.dataset.label || a.textContent.trim();
  if (inFlight.has(url)) {
    inFlight.get(url).row.classList.add('flash');
    setTimeout(() => inFlight.get(url) && inFlight.get(url).row.classList.remove('flash'), 600);
    return;
  }
  const box = document.getElementById(a.dataset.progressIn || 'downloads-progress') || document.getElementById('downloads-progress');
  const bar = el('progress', { max: 1, hidden: true });
  const text = el('span', {}, `${label}: starting…`);
  const cancel = el('button', { type: 'button', class: 'small' }, 'Cancel');
  const close = el('button', { type: 'button', class: 'small link', hidden: true, title: 'Remove this line' }, '×');
  const row = el('div', { class: 'download-row' }, text, bar, cancel, close);
  box.prepend(row);
  while (box.children.length > 8) box.lastElementChild.remove();
  close.addEventListener('click', () => row.remove());
  const ctrl = new AbortController();
  cancel.addEventListener('click', () => ctrl.abort());
  const job = { row };
  inFlight.set(url, job);
  a.setAttribute('aria-busy', 'true');
  const t0 = performance.now();
  // Only downloads that take more than a second show the bar.
  const showBar = setTimeout(() => {
    bar.hidden = false;
  }, 1000);
  const finish = (kind, msg) => {
    clearTimeout(showBar);
    inFlight.delete(url);
    a.removeAttribute('aria-busy');
    bar.hidden = true;
    cancel.hidden = true;
    close.hidden = false;
    row.classList.add(kind);
    text.textContent = msg;
    logActivity(kind === 'ok', msg);
  };
  let res;
  try {
    res = await fetch(url, { credentials: 'same-origin', signal: ctrl.signal });
  } catch (e) {
    finish('err', `${label}: ${ctrl.signal.aborted ? 'cancelled' : `network error: ${e.message}`}`);
    return;
  }
  if (!res.ok) {
    let data = null;
    try {
      const t = await res.text();
      try {
        data = JSON.parse(t);
      } catch {
        data = { error: t.slice(0, 200) };
      }
    } catch {
      // No body.
    }
    finish('err', `${label}: download failed: ${errText({ status: res.status, data })}`);
    return;
  }
  const total = Number(res.headers.get('content-length')) || 0;
  if (total) bar.max = total;
  else bar.removeAttribute('value');
  const chunks = [];
  let received = 0;
  try {
    if (res.body && res.body.getReader) {
      const reader = res.body.getReader();
      for (;;) {
        const { done, value } = await reader.read();
        if (done) break;
        chunks.push(value);
        received += value.length;
        if (total) bar.value = received;
        const secs = (performance.now() - t0) / 1000;
        text.textContent = `${label}: ${bytes(received)}${total ? ` of ${bytes(total)}` : ' received'} (${secs.toFixed(1)} s)`;
      }
    } else {
      const b = await res.arrayBuffer();
      chunks.push(new Uint8Array(b));
      received = b.byteLength;
    }
  } catch (e) {
    finish('err', `${label}: ${ctrl.signal.aborted ? 'cancelled' : `interrupted: ${e.message}`} after ${bytes(received)}`);
    return;
  }
  const name =
    dispositionName(res.headers.get('content-disposition')) ||
    a.getAttribute('download') ||
    decodeURIComponent(new URL(url).pathname.split('/').pop() || 'download');
  const blob = new Blob(chunks, { type: res.headers.get('content-type') || 'application/octet-stream' });
  const href = URL.createObjectURL(blob);
  const save = document.createElement('a');
  save.href = href;
  save.download = name;
  document.body.append(save);
  save.click();
  save.remove();
  setTimeout(() => URL.revokeObjectURL(href), 60000);
  const secs = (performance.now() - t0) / 1000;
  finish('ok', `${label}: saved ${name} (${bytes(received)}, ${secs.toFixed(1)} s)`);
}
