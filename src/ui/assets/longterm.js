// Long-term tests (issue 32): the station's list, and a test's page: the
// family of K(x) curves over time (paper Fig. 23), K(0), Keff and f0 against
// test time or accumulated load with the fitted law and its 95 % band, the
// prediction, the events (pauses, resumptions, the failure), progress and
// time left, pause, resume and cancel, the printable report (the API's
// page saved as a file, decision 0131), the ambient conditions per interval
// (°C and % beside the values; entered by hand by an operator), and the
// series as CSV / JSON. A law that is not valid
// is drawn dashed and grey and says so in its legend and its table.
//
// `#/long-term` lists the tests, `#/long-term/<id>` is one test. The page
// polls the test every 2 s while it runs.

import { api, download, daemon } from './api.js';
import { h, put, num, dur, when, shortId, poly, linspace, withSe, stated, stateText, STATE_WORDS } from './util.js';
import { chart } from './plots.js';
import { saveText } from './export.js';

const TERMINAL = ['succeeded', 'failed', 'cancelled', 'interrupted'];
const POLL_MS = 2000;
/** Points of each K(x) curve of the family. */
const KX_POINTS = 81;

const hours = (s) => (Number.isFinite(s) ? s / 3600 : null);
const kj = (j) => (Number.isFinite(j) ? j / 1000 : null);
const mm = (k) => (Number.isFinite(k) ? k / 1000 : null); // N/m -> N/mm

// The stimulus in words: its kind, its level in its own measure (decision 0137).
function stimulusText(stim) {
  if (stim.kind === 'noise') {
    const [lo, hi] = stim.band_hz || [];
    return `band-limited noise, ${num(lo, 4)} to ${num(hi, 4)} Hz, target ${num((stim.excursion_rms_m || 0) * 1000, 3)} mm RMS displacement`;
  }
  if (stim.kind === 'wav') {
    return `WAV file ${String(stim.wav_id || '').slice(0, 12)} as a loop, target ${num((stim.excursion_rms_m || 0) * 1000, 3)} mm RMS displacement`;
  }
  return `sine at the part\u2019s resonance, ${num((stim.excursion_m || 0) * 1000, 3)} mm peak, held at its ${stim.hold === 'drive' ? 'drive level' : 'excursion'}`;
}

function badge(state) {
  return h('span', { class: `badge state-${state}` }, state);
}

function lawWord(v) {
  if (!v) return 'no law yet';
  return v.state === 'valid' ? 'valid' : STATE_WORDS[v.state] || v.state;
}

export async function render(main, ctx) {
  if (ctx.arg) return renderTest(main, ctx, ctx.arg);
  return renderList(main, ctx);
}

// --- the list ---------------------------------------------------------------

