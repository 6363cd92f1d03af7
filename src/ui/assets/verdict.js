// A QC verdict as the part, measurement and report pages show it: the word,
// the failing parameters, every judged parameter with its value, limits and
// result, the recipe (name, version, hash) and the traceability record.

import { h, when, shortId, siq, limitsText, paramLabel, row, VERDICT_WORDS } from './util.js';

// An INVALID verdict's reasons, the cause first: a drive limit or a fault
// makes the target unreachable, which then leaves K(x) points outside the
// measured range and the model error high. Each code: what the station
// says, and what the operator does about it.
const INVALID = [
  ['hardware_fault', 'The bench reported a fault', 'Call the engineer: the bench needs attention before the next part.'],
  ['job_failed', 'The measurement did not complete', 'Call the engineer if it happens again; the part was not judged.'],
  ['target_not_reached', 'The part did not reach the target displacement', 'Check the clamping and the part (torn, glued, wrong type), then measure it again.'],
  ['clipping', 'A sensor was out of range', 'Clean the laser spot or the surface and check the laser\u2019s aim, then measure it again.'],
  ['alignment', 'The laser and microphone signals did not line up', 'Clean the laser spot or the surface and check the laser\u2019s aim, then measure it again.'],
  ['noise_high', 'The signals were too noisy', 'Clean the laser spot or the surface; keep the bench free of knocks; measure it again.'],
  ['analysis_failed', 'The analysis found no result', 'Call the engineer.'],
  ['non_finite_value', 'The result held an invalid number', 'Call the engineer.'],
  ['small_signal_unreliable', 'The small-signal fit is unreliable', 'Measure it again; if it repeats, call the engineer.'],
  ['model_error_high', 'The model does not fit this part', 'Measure it again; if it repeats, call the engineer.'],
  ['value_not_determined', 'A judged value could not be determined from this measurement', 'Measure it again; if it repeats, call the engineer.'],
  ['outside_measured_range', 'A judged point lies outside the measured range', 'Call the engineer: the recipe judges K(x) where this part was not measured.'],
  ['mask_coverage', 'The K(x) mask lies outside the measured range', 'Call the engineer: the recipe\u2019s mask is wider than the range measured.'],
];

/** The reasons sorted cause first: [primary, ...knock-on]. */
export function rankReasons(reasons) {
  const rank = (r) => {
    const i = INVALID.findIndex(([c]) => c === r.code);
    return i < 0 ? INVALID.length : i;
  };
  return (reasons || []).slice().sort((a, b) => rank(a) - rank(b));
}

export function reasonText(code) {
  const e = INVALID.find(([c]) => c === code);
  return e ? { title: e[1], action: e[2] } : { title: String(code).replace(/_/g, ' '), action: 'Call the engineer.' };
}

/** A judged parameter's failure as people read it ("k0: 5.1 N/mm, limits 3.1 \u2026 4.9 N/mm"). */
export function failureText(f) {
  return `${paramLabel(f)}: ${siq(f.value, f.unit, 4)}, limits ${limitsText(f.lower, f.upper, f.unit)}`;
}

/** Every judged parameter: name, value, limits (one-sided as "\u2264 0.1 N"), result.
 * An INVALID verdict is never judged: its values are shown as measured,
 * marked so, with no pass or fail (issue 35). */
export function parameterTable(v, id = 'verdict-parameters') {
  const ps = (v.detail && v.detail.parameters) || [];
  if (!ps.length) return h('p', { class: 'muted' }, 'No parameter was judged.');
  const invalid = v.verdict === 'invalid';
  const result = (p) => (invalid ? 'unjudged' : p.result);
  const word = (p) => (invalid ? 'not judged' : { pass: 'pass', fail: 'fail', not_judged: 'no limits' }[p.result] || p.result);
  return h('div', {},
    invalid ? h('p', { class: 'unjudged-note', id: `${id}-note` }, 'INVALID: the values below are shown as measured; none of them is judged against its limits.') : null,
    h('table', { class: `list${invalid ? ' unjudged' : ''}`, id },
      h('thead', {}, h('tr', {}, h('th', {}, 'parameter'), h('th', {}, invalid ? 'value (as measured)' : 'value'), h('th', {}, 'limits'), h('th', {}, 'result'))),
      h('tbody', {}, ps.map((p) => h('tr', { class: `result-${result(p)}`, dataset: { name: p.name, result: result(p) } },
        h('td', {}, paramLabel(p)),
        h('td', { class: 'num' }, siq(p.value, p.unit, 5)),
        h('td', {}, limitsText(p.lower, p.upper, p.unit)),
        h('td', {}, h('span', { class: `badge result-${result(p)}` }, word(p))))))));
}

/** Software version, recipe, bench, calibration, who submitted and when. */
export function traceTable(v) {
  const t = v.traceability || {};
  const cal = t.calibration;
  return h('table', { class: 'kv trace', id: 'traceability' },
    row('recipe', `${v.recipe_name} version ${v.recipe_version}`),
    row('recipe hash (SHA-256)', h('span', { class: 'mono' }, v.recipe_sha256 || '\u2013')),
    v.station_id ? row('station', h('span', { id: 'trace-station' }, v.station_id)) : null,
    row('software', t.software_version || '\u2013'),
    row('bench', `${t.bench_id || '\u2013'}${t.bench_kind ? ` (${t.bench_kind})` : ''}`),
    row('calibration record', cal ? (cal.id ? `${cal.id}${cal.created_at ? `, ${when(cal.created_at)}` : ''}` : JSON.stringify(cal)) : 'none (virtual bench)'),
    row('submitted by', t.submitted_by || 'open access'),
    row('judged', when(t.judged_at || v.created_at)),
    row('job', v.job_id ? shortId(v.job_id) : '\u2013'));
}

/** The verdict card: the word in colour, the reasons or failures, parameters, traceability. */
export function verdictCard(v, { title = 'QC verdict', id = 'qc-verdict' } = {}) {
  if (!v) return null;
  const d = v.detail || {};
  const word = VERDICT_WORDS[v.verdict] || v.verdict;
  const reasons = d.invalid_reasons || [];
  return h('section', { class: `card verdict-card v-${v.verdict}`, id, dataset: { verdict: v.verdict } },
    h('h2', {}, title),
    h('div', { class: 'verdict-line' },
      h('span', { class: `verdict-word v-${v.verdict}`, id: `${id}-word` }, word),
      h('span', { class: 'muted' }, ` recipe ${v.recipe_name} version ${v.recipe_version}`)),
    v.verdict === 'fail'
      ? h('ul', { class: 'failing', id: `${id}-failing` }, (d.failures || []).map((f) => h('li', { dataset: { name: f.name } }, failureText(f))))
      : null,
    v.verdict === 'invalid' && reasons.length
      ? h('ul', { class: 'verdict-why', id: `${id}-reasons` }, rankReasons(reasons).map((r, i) => h('li', { class: i ? 'muted' : 'primary' }, `${reasonText(r.code).title}: ${r.detail}`, i ? '' : h('strong', {}, ` ${reasonText(r.code).action}`))))
      : null,
    h('div', { class: 'two' }, parameterTable(v, `${id}-parameters`), traceTable(v)));
}
