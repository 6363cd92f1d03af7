// Plots: uPlot (vendored, see vendor/uplot/README.md) with what every plot
// here needs: axis labels that name quantity and unit, hover values with
// units (the legend under the plot, never over the data), 1-2-5 ticks on log
// axes, shaded x ranges (valid range, harmonic bands) and horizontal bands
// (noise level).

import uPlot from './vendor/uplot/uPlot.esm.js';
import { num, tickLabel } from './util.js';
import { svgChart } from './svgplot.js';

export const COLORS = ['#1f77b4', '#d62728', '#2ca02c', '#9467bd', '#ff7f0e', '#17becf', '#8c564b', '#e377c2'];

/** 1-2-5 ticks of a log axis between lo and hi (both > 0); 1..9 when the range is under a decade. */
export function ticks125(lo, hi) {
  if (!(lo > 0) || !(hi > lo)) return [];
  const decades = Math.log10(hi / lo);
  const mults = decades > 4 ? [1] : decades < 1.2 ? [1, 2, 3, 4, 5, 6, 7, 8, 9] : [1, 2, 5];
  const out = [];
  for (let e = Math.floor(Math.log10(lo)); e <= Math.ceil(Math.log10(hi)); e++) {
    for (const m of mults) {
      const v = m * 10 ** e;
      if (v >= lo * (1 - 1e-9) && v <= hi * (1 + 1e-9)) out.push(Number(v.toPrecision(6)));
    }
  }
  return out;
}

function clean(arr) {
  return Array.from(arr || [], (v) => (v === null || v === undefined || !Number.isFinite(v) ? null : v));
}

/**
 * A line chart.
 * spec: {title, x: {label, unit, log}, y: {label, unit, log}, y2: {label, unit} (optional right axis),
 *        series: [{label, unit, color, dash, y2, points, width, spanGaps}], data: [xs, ys1, ys2, ...],
 *        xBands: [{from, to, label, fill}], validRange: [lo, hi], hBands: [{from, to, label}],
 *        height, sync: key, kind: 'K(x)' (for tests), vector: true (an SVG for print, svgplot.js)}
 */
