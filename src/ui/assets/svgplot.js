// Vector plots for print (issue 35): the printable report draws its curves
// as SVG, which prints sharp at any resolution, with a legend that names each
// series by its line style. The same spec as plots.js's chart() (linear axes:
// the report's K(x), C(x), F(x) and Keff(Xpeak)); no hover, no resize.
// Written here rather than taken from a library: uPlot draws to a canvas only,
// and the four report plots need a few hundred lines, not a charting package
// (decision in docs/ui.md, "The printable report").

import { num, tickLabel } from './util.js';

const NS = 'http://www.w3.org/2000/svg';

function el(name, attrs = {}, text) {
  const e = document.createElementNS(NS, name);
  for (const [k, v] of Object.entries(attrs)) if (v !== undefined && v !== null) e.setAttribute(k, String(v));
  if (text !== undefined) e.textContent = text;
  return e;
}

/** "Nice" linear ticks (1-2-5 steps) covering [lo, hi], about `n` of them. */
export function niceTicks(lo, hi, n = 5) {
  if (!(hi > lo)) return [lo];
  const raw = (hi - lo) / n;
  const mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw * 0.999);
  const out = [];
  for (let v = Math.ceil(lo / step - 1e-9) * step; v <= hi + step * 1e-9; v += step) out.push(Number(v.toPrecision(12)));
  return out;
}

const finite = (v) => v !== null && v !== undefined && Number.isFinite(v);

/**
 * Draws `spec` (see plots.js chart()) as an SVG into `host`. Series of null
 * values break their line; `points: 'only'` draws markers; `areas` fill
 * between two series (a mask, a band); `validRange` shades what lies
 * outside it; `hBands` are horizontal bands.
 */
