// What an engineer takes away: the parameter table and the K(x), C(x), F(x)
// tables on a grid inside the valid range, as CSV or JSON files and on the
// clipboard. Values are SI with the unit in the column name (as the API),
// written with full precision (shortest round-trip decimal), so a file
// reproduces the API's numbers.

import { pick } from './util.js';

/** Grid points of the exported curves (both ends of the valid range included). */
export const GRID_POINTS = 201;

/** K(x), C(x) = 1/K(x), F(x) = integral of K from 0 to x, SI, inside the valid range. */
export function curves(doc, n = GRID_POINTS) {
  const s = doc.stiffness || {};
  const c = s.coefficients_n_per_m_pow_i_plus_1 || [];
  const [lo, hi] = s.valid_range_m || [NaN, NaN];
  if (!c.length || !Number.isFinite(lo) || !Number.isFinite(hi) || !(hi > lo)) return null;
  const columns = ['x_m', 'k_n_per_m', 'c_m_per_n', 'f_n'];
  const rows = [];
  for (let i = 0; i < n; i++) {
    const x = i === n - 1 ? hi : lo + ((hi - lo) * i) / (n - 1);
    let k = 0;
    let f = 0;
    for (let j = c.length - 1; j >= 0; j--) {
      k = k * x + c[j];
      f = f * x + c[j] / (j + 1);
    }
    f *= x;
    rows.push([x, k, k > 0 ? 1 / k : null, f]);
  }
  return { columns, rows, valid_range_m: [lo, hi] };
}

/** One parameter row: what people read and what the API calls it. */
function prow(name, field, value, se, unit, validity) {
  return { parameter: name, api_field: field, value, standard_error: se, unit, validity };
}

/** The parameter table of a result document (SI, with standard errors and validity). */
export function parameters(doc) {
  const out = [];
  const ss = doc.small_signal;
  const ls = doc.large_signal || {};
  const st = doc.stiffness || {};
  const m = doc.model || {};
  if (ss) {
    const v = ss.reliable ? 'valid' : `unreliable (misfit ${Number(ss.misfit_percent).toPrecision(3)} %)`;
    out.push(prow('resonance f0 (small signal)', 'small_signal.f0_hz', ss.f0_hz, ss.f0_se_hz, 'Hz', v));
    out.push(prow('stiffness k0 (small signal)', 'small_signal.k0_n_per_m', ss.k0_n_per_m, ss.k0_se_n_per_m, 'N/m', v));
    out.push(prow('mechanical resistance R (small signal)', 'small_signal.r_ns_per_m', ss.r_ns_per_m, ss.r_se_ns_per_m, 'N s/m', v));
    out.push(prow('quality factor Q (small signal)', 'small_signal.q', ss.q, ss.q_se, '1', Number.isFinite(ss.q) ? v : `not determined: ${ss.q_null_reason || 'no value'}`));
  }
  out.push(prow('effective stiffness Keff at Xpeak', 'large_signal.keff_n_per_m', ls.keff_n_per_m, ls.keff_se_n_per_m, 'N/m', 'valid'));
  if (Number.isFinite(ls.keff_at_target_n_per_m)) {
    out.push(prow('Keff at the target Xpeak (judged by QC)', 'large_signal.keff_at_target_n_per_m', ls.keff_at_target_n_per_m, null, 'N/m', 'valid'));
  }
  out.push(prow('peak displacement Xpeak', 'large_signal.xpeak_m', ls.xpeak_m, null, 'm', 'valid'));
  out.push(prow('resonance (large signal)', 'large_signal.resonance_hz', ls.resonance_hz, null, 'Hz', 'valid'));
  out.push(prow('moving mass', 'large_signal.moving_mass_kg', ls.moving_mass_kg, null, 'kg', 'entered'));
  const c = st.coefficients_n_per_m_pow_i_plus_1 || [];
  const se = st.coefficients_se_n_per_m_pow_i_plus_1 || [];
  const vr = st.valid_range_m || [];
  const range = `valid for ${Number(vr[0] * 1e3).toFixed(3)} .. ${Number(vr[1] * 1e3).toFixed(3)} mm`;
  c.forEach((k, i) => out.push(prow(`K(x) coefficient k${i}`, `stiffness.coefficients_n_per_m_pow_i_plus_1[${i}]`, k, se[i], i === 0 ? 'N/m' : `N/m^${i + 1}`, range)));
  out.push(prow('mechanical resistance R (large signal)', 'stiffness.r_ns_per_m', st.r_ns_per_m, st.r_se_ns_per_m, 'N s/m', 'valid'));
  out.push(prow('model error', 'model.model_error_percent', m.model_error_percent, null, '%', 'valid'));
  out.push(prow('noise floor', 'model.noise_floor_percent', m.noise_floor_percent, null, '%', 'valid'));
  for (const [effect, ps] of Object.entries(m.effects || pick(doc, 'model.effects') || {})) {
    if (!ps) continue;
    for (const [k, v] of Object.entries(ps)) out.push(prow(`${effect} ${k}`, `model.effects.${effect}.${k}`, v, null, unitFromName(k), 'valid'));
  }
  return out;
}