async function renderList(main, ctx) {
  const body = h('tbody', { id: 'lt-list' });
  const msg = h('p', { class: 'muted', id: 'lt-list-msg' }, 'Loading\u2026');
  put(
    main,
    h('section', { class: 'card' },
      h('h1', {}, 'Long-term tests'),
      h('p', { class: 'muted' }, daemon.center
        ? 'Every station\u2019s long-term tests, read only: the copy each station sent when its test last changed (a running test is as current as its station\u2019s link).'
        : 'Tests that age a part on one bench: the full procedure at intervals, a sine at the part\u2019s resonance in between. Submit one with POST /api/v1/long-term-tests.'),
      msg,
      h('table', { class: 'list' },
        h('thead', {}, h('tr', {}, [...(daemon.center ? ['station'] : []), 'test', 'part', 'bench', 'state', 'progress', 'intervals', 'time left', 'law', 'failure', 'created'].map((t) => h('th', {}, t)))),
        body)),
  );
  const draw = async () => {
    const list = await api('/api/v1/long-term-tests');
    if (ctx.stale()) return;
    msg.textContent = list.items.length ? '' : (daemon.center ? 'No station has sent a long-term test yet.' : 'No long-term test on this station yet.');
    put(body, list.items.map((t) => {
      const j = t.job;
      const running = !TERMINAL.includes(j.state);
      return h('tr', { dataset: { id: j.id, state: j.state } },
        daemon.center ? h('td', { class: 'station' }, t.station_id) : null,
        h('td', {}, h('a', { href: `#/long-term/${encodeURIComponent(j.id)}`, class: 'mono' }, shortId(j.id))),
        h('td', { class: 'serial' }, j.part_serial),
        h('td', {}, j.bench_id),
        h('td', {}, badge(j.state), j.step && j.step.startsWith('paused') ? h('span', { class: 'error' }, ' paused') : null),
        h('td', {}, `${num(100 * (j.progress || 0), 3)} %`),
        h('td', {}, `${t.intervals_done} of ${t.intervals_planned} (every ${num(t.interval_s / 60, 3)} min over ${num(t.duration_s / 3600, 3)} h${t.accelerated ? ', accelerated' : ''})`),
        h('td', {}, running ? dur(j.eta_s) : '\u2013'),
        h('td', { class: t.law_validity && t.law_validity.state !== 'valid' ? 'error' : '' }, lawWord(t.law_validity)),
        h('td', { class: 'error' }, t.failure ? t.failure.limit : ''),
        h('td', {}, when(j.created_at)));
    }));
    return list.items.some((t) => !TERMINAL.includes(t.job.state));
  };
  let timer = null;
  const tick = async () => {
    try {
      const more = await draw();
      if (more && !ctx.stale()) timer = setTimeout(tick, POLL_MS);
    } catch (e) {
      msg.className = 'error';
      msg.textContent = String(e.message || e);
    }
  };
  await tick();
  return () => clearTimeout(timer);
}

// --- one test ----------------------------------------------------------------

/** The K(x) family: each interval's polynomial over its own valid range (mm, N/mm), on one x grid. */
export function kxFamily(doc) {
  const ivs = (doc && doc.intervals) || [];
  if (!ivs.length) return null;
  const lo = Math.min(...ivs.map((i) => i.valid_range_m[0]));
  const hi = Math.max(...ivs.map((i) => i.valid_range_m[1]));
  const xs = linspace(lo, hi, KX_POINTS);
  const ys = ivs.map((i) => xs.map((x) => (x >= i.valid_range_m[0] - 1e-12 && x <= i.valid_range_m[1] + 1e-12 ? poly(i.k_coefficients_n_per_m_pow_i_plus_1, x) / 1000 : null)));
  return { xs: xs.map((x) => x * 1000), ys, times: ivs.map((i) => i.elapsed_s) };
}

/** A colour from blue (new) to red (aged). */
function ramp(u) {
  const a = [31, 119, 180];
  const b = [214, 39, 40];
  const c = a.map((v, k) => Math.round(v + (b[k] - v) * u));
  return `rgb(${c.join(',')})`;
}

/** Measured points, the law, its band and the prediction of one quantity against the chosen axis. */
function lawSeries(doc, quantity, axis, scale, measured) {
  const ivs = doc.intervals || [];
  const cur = doc.curves || null;
  const curve = cur && (cur.curves || []).find((c) => c.quantity === quantity);
  const xOfIv = (i) => (axis === 'load' ? kj(i.load_j) : hours(i.elapsed_s));
  const xm = ivs.map(xOfIv);
  const ym = ivs.map((i) => (Number.isFinite(measured(i)) ? measured(i) * scale : null));
  let xl = [];
  if (curve) xl = axis === 'load' ? (cur.load_j || []).map(kj) : cur.elapsed_s.map(hours);
  // One x array: the measured points and the curve's points, each series null where it has none.
  const n = xm.length;
  const xs = xm.concat(xl);
  const pad = (arr, before, after) => Array(before).fill(null).concat(arr, Array(after).fill(null));
  const s = (v) => (Number.isFinite(v) ? v * scale : null);
  const data = [xs, pad(ym, 0, xl.length)];
  if (curve) {
    data.push(pad(curve.value.map(s), n, 0), pad(curve.band_low.map(s), n, 0), pad(curve.band_high.map(s), n, 0));
  }
  // uPlot needs x ascending: sort every column by x.
  const order = xs.map((_, k) => k).filter((k) => Number.isFinite(xs[k])).sort((a, b) => xs[a] - xs[b]);
  return { data: data.map((col) => order.map((k) => col[k])), hasCurve: !!curve, curve };
}