export function chart(el, spec) {
  if (spec.vector) return svgChart(el, spec);
  const xUnit = spec.x.unit || '';
  const series = [
    {
      label: spec.x.label,
      value: (u, v) => (v === null || v === undefined ? '\u2013' : `${num(v, 4)} ${xUnit}`),
    },
  ];
  spec.series.forEach((s, i) => {
    const unit = s.unit !== undefined ? s.unit : (s.y2 ? spec.y2 : spec.y).unit || '';
    const color = s.color || COLORS[i % COLORS.length];
    series.push({
      label: s.label,
      stroke: color,
      width: s.width || 1.5,
      dash: s.dash ? [6, 4] : undefined,
      scale: s.y2 ? 'y2' : 'y',
      spanGaps: s.spanGaps === true,
      points: s.points ? { show: true, size: 7, fill: color } : { show: false },
      paths: s.points === 'only' ? () => null : undefined,
      value: (u, v) => (v === null || v === undefined ? '\u2013' : `${num(v, 4)}${unit ? ` ${unit}` : ''}`),
    });
  });
  const logAxis = (log) =>
    log
      ? {
          splits: (u, ai, min, max) => ticks125(min, max),
          values: (u, splits) => splits.map(tickLabel),
        }
      : { values: (u, splits) => splits.map(tickLabel) };
  const lab = (a) => (a.unit ? `${a.label} (${a.unit})` : a.label);
  const axes = [
    { label: lab(spec.x), ...logAxis(spec.x.log), size: 42 },
    // Short plots get denser y ticks (a residual strip had a single "0").
    { label: lab(spec.y), scale: 'y', ...logAxis(spec.y.log), size: 64, space: (spec.height || 260) < 200 ? 18 : 30 },
  ];
  const scales = {
    x: spec.x.log ? { time: false, distr: 3, log: 10 } : { time: false },
    y: spec.y.log ? { distr: 3, log: 10 } : {},
  };
  if (spec.y2) {
    axes.push({ label: lab(spec.y2), scale: 'y2', side: 1, grid: { show: false }, ...logAxis(false), size: 64 });
    scales.y2 = {};
  }
  if (spec.xRange) scales.x.range = () => spec.xRange;
  // A log axis spans the data (uPlot would round it out to whole decades:
  // 20-110 Hz drawn up to 1 kHz), and a log y axis at most `maxDecades`
  // below its largest value (a residual spectrum would otherwise span 14).
  const data0 = spec.data.map(clean);
  const finitePos = (arrs) => arrs.flat().filter((v) => v !== null && v > 0);
  if (spec.x.log && !spec.xRange) {
    const xs = finitePos([data0[0]]);
    if (xs.length) {
      const a = Math.min(...xs);
      const b = Math.max(...xs);
      scales.x.range = () => [a, b > a ? b : a * 10];
    }
  }
  // A signal around zero: a symmetric y range with room, so ticks fall on both sides.
  if (spec.y.symmetric) {
    const m = Math.max(...data0.slice(1).flat().filter((v) => v !== null).map(Math.abs), ...(spec.hBands || []).map((b) => Math.max(Math.abs(b.from), Math.abs(b.to))));
    if (m > 0) scales.y.range = () => [-1.15 * m, 1.15 * m];
  }
  if (spec.y.log) {
    const ys = finitePos(data0.slice(1).filter((_, i) => !spec.series[i].y2));
    if (ys.length) {
      const top = Math.max(...ys);
      const bottom = Math.max(Math.min(...ys), top * 10 ** -(spec.y.maxDecades || 6));
      scales.y.range = () => [bottom / 1.5, top * 1.5];
    }
  }
  // Counts (sample numbers) get whole-number ticks only.
  if (spec.x.integer) axes[0].incrs = [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10000];
  const width = Math.max(320, el.clientWidth || 600);
  const opts = {
    title: spec.title,
    width,
    height: spec.height || 260,
    scales,
    axes,
    series,
    legend: { show: true, live: true },
    // Filled areas between two series (a mask or a band): uPlot series indices (x is 0).
    bands: (spec.areas || []).map((a) => ({ series: [a.upper, a.lower], fill: a.fill || 'rgba(44,160,44,0.13)' })),
    cursor: spec.sync ? { sync: { key: spec.sync, setSeries: false } } : {},
    hooks: {
      drawClear: [(u) => drawBands(u, spec)],
      draw: [(u) => drawBandLabels(u, spec)],
    },
  };
  el.replaceChildren();
  el.classList.add('plot');
  const data = data0;
  const u = new uPlot(opts, data, el);
  // What the plot shows, for people using assistive tools and for the tests.
  el.dataset.kind = spec.kind || spec.title || '';
  el.dataset.series = String(spec.series.length);
  el.dataset.points = String(data[0].length);
  if (spec.validRange) el.dataset.validRange = spec.validRange.map((v) => num(v, 4)).join(',');
  // The plot itself, for the tests (series labels and data as drawn).
  el.uplot = u;
  el.setAttribute('role', 'img');
  el.setAttribute('aria-label', `${spec.title}: ${spec.series.map((s) => s.label).join(', ')}`);
  if (typeof ResizeObserver !== 'undefined') {
    const ro = new ResizeObserver(() => {
      const w = Math.max(320, el.clientWidth);
      if (Math.abs(w - u.width) > 4) u.setSize({ width: w, height: u.height });
    });
    ro.observe(el);
  }
  return u;
}

function xPos(u, v) {
  return u.valToPos(v, 'x', true);
}

function drawBands(u, spec) {
  const ctx = u.ctx;
  const { left, top, width, height } = u.bbox;
  ctx.save();
  // Outside the valid range: grey.
  if (spec.validRange) {
    const [lo, hi] = spec.validRange;
    const a = Math.max(left, Math.min(left + width, xPos(u, lo)));
    const b = Math.max(left, Math.min(left + width, xPos(u, hi)));
    ctx.fillStyle = 'rgba(120,120,120,0.18)';
    if (a > left) ctx.fillRect(left, top, a - left, height);
    if (b < left + width) ctx.fillRect(b, top, left + width - b, height);
    ctx.strokeStyle = '#555';
    ctx.setLineDash([4, 4]);
    ctx.lineWidth = 1;
    for (const p of [a, b]) {
      ctx.beginPath();
      ctx.moveTo(p, top);
      ctx.lineTo(p, top + height);
      ctx.stroke();
    }
    ctx.setLineDash([]);
  }
  for (const b of spec.xBands || []) {
    const a = Math.max(left, xPos(u, b.from));
    const z = Math.min(left + width, xPos(u, b.to));
    if (z > a) {
      ctx.fillStyle = b.fill || 'rgba(240,200,80,0.30)';
      ctx.fillRect(a, top, z - a, height);
    }
  }
  for (const b of spec.hBands || []) {
    const scale = b.scale || 'y';
    const y1 = u.valToPos(b.to, scale, true);
    const y0 = u.valToPos(b.from, scale, true);
    const ya = Math.max(top, Math.min(y0, y1));
    const yb = Math.min(top + height, Math.max(y0, y1));
    if (yb > ya) {
      ctx.fillStyle = b.fill || 'rgba(44,160,44,0.15)';
      ctx.fillRect(left, ya, width, yb - ya);
    }
  }
  ctx.restore();
}