function unitFromName(k) {
  const u = [['_ns2_per_m2', 'N s^2/m^2'], ['_ns_per_m3', 'N s/m^3'], ['_ns_per_m2', 'N s/m^2'], ['_n_per_m_s', 'N/(m s)'], ['_n_per_m', 'N/m'], ['_m_per_s', 'm/s'], ['_n', 'N'], ['_s', 's']];
  const f = u.find(([s]) => k.endsWith(s));
  return f ? f[1] : '1';
}

function cell(v) {
  if (v === null || v === undefined || (typeof v === 'number' && !Number.isFinite(v))) return '';
  if (typeof v === 'number') return String(v); // shortest round-trip decimal
  const s = String(v);
  return /[",\n\t]/.test(s) ? `"${s.replace(/"/g, '""')}"` : s;
}

/** CSV (RFC 4180, comma, header row) of columns and rows. */
export function toCsv(columns, rows, sep = ',') {
  const t = sep === '\t' ? (v) => cell(v).replace(/\t/g, ' ') : cell;
  return [columns.map(t).join(sep), ...rows.map((r) => r.map(t).join(sep))].join('\r\n') + '\r\n';
}

export function parametersCsv(doc, sep = ',') {
  const cols = ['parameter', 'api_field', 'value', 'standard_error', 'unit', 'validity'];
  return toCsv(cols, parameters(doc).map((p) => cols.map((c) => p[c])), sep);
}

export function curvesCsv(doc, sep = ',') {
  const t = curves(doc);
  return t ? toCsv(t.columns, t.rows, sep) : '';
}

/** The whole export as one JSON document. */
export function exportJson(doc) {
  const info = doc.measurement || {};
  const t = curves(doc);
  return JSON.stringify({
    measurement_id: info.id,
    part_serial: info.part_serial,
    software_version: info.software_version,
    created_at: info.created_at,
    parameters: parameters(doc),
    curves: t ? { grid_points: t.rows.length, valid_range_m: t.valid_range_m, columns: t.columns, rows: t.rows } : null,
    verdict: info.verdict ? { verdict: info.verdict.verdict, recipe: info.verdict.recipe_name, recipe_version: info.verdict.recipe_version, recipe_sha256: info.verdict.recipe_sha256 } : null,
  }, null, 1);
}

/** Saves text as a file (the browser's download). */
export function saveText(filename, text, type) {
  const url = URL.createObjectURL(new Blob([text], { type }));
  const a = document.createElement('a');
  a.href = url;
  a.download = filename;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}

/** Puts text on the clipboard; resolves to true when it is there. */
export async function copyText(text) {
  try {
    await navigator.clipboard.writeText(text);
    return true;
  } catch {
    // No clipboard permission (e.g. not focused): the old way.
    const ta = document.createElement('textarea');
    ta.value = text;
    ta.setAttribute('readonly', '');
    ta.className = 'offscreen';
    document.body.append(ta);
    ta.select();
    const ok = document.execCommand('copy');
    ta.remove();
    return ok;
  }
}
