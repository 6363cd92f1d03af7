// QC views: recipes (#/qc), one recipe (#/qc/NAME): its parameters and
// limits, versions, limit proposals from golden units (propose: operator;
// approve / reject: admin), and SPC per parameter (capability figures and an
// individuals chart with the specification and control limits).

import { api, download, ApiError, daemon } from './api.js';
import { h, put, num, when, shortId, siq, limitsText, displayUnit } from './util.js';
import { chart } from './plots.js';

/** A limit or value in its display unit (N/m as N/mm, "1" as none). */
function lim(v, unit) {
  return siq(v, unit, 5);
}

/** The unit of a recipe parameter's limits (docs/qc.md, "quantity"). */
const UNITS = { k0: 'N/m', keff: 'N/m', k_at_x: 'N/m', f0: 'Hz', q: '1', r: 'N s/m', k_asymmetry: '1', model_error: '%' };
function unitOf(p) {
  if (p.unit) return p.unit;
  if (p.quantity === 'effect_size') return p.effect_parameter && p.effect_parameter.endsWith('_n') ? 'N' : '';
  return UNITS[p.quantity] || '';
}

function paramLabel(p) {
  const x = p.x_m !== undefined && p.x_m !== null ? ` at x = ${num(p.x_m * 1e3, 3)} mm` : '';
  return `${p.name}${x}`;
}

export async function render(main, ctx) {
  if (ctx.arg) return renderRecipe(main, ctx, ctx.arg);
  const list = await api('/api/v1/recipes');
  if (ctx.stale()) return;
  const items = list.items || [];
  put(
    main,
    h('section', { class: 'card', id: 'recipes' },
      h('h1', {}, 'QC recipes'),
      items.length
        ? h('table', { class: 'list' },
            h('thead', {}, h('tr', {}, h('th', {}, 'recipe'), h('th', {}, 'part kind'), h('th', {}, 'version'), h('th', {}, 'SHA-256'), h('th', {}, 'parameters'), h('th', {}, 'limits'), h('th', {}, 'created'))),
            h('tbody', {}, items.map((r) => {
              const rec = r.recipe || {};
              const ps = rec.parameters || [];
              const limited = ps.filter((p) => p.lower !== null && p.lower !== undefined || p.upper !== null && p.upper !== undefined).length;
              return h('tr', { dataset: { recipe: r.name } },
                h('td', {}, h('a', { href: `#/qc/${encodeURIComponent(r.name)}` }, r.name)),
                h('td', {}, rec.part_kind || '\u2013'),
                h('td', {}, String(r.version)),
                h('td', { class: 'mono' }, String(r.sha256 || '').slice(0, 12)),
                h('td', {}, String(ps.length)),
                h('td', {}, limited ? `${limited} of ${ps.length}` : h('span', { class: 'badge state-queued' }, 'none yet')),
                h('td', {}, when(r.created_at)),
              );
            })))
        : h('p', { class: 'muted', id: 'no-recipes' }, 'No recipe yet. An admin creates one with POST /api/v1/recipes (see the README\u2019s QC walk-through).'),
    ),
  );
}

