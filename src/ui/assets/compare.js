// Comparison: K(x) of several measurements (parts or repeats) overlaid,
// each drawn over its own valid range only, with their headline figures.

import { api } from './api.js';
import { h, put, q, when, shortId, poly, linspace, validityOf, stated } from './util.js';
import { chart, COLORS } from './plots.js';
import { stiffnessMm } from './measurement.js';
import { keffChart } from './report.js';

export async function render(main, ctx) {
  const ids = (ctx.params.get('ids') || '').split(',').filter(Boolean);
  const add = h('input', { id: 'compare-add', placeholder: 'part serial or measurement id', 'aria-label': 'Add a part or measurement' });
  const msg = h('span', { class: 'error', id: 'compare-msg' });
  const form = h('form', { class: 'toolbar', id: 'compare-form' }, h('label', { for: 'compare-add' }, 'Add '), add, h('button', { type: 'submit' }, 'Add'), msg);
  form.addEventListener('submit', async (ev) => {
    ev.preventDefault();
    const v = add.value.trim();
    if (!v) return;
    msg.textContent = '';
    let mid = null;
    try {
      const list = await api(`/api/v1/parts/${encodeURIComponent(v)}/measurements?limit=1`);
      mid = list.items.length ? list.items[0].id : null;
    } catch {
      mid = null;
    }
    if (!mid) {
      try {
        mid = (await api(`/api/v1/measurements/${encodeURIComponent(v)}`)).measurement.id;
      } catch {
        msg.textContent = `No part or measurement '${v}'.`;
        return;
      }
    }
    if (!ids.includes(mid)) ids.push(mid);
    location.hash = `#/compare?ids=${ids.join(',')}`;
  });
  const plotEl = h('div', { id: 'plot-compare' });
  const keffEl = h('div', { id: 'plot-compare-keff' });
  const table = h('tbody', { id: 'compare-rows' });
  put(
    main,
    h('section', { class: 'card' },
      h('h1', {}, 'Compare K(x)'),
      h('p', { class: 'muted' }, 'Each curve is drawn over its own measured (valid) range only. Pick measurements on a part\u2019s page, or add them here.'),
      form,
      ids.length ? h('div', { class: 'toolbar' }, h('a', { class: 'button', id: 'open-compare-report', href: `#/report?ids=${ids.join(',')}` }, 'Printable report')) : null,
      h('div', { class: 'plot-grid compare-grid' }, plotEl, keffEl),
      h('table', { class: 'list' },
        h('thead', {}, h('tr', {}, h('th', {}, ''), h('th', {}, 'part'), h('th', {}, 'measurement'), h('th', {}, 'measured'), h('th', {}, 'Xpeak'), h('th', {}, 'Keff(Xpeak)'), h('th', {}, 'K(0)'), h('th', {}, 'valid range'), h('th', {}, ''))),
        table)),
  );
  add.focus();
  if (!ids.length) {
    put(plotEl, h('p', { class: 'muted' }, 'Nothing selected yet.'));
    return;
  }
  const docs = await Promise.all(ids.map((id) => api(`/api/v1/measurements/${encodeURIComponent(id)}`).catch((e) => ({ error: e, id }))));
  if (ctx.stale()) return;
  const ok = docs.filter((d) => !d.error && d.stiffness && Number.isFinite(stiffnessMm(d).lo));
  const all = ok.map(stiffnessMm);
  const lo = Math.min(...all.map((s) => s.lo));
  const hi = Math.max(...all.map((s) => s.hi));
  const xs = linspace(lo, hi, 301);
  const series = [];
  const data = [xs];
  ok.forEach((d, i) => {
    const s = all[i];
    series.push({ label: `${d.measurement.part_serial} ${shortId(d.measurement.id)}`, unit: 'N/mm', color: COLORS[i % COLORS.length] });
    data.push(xs.map((x) => (x >= s.lo - 1e-9 && x <= s.hi + 1e-9 ? poly(s.c, x) : null)));
  });
  if (ok.length) {
    chart(plotEl, {
      title: `K(x) of ${ok.length} measurement${ok.length === 1 ? '' : 's'}`, kind: 'compare K(x)',
      x: { label: 'displacement x', unit: 'mm' }, y: { label: 'stiffness K', unit: 'N/mm' },
      series, data, height: 360,
    });
    keffChart(keffEl, ok, 360);
  } else put(plotEl, h('p', { class: 'muted' }, 'None of these has a stiffness result.'));
  put(table, docs.map((d) => {
    if (d.error) return h('tr', {}, h('td', {}), h('td', { colspan: '8', class: 'error' }, `${d.id}: ${d.error.message}`));
    const i = ok.indexOf(d);
    const s = stiffnessMm(d);
    const ls = d.large_signal || {};
    const remove = h('button', { class: 'link', onclick: () => { location.hash = `#/compare?ids=${ids.filter((x) => x !== d.measurement.id).join(',')}`; } }, 'remove');
    return h('tr', { dataset: { measurement: d.measurement.id } },
      h('td', {}, i >= 0 ? h('span', { class: 'swatch', style: undefined, dataset: { color: String(i % COLORS.length) } }) : ''),
      h('td', {}, h('a', { href: `#/part/${encodeURIComponent(d.measurement.part_serial)}` }, d.measurement.part_serial),
        d.measurement.station_id ? h('span', { class: 'muted station' }, ` (${d.measurement.station_id})`) : null),
      h('td', {}, h('a', { href: `#/measurement/${d.measurement.id}` }, shortId(d.measurement.id))),
      h('td', {}, when(d.measurement.created_at)),
      h('td', {}, q(ls.xpeak_m, 'mm', 1e3, 3)),
      h('td', {}, stated(q(ls.keff_n_per_m, 'N/mm', 1e-3), validityOf(d, 'large_signal.keff_n_per_m'), { unit: 'N/mm', scale: 1e-3, raw: ls.keff_n_per_m })),
      h('td', {}, stated(q(s.c[0], 'N/mm'), validityOf(d, 'stiffness.k_of_x'), { unit: 'N/mm', raw: s.c[0] })),
      h('td', {}, `${q(s.lo, 'mm', 1, 3)} \u2026 ${q(s.hi, 'mm', 1, 3)}`),
      h('td', {}, remove));
  }));
}