function drawBandLabels(u, spec) {
  const ctx = u.ctx;
  const { left, top, width, height } = u.bbox;
  const px = devicePixelRatio || 1;
  ctx.save();
  ctx.font = `${11 * px}px sans-serif`;
  ctx.textBaseline = 'top';
  if (spec.validRange) {
    ctx.fillStyle = '#444';
    const a = xPos(u, spec.validRange[0]);
    const b = xPos(u, spec.validRange[1]);
    // The longest wording that fits inside the shaded part, else none.
    const fit = (room) => ['outside valid range', 'outside'].find((t) => ctx.measureText(t).width + 8 * px <= room);
    const ta = fit(a - left);
    if (ta) {
      ctx.textAlign = 'right';
      ctx.fillText(ta, a - 4 * px, top + 4 * px);
    }
    const tb = fit(left + width - b);
    if (tb) {
      ctx.textAlign = 'left';
      ctx.fillText(tb, b + 4 * px, top + 4 * px);
    }
  }
  ctx.textAlign = 'center';
  ctx.fillStyle = '#806000';
  // Band labels never overlap: one that would touch the previous is left out
  // (on a log axis the upper harmonics crowd together).
  let lastRight = -Infinity;
  for (const b of spec.xBands || []) {
    if (!b.label) continue;
    const m = (xPos(u, b.from) + xPos(u, b.to)) / 2;
    const w = ctx.measureText(b.label).width;
    if (m > left && m < left + width && m - w / 2 > lastRight + 4 * px) {
      ctx.fillText(b.label, m, top + 3 * px);
      lastRight = m + w / 2;
    }
  }
  ctx.textAlign = 'right';
  ctx.fillStyle = '#1a6e1a';
  for (const b of spec.hBands || []) {
    if (!b.label) continue;
    const y = u.valToPos(b.to, b.scale || 'y', true);
    if (y > top && y < top + height) ctx.fillText(b.label, left + width - 4 * px, y + 2 * px);
  }
  ctx.restore();
}

/** A horizontal bar list (HTML): [{label, value, note}] scaled to the largest value. */
export function bars(el, items, { unit = '%', floor, floorLabel } = {}) {
  const max = Math.max(1e-12, ...items.map((i) => i.value), floor || 0);
  el.replaceChildren();
  el.classList.add('bars');
  for (const it of items) {
    const w = (100 * it.value) / max;
    const rowEl = document.createElement('div');
    rowEl.className = 'bar-row' + (it.highlight ? ' highlight' : '');
    const lab = document.createElement('span');
    lab.className = 'bar-label';
    lab.textContent = it.label;
    const track = document.createElement('span');
    track.className = 'bar-track';
    const bar = document.createElement('span');
    bar.className = 'bar';
    bar.style.width = `${w.toFixed(2)}%`;
    track.append(bar);
    if (floor) {
      const f = document.createElement('span');
      f.className = 'bar-floor';
      f.style.left = `${((100 * floor) / max).toFixed(2)}%`;
      f.title = floorLabel || 'noise floor';
      track.append(f);
    }
    const val = document.createElement('span');
    val.className = 'bar-value';
    val.textContent = `${num(it.value, 3)} ${unit}`;
    rowEl.append(lab, track, val);
    if (it.note) {
      const n = document.createElement('span');
      n.className = 'bar-note';
      n.textContent = it.note;
      rowEl.append(n);
    }
    el.append(rowEl);
  }
}