async function renderRecipe(main, ctx, name) {
  const r = await api(`/api/v1/recipes/${encodeURIComponent(name)}`);
  if (ctx.stale()) return;
  const rec = r.recipe || {};
  const params = rec.parameters || [];
  const versions = await api(`/api/v1/recipes/${encodeURIComponent(name)}/versions`).catch(() => ({ items: [] }));
  // Limit proposals, gauge studies and bench calibrations are a station's.
  const proposals = daemon.center ? null : await api(`/api/v1/recipes/${encodeURIComponent(name)}/limit-proposals`).catch(() => ({ items: [] }));
  if (ctx.stale()) return;

  const spcEl = h('section', { class: 'card', id: 'spc' });
  const propEl = h('section', { class: 'card', id: 'proposals' });
  const gaugeEl = h('section', { class: 'card', id: 'gauge' });

  put(
    main,
    h('div', { class: 'qc' },
      h('section', { class: 'card', id: 'recipe' },
        h('h1', {}, `Recipe ${r.name}`, h('span', { class: 'muted' }, `  version ${r.version}, SHA-256 ${String(r.sha256 || '').slice(0, 16)}\u2026`)),
        h('p', { class: 'muted' }, `part kind ${rec.part_kind || '\u2013'}; levels ${((rec.procedure || {}).levels_m || []).map((x) => `${num(x * 1e3, 3)} mm`).join(', ') || '\u2013'}`),
        h('table', { class: 'list', id: 'recipe-params' },
          h('thead', {}, h('tr', {}, h('th', {}, 'parameter'), h('th', {}, 'quantity'), h('th', {}, 'lower'), h('th', {}, 'upper'))),
          h('tbody', {}, params.map((p) => h('tr', {},
            h('td', {}, paramLabel(p)),
            h('td', {}, p.quantity),
            h('td', {}, lim(p.lower, unitOf(p))),
            h('td', {}, lim(p.upper, unitOf(p))),
          )))),
        rec.kx_mask ? h('p', { class: 'muted' }, `K(x) mask: ${(rec.kx_mask.x_m || []).length} points over ${num(rec.kx_mask.x_m[0] * 1e3, 3)} \u2026 ${num(rec.kx_mask.x_m[rec.kx_mask.x_m.length - 1] * 1e3, 3)} mm`) : null,
        h('details', {}, h('summary', {}, `${(versions.items || []).length} versions`),
          h('ul', {}, (versions.items || []).map((v) => h('li', {}, `version ${v.version} (${String(v.sha256 || '').slice(0, 12)}), ${when(v.created_at)}`)))),
      ),
      propEl,
      spcEl,
      gaugeEl,
    ),
  );
  drawSpc(spcEl, ctx, name, params);
  if (daemon.center) {
    const why = 'Limit proposals from golden units, gauge studies and bench calibrations are made on a station (its benches and parts); the fleet\u2019s center receives the approved recipe versions and every station\u2019s verdicts.';
    put(propEl, h('h2', {}, 'Limit proposals and gauge studies'), h('p', { class: 'muted', id: 'center-station-only' }, why));
    gaugeEl.remove();
    return;
  }
  drawProposals(propEl, ctx, name, proposals.items || []);
  drawGauge(gaugeEl, ctx, name, params);
}

// Gauge studies (issue 21): the newest studies of this recipe, each with its
// figures per judged parameter once every run has ended (docs/qc.md, "Gauge
// study"). Read only: a study is started with POST /api/v1/gauge-studies.
const ACCEPTANCE = {
  acceptable: ['acceptable (< 10 %)', 'verdict-pass'],
  conditionally_acceptable: ['conditionally acceptable (10\u201330 %)', 'state-interrupted'],
  not_acceptable: ['not acceptable (> 30 %)', 'verdict-fail'],
  not_applicable: ['not applicable (mean beyond the limit)', 'state-interrupted'],
};

/**
 * The unit a study's figures are shown in (issue 35): all of one quantity's
 * figures in one unit, chosen so that its GRR reads without an exponent
 * (a stiffness's EV of 0.0115 N/m, not 1.1464e-5 N/mm), 3 significant digits.
 */
function gaugeUnit(qd) {
  const { unit, scale } = displayUnit(qd.unit);
  const big = Math.max(...[qd.ev_sd, qd.av_sd, qd.grr_sd, qd.pv_sd].filter(Number.isFinite).map(Math.abs), 0);
  if (qd.unit === 'N/m' && big * scale < 0.1) return { unit: 'N/m', scale: 1 };
  return { unit, scale };
}
function gq(v, gu) {
  if (v === null || v === undefined || !Number.isFinite(v)) return '\u2013';
  const x = v * gu.scale;
  const t = x === 0 ? '0' : Math.abs(x) >= 1e-3 && Math.abs(x) < 1e6 ? Number(x.toPrecision(3)).toString() : x.toExponential(2);
  return `${t}${gu.unit ? ` ${gu.unit}` : ''}`;
}

