// The printable report (A4 and Letter, the print stylesheet in style.css):
// per measurement (#/report/ID): part identity, verdict and limits,
// parameters with units, uncertainties and validity, K(x) with the recipe's
// mask, C(x), F(x), Keff(Xpeak), traceability; per comparison
// (#/report?ids=a,b,...): each part's identity and figures, and the four
// curves overlaid. Print it with the browser (Ctrl+P, or "Print" here).

import { api } from './api.js';
import { h, put, q, when, shortId, poly, polyIntegral, linspace, withSe, displayUnit, coefUnitMm, VERDICT_WORDS, validityOf, stated, modelErrorText } from './util.js';
import { chart, COLORS } from './plots.js';
import { stiffnessMm, headlineDoc, drawCurves, drawLevels, effectsText, recipeBands } from './measurement.js';
import { parameters } from './export.js';
import { parameterTable, traceTable, rankReasons, reasonText, failureText } from './verdict.js';

const PLOT_H = 190;

function printButton() {
  return h('div', { class: 'toolbar no-print' },
    h('button', { class: 'primary', id: 'print', onclick: () => window.print() }, 'Print / save as PDF'),
    h('span', { class: 'muted' }, 'A4 or Letter, portrait; the page header and buttons are left out of the print.'));
}

/** Parameters with display units, rounded to their uncertainty, and validity. */
function parameterRows(doc) {
  return h('table', { class: 'list report-params', id: 'report-parameters' },
    h('thead', {}, h('tr', {}, h('th', {}, 'parameter'), h('th', {}, 'value \u00b1 standard error'), h('th', {}, 'validity'))),
    h('tbody', {}, parameters(doc).map((p) => {
      const d = displayUnit(p.unit);
      // K(x) coefficients k_i (N/m^(i+1)) in N/mm^(i+1).
      const m = /^N\/m\^(\d+)$/.exec(p.unit);
      const unit = m ? coefUnitMm(Number(m[1]) - 1) : d.unit;
      const scale = m ? 1e-3 ** Number(m[1]) : d.scale;
      return h('tr', { dataset: { field: p.api_field } },
        h('td', {}, p.parameter),
        h('td', { class: 'num' }, withSe(p.value, p.standard_error, unit, scale)),
        h('td', { class: p.validity === 'valid' || p.validity === 'entered' || p.validity === 'diagnostic' || /^valid for /.test(p.validity) ? '' : 'validity-word' }, p.validity));
    })));
}

function identity(doc, fit) {
  const info = doc.measurement || {};
  return h('table', { class: 'kv', id: 'report-identity' },
    h('tr', {}, h('th', {}, 'part'), h('td', { class: 'serial' }, info.part_serial || '\u2013')),
    h('tr', {}, h('th', {}, 'measurement'), h('td', { class: 'mono' }, info.id || '\u2013')),
    h('tr', {}, h('th', {}, 'measured'), h('td', {}, `${when(info.created_at)}${info.bench_id ? ` on ${info.bench_id}` : ''} (${info.source || '?'})`)),
    h('tr', {}, h('th', {}, 'target Xpeak'), h('td', {}, q(info.target_xpeak_m, 'mm', 1e3))),
    h('tr', {}, h('th', {}, 'result from'), h('td', {}, fit ? `fit ${shortId(fit.id)} chosen by ${(info.headline && info.headline.chosen_by) || 'open access'}` : 'the measurement\u2019s own fit')),
    h('tr', {}, h('th', {}, 'effects in the model'), h('td', {}, effectsText((doc.model || {}).effects))));
}

function verdictBlock(v) {
  if (!v) return h('p', { class: 'muted', id: 'report-verdict', dataset: { verdict: '' } }, 'Not judged: measured without a QC recipe.');
  const d = v.detail || {};
  const reasons = rankReasons(d.invalid_reasons);
  return h('div', { id: 'report-verdict', dataset: { verdict: v.verdict } },
    h('p', {}, h('span', { class: `verdict-word v-${v.verdict}` }, VERDICT_WORDS[v.verdict] || v.verdict), ` under recipe ${v.recipe_name} version ${v.recipe_version}`),
    v.verdict === 'fail' ? h('ul', { class: 'failing' }, (d.failures || []).map((f) => h('li', {}, failureText(f)))) : null,
    reasons.length ? h('ul', {}, reasons.map((r) => h('li', {}, `${reasonText(r.code).title}: ${r.detail}`))) : null,
    parameterTable(v, 'report-limits'));
}