export function svgChart(host, spec) {
  const W = 400; // about a report column's width in CSS px: 11 px text prints at ~7 pt
  const H = spec.height || 260;
  const pad = { l: 58, r: 10, t: 22, b: 36 };
  const xs = spec.data[0];
  const ys = spec.data.slice(1);
  const xv = xs.filter(finite);
  const yv = ys.flat().filter(finite).concat((spec.hBands || []).flatMap((b) => [b.from, b.to]).filter(finite));
  let [x0, x1] = spec.xRange || [Math.min(...xv), Math.max(...xv)];
  let y0 = Math.min(...yv);
  let y1 = Math.max(...yv);
  if (!finite(x0) || !finite(x1)) [x0, x1] = [0, 1];
  if (!finite(y0) || !finite(y1)) [y0, y1] = [0, 1];
  if (x1 <= x0) [x0, x1] = [x0 - 1, x0 + 1];
  if (y1 <= y0) [y0, y1] = [y0 - Math.max(1, Math.abs(y0) * 0.1), y0 + Math.max(1, Math.abs(y0) * 0.1)];
  const my = (y1 - y0) * 0.06;
  const xt = niceTicks(x0, x1, 6);
  const yt = niceTicks(y0 - my, y1 + my, 4);
  y0 = Math.min(y0 - my, yt[0]);
  y1 = Math.max(y1 + my, yt[yt.length - 1]);
  const pw = W - pad.l - pad.r;
  const ph = H - pad.t - pad.b;
  const X = (v) => pad.l + ((v - x0) / (x1 - x0)) * pw;
  const Y = (v) => pad.t + (1 - (v - y0) / (y1 - y0)) * ph;
  const f = (v) => v.toFixed(2);

  const svg = el('svg', { viewBox: `0 0 ${W} ${H}`, width: '100%', class: 'svg-plot', role: 'img', 'font-family': 'sans-serif', 'font-size': 11 });
  svg.append(el('title', {}, `${spec.title}: ${spec.series.map((s) => s.label).join(', ')}`));
  svg.append(el('text', { x: W / 2, y: 14, 'text-anchor': 'middle', 'font-weight': 'bold', 'font-size': 12 }, spec.title));
  const clipId = `clip-${Math.random().toString(36).slice(2, 10)}`;
  const clip = el('clipPath', { id: clipId });
  clip.append(el('rect', { x: pad.l, y: pad.t, width: pw, height: ph }));
  svg.append(clip);
  const plot = el('g', { 'clip-path': `url(#${clipId})` });
  // Outside the valid range: grey, with a dashed edge.
  if (spec.validRange) {
    const [lo, hi] = spec.validRange.map(X);
    if (lo > pad.l) plot.append(el('rect', { x: pad.l, y: pad.t, width: f(lo - pad.l), height: ph, fill: 'rgb(120,120,120)', 'fill-opacity': 0.18 }));
    if (hi < pad.l + pw) plot.append(el('rect', { x: f(hi), y: pad.t, width: f(pad.l + pw - hi), height: ph, fill: 'rgb(120,120,120)', 'fill-opacity': 0.18 }));
    for (const p of [lo, hi]) plot.append(el('line', { x1: f(p), x2: f(p), y1: pad.t, y2: pad.t + ph, stroke: '#555', 'stroke-dasharray': '4 4' }));
  }
  for (const b of spec.hBands || []) {
    const a = Y(b.to);
    const z = Y(b.from);
    plot.append(el('rect', { x: pad.l, y: f(Math.min(a, z)), width: pw, height: f(Math.abs(z - a)), fill: 'rgb(44,160,44)', 'fill-opacity': 0.15 }));
  }
  // Grid and axes.
  const grid = el('g', { stroke: '#ddd', 'stroke-width': 0.6 });
  for (const t of xt) grid.append(el('line', { x1: f(X(t)), x2: f(X(t)), y1: pad.t, y2: pad.t + ph }));
  for (const t of yt) grid.append(el('line', { x1: pad.l, x2: pad.l + pw, y1: f(Y(t)), y2: f(Y(t)) }));
  svg.append(grid);
  // Filled areas between two series (uPlot's indices: x is 0).
  for (const a of spec.areas || []) {
    const up = ys[a.upper - 1] || [];
    const lo = ys[a.lower - 1] || [];
    const idx = xs.map((_, i) => i).filter((i) => finite(xs[i]) && finite(up[i]) && finite(lo[i]));
    if (idx.length < 2) continue;
    const d = `M${idx.map((i) => `${f(X(xs[i]))},${f(Y(up[i]))}`).join('L')}L${idx.reverse().map((i) => `${f(X(xs[i]))},${f(Y(lo[i]))}`).join('L')}Z`;
    plot.append(el('path', { d, fill: a.fill || 'rgba(44,160,44,0.13)', stroke: 'none', class: 'svg-area' }));
  }
  spec.series.forEach((s, k) => {
    const color = s.color || '#1f77b4';
    const y = ys[k] || [];
    if (s.points === 'only' || s.points) {
      for (let i = 0; i < xs.length; i++) {
        if (finite(xs[i]) && finite(y[i])) plot.append(el('circle', { cx: f(X(xs[i])), cy: f(Y(y[i])), r: 3.5, fill: color, 'data-series': k }));
      }
    }
    if (s.points === 'only') return;
    let d = '';
    let pen = false;
    for (let i = 0; i < xs.length; i++) {
      if (finite(xs[i]) && finite(y[i])) {
        d += `${pen ? 'L' : 'M'}${f(X(xs[i]))},${f(Y(y[i]))}`;
        pen = true;
      } else pen = false;
    }
    if (d) plot.append(el('path', { d, fill: 'none', stroke: color, 'stroke-width': s.width || 1.5, 'stroke-dasharray': s.dash ? '6 4' : undefined, 'data-series': k }));
  });
  svg.append(plot);
  const axes = el('g', { stroke: '#333', 'stroke-width': 1 });
  axes.append(el('line', { x1: pad.l, x2: pad.l + pw, y1: pad.t + ph, y2: pad.t + ph }));
  axes.append(el('line', { x1: pad.l, x2: pad.l, y1: pad.t, y2: pad.t + ph }));
  svg.append(axes);
  for (const t of xt) svg.append(el('text', { x: f(X(t)), y: pad.t + ph + 12, 'text-anchor': 'middle' }, tickLabel(t)));
  for (const t of yt) svg.append(el('text', { x: pad.l - 4, y: f(Y(t) + 3.5), 'text-anchor': 'end' }, tickLabel(t)));
  const lab = (a) => (a.unit ? `${a.label} (${a.unit})` : a.label);
  svg.append(el('text', { x: pad.l + pw / 2, y: H - 4, 'text-anchor': 'middle' }, lab(spec.x)));
  svg.append(el('text', { x: 12, y: pad.t + ph / 2, 'text-anchor': 'middle', transform: `rotate(-90 12 ${f(pad.t + ph / 2)})` }, lab(spec.y)));

  // The legend: each series' line (or marker) and its name, under the plot;
  // then each named area and the range outside the valid one.
  const legend = document.createElement('ul');
  legend.className = 'svg-legend';
  const entry = (data, mark, text) => {
    const li = document.createElement('li');
    Object.assign(li.dataset, data);
    const sw = el('svg', { width: 26, height: 10, viewBox: '0 0 26 10', 'aria-hidden': 'true' });
    sw.append(mark);
    const name = document.createElement('span');
    name.className = 'svg-legend-name';
    name.textContent = text;
    li.append(sw, name);
    legend.append(li);
  };
  const box = (fill) => el('rect', { x: 1, y: 1, width: 24, height: 8, fill });
  spec.series.forEach((s, k) => {
    const color = s.color || '#1f77b4';
    entry({ series: String(k) }, s.points === 'only'
      ? el('circle', { cx: 13, cy: 5, r: 3.5, fill: color })
      : el('line', { x1: 1, x2: 25, y1: 5, y2: 5, stroke: color, 'stroke-width': 2, 'stroke-dasharray': s.dash ? '6 4' : undefined }), s.label);
  });
  for (const a of (spec.areas || []).filter((x) => x.label)) entry({ area: 'true' }, box(a.fill || 'rgba(44,160,44,0.13)'), a.label);
  if (spec.validRange) {
    entry({ valid: 'true' }, box('rgba(120,120,120,0.35)'),
      `outside the valid range (${num(spec.validRange[0], 3)} to ${num(spec.validRange[1], 3)} ${spec.x.unit || ''})`);
  }
  host.replaceChildren(svg, legend);
  host.classList.add('plot', 'plot-vector');
  host.dataset.kind = spec.kind || spec.title || '';
  host.dataset.series = String(spec.series.length);
  host.dataset.points = String(xs.length);
  if (spec.validRange) host.dataset.validRange = spec.validRange.map((v) => num(v, 4)).join(',');
  host.setAttribute('role', 'img');
  host.setAttribute('aria-label', `${spec.title}: ${spec.series.map((s) => s.label).join(', ')}`);
  return null;
}