async function drawGauge(el, ctx, name, params) {
  const head = [
    h('h2', {}, 'Gauge studies (measurement-system analysis)'),
    h('p', { class: 'muted', id: 'gauge-legend' },
      'AIAG MSA, ANOVA: EV repeatability (same bench), AV reproducibility (between benches), GRR = \u221a(EV\u00b2 + AV\u00b2), PV part variation, as standard deviations. ',
      '%GRR = 100 \u00b7 6 GRR / tolerance (upper \u2212 lower limit); with one limit, as AIAG judges a one-sided characteristic, 100 \u00b7 3 GRR / distance from the mean to the limit (not applicable with the mean beyond it); of the total variation when the parameter has no limits: ',
      h('b', {}, '< 10 % acceptable, 10\u201330 % conditionally acceptable, > 30 % not acceptable'),
      '. ndc (number of distinct categories) = \u230a1.41 PV / GRR\u230b: at least 5 wanted.'),
  ];
  let list;
  try {
    list = await api('/api/v1/gauge-studies');
  } catch (e) {
    put(el, ...head, h('p', { class: 'error' }, `Gauge studies not available: ${e.message}`));
    return;
  }
  if (ctx.stale()) return;
  // Bench calibrations from golden units (decision 0049): the one in effect per bench and procedure.
  const cals = await api(`/api/v1/recipes/${encodeURIComponent(name)}/bench-calibrations`).catch(() => ({ items: [] }));
  if (ctx.stale()) return;
  const seen = new Set();
  const key = (c) => `${c.bench_id}/${c.procedure}`;
  const current = (cals.items || []).filter((c) => !seen.has(key(c)) && seen.add(key(c)));
  // After the studies: the legend above explains the studies' table, not this one.
  const calBlock = [h('h3', {}, 'Bench calibrations'), current.length
    ? h('table', { class: 'list bench-cal-table' },
      h('thead', {}, h('tr', {}, h('th', {}, 'bench'), h('th', {}, 'procedure'), h('th', {}, 'state'), h('th', {}, 'reference bench'),
        h('th', { title: 'laser sensitivity error e: the bench reads (1 + e) x' }, 'laser'),
        h('th', { title: 'extra clamp mass dm: k0 reads m / (m + dm) times' }, 'clamp mass'),
        h('th', {}, 'golden units'), h('th', {}, 'calibrated'))),
      h('tbody', {}, current.map((c) => {
        const k = c.calibration || {};
        const out = c.state !== 'in_calibration';
        return h('tr', { dataset: { bench: c.bench_id, procedure: c.procedure, state: c.state } },
          h('td', {}, c.bench_id),
          h('td', {}, c.procedure),
          h('td', { title: (k.problems || []).join('; ') }, h('span', { class: `badge ${out ? 'verdict-fail' : 'verdict-pass'}` },
            out ? 'out of calibration: measurements invalid' : 'in calibration: judged corrected')),
          h('td', {}, k.reference_bench_id || '\u2013'),
          h('td', {}, Number.isFinite(k.laser_gain_error) ? `${num(100 * k.laser_gain_error, 3)} %` : '\u2013'),
          h('td', {}, Number.isFinite(k.clamp_mass_kg) ? `${num(1e3 * k.clamp_mass_kg, 3)} g` : '\u2013'),
          h('td', {}, String((k.units || []).length)),
          h('td', {}, when(c.created_at)));
      })))
    : h('p', { class: 'muted', id: 'no-bench-cal' }, 'No bench calibration: every bench is judged as measured (POST /api/v1/recipes/NAME/bench-calibrations; docs/qc.md, \u201cBench calibration\u201d).')];
  const mine = (list.items || []).filter((s) => s.recipe === name).slice(0, 5);
  if (!mine.length) {
    put(el, ...head, h('p', { class: 'muted', id: 'no-gauge' }, 'No gauge study of this recipe yet (POST /api/v1/gauge-studies; docs/qc.md, \u201cGauge study\u201d).'), ...calBlock);
    return;
  }
  const docs = await Promise.all(mine.map((s) => api(`/api/v1/gauge-studies/${s.id}`).catch((e) => ({ id: s.id, error: e.message }))));
  if (ctx.stale()) return;
  const label = (qname) => {
    const p = params.find((x) => x.name === qname);
    return p ? paramLabel(p) : qname;
  };
  const pct = (v) => (v === null || v === undefined || !Number.isFinite(v) ? '\u2013' : `${num(v, 3)} %`);
  const studies = docs.map((g) => {
    if (g.error) return h('p', { class: 'error' }, `Study ${shortId(g.id)}: ${g.error}`);
    const procedure = (g.job && g.job.procedure) || 'as the recipe says';
    const title = h('h3', {}, `Study ${shortId(g.id)} `,
      h('span', { class: `badge state-${g.state === 'done' ? 'succeeded' : 'running'}` }, g.state === 'done' ? 'done' : `running: ${g.runs_finished} of ${g.runs_total} runs`),
      h('span', { class: 'muted' }, `  ${(g.parts || []).length} parts \u00d7 ${g.repeats} repeats \u00d7 ${(g.benches || []).length} benches (${(g.benches || []).join(', ')}); procedure ${procedure}; recipe version ${g.recipe_version ?? '\u2013'}; ${when(g.created_at)}`));
    if (g.state !== 'done') return h('div', { class: 'gauge-study', dataset: { study: g.id, state: g.state } }, title);
    const rows = (g.quantities || []).map((q) => {
      const [text, cls] = ACCEPTANCE[q.acceptance] || [q.acceptance, ''];
      const gu = gaugeUnit(q);
      const side = q.limits === 'upper' ? '\u2264' : '\u2265';
      const one = q.limits === 'upper' || q.limits === 'lower';
      const tol = one
        ? `one-sided ${side} ${gq(q.one_sided_limit, gu)}${Number.isFinite(q.limit_distance) ? `; mean ${gq(q.limit_distance, gu)} inside` : ''}`
        : q.tolerance === null || q.tolerance === undefined ? 'no limits' : gq(q.tolerance, gu);
      const grrTol = one
        ? (q.acceptance === 'not_applicable' ? 'not applicable' : `${pct(q.grr_percent_of_limit_distance)} of the distance to the limit`)
        : pct(q.grr_percent_of_tolerance);
      return h('tr', { dataset: { quantity: q.quantity, acceptance: q.acceptance, limits: q.limits || '' } },
        h('td', {}, label(q.quantity)),
        h('td', {}, gq(q.ev_sd, gu)),
        h('td', {}, gq(q.av_sd, gu)),
        h('td', {}, gq(q.grr_sd, gu)),
        h('td', {}, gq(q.pv_sd, gu)),
        h('td', { class: 'grr-limits' }, tol),
        h('td', { class: 'grr-tol' }, grrTol),
        h('td', {}, pct(q.grr_percent_of_total)),
        h('td', { class: 'ndc' }, q.ndc === null || q.ndc === undefined ? '\u2013 (GRR 0)' : String(q.ndc)),
        h('td', {}, h('span', { class: `badge ${cls}` }, text)));
    });
    return h('div', { class: 'gauge-study', dataset: { study: g.id, state: g.state } }, title,
      h('table', { class: 'list gauge-table' },
        h('thead', {}, h('tr', {},
          h('th', {}, 'parameter'), h('th', { title: 'repeatability: same part, same bench (1 \u03c3)' }, 'EV'),
          h('th', { title: 'reproducibility: between benches (1 \u03c3)' }, 'AV'), h('th', {}, 'GRR'),
          h('th', { title: 'part-to-part variation (1 \u03c3)' }, 'PV'), h('th', {}, 'tolerance'),
          h('th', {}, '%GRR of tolerance (or limit distance)'), h('th', {}, '%GRR of total'), h('th', {}, 'ndc'), h('th', {}, 'AIAG'))),
        h('tbody', {}, rows)),
      (() => {
        // Each warning once (the same part count applies to every quantity).
        const ws = [...new Set((g.quantities || []).flatMap((q) => q.warnings || []))];
        return ws.length ? h('ul', { class: 'gauge-warnings flag', id: `gauge-warnings-${g.id}` }, ws.map((w) => h('li', {}, w))) : null;
      })(),
      (g.not_computed || []).length
        ? h('ul', { class: 'error' }, g.not_computed.map((n) => h('li', {}, `${label(n.parameter)}: not computed, ${n.reason}`)))
        : null);
  });
  put(el, ...head, ...studies, ...calBlock);
}