function lawPlot(el, doc, { quantity, title, unit, scale, measured, axis, lawState }) {
  const { data, hasCurve } = lawSeries(doc, quantity, axis, scale, measured);
  const valid = lawState === 'valid';
  const word = valid ? '' : ` \u2014 ${STATE_WORDS[lawState] || lawState}`;
  const series = [{ label: `measured ${title}`, unit, points: 'only', color: '#1f77b4' }];
  const areas = [];
  if (hasCurve) {
    series.push(
      // The curves share the x array with the measured points: their lines span those.
      { label: `fitted law${word}`, unit, color: valid ? '#d62728' : '#888888', dash: !valid, width: 2, spanGaps: true },
      { label: `95 % band, low${word}`, unit, color: valid ? 'rgba(214,39,40,0.55)' : '#aaaaaa', dash: true, width: 1, spanGaps: true },
      { label: `95 % band, high${word}`, unit, color: valid ? 'rgba(214,39,40,0.55)' : '#aaaaaa', dash: true, width: 1, spanGaps: true },
    );
    areas.push({ upper: 4, lower: 3, fill: valid ? 'rgba(214,39,40,0.10)' : 'rgba(120,120,120,0.12)' });
  }
  chart(el, {
    title: `${title} against ${axis === 'load' ? 'the accumulated load' : 'test time'}`,
    kind: `${quantity}-vs-${axis}`,
    x: axis === 'load' ? { label: 'accumulated load', unit: 'kJ' } : { label: 'test time', unit: 'h' },
    y: { label: title, unit },
    series,
    areas,
    data,
    height: 240,
  });
  el.dataset.lawState = hasCurve ? lawState : 'none';
  el.dataset.measured = String(data[1].filter((v) => v !== null).length);
}