async function measurementReport(main, ctx, id) {
  const doc = await api(`/api/v1/measurements/${encodeURIComponent(id)}`);
  const { shown, fit } = await headlineDoc(id, doc);
  const info = doc.measurement || {};
  const { mask, golden } = await recipeBands(info.verdict);
  if (ctx.stale()) return;
  const kx = h('div', { id: 'report-kx' });
  const cx = h('div', { id: 'report-cx' });
  const fx = h('div', { id: 'report-fx' });
  const lev = h('div', { id: 'report-levels' });
  put(main,
    printButton(),
    h('article', { class: 'report', id: 'report', dataset: { measurement: id } },
      h('header', { class: 'report-head' },
        h('h1', {}, `Suspension test report: part ${info.part_serial || '?'}`),
        h('p', { class: 'muted' }, `Springbench ${info.software_version || ''}, printed ${when(new Date().toISOString())}`)),
      h('div', { class: 'report-two' },
        h('section', {}, h('h2', {}, 'Part and measurement'), identity(shown, fit)),
        h('section', {}, h('h2', {}, 'Verdict and limits'), verdictBlock(info.verdict))),
      h('section', {}, h('h2', {}, 'Parameters'), parameterRows(shown)),
      h('section', { class: 'report-plots' }, h('h2', {}, 'Curves (shaded: outside the measured, valid range)'),
        h('div', { class: 'report-grid' }, kx, cx, fx, lev)),
      h('section', { class: 'report-trace' }, h('h2', {}, 'Traceability'),
        info.verdict ? traceTable(info.verdict) : h('table', { class: 'kv', id: 'traceability' },
          h('tr', {}, h('th', {}, 'software'), h('td', {}, info.software_version || '\u2013')),
          h('tr', {}, h('th', {}, 'recipe'), h('td', {}, 'none')),
          h('tr', {}, h('th', {}, 'calibration record'), h('td', {}, 'none (virtual bench or import)'))))));
  if (!stiffnessMm(shown).c.length) return;
  drawCurves({ kx, cx, fx }, shown, { mask, golden, height: PLOT_H, vector: true });
  await drawLevels(lev, shown, id, { height: PLOT_H, vector: true });
  main.querySelector('#report').dataset.ready = 'true';
}

async function comparisonReport(main, ctx, ids) {
  const docs = [];
  for (const id of ids) {
    const d = await api(`/api/v1/measurements/${encodeURIComponent(id)}`);
    docs.push((await headlineDoc(id, d)).shown);
  }
  if (ctx.stale()) return;
  const ok = docs.filter((d) => Number.isFinite(stiffnessMm(d).lo));
  const all = ok.map(stiffnessMm);
  const lo = Math.min(...all.map((s) => s.lo));
  const hi = Math.max(...all.map((s) => s.hi));
  const xs = linspace(lo, hi, 241);
  const label = (d) => `${d.measurement.part_serial} ${shortId(d.measurement.id)}`;
  const series = (unit) => ok.map((d, i) => ({ label: label(d), unit, color: COLORS[i % COLORS.length] }));
  const inside = (s, f) => xs.map((x) => (x >= s.lo - 1e-9 && x <= s.hi + 1e-9 ? f(x) : null));
  const els = ['kx', 'cx', 'fx', 'levels'].map((k) => h('div', { id: `report-${k}` }));
  // One software version for all (the usual case) is said once, in the
  // header, which leaves the table's width to the values.
  const versions = [...new Set(docs.map((d) => d.measurement.software_version))];
  const oneSoftware = versions.length === 1;
  put(main,
    printButton(),
    h('article', { class: 'report', id: 'report', dataset: { compare: ids.join(',') } },
      h('header', { class: 'report-head' },
        h('h1', {}, `Suspension comparison report: ${ok.length} measurements`),
        h('p', { class: 'muted' }, `printed ${when(new Date().toISOString())}${oneSoftware ? `; every measurement by Springbench ${versions[0]}` : ''}`)),
      h('table', { class: 'list report-params report-compare', id: 'report-parameters' },
        h('thead', {}, h('tr', {}, ['', 'part', 'measurement', 'measured', 'verdict', 'Keff at Xpeak', 'Xpeak', 'k0 (small signal)', 'f0', 'model error', oneSoftware ? null : 'software'].filter((t) => t !== null).map((t) => h('th', {}, t)))),
        h('tbody', {}, docs.map((d) => {
          const i = ok.indexOf(d);
          const ls = d.large_signal || {};
          const ss = d.small_signal || {};
          const v = d.measurement.verdict;
          return h('tr', {},
            h('td', {}, i >= 0 ? h('span', { class: 'swatch', dataset: { color: String(i % COLORS.length) } }) : ''),
            h('td', { class: 'serial' }, d.measurement.part_serial),
            h('td', { class: 'mono' }, shortId(d.measurement.id)),
            h('td', {}, when(d.measurement.created_at)),
            h('td', {}, v ? `${VERDICT_WORDS[v.verdict] || v.verdict} (${v.recipe_name} v${v.recipe_version}, ${String(v.recipe_sha256 || '').slice(0, 12)})` : 'not judged'),
            h('td', { class: 'num' }, stated(withSe(ls.keff_n_per_m, ls.keff_se_n_per_m, 'N/mm', 1e-3), validityOf(d, 'large_signal.keff_n_per_m'), { unit: 'N/mm', scale: 1e-3, raw: ls.keff_n_per_m })),
            h('td', { class: 'num' }, q(ls.xpeak_m, 'mm', 1e3)),
            h('td', { class: 'num' }, stated(withSe(ss.k0_n_per_m, ss.k0_se_n_per_m, 'N/mm', 1e-3), validityOf(d, 'small_signal.k0_n_per_m'), { unit: 'N/mm', scale: 1e-3 })),
            h('td', { class: 'num' }, stated(withSe(ss.f0_hz, ss.f0_se_hz, 'Hz'), validityOf(d, 'small_signal.f0_hz'), { unit: 'Hz' })),
            h('td', { class: 'num' }, modelErrorText(d.model, '%', true)),
            oneSoftware ? null : h('td', {}, d.measurement.software_version));
        }))),
      h('section', { class: 'report-plots' }, h('h2', {}, 'Curves, each over its own valid range'), h('div', { class: 'report-grid' }, els))));
  reasonsAsNotes(main.querySelector('#report-parameters'));
  if (!ok.length) return;
  const [kx, cx, fx, lev] = els;
  const base = { x: { label: 'displacement x', unit: 'mm' }, height: PLOT_H, vector: true };
  chart(kx, { ...base, title: 'Stiffness K(x)', kind: 'K(x)', y: { label: 'K', unit: 'N/mm' }, series: series('N/mm'), data: [xs, ...all.map((s) => inside(s, (x) => poly(s.c, x)))] });
  chart(cx, { ...base, title: 'Compliance C(x)', kind: 'C(x)', y: { label: 'C', unit: 'mm/N' }, series: series('mm/N'), data: [xs, ...all.map((s) => inside(s, (x) => 1 / poly(s.c, x)))] });
  chart(fx, { ...base, title: 'Restoring force F(x)', kind: 'F(x)', y: { label: 'F', unit: 'N' }, series: series('N'), data: [xs, ...all.map((s) => inside(s, (x) => polyIntegral(s.c, x)))] });
  keffChart(lev, ok, PLOT_H, true);
  main.querySelector('#report').dataset.ready = 'true';
}

