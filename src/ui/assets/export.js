// What an engineer takes away: the parameter table and the K(x), C(x), F(x)
// tables on a grid inside the valid range, as CSV or JSON files and on the
// clipboard. Values are SI with the unit in the column name (as the API),
// written with full precision (shortest round-trip decimal), so a file
// reproduces the API's numbers.

import { pick, validityOf, stateText } from './util.js';

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

/**
 * The rows of a headline value with its state (issue 22): the value and
 * 'valid' or 'UNRELIABLE: <reason>' ...; a not_determined value has no
 * value, and the fit's number comes in a row of its own named as a
 * diagnostic.
 */
function hrows(doc, name, field, value, se, unit, vfield = field) {
  const v = validityOf(doc, vfield);
  if (v.state !== 'not_determined') return [prow(name, field, value, se, unit, stateText(v))];
  const [sec, key] = vfield.split('.');
  const fit = Number.isFinite(v.fit_value) ? v.fit_value : value;
  const out = [prow(name, field, null, null, unit, stateText(v))];
  if (Number.isFinite(fit)) out.push(prow(`${name}: fit value (diagnostic, not a measurement)`, Number.isFinite(v.fit_value) ? `${sec}.validity.${key}.fit_value` : field, fit, null, unit, 'diagnostic'));
  return out;
}

/** The parameter table of a result document (SI, with standard errors and each value's state). */
export function parameters(doc) {
  const out = [];
  const ss = doc.small_signal;
  const ls = doc.large_signal || {};
  const st = doc.stiffness || {};
  const m = doc.model || {};
  if (ss) {
    out.push(...hrows(doc, 'resonance f0 (small signal)', 'small_signal.f0_hz', ss.f0_hz, ss.f0_se_hz, 'Hz'));
    out.push(...hrows(doc, 'stiffness k0 (small signal)', 'small_signal.k0_n_per_m', ss.k0_n_per_m, ss.k0_se_n_per_m, 'N/m'));
    out.push(...hrows(doc, 'mechanical resistance R (small signal)', 'small_signal.r_ns_per_m', ss.r_ns_per_m, ss.r_se_ns_per_m, 'N s/m'));
    const qv = validityOf(doc, 'small_signal.q');
    if (qv.state === 'valid' && !Number.isFinite(ss.q)) out.push(prow('quality factor Q (small signal)', 'small_signal.q', null, null, '1', `NOT DETERMINED: ${ss.q_null_reason || 'no value'}`));
    else out.push(...hrows(doc, 'quality factor Q (small signal)', 'small_signal.q', ss.q, ss.q_se, '1'));
  }
  out.push(...hrows(doc, 'effective stiffness Keff at Xpeak', 'large_signal.keff_n_per_m', ls.keff_n_per_m, ls.keff_se_n_per_m, 'N/m'));
  if (Number.isFinite(ls.target_xpeak_m)) {
    out.push(...hrows(doc, 'Keff at the target Xpeak (judged by QC)', 'large_signal.keff_at_target_n_per_m', ls.keff_at_target_n_per_m, null, 'N/m'));
  }
  out.push(prow('peak displacement Xpeak', 'large_signal.xpeak_m', ls.xpeak_m, null, 'm', 'valid'));
  out.push(...hrows(doc, 'resonance (large signal)', 'large_signal.resonance_hz', ls.resonance_hz, null, 'Hz'));
  out.push(prow('moving mass', 'large_signal.moving_mass_kg', ls.moving_mass_kg, null, 'kg', 'entered'));
  const c = st.coefficients_n_per_m_pow_i_plus_1 || [];
  const se = st.coefficients_se_n_per_m_pow_i_plus_1 || [];
  const vr = st.valid_range_m || [];
  const kv = validityOf(doc, 'stiffness.k_of_x');
  const range = `valid for ${Number(vr[0] * 1e3).toFixed(3)} .. ${Number(vr[1] * 1e3).toFixed(3)} mm`;
  const kstate = kv.state === 'valid' ? range : `${stateText(kv)} (${range})`;
  // A K(x) not determined: its coefficients are the fit's, named as diagnostics.
  const kname = kv.state === 'not_determined' ? 'K(x) fit coefficient (diagnostic, not a measurement)' : 'K(x) coefficient';
  c.forEach((k, i) => out.push(prow(`${kname} k${i}`, `stiffness.coefficients_n_per_m_pow_i_plus_1[${i}]`, k, se[i], i === 0 ? 'N/m' : `N/m^${i + 1}`, kstate)));
  out.push(...hrows(doc, 'mechanical resistance R (large signal)', 'stiffness.r_ns_per_m', st.r_ns_per_m, st.r_se_ns_per_m, 'N s/m'));
  out.push(prow('residual', 'model.residual_percent', m.residual_percent, null, '%', 'valid'));
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

/**
 * The parameter table as CSV, each row naming its part and measurement
 * (issue 35): serial, measurement id, when it was measured (UTC, as the
 * API), and the QC verdict of the measurement (empty without a recipe), so
 * that files from several parts can be put together.
 */
export function parametersCsv(doc, sep = ',') {
  const info = doc.measurement || {};
  const ids = [info.part_serial, info.id, info.created_at, info.verdict ? info.verdict.verdict : ''];
  const cols = ['parameter', 'api_field', 'value', 'standard_error', 'unit', 'validity'];
  return toCsv(['serial', 'measurement_id', 'measured_at', 'verdict', ...cols], parameters(doc).map((p) => [...ids, ...cols.map((c) => p[c])]), sep);
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