async function renderTest(main, ctx, id) {
  const head = h('div', { id: 'lt-head' });
  const progressEl = h('div', { id: 'lt-progress' });
  const lawEl = h('div', { id: 'lt-law' });
  const predEl = h('div', { id: 'lt-prediction' });
  const eventsEl = h('div', { id: 'lt-events' });
  const kxEl = h('div', { id: 'plot-lt-kx' });
  const k0El = h('div', { id: 'plot-lt-k0' });
  const keffEl = h('div', { id: 'plot-lt-keff' });
  const f0El = h('div', { id: 'plot-lt-f0' });
  const tableEl = h('tbody', { id: 'lt-intervals' });
  const msg = h('p', { class: 'status', id: 'lt-msg', role: 'status' });
  const axisSel = h('select', { id: 'lt-axis', 'aria-label': 'Plot against' },
    h('option', { value: 'time' }, 'test time (h)'),
    h('option', { value: 'load' }, 'accumulated load (kJ)'));
  const csvBtn = h('button', { id: 'lt-csv' }, 'Series as CSV');
  const jsonBtn = h('button', { id: 'lt-json' }, 'Series as JSON');
  const reportBtn = h('button', { id: 'lt-report', title: 'The report as an HTML file: open it and print it (A4 or Letter)', dataset: { href: `/api/v1/long-term-tests/${encodeURIComponent(id)}/report.html` } }, 'Printable report');
  const cancelBtn = h('button', { id: 'lt-cancel', class: 'danger' }, 'Cancel the test');
  const pauseBtn = h('button', { id: 'lt-pause' }, 'Pause the test');
  const resumeBtn = h('button', { id: 'lt-resume' }, 'Resume the test');
  const wavLink = h('button', { id: 'lt-last-signals' }, 'Last 10 s of signals (WAV)');
  // A button's display rule outranks the `hidden` attribute: both are set.
  const show = (el, yes) => {
    el.hidden = !yes;
    el.style.display = yes ? '' : 'none';
  };
  show(cancelBtn, false);
  show(pauseBtn, false);
  show(resumeBtn, false);
  show(wavLink, false);
  // Ambient conditions entered by hand (operator): in °C and %, stored in K.
  const ambIndex = h('input', { id: 'lt-amb-index', type: 'number', min: 0, step: 1, value: 0, 'aria-label': 'interval' });
  const ambTemp = h('input', { id: 'lt-amb-temp', type: 'number', step: 0.1, 'aria-label': 'air temperature (°C)' });
  const ambRh = h('input', { id: 'lt-amb-rh', type: 'number', step: 0.1, min: 0, max: 100, 'aria-label': 'relative humidity (%)' });
  const ambBtn = h('button', { id: 'lt-amb-save' }, 'Enter');
  const ambientForm = h('div', { class: 'toolbar', id: 'lt-ambient-form' },
    h('span', {}, 'Ambient conditions by hand: interval '), ambIndex,
    h('label', { for: 'lt-amb-temp' }, ' air temperature (\u00b0C) '), ambTemp,
    h('label', { for: 'lt-amb-rh' }, ' relative humidity (%) '), ambRh, ambBtn);
  show(ambientForm, false);

  put(
    main,
    h('section', { class: 'card' }, h('p', {}, h('a', { href: '#/long-term' }, '\u2190 all long-term tests')), head, progressEl,
      h('div', { class: 'toolbar' }, pauseBtn, resumeBtn, cancelBtn, reportBtn, csvBtn, jsonBtn, wavLink,
        h('span', { class: 'muted' }, 'A paused test stops its stimulus at its next step; its test time and load stand still. It also pauses by itself on a full disk.')),
      msg),
    h('section', { class: 'card' }, h('h2', {}, 'The fitted ageing law'), lawEl, predEl),
    h('section', { class: 'card' },
      h('div', { class: 'toolbar' }, h('h2', {}, 'The part over time'), h('label', { for: 'lt-axis' }, 'Plot against '), axisSel),
      h('div', { class: 'plot-grid two', id: 'lt-plots' }, kxEl, k0El, keffEl, f0El)),
    h('section', { class: 'card' }, h('h2', {}, 'Events'), eventsEl),
    h('section', { class: 'card' }, h('h2', {}, 'Intervals'),
      h('table', { class: 'list' },
        h('thead', {}, h('tr', {}, ['#', 'test time', 'load', 'K(0)', 'f0', 'Keff', 'Xpeak', 'air temperature', 'relative humidity', 'measurement'].map((t) => h('th', {}, t)))),
        tableEl),
      ambientForm),
  );

  let doc = null;
  let drawnKey = '';
  let timer = null;

  csvBtn.addEventListener('click', () => download(doc.series_csv, `long-term-${id}.csv`).catch((e) => (msg.textContent = String(e.message || e))));
  jsonBtn.addEventListener('click', () => {
    const series = (doc.state && doc.state.document) || null;
    const out = { test_id: id, part_serial: doc.job.part_serial, bench_id: doc.job.bench_id, accelerated: doc.accelerated, intervals: doc.intervals, events: doc.events, failure: doc.state && doc.state.failure, ageing: series };
    saveText(`long-term-${id}.json`, JSON.stringify(out, null, 2), 'application/json');
  });
  // The report is the API's page (decision 0131), saved as a file to open
  // and print: a plain link cannot send the session's token, and a tab or
  // frame made from this page would carry this page's policy, which refuses
  // the report's inline styles.
  reportBtn.addEventListener('click', () => download(reportBtn.dataset.href, `long-term-${id}-report.html`).catch((e) => {
    msg.className = 'status error';
    msg.textContent = String(e.message || e);
  }));
  wavLink.addEventListener('click', () => download(doc.last_signals, `long-term-${id}-last-signals.wav`).catch((e) => (msg.textContent = String(e.message || e))));
  cancelBtn.addEventListener('click', async () => {
    if (!(await ctx.confirm(`Cancel long-term test ${shortId(id)} of ${doc.job.part_serial}? The finished intervals stay.`, { yes: 'Yes, cancel the test', no: 'Keep running' }))) return;
    try {
      await api(`/api/v1/jobs/${encodeURIComponent(id)}/cancel`, { method: 'POST' });
      msg.textContent = 'Cancel requested: the test stops after the step it is in.';
      poll();
    } catch (e) {
      msg.textContent = String(e.message || e);
    }
  });
  ambBtn.addEventListener('click', async () => {
    const body = {};
    if (ambTemp.value !== '') body.temperature_k = Number(ambTemp.value) + 273.15;
    if (ambRh.value !== '') body.relative_humidity_percent = Number(ambRh.value);
    try {
      await api(`/api/v1/long-term-tests/${encodeURIComponent(id)}/intervals/${encodeURIComponent(ambIndex.value)}/ambient`, { method: 'PUT', body });
      msg.className = 'status';
      msg.textContent = `Ambient conditions of interval ${ambIndex.value} entered.`;
      drawnKey = '';
      poll();
    } catch (e) {
      msg.className = 'status error';
      msg.textContent = String(e.message || e);
    }
  });
  for (const [btn, what] of [[pauseBtn, 'pause'], [resumeBtn, 'resume']]) {
    btn.addEventListener('click', async () => {
      try {
        await api(`/api/v1/long-term-tests/${encodeURIComponent(id)}/${what}`, { method: 'POST' });
        msg.className = 'status';
        msg.textContent = what === 'pause' ? 'Pause requested: the test stops its stimulus at its next step.' : 'Resume requested.';
        poll();
      } catch (e) {
        msg.className = 'status error';
        msg.textContent = String(e.message || e);
      }
    });
  }
  axisSel.addEventListener('change', () => {
    drawnKey = '';
    drawAll();
  });

  function drawHead() {
    const j = doc.job;
    const req = j.request || {};
    const stim = req.stimulus || {};
    put(head,
      h('h1', {}, 'Long-term test ', h('span', { class: 'mono' }, shortId(j.id)), ' ', badge(j.state)),
      h('table', { class: 'kv' },
        doc.station_id ? h('tr', {}, h('th', {}, 'station'), h('td', { id: 'lt-station' }, doc.station_id, h('span', { class: 'muted' }, ` \u2014 the station\u2019s copy of ${when(doc.copy_received_at)}, read only`))) : null,
        h('tr', {}, h('th', {}, 'part'), h('td', { class: 'serial', id: 'lt-part' }, j.part_serial)),
        h('tr', {}, h('th', {}, 'bench'), h('td', {}, j.bench_id, doc.accelerated ? h('span', { class: 'muted', id: 'lt-accelerated' }, ' \u2014 accelerated: the stimulus applied faster than real time on the virtual bench; each measurement simulated in full') : null)),
        h('tr', {}, h('th', {}, 'test'), h('td', {}, `${num((req.duration_s || 0) / 3600, 4)} h, a measurement every ${num((req.interval_s || 0) / 60, 4)} min`)),
        h('tr', {}, h('th', {}, 'stimulus'), h('td', { id: 'lt-stimulus' }, `${stimulusText(stim)}${Number.isFinite(stim.on_s) ? `, ${num(stim.on_s, 4)} s on / ${num(stim.off_s, 4)} s off` : ''}`,
          (stim.steps || []).length ? h('span', { id: 'lt-steps' }, `; level steps: ${stim.steps.map(st => `${num((stim.kind && stim.kind !== 'sine' ? st.excursion_rms_m : st.excursion_m) * 1000, 3)} mm${stim.kind && stim.kind !== 'sine' ? ' RMS' : ''} from ${num(hours(st.from_s), 4)} h`).join(', ')}`) : null)),
        j.problem ? h('tr', {}, h('th', {}, 'stopped'), h('td', { class: 'error', id: 'lt-problem' }, j.problem.detail || j.problem.title)) : null));
    const running = !TERMINAL.includes(j.state);
    const st = doc.state || {};
    const paused = j.step && j.step.startsWith('paused');
    put(progressEl,
      h('progress', { class: 'job-progress', id: 'lt-progress-bar', max: 1, value: j.progress || 0 }),
      h('p', { id: 'lt-progress-text' },
        `${doc.intervals.length} of ${doc.intervals_planned} intervals, test time ${num(hours(Math.min(st.clock_s || 0, req.duration_s || Infinity)), 4)} h of ${num(hours(req.duration_s || 0), 4)} h (${num(100 * (j.progress || 0), 3)} %)`,
        running ? ` \u2014 time left ${dur(j.eta_s)}${doc.accelerated ? ' (at the pace so far)' : ''}` : '',
        paused ? h('strong', { class: 'error', id: 'lt-paused' }, ` ${j.step}`) : null));
    const station = !daemon.center;
    show(cancelBtn, running && station && ctx.can('operator'));
    show(pauseBtn, running && station && !doc.user_pause && ctx.can('operator'));
    show(resumeBtn, running && station && !!doc.user_pause && ctx.can('operator'));
    show(wavLink, !!doc.last_signals);
    show(ambientForm, station && doc.intervals.length > 0 && ctx.can('operator'));
    // At the fleet's center (decision 0134) the report is the station's page:
    // not offered; the signals' bytes stay at the station: the button says where.
    show(reportBtn, station);
    if (doc.station_id) {
      wavLink.disabled = true;
      wavLink.textContent = `Last 10 s of signals: at station ${doc.station_id}`;
    }
  }

  function drawLaw() {
    const d = doc.state && doc.state.document;
    if (!d || !d.law) {
      put(lawEl, h('p', { class: 'muted', id: 'lt-no-law' }, d && d.problem ? `No law yet: ${d.problem}.` : 'No law yet: the first interval is not finished.'));
      put(predEl);
      return;
    }
    const l = d.law;
    const byLoad = l.axis === 'load_j';
    const rows = [
      ['K\u221e (aged, the law\u2019s limit)', withSe(l.k_inf_n_per_m.value, l.k_inf_n_per_m.se, 'N/mm', 1e-3)],
      ['break-in loss \u0394K_b', withSe(l.break_in_k_n_per_m.value, l.break_in_k_n_per_m.se, 'N/mm', 1e-3)],
      byLoad ? ['break-in load scale E_b', withSe(l.break_in_load_j.value, l.break_in_load_j.se, 'kJ', 1e-3)] : null,
      ['break-in time scale', withSe(l.break_in_time_s.value, l.break_in_time_s.se, 'h', 1 / 3600)],
      ['fatigue loss \u0394K_f', withSe(l.fatigue_k_n_per_m.value, l.fatigue_k_n_per_m.se, 'N/mm', 1e-3)],
      byLoad ? ['fatigue load scale E_f', withSe(l.fatigue_load_j.value, l.fatigue_load_j.se, 'kJ', 1e-3)] : null,
      ['fatigue time scale', withSe(l.fatigue_time_s.value, l.fatigue_time_s.se, 'h', 1 / 3600)],
      ['scatter about the law', `${num(l.residual_sd_n_per_m / 1000, 3)} N/mm (${l.intervals_used} intervals)`],
    ].filter(Boolean);
    const c = d.characteristics;
    put(lawEl,
      h('p', {}, `K(0) = K\u221e + \u0394K_b e^(\u2212E/E_b) + \u0394K_f e^(\u2212E/E_f), fitted against ${byLoad ? 'the accumulated load E' : 'test time (the load unknown)'}. State: `,
        stated(l.validity.state === 'valid' ? 'valid' : '', l.validity, { id: 'lt-law-state' })),
      h('table', { class: 'kv', id: 'lt-law-table', dataset: { state: l.validity.state } },
        rows.map(([k, v]) => h('tr', {}, h('th', {}, k), h('td', { class: l.validity.state === 'valid' ? '' : 'muted' }, v)))),
      c ? h('p', { id: 'lt-characteristics' },
        `Break-in ${num(c.break_in_loss_percent, 3)} % of the new part\u2019s K(0) (${num(100 * c.break_in_share, 3)} % of the whole loss), 95 % of it done after ${num(hours(c.break_in_95_time_s), 3)} h; fatigue ${num(c.fatigue_loss_percent, 3)} %, at ${num(c.fatigue_rate_percent_per_h, 3)} %/h after break-in${Number.isFinite(c.mean_power_w) ? `; the stimulus\u2019 mean load power ${num(c.mean_power_w, 4)} W` : ''}.`) : null,
      d.large_excursion ? h('p', { id: 'lt-large-excursion', class: d.large_excursion.below_2_percent ? '' : 'error' }, d.large_excursion.statement) : null);
    const p = d.prediction;
    if (!p) {
      put(predEl);
      return;
    }
    put(predEl,
      h('h2', {}, `Prediction at ${num(hours(p.elapsed_s), 4)} h${Number.isFinite(p.load_j) ? ` (${num(kj(p.load_j), 4)} kJ)` : ''}`),
      h('table', { class: 'kv', id: 'lt-prediction-table', dataset: { state: p.validity.state } },
        h('tr', {}, h('th', {}, 'K(0)'), h('td', {}, stated(withSe(p.k0_n_per_m, p.k0_se_n_per_m, 'N/mm', 1e-3), p.validity, { id: 'lt-pred-k0' }))),
        h('tr', {}, h('th', {}, '95 % band of a measurement then'), h('td', { id: 'lt-pred-band' }, `${num(p.k0_band_n_per_m[0] / 1000, 4)} \u2026 ${num(p.k0_band_n_per_m[1] / 1000, 4)} N/mm`)),
        h('tr', {}, h('th', {}, 'f0'), h('td', {}, withSe(p.f0_hz, p.f0_se_hz, 'Hz'))),
        h('tr', {}, h('th', {}, 'state'), h('td', {}, stateText(p.validity)))));
  }

  function drawPlots() {
    const d = (doc.state && doc.state.document) || null;
    const axis = axisSel.value;
    const byLoad = !d || !d.law || d.law.axis === 'load_j';
    axisSel.querySelector('option[value="load"]').disabled = !byLoad;
    if (!d || !d.intervals.length) {
      for (const el of [kxEl, k0El, keffEl, f0El]) put(el, h('p', { class: 'muted' }, 'No interval measured yet.'));
      return;
    }
    const fam = kxFamily(d);
    const t0 = fam.times[0];
    const t1 = fam.times[fam.times.length - 1];
    chart(kxEl, {
      title: 'K(x) over time (each over its valid range)',
      kind: 'K(x) family',
      x: { label: 'displacement x', unit: 'mm' },
      y: { label: 'K(x)', unit: 'N/mm' },
      series: fam.ys.map((_, k) => ({ label: `${num(hours(fam.times[k]), 3)} h`, unit: 'N/mm', color: ramp(t1 > t0 ? (fam.times[k] - t0) / (t1 - t0) : 0) })),
      data: [fam.xs, ...fam.ys],
      height: 240,
    });
    kxEl.dataset.curves = String(fam.ys.length);
    const lawState = d.law ? d.law.validity.state : 'none';
    lawPlot(k0El, d, { quantity: 'k0_n_per_m', title: 'K(0) small-signal', unit: 'N/mm', scale: 1e-3, measured: (i) => i.k0_n_per_m, axis, lawState });
    lawPlot(keffEl, d, { quantity: 'keff_n_per_m', title: 'Keff at Xpeak', unit: 'N/mm', scale: 1e-3, measured: (i) => i.keff_n_per_m, axis, lawState });
    lawPlot(f0El, d, { quantity: 'f0_hz', title: 'f0 small-signal', unit: 'Hz', scale: 1, measured: (i) => i.f0_hz, axis, lawState });
  }

  function drawEvents() {
    const ev = doc.events || [];
    if (!ev.length) {
      put(eventsEl, h('p', { class: 'muted', id: 'lt-no-events' }, 'No pause, resumption or failure.'));
      return;
    }
    put(eventsEl, h('table', { class: 'list' },
      h('thead', {}, h('tr', {}, ['test time', 'event', 'what', 'when'].map((t) => h('th', {}, t)))),
      h('tbody', { id: 'lt-event-rows' }, ev.map((e) => h('tr', { dataset: { kind: e.kind }, class: e.kind === 'failure' || e.kind === 'stopped' ? 'error' : '' },
        h('td', {}, Number.isFinite(e.elapsed_s) ? `${num(hours(e.elapsed_s), 4)} h` : '\u2013'),
        h('td', { class: 'lt-event-kind' }, e.kind, e.cause ? ` (${e.cause === 'user' ? 'user' : 'disk full'})` : ''),
        h('td', {}, e.detail),
        h('td', {}, when(e.at)))))));
  }

  function drawTable() {
    const d = (doc.state && doc.state.document) || { intervals: [] };
    put(tableEl, doc.intervals.map((iv, k) => {
      const v = d.intervals[k] || {};
      const vs = v.validity || {};
      return h('tr', { dataset: { index: iv.index } },
        h('td', {}, iv.index),
        h('td', {}, `${num(hours(iv.elapsed_s), 4)} h`),
        h('td', {}, `${num(kj(iv.load_j), 4)} kJ`),
        // Each value with its measurement's own state (an unreliable K(0) reads so here too).
        h('td', { class: 'lt-k0' }, stated(withSe(v.k0_n_per_m, v.k0_se_n_per_m, 'N/mm', 1e-3), vs.k0_n_per_m)),
        h('td', { class: 'lt-f0' }, Number.isFinite(v.f0_hz) ? stated(`${num(v.f0_hz, 4)} Hz`, vs.f0_hz) : '\u2013'),
        h('td', { class: 'lt-keff' }, Number.isFinite(v.keff_n_per_m) ? stated(`${num(mm(v.keff_n_per_m), 4)} N/mm`, vs.keff_n_per_m) : '\u2013'),
        h('td', {}, Number.isFinite(v.xpeak_m) ? `${num(v.xpeak_m * 1000, 4)} mm` : '\u2013'),
        h('td', { class: 'lt-temp', dataset: { k: Number.isFinite(iv.temperature_k) ? String(iv.temperature_k) : '' } },
          Number.isFinite(iv.temperature_k) ? `${(iv.temperature_k - 273.15).toFixed(1)} \u00b0C${iv.temperature_source === 'hand' ? ' (by hand)' : ''}` : '\u2013'),
        h('td', { class: 'lt-rh', dataset: { percent: Number.isFinite(iv.relative_humidity_percent) ? String(iv.relative_humidity_percent) : '' } },
          Number.isFinite(iv.relative_humidity_percent) ? `${iv.relative_humidity_percent.toFixed(1)} %${iv.humidity_source === 'hand' ? ' (by hand)' : ''}` : '\u2013'),
        h('td', {}, h('a', { href: `#/measurement/${encodeURIComponent(iv.measurement_id)}`, class: 'mono' }, shortId(iv.measurement_id))));
    }));
  }

  function drawAll() {
    drawHead();
    const ambient = doc.intervals.map((i) => `${i.temperature_k}/${i.relative_humidity_percent}`).join(',');
    const key = `${doc.intervals.length}|${doc.job.state}|${axisSel.value}|${(doc.events || []).length}|${ambient}|${!!doc.user_pause}`;
    if (key === drawnKey) return;
    drawnKey = key;
    drawLaw();
    drawPlots();
    drawEvents();
    drawTable();
    main.dataset.intervals = String(doc.intervals.length);
  }

  async function poll() {
    clearTimeout(timer);
    try {
      doc = await api(`/api/v1/long-term-tests/${encodeURIComponent(id)}`);
      if (ctx.stale()) return;
      drawAll();
      if (!TERMINAL.includes(doc.job.state)) timer = setTimeout(poll, POLL_MS);
    } catch (e) {
      if (ctx.stale()) return;
      // The first read failing is the page's error (app.js shows it); later ones retry.
      if (!doc) throw e;
      msg.className = 'status error';
      msg.textContent = String(e.message || e);
      timer = setTimeout(poll, POLL_MS);
    }
  }
  await poll();
  return () => clearTimeout(timer);
}