function drawProposals(el, ctx, name, items) {
  const msg = h('p', { id: 'proposal-msg', role: 'status' });
  const rows = items.map((p) => {
    const pr = p.proposal || {};
    const decide = ctx.can('admin') && p.state === 'proposed'
      ? h('span', {},
          h('button', {
            class: 'primary', id: `approve-${p.id}`,
            onclick: async () => {
              const ok = await ctx.confirm(`Approve the limits of proposal ${shortId(p.id)} (${(pr.serials || []).length} golden units)? A new recipe version judges every later part with them.`, { yes: 'Yes, approve', no: 'Back' });
              if (!ok) return;
              try {
                const v = await api(`/api/v1/limit-proposals/${p.id}/approve`, { method: 'POST', body: {} });
                msg.className = 'ok';
                msg.textContent = `Approved: recipe ${name} version ${v.version}.`;
                location.hash = `#/qc/${encodeURIComponent(name)}?approved=${v.version}`;
              } catch (e) {
                msg.className = 'error';
                msg.textContent = `Not approved: ${e.message}`;
              }
            },
          }, 'Approve'),
          ' ',
          h('button', {
            class: 'danger', id: `reject-${p.id}`,
            onclick: async () => {
              if (!(await ctx.confirm(`Reject proposal ${shortId(p.id)}?`, { yes: 'Yes, reject', no: 'Back' }))) return;
              try {
                await api(`/api/v1/limit-proposals/${p.id}/reject`, { method: 'POST', body: {} });
                location.hash = `#/qc/${encodeURIComponent(name)}?rejected=${p.id}`;
              } catch (e) {
                msg.className = 'error';
                msg.textContent = `Not rejected: ${e.message}`;
              }
            },
          }, 'Reject'))
      : null;
    return h('div', { class: 'proposal', dataset: { proposal: p.id, state: p.state } },
      h('h3', {}, `Proposal ${shortId(p.id)} `, h('span', { class: `badge proposal-${p.state}` }, p.state),
        h('span', { class: 'muted' }, `  by ${p.created_by || 'open access'}, ${when(p.created_at)}`),
        p.decided_at ? h('span', { class: 'muted' }, `; ${p.state} by ${p.decided_by || 'open access'}, ${when(p.decided_at)}${p.approved_version ? ` (version ${p.approved_version})` : ''}`) : null),
      h('p', { class: 'muted' }, `golden units: ${(pr.serials || []).join(', ')}; spread ${spreadText(pr.options)}`),
      h('table', { class: 'list' },
        h('thead', {}, h('tr', {}, h('th', {}, 'parameter'), h('th', {}, 'n'), h('th', {}, 'mean'), h('th', {}, 'sigma'), h('th', {}, 'lower'), h('th', {}, 'upper'))),
        h('tbody', {}, (pr.parameters || []).map((l) => h('tr', {},
          h('td', {}, l.name), h('td', {}, String(l.n)), h('td', {}, lim(l.mean, l.unit)), h('td', {}, lim(l.sigma, l.unit)),
          h('td', {}, lim(l.lower, l.unit)), h('td', {}, lim(l.upper, l.unit)))))),
      decide,
    );
  });
  let form = null;
  if (ctx.can('operator')) {
    const serials = h('input', { id: 'golden-serials', required: true, placeholder: 'G-01, G-02, G-03, G-04, G-05', size: 48 });
    const k = h('input', { id: 'golden-k', type: 'number', min: '0.5', max: '10', step: '0.5', value: '3', required: true });
    form = h('form', { id: 'propose-form', class: 'form-grid' },
      h('label', { for: 'golden-serials' }, 'Golden units (serials, at least 5)'), serials,
      h('label', { for: 'golden-k' }, 'Limits: mean \u00b1 k \u03c3, k ='), k,
      h('button', { type: 'submit', id: 'propose' }, 'Propose limits'));
    form.addEventListener('submit', async (ev) => {
      ev.preventDefault();
      const list = serials.value.split(/[\s,;]+/).filter(Boolean);
      try {
        const p = await api(`/api/v1/recipes/${encodeURIComponent(name)}/limit-proposals`, { method: 'POST', body: { serials: list, method: 'k_sigma', k: Number(k.value) } });
        location.hash = `#/qc/${encodeURIComponent(name)}?proposed=${p.id}`;
      } catch (e) {
        msg.className = 'error';
        msg.textContent = e instanceof ApiError ? `Not proposed: ${e.message}` : `Not proposed: ${e}`;
      }
    });
  }
  put(el, h('h2', {}, 'Limits from golden units'), form, msg,
    rows.length ? rows : h('p', { class: 'muted' }, 'No proposal yet.'),
    ctx.can('admin') ? null : h('p', { class: 'muted' }, 'Approving limits needs an admin token.'));
}