/**
 * The comparison table's state reasons as numbered notes below it: a cell
 * keeps its value, its state word and a reference [n]; each distinct reason
 * is written once. In the cells, the same long reason stood in three narrow
 * columns of one row (a row 300 px tall on the screen and the page).
 */
function reasonsAsNotes(table) {
  if (!table) return;
  const notes = [];
  for (const why of table.querySelectorAll('.validity-reason')) {
    const text = why.textContent;
    let n = notes.indexOf(text) + 1;
    if (!n) n = notes.push(text);
    const br = why.previousSibling;
    if (br && br.nodeName === 'BR') br.remove();
    why.replaceWith(h('sup', { class: 'note-ref', dataset: { note: String(n) } }, `[${n}]`));
  }
  if (!notes.length) return;
  table.after(h('ol', { class: 'report-notes', id: 'report-notes' },
    notes.map((t, i) => h('li', { dataset: { note: String(i + 1) } }, t))));
}

/** Keff against Xpeak of several measurements (one point each; a level series joined). */
export function keffChart(el, docs, height, vector = false) {
  const pts = docs.map((d) => [(d.large_signal || {}).xpeak_m * 1e3, (d.large_signal || {}).keff_n_per_m * 1e-3]);
  const xs = [...new Set(pts.map((p) => p[0]).filter(Number.isFinite))].sort((a, b) => a - b);
  const data = [xs, ...pts.map((p) => xs.map((x) => (x === p[0] ? p[1] : null)))];
  chart(el, {
    title: 'Keff against Xpeak', kind: 'Keff(Xpeak)',
    x: { label: 'peak displacement Xpeak', unit: 'mm' }, y: { label: 'Keff', unit: 'N/mm' },
    series: docs.map((d, i) => ({ label: `${d.measurement.part_serial} ${shortId(d.measurement.id)}`, unit: 'N/mm', points: 'only', color: COLORS[i % COLORS.length] })),
    data,
    xRange: xs.length ? [Math.min(0, xs[0]), xs[xs.length - 1] * 1.2] : undefined,
    height,
    vector,
  });
}

export async function render(main, ctx) {
  const ids = (ctx.params.get('ids') || '').split(',').filter(Boolean);
  if (ctx.arg) return measurementReport(main, ctx, ctx.arg);
  if (ids.length) return comparisonReport(main, ctx, ids);
  put(main, h('p', { class: 'muted' }, 'Open a report from a measurement or a comparison.'));
  return undefined;
}
