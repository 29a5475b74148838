// A strip chart on a canvas: the last `window_s` seconds of one or more series, time on x,
// newest at the right edge.

const FONT = '12px system-ui, -apple-system, "Segoe UI", Roboto, sans-serif';

/** A step of 1, 2 or 5 × 10^k giving about `n` ticks over `span`. */
export function niceStep(span, n) {
  const raw = Math.max(span / n, Number.MIN_VALUE);
  const mag = 10 ** Math.floor(Math.log10(raw));
  const f = raw / mag;
  return mag * (f < 1.5 ? 1 : f < 3.5 ? 2 : f < 7.5 ? 5 : 10);
}

export function tickLabel(v, step) {
  if (Math.abs(v) >= 1e5) return v.toExponential(1).replace('e+', 'e');
  const digits = step >= 1 ? 0 : Math.min(3, Math.ceil(-Math.log10(step)));
  return v.toFixed(digits);
}

/** Sizes a canvas to its laid-out box at the device's pixel ratio; returns its context, with
 *  the font set, and its size in CSS pixels. */
export function fitCanvas(c) {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.max(50, Math.round(c.clientWidth * dpr));
  const h = Math.max(40, Math.round(c.clientHeight * dpr));
  if (c.width !== w || c.height !== h) {
    c.width = w;
    c.height = h;
  }
  const g = c.getContext('2d');
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.font = FONT;
  return { g, W: w / dpr, H: h / dpr };
}

/** Horizontal grid lines at nice steps over [lo, hi], labelled left of `left`; y maps a value
 *  to its pixel row. Expects the stroke and fill colours set. */
export function yGrid(g, { left, width, lo, hi, y, n }) {
  const step = niceStep(hi - lo, n);
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9; v += step) {
    const yy = Math.round(y(v)) + 0.5;
    g.beginPath();
    g.moveTo(left, yy);
    g.lineTo(left + width, yy);
    g.stroke();
    g.fillText(tickLabel(v, step), left - 5, yy);
  }
}

/** The plot's border and its unit written up the left edge. */
export function frame(g, { left, top, width, height, unit }) {
  g.strokeStyle = '#888';
  g.strokeRect(left + 0.5, top + 0.5, width, height);
  g.save();
  g.translate(12, top + height / 2);
  g.rotate(-Math.PI / 2);
  g.textAlign = 'center';
  g.textBaseline = 'middle';
  g.fillStyle = '#444';
  g.fillText(unit, 0, 0);
  g.restore();
}

export class StripChart {
  /**
   * series: [{key, color, label, dash?}]; opts: {window_s, unit, minSpan}.
   */
  constructor(canvas, series, opts = {}) {
    this.canvas = canvas;
    this.series = series;
    this.window = opts.window_s || 10;
    this.unit = opts.unit || '';
    this.minSpan = opts.minSpan || 1;
  }

  /** Draws `samples` (sorted by t) over [tEnd − window, tEnd]; `range` = [lo, hi] or null (auto). */
  draw(samples, tEnd, range, note) {
    const { g, W, H } = fitCanvas(this.canvas);
    const left = 58;
    const right = 16;
    const top = 8;
    const bottom = 20;
    const pw = W - left - right;
    const ph = H - top - bottom;
    g.clearRect(0, 0, W, H);
    g.fillStyle = '#fff';
    g.fillRect(0, 0, W, H);
    g.font = FONT;

    const t0 = tEnd - this.window;
    const visible = samples.filter((s) => s.t >= t0 && s.t <= tEnd);
    let lo;
    let hi;
    if (range) {
      [lo, hi] = range;
    }
    // Widen a fixed range, or fit an automatic one, to the data shown.
    let dlo = Infinity;
    let dhi = -Infinity;
    for (const s of visible) {
      for (const se of this.series) {
        const v = s[se.key];
        if (Number.isFinite(v)) {
          if (v < dlo) dlo = v;
          if (v > dhi) dhi = v;
        }
      }
    }
    if (!range) {
      if (!Number.isFinite(dlo)) {
        dlo = -this.minSpan / 2;
        dhi = this.minSpan / 2;
      }
      const m = Math.max(Math.abs(dlo), Math.abs(dhi), this.minSpan / 2) * 1.1;
      lo = -m;
      hi = m;
    } else if (Number.isFinite(dlo)) {
      lo = Math.min(lo, dlo);
      hi = Math.max(hi, dhi);
    }
    const y = (v) => top + ph - ((v - lo) / (hi - lo)) * ph;
    const x = (t) => left + ((t - t0) / this.window) * pw;

    // Grid and axes.
    g.strokeStyle = '#e3e6ea';
    g.fillStyle = '#444';
    g.lineWidth = 1;
    g.textAlign = 'right';
    g.textBaseline = 'middle';
    yGrid(g, { left, width: pw, lo, hi, y, n: Math.max(2, Math.min(5, Math.floor(ph / 26))) });
    g.textAlign = 'center';
    g.textBaseline = 'top';
    for (let t = Math.ceil(t0); t <= tEnd; t += 1) {
      if (t < 0) continue;
      const xx = Math.round(x(t)) + 0.5;
      g.beginPath();
      g.moveTo(xx, top);
      g.lineTo(xx, top + ph);
      g.stroke();
      if (t % 2 === 0) g.fillText(`${t}s`, xx, top + ph + 4);
    }
    frame(g, { left, top, width: pw, height: ph, unit: this.unit });

    // The series, clipped to the plot.
    g.save();
    g.beginPath();
    g.rect(left, top, pw, ph);
    g.clip();
    for (const se of this.series) {
      g.strokeStyle = se.color;
      g.lineWidth = se.width || 1.6;
      g.setLineDash(se.dash || []);
      g.beginPath();
      let first = true;
      for (const s of visible) {
        const v = s[se.key];
        if (!Number.isFinite(v)) continue;
        if (first) g.moveTo(x(s.t), y(v));
        else g.lineTo(x(s.t), y(v));
        first = false;
      }
      g.stroke();
    }
    g.restore();
    g.setLineDash([]);
    if (note) {
      g.fillStyle = '#666';
      g.textAlign = 'center';
      g.textBaseline = 'middle';
      g.fillText(note, left + pw / 2, top + ph / 2);
    }
  }
}