function spreadText(o) {
  if (!o) return '\u2013';
  if (o.method === 'k_sigma') return `mean \u00b1 ${o.k} \u03c3`;
  if (o.method === 'tolerance') return `mean \u00b1 ${o.tolerance_percent} %`;
  return JSON.stringify(o);
}

function drawSpc(el, ctx, name, params) {
  if (!params.length) {
    put(el, h('h2', {}, 'SPC'), h('p', { class: 'muted' }, 'The recipe judges no parameter.'));
    return;
  }
  const sel = h('select', { id: 'spc-parameter' }, params.map((p) => h('option', { value: p.name }, paramLabel(p))));
  const last = h('input', { id: 'spc-last', type: 'number', min: '2', max: daemon.center ? '10000' : '100000', value: '100' });
  const stats = h('table', { class: 'kv', id: 'spc-stats' });
  const plot = h('div', { id: 'spc-plot' });
  const note = h('p', { class: 'muted', id: 'spc-note' });
  const csv = h('button', { id: 'spc-csv', class: 'link' }, 'download CSV');
  const perStation = h('div', { id: 'spc-stations' });
  const want = ctx.params.get('parameter');
  if (want) sel.value = want;
  async function load() {
    const path = `/api/v1/recipes/${encodeURIComponent(name)}/spc?parameter=${encodeURIComponent(sel.value)}&last=${Number(last.value) || 100}`;
    csv.onclick = () => download(`${path}&format=csv`, `spc-${name}-${sel.value}.csv`);
    let s;
    try {
      s = await api(path);
    } catch (e) {
      put(stats);
      plot.replaceChildren();
      note.textContent = `No SPC: ${e.message}`;
      return;
    }
    if (ctx.stale()) return;
    const u = s.unit || '';
    const du = displayUnit(u);
    const row = (k, v) => h('tr', {}, h('th', {}, k), h('td', {}, v));
    put(stats,
      row('n (valid measurements)', String(s.n)),
      row('mean', lim(s.mean, u)),
      row('\u03c3 overall (Pp, Ppk)', lim(s.sigma, u)),
      row('\u03c3 within (Cp, Cpk)', lim(s.sigma_within, u)),
      row('specification', limitsText(s.lower, s.upper, u)),
      row('Cp / Cpk', `${num(s.cp, 3)} / ${num(s.cpk, 3)}`),
      row('Pp / Ppk', `${num(s.pp, 3)} / ${num(s.ppk, 3)}`),
      row('yield', s.yield_fraction === null || s.yield_fraction === undefined ? '\u2013' : `${num(100 * s.yield_fraction, 4)} % (${s.passed} pass, ${s.failed} fail; ${s.invalid} invalid not counted)`),
    );
    // Verdicts this version could not read are out of every figure above: say so beside them.
    stats.dataset.unreadable = String(s.unreadable_verdicts || 0);
    if (s.unreadable_verdicts) {
      stats.append(h('tr', { id: 'spc-unreadable' }, h('th', { class: 'error' }, 'left out'), h('td', { class: 'error' }, (s.warnings || []).join(' ') || `${s.unreadable_verdicts} verdicts unreadable`)));
    }
    // Out-of-control signals (Western Electric rules 1-4 on the individuals chart).
    const rules = s.rules || [];
    const ruleText = { 1: 'beyond 3σ', 2: '2 of 3 beyond 2σ', 3: '4 of 5 beyond 1σ', 4: '8 on one side' };
    stats.append(h('tr', { id: 'spc-rules', dataset: { n: String(rules.length) } },
      h('th', { class: rules.length ? 'error' : '' }, 'out of control (Western Electric)'),
      h('td', { class: rules.length ? 'error' : '' }, rules.length
        ? rules.map((r) => `rule ${r.rule} (${ruleText[r.rule] || ''}, ${r.side}) at ${(s.points[r.index] || {}).part_serial || `#${r.index + 1}`}`).join('; ')
        : 'none')));
    stats.append(h('tr', {}, h('th', {}, 'counted'), h('td', { id: 'spc-purpose' }, s.purpose === 'all' ? 'every pool' : `${s.purpose || 'production'} parts only`)));
    stats.dataset.cpk = s.cpk === null || s.cpk === undefined ? '' : String(s.cpk);
    if (daemon.center) drawStations(perStation, name, sel.value, Number(last.value) || 100, u);
    stats.dataset.n = String(s.n);
    const pts = s.points || [];
    // A time axis (issue 35): hours since the window's first point, so that
    // gaps and shifts show; the recipe version changes are named.
    const t0 = pts.length ? Date.parse(pts[0].time) : 0;
    // The axis unit follows the window's span: a shift's few minutes read
    // as minutes, not as 5e-5 h (seen at 1280x800, issue 35).
    const spanMs = pts.length ? Date.parse(pts[pts.length - 1].time) - t0 : 0;
    const tu = spanMs >= 2 * 3.6e6 ? { name: 'hours', unit: 'h', ms: 3.6e6 }
      : spanMs >= 2 * 6e4 ? { name: 'minutes', unit: 'min', ms: 6e4 } : { name: 'seconds', unit: 's', ms: 1e3 };
    const changes = pts.filter((p, i) => i > 0 && p.recipe_version !== pts[i - 1].recipe_version)
      .map((p) => `version ${p.recipe_version} from ${p.part_serial} (${new Date(Date.parse(p.time)).toLocaleString()})`);
    note.textContent = pts.length < 2 ? 'The chart needs at least two valid measurements.'
      : `Individuals chart of the last ${pts.length} valid measurements (x: ${tu.name} since ${new Date(t0).toLocaleString()}; hover for the part).`
        + (changes.length ? ` Recipe version changes: ${changes.join('; ')}.` : ` One recipe version${pts[0].recipe_version ? ` (${pts[0].recipe_version})` : ''}.`);
    note.dataset.versionChanges = String(changes.length);
    if (pts.length < 1) {
      plot.replaceChildren();
      return;
    }
    const xs = pts.map((p) => (Date.parse(p.time) - t0) / tu.ms);
    const sc = (v) => (v === null || v === undefined ? null : v * du.scale);
    const flat = (v) => xs.map(() => sc(v));
    const su = du.unit;
    const series = [
      { label: `${s.parameter}`, unit: su, points: true },
      { label: 'lower spec', unit: su, color: '#d62728', dash: true },
      { label: 'upper spec', unit: su, color: '#d62728', dash: true },
      { label: 'centre line', unit: su, color: '#2ca02c' },
      { label: 'LCL', unit: su, color: '#9467bd', dash: true },
      { label: 'UCL', unit: su, color: '#9467bd', dash: true },
    ];
    chart(plot, {
      title: `${s.parameter}: individuals chart`,
      kind: 'SPC',
      x: { label: 'time since the first point', unit: tu.unit },
      y: { label: s.parameter, unit: su },
      series,
      data: [xs, pts.map((p) => sc(p.value)), flat(s.lower), flat(s.upper), flat(s.center_line), flat(s.lcl), flat(s.ucl)],
      height: 280,
    });
  }
  sel.addEventListener('change', load);
  last.addEventListener('change', load);
  put(el, h('h2', {}, 'SPC'),
    h('div', { class: 'form-grid' }, h('label', { for: 'spc-parameter' }, 'Parameter'), sel, h('label', { for: 'spc-last' }, 'Last N measurements'), last),
    stats, perStation, note, plot, csv);
  load();
}

/** At the fleet's center: the same window with each station as a subgroup (Cpk per line). */
async function drawStations(el, name, parameter, last, u) {
  let f;
  try {
    f = await api(`/api/v1/fleet/recipes/${encodeURIComponent(name)}/spc?parameter=${encodeURIComponent(parameter)}&last=${last}`);
  } catch (e) {
    put(el, h('p', { class: 'error' }, `SPC per station: ${e.message}`));
    return;
  }
  put(el, h('h3', {}, 'Per station (the same window; each station a subgroup)'), h('table', { class: 'list', id: 'spc-per-station' },
    h('thead', {}, h('tr', {}, h('th', {}, 'station'), h('th', {}, 'n'), h('th', {}, 'mean'), h('th', {}, '\u03c3 within'), h('th', {}, 'Cpk'), h('th', {}, 'Ppk'), h('th', {}, 'pass / fail / invalid'))),
    h('tbody', {}, (f.stations || []).map((g) => h('tr', { dataset: { station: g.station_id || '', n: String(g.spc.n), cpk: g.spc.cpk === null || g.spc.cpk === undefined ? '' : String(g.spc.cpk) } },
      h('td', { class: 'station' }, g.station_id || '\u2013'),
      h('td', {}, String(g.spc.n)),
      h('td', {}, lim(g.spc.mean, u)),
      h('td', {}, lim(g.spc.sigma_within, u)),
      h('td', {}, num(g.spc.cpk, 3)),
      h('td', {}, num(g.spc.ppk, 3)),
      h('td', {}, `${g.spc.passed} / ${g.spc.failed} / ${g.spc.invalid}`))))));
}
