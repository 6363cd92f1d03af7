// Operator view (a 1280x800 station screen): benches with the current job,
// step, progress and time left; live displacement and microphone signal;
// the submit form (serial field focused, Enter submits: a barcode scanner
// types the serial and Enter; the recipe choice is kept per station); cancel
// with a confirmation; the verdict panel of the part on the bench (while a
// part runs it shows that part, never the previous verdict); the queue and
// the recent jobs with their verdicts.

import { api, events, ApiError, Unreachable } from './api.js';
import { h, put, q, dur, when, shortId, pick, VERDICT_WORDS, validityOf, stated } from './util.js';
import { rankReasons, reasonText, failureText } from './verdict.js';
import { chart } from './plots.js';
import { studyKind, promptText, KIND_TEXT } from './studies.js';

const STEPS = {
  pre_measurement: 'pre-measurement',
  resonance_search: 'resonance search',
  narrow_sweep: 'narrow sweep',
  fit: 'fit',
  // A study of the part's memory (issue 33): the operator's step, the second run.
  awaiting_operator: 'waiting for the operator',
  added_mass: 'measuring with the added mass',
};
const FINISHED = ['succeeded', 'failed', 'cancelled', 'interrupted'];

/** Time left, or nothing while a study waits for the operator (its time is the operator's: no "0 s left"). */
function etaText(step, eta) {
  if (step === 'awaiting_operator') return 'until you confirm';
  return eta !== null && eta !== undefined ? `${dur(eta)} left` : '';
}

// Where the station keeps its choices (this browser is the station).
const STATION_KEY = 'springbench.station';

function stationGet() {
  try {
    return JSON.parse(localStorage.getItem(STATION_KEY) || '{}') || {};
  } catch {
    return {};
  }
}

function stationSet(k, v) {
  const s = stationGet();
  s[k] = v;
  try {
    localStorage.setItem(STATION_KEY, JSON.stringify(s));
  } catch {
    /* private mode: the choice lasts for this page only */
  }
}

const LIVE_POINTS = 3000;

function randomKey() {
  const b = new Uint8Array(12);
  crypto.getRandomValues(b);
  return Array.from(b, (x) => x.toString(16).padStart(2, '0')).join('');
}

export async function render(main, ctx) {
  const benchesEl = h('div', { id: 'benches', class: 'benches' });
  const liveEl = h('div', { id: 'live-plot' });
  const liveNote = h('p', { class: 'muted', id: 'live-note' }, 'Live signals appear here during a sweep.');
  // One verdict panel per bench, each tied to the part on its bench (issue
  // 35): two benches finishing out of order both keep their verdict. With
  // one bench the panel's ids are the plain ones (#verdict, #verdict-big...);
  // with several, each id ends in the bench's (#verdict-virtual-2...).
  const verdictsEl = h('div', { id: 'verdicts', class: 'verdicts' });
  // Shift counters (issue 35): the parts judged since the shift began
  // (shifts start at 06:00, 14:00 and 22:00 local time).
  const shiftEl = h('section', { id: 'shift', class: 'card shift' }, h('span', { class: 'muted' }, 'shift: counting\u2026'));
  function shiftStart(now = new Date()) {
    const t = new Date(now);
    const hr = now.getHours();
    const start = hr >= 22 ? 22 : hr >= 14 ? 14 : hr >= 6 ? 6 : -2;
    t.setHours(start, 0, 0, 0); // -2: 22:00 of the day before
    return t;
  }
  async function drawShift() {
    const since = shiftStart();
    let l;
    try {
      l = await api(`/api/v1/jobs?since=${encodeURIComponent(since.toISOString())}&limit=500`);
    } catch {
      return;
    }
    // Production parts only (a job stored before purposes is production).
    const production = (j) => ((j.request && j.request.purpose) || 'production') === 'production';
    const judged = (l.items || []).filter((j) => FINISHED.includes(j.state) && j.verdict && j.verdict !== 'no_limits' && production(j));
    const n = (v) => judged.filter((j) => j.verdict === v).length;
    const [pass, fail, invalid] = [n('pass'), n('fail'), n('invalid')];
    const tested = judged.length;
    const more = l.next_cursor ? '+' : '';
    const c = (id, label, v, cls = '') => h('span', { class: `count ${cls}`, id: `shift-${id}`, dataset: { n: String(v) } }, h('b', {}, `${v}${more}`), ` ${label}`);
    put(shiftEl,
      h('span', { class: 'muted' }, `shift since ${String(since.getHours()).padStart(2, '0')}:00 `),
      c('tested', 'tested', tested), c('pass', 'pass', pass, 'ok'), c('fail', 'fail', fail, 'error'), c('invalid', 'invalid', invalid, 'flag'),
      h('span', { class: 'count', id: 'shift-yield' }, h('b', {}, tested ? `${(100 * pass / tested).toFixed(1)} %` : '\u2013'), ' yield (pass of tested)'));
  }
  const panels = new Map(); // bench id -> { el, id(name), verdictFor }
  function panelOf(benchId) {
    let p = panels.get(benchId);
    if (p) return p;
    const single = () => benches.length <= 1;
    const tag = single() ? '' : `-${benchId}`;
    p = {
      bench: benchId,
      id: (name) => `${name}${tag}`,
      verdictFor: null,
      el: h('section', { id: `verdict${tag}`, class: 'verdict none', dataset: { bench: benchId } },
        h('div', { class: 'verdict-bench' }, `bench ${benchId}`),
        h('p', {}, 'No part measured on this bench yet.')),
    };
    panels.set(benchId, p);
    return p;
  }
  function drawPanels() {
    const want = benches.map((b) => b.id);
    const have = [...panels.keys()];
    if (want.join(',') !== have.join(',')) {
      // The ids depend on the number of benches: made afresh when it changes.
      panels.clear();
      for (const b of want) panelOf(b);
      verdictsEl.className = `verdicts n${Math.min(want.length, 4)}`;
      put(verdictsEl, [...panels.values()].map((p) => p.el));
    }
  }
  const queueEl = h('tbody', { id: 'queue' });
  const recentEl = h('tbody', { id: 'recent' });
  const formMsg = h('p', { id: 'submit-msg', role: 'status' });
  const wsState = h('span', { id: 'ws-state', class: 'muted' }, 'connecting\u2026');

  let benches = [];
  const jobs = new Map(); // id -> job (the ones on screen)
  const progressSeen = new Map(); // job id -> number of progress updates shown

  // --- submit form -----------------------------------------------------------
  let form = null;
  let idemKey = randomKey();
  let recipesReady = Promise.resolve();
  if (ctx.can('operator')) {
    const serial = h('input', {
      id: 'serial',
      name: 'serial',
      required: true,
      autocomplete: 'off',
      spellcheck: 'false',
      pattern: '[A-Za-z0-9][A-Za-z0-9._\\-]{0,63}',
      title: '1-64 characters: letters, digits, - _ . (starting with a letter or digit)',
      placeholder: 'scan or type',
    });
    const kind = h(
      'select',
      { id: 'kind', name: 'kind' },
      ['spider', 'surround', 'cone', 'passive_radiator', 'other'].map((k) => h('option', { value: k }, k.replace('_', ' '))),
    );
    const level = h('input', { id: 'level-mm', name: 'level', type: 'number', min: '0.1', max: '15', step: '0.1', value: '8', required: true });
    const benchSel = h('select', { id: 'bench', name: 'bench' });
    const recipeSel = h('select', { id: 'recipe', name: 'recipe' }, h('option', { value: '' }, 'none (level below)'));
    // Why the part is measured (issue 35, decision 0100): SPC, yield and the
    // shift counters count production only. Not kept across reloads: a
    // golden-unit choice left over must not take the next shift's parts.
    const purposeSel = h('select', { id: 'purpose', name: 'purpose' },
      [['production', 'production'], ['golden_unit', 'golden unit'], ['bench_calibration', 'bench calibration'], ['repeat', 're-test'], ['engineering', 'engineering / R&D']]
        .map(([v, t]) => h('option', { value: v }, t)));
    const recipeKinds = new Map();
    const saved = stationGet();
    if (saved.kind) kind.value = saved.kind;
    const applyRecipe = () => {
      level.disabled = !!recipeSel.value;
      // A recipe names the part kind; the form shows it and sends none of its own.
      const rk = recipeKinds.get(recipeSel.value);
      kind.disabled = !!(recipeSel.value && rk);
      if (recipeSel.value && rk) kind.value = rk;
    };
    // Submitting waits for the list when a recipe was chosen at this station:
    // a scanner's first part must not go out without it.
    recipesReady = api('/api/v1/recipes')
      .then((l) => {
        for (const r of l.items || []) {
          recipeKinds.set(r.name, r.recipe && r.recipe.part_kind);
          recipeSel.append(h('option', { value: r.name }, `${r.name} (v${r.version})`));
        }
        if (saved.recipe && recipeKinds.has(saved.recipe)) recipeSel.value = saved.recipe;
        else if (saved.recipe) {
          formMsg.className = 'error';
          formMsg.textContent = `The recipe '${saved.recipe}' chosen at this station no longer exists: choose one.`;
        }
        applyRecipe();
      })
      .catch(() => {});
    recipeSel.addEventListener('change', () => {
      stationSet('recipe', recipeSel.value);
      applyRecipe();
    });
    kind.addEventListener('change', () => stationSet('kind', kind.value));
    form = h(
      'form',
      { id: 'submit-form', class: 'card submit', autocomplete: 'off' },
      h('h2', {}, 'Measure a part'),
      h('div', { class: 'form-grid' },
        h('label', { for: 'serial' }, 'Serial'), serial,
        h('label', { for: 'kind' }, 'Part kind'), kind,
        h('label', { for: 'recipe' }, 'QC recipe'), recipeSel,
        h('label', { for: 'purpose' }, 'Purpose'), purposeSel,
        h('label', { for: 'level-mm' }, 'Target Xpeak (mm)'), level,
        h('label', { for: 'bench' }, 'Bench'), benchSel,
      ),
      h('button', { type: 'submit', id: 'submit', class: 'primary big' }, 'Measure (Enter)'),
      formMsg,
    );
    serial.addEventListener('input', () => {
      idemKey = randomKey();
    });
    form.addEventListener('submit', async (ev) => {
      ev.preventDefault();
      const s = serial.value.trim();
      await recipesReady;
      const mm = Number(level.value);
      const body = { part: { serial: s } };
      // A recipe sets the levels and the part kind (and is judged by); otherwise the form's.
      if (recipeSel.value) body.recipe = recipeSel.value;
      else body.target_xpeak_m = mm / 1000;
      // Without a recipe the daemon's default is engineering; production then means nothing.
      if (recipeSel.value || purposeSel.value !== 'production') body.purpose = purposeSel.value;
      if (!kind.disabled) body.part.kind = kind.value;
      if (benchSel.value) body.bench = benchSel.value;
      formMsg.className = '';
      formMsg.textContent = 'Submitting\u2026';
      try {
        const j = await api('/api/v1/jobs', { method: 'POST', body, headers: { 'Idempotency-Key': idemKey } });
        formMsg.className = 'ok';
        formMsg.textContent = `Queued: ${s} as job ${shortId(j.id)}.`;
        jobs.set(j.id, j);
        serial.value = '';
        idemKey = randomKey();
        refresh();
      } catch (e) {
        formMsg.className = 'error';
        formMsg.textContent = e instanceof ApiError ? `Not queued: ${e.message}` : `Not queued: ${e.message}`;
      }
      serial.focus();
    });
  }

  put(
    main,
    h('div', { class: 'operator' },
      h('div', { class: 'col-left' },
        h('section', { class: 'card' }, h('h2', {}, 'Benches ', wsState), benchesEl),
        h('section', { class: 'card' }, h('h2', {}, 'Live signals'), liveNote, liveEl),
        h('section', { class: 'card' }, h('h2', {}, 'Queue'),
          h('table', { class: 'list' }, h('thead', {}, h('tr', {}, h('th', {}, 'job'), h('th', {}, 'part'), h('th', {}, 'bench'), h('th', {}, 'queued'), h('th', {}, ''))), queueEl)),
      ),
      h('div', { class: 'col-right' },
        form || h('section', { class: 'card', id: 'no-submit' }, h('p', { class: 'muted' }, `Your role (${ctx.role}) can watch the benches but not start or cancel jobs.`)),
        shiftEl,
        verdictsEl,
        h('section', { class: 'card' }, h('h2', {}, 'Recent jobs'),
          h('table', { class: 'list' }, h('thead', {}, h('tr', {}, h('th', {}, 'job'), h('th', {}, 'part'), h('th', {}, 'bench'), h('th', {}, 'outcome'), h('th', {}, 'finished'))), recentEl)),
      ),
    ),
  );
  if (form) form.querySelector('#serial').focus();

  // --- benches ---------------------------------------------------------------
  function cancelButton(j) {
    if (!ctx.can('operator') || FINISHED.includes(j.state)) return null;
    return h('button', {
      class: 'danger',
      id: `cancel-${j.id}`,
      onclick: async () => {
        const ok = await ctx.confirm(`Cancel job ${shortId(j.id)} of part ${j.part_serial}? A running sweep is ramped down; the part is not measured.`);
        if (!ok) return;
        try {
          await api(`/api/v1/jobs/${j.id}/cancel`, { method: 'POST', body: {} });
          if (formMsg) {
            formMsg.className = 'ok';
            formMsg.textContent = `Cancel requested for job ${shortId(j.id)}.`;
          }
        } catch (e) {
          if (formMsg) {
            formMsg.className = 'error';
            formMsg.textContent = `Not cancelled: ${e.message}`;
          }
        }
        refresh();
      },
    }, 'Cancel\u2026');
  }

  function benchCard(b) {
    const j = b.job_id ? jobs.get(b.job_id) : null;
    const stateName = b.state;
    const card = h('div', { class: `bench state-${stateName}`, id: `bench-${b.id}`, dataset: { state: stateName } },
      h('div', { class: 'bench-head' }, h('strong', {}, b.id), h('span', { class: `badge state-${stateName}` }, stateName.toUpperCase())),
    );
    if (j) {
      const prog = h('progress', { max: '1', value: String(j.progress || 0), class: 'job-progress', id: `progress-${b.id}` });
      prog.dataset.updates = String(progressSeen.get(j.id) || 0);
      card.append(
        h('div', { class: 'bench-job' },
          h('span', {}, 'part ', h('strong', { class: 'serial' }, j.part_serial)),
          h('span', { class: 'muted' }, ` job ${shortId(j.id)}`)),
        h('div', { class: 'bench-step' },
          // A study reports no step while it measures: not "waiting" then.
          h('span', { class: 'step', id: `step-${b.id}` }, STEPS[j.step] || j.step || (studyKind(j) ? 'measuring' : 'waiting')),
          h('span', { class: 'pct', id: `pct-${b.id}` }, `${Math.round(100 * (j.progress || 0))} %`),
          h('span', { class: 'eta', id: `eta-${b.id}` }, etaText(j.step, j.eta_s))),
        prog,
        // A study's own page: its prompt, confirm and result (decision 0142).
        studyKind(j) ? h('a', { href: `#/study/${encodeURIComponent(j.id)}`, id: `study-link-${b.id}`, class: 'button' }, j.step === 'awaiting_operator' ? 'Add the mass: open the study to confirm' : `open the ${KIND_TEXT[studyKind(j)]}`) : null,
        cancelButton(j),
      );
    } else if (stateName === 'idle') {
      card.append(h('div', { class: 'muted' }, `ready; mounted preset ${b.preset || '\u2013'}`));
    } else if (stateName === 'faulted' || stateName === 'stopped') {
      // The fault is an object (detail, since, job): its words, not "[object Object]".
      const f = b.fault || {};
      card.append(
        h('div', { class: 'error bench-fault', id: `fault-${b.id}` },
          h('strong', {}, 'Faulted: '), f.detail || 'the bench is not available: see the daemon log.',
          f.since ? h('span', { class: 'muted' }, ` (since ${when(f.since)})`) : null),
        h('p', { class: 'muted' }, 'It takes no part until a self-check passes.'),
        ctx.can('operator') && b.kind !== 'virtual'
          ? h('button', {
            id: `self-check-${b.id}`,
            onclick: async () => {
              try {
                await api(`/api/v1/benches/${b.id}/self-check`, { method: 'POST', body: {} });
                if (formMsg) {
                  formMsg.className = 'ok';
                  formMsg.textContent = `Self-check of ${b.id} queued.`;
                }
              } catch (e) {
                if (formMsg) {
                  formMsg.className = 'error';
                  formMsg.textContent = `Self-check not started: ${e.message}`;
                }
              }
              refresh();
            },
          }, 'Run the self-check')
          : h('p', { class: 'muted', id: `self-check-${b.id}` }, b.kind === 'virtual' ? 'Self-check: a virtual bench has no devices; the engineer clears the fault.' : 'Self-check: an operator runs it.'),
      );
    }
    return card;
  }

  function drawBenches() {
    put(benchesEl, benches.length ? benches.map(benchCard) : h('p', { class: 'muted' }, 'No bench configured.'));
    const sel = form && form.querySelector('#bench');
    // A faulted bench cannot be chosen (the daemon refuses it too).
    const sig = benches.map((b) => `${b.id}:${b.state === 'faulted'}`).join(',');
    if (sel && sel.dataset.sig !== sig) {
      const keep = sel.value;
      sel.dataset.sig = sig;
      put(sel, benches.map((b) => h('option', { value: b.id, disabled: b.state === 'faulted' }, b.state === 'faulted' ? `${b.id} (faulted)` : b.id)));
      const usable = benches.filter((b) => b.state !== 'faulted');
      sel.value = usable.some((b) => b.id === keep) ? keep : usable.length ? usable[0].id : '';
      const btn = form.querySelector('#submit');
      if (btn) btn.disabled = !usable.length;
    }
  }

  function updateProgress(jobId, data) {
    const j = jobs.get(jobId);
    if (j) {
      j.step = data.step;
      j.progress = data.progress;
      j.eta_s = data.eta_s;
    }
    progressSeen.set(jobId, (progressSeen.get(jobId) || 0) + 1);
    const vp = [...panels.values()].find((p) => p.el.dataset.verdict === 'running' && p.el.dataset.job === jobId);
    if (vp) {
      const st = document.getElementById(vp.id('verdict-step'));
      const pc = document.getElementById(vp.id('verdict-pct'));
      if (st) st.textContent = STEPS[data.step] || data.step;
      if (pc) pc.textContent = `${Math.round(100 * data.progress)} %`;
    }
    const b = benches.find((x) => x.job_id === jobId);
    if (!b) return;
    const prog = document.getElementById(`progress-${b.id}`);
    if (!prog) return;
    prog.value = data.progress;
    prog.dataset.updates = String(progressSeen.get(jobId));
    document.getElementById(`step-${b.id}`).textContent = STEPS[data.step] || data.step;
    document.getElementById(`pct-${b.id}`).textContent = `${Math.round(100 * data.progress)} %`;
    document.getElementById(`eta-${b.id}`).textContent = etaText(data.step, data.eta_s);
  }

  // --- lists and verdict -----------------------------------------------------
  function outcomeBadge(j) {
    if (j.verdict) return h('span', { class: `badge verdict-${j.verdict}` }, VERDICT_WORDS[j.verdict] || j.verdict);
    if (j.state === 'succeeded') return h('span', { class: 'badge state-succeeded' }, 'measured');
    return h('span', { class: `badge state-${j.state}` }, j.state === 'failed' ? 'not measured' : j.state);
  }

  function jobRow(j, finished) {
    const link = studyKind(j)
      ? h('a', { href: `#/study/${encodeURIComponent(j.id)}`, title: KIND_TEXT[studyKind(j)] }, `${shortId(j.id)} (study)`)
      : j.measurement_ids && j.measurement_ids.length ? h('a', { href: `#/measurement/${j.measurement_ids[0]}` }, shortId(j.id)) : shortId(j.id);
    return h('tr', { dataset: { job: j.id, state: j.state, verdict: j.verdict || '' } },
      h('td', {}, link),
      h('td', {}, j.part_serial),
      finished ? h('td', {}, j.bench_id) : null,
      finished ? h('td', {}, outcomeBadge(j)) : h('td', {}, j.bench_id),
      h('td', {}, when(finished ? j.finished_at || j.created_at : j.created_at)),
      finished ? null : h('td', {}, cancelButton(j)),
    );
  }

  // One line per failing value as shown: the repeats of a job that read the
  // same (at the shown precision) are one line with their count, not the
  // same line twice (seen at 1280x800, issue 35).
  const failingLines = (failures) => {
    const lines = new Map();
    for (const f of failures || []) {
      const t = failureText(f);
      const l = lines.get(t);
      if (l) l.n += 1;
      else lines.set(t, { f, n: 1 });
    }
    return [...lines.entries()].map(([t, { f, n }]) => h('li', { dataset: { name: f.name } }, n > 1 ? `${t} (${n} repeats)` : t));
  };

  // Full screen never takes the scanner's keys (issue 35): the button takes
  // no focus (a scan's Enter would press it and leave full screen), the
  // serial field gets the focus back, and a key typed anywhere else on the
  // page goes to the serial field, Enter submitting it.
  const serialField = () => form && form.querySelector('#serial');
  const refocus = () => {
    const f = serialField();
    if (f) f.focus();
  };
  const fullBtn = (vp) =>
    document.fullscreenEnabled
      ? h('button', {
        class: 'link verdict-full',
        id: vp.id('verdict-full'),
        type: 'button',
        tabindex: '-1',
        title: 'Full screen (Esc leaves; the scanner keeps working)',
        onmousedown: (e) => e.preventDefault(),
        onclick: () => (document.fullscreenElement ? document.exitFullscreen() : vp.el.requestFullscreen()).catch(() => {}).finally(refocus),
      }, 'full screen')
      : null;
  if (form) {
    const onKey = (e) => {
      if (!document.body.contains(form)) {
        document.removeEventListener('keydown', onKey, true);
        return;
      }
      const t = e.target;
      const f = serialField();
      if (!f || t === f || (t && t.closest && t.closest('input, select, textarea, dialog'))) return;
      if (e.ctrlKey || e.metaKey || e.altKey) return;
      if (e.key === 'Enter') {
        // A scan ends with Enter: submit what was scanned, press nothing else.
        e.preventDefault();
        e.stopPropagation();
        if (f.value.trim()) form.requestSubmit();
      } else if (e.key.length === 1) {
        e.preventDefault();
        f.value += e.key;
        f.dispatchEvent(new Event('input'));
        f.focus();
      }
    };
    document.addEventListener('keydown', onKey, true);
    document.addEventListener('fullscreenchange', refocus);
  }

  /** The verdict panel shows the part on the bench: a running job, else the last finished. */
  async function drawVerdict(vp, j) {
    const verdictEl = vp.el;
    // A study's panel also changes with its step (the operator's prompt).
    const key = j ? `${j.id}:${j.state}${studyKind(j) ? `:${j.step}` : ''}` : '';
    if (!j || vp.verdictFor === key) return;
    vp.verdictFor = key;
    const head = (cls, big, ...sub) => {
      verdictEl.className = `verdict ${cls}`;
      verdictEl.dataset.verdict = cls;
      verdictEl.dataset.job = j.id;
      verdictEl.dataset.serial = j.part_serial;
      return [
        h('div', { class: 'verdict-top' }, h('div', { class: 'verdict-big', id: vp.id('verdict-big') }, big), h('span', { class: 'verdict-bench' }, benches.length > 1 ? `bench ${vp.bench}` : ''), fullBtn(vp)),
        h('div', { class: 'verdict-part' }, h('span', { class: 'verdict-serial', id: vp.id('verdict-serial') }, j.part_serial)),
        h('div', { class: 'verdict-when' }, `job ${shortId(j.id)}${j.finished_at ? `, ${when(j.finished_at)}` : ''}`),
        sub,
      ];
    };
    const sk = studyKind(j);
    if (sk) {
      // A study judges no part: its page has the prompt and the result.
      const link = h('a', { href: `#/study/${encodeURIComponent(j.id)}`, id: vp.id('open-study') }, 'open the study');
      if (!FINISHED.includes(j.state) && j.step === 'awaiting_operator') {
        put(verdictEl, head('running', 'ADD THE MASS', h('p', { class: 'verdict-why', id: vp.id('verdict-prompt') }, promptText(j)), link));
      } else if (!FINISHED.includes(j.state)) {
        put(verdictEl, head('running', 'STUDYING\u2026', h('p', { class: 'verdict-step' }, `${KIND_TEXT[sk]}: `, h('span', { id: vp.id('verdict-step') }, STEPS[j.step] || j.step || 'measuring')), link));
      } else {
        put(verdictEl, head(j.state === 'succeeded' ? 'measured' : 'not-measured', j.state === 'succeeded' ? 'STUDY DONE' : 'NO RESULT',
          h('p', { class: 'verdict-why' }, `${KIND_TEXT[sk]} ${j.state}${j.problem && j.problem.detail ? `: ${j.problem.detail}` : ''}. No QC verdict: a study judges no part.`), link));
      }
      return;
    }
    if (!FINISHED.includes(j.state)) {
      const pct = Math.round(100 * (j.progress || 0));
      put(verdictEl, head('running', 'MEASURING\u2026',
        h('p', { class: 'verdict-step' }, h('span', { id: vp.id('verdict-step') }, STEPS[j.step] || j.step || 'starting'), ' ', h('span', { id: vp.id('verdict-pct') }, `${pct} %`)),
        h('p', { class: 'verdict-why' }, 'The verdict appears here when this part is done.')));
      return;
    }
    // A job run under a recipe has a verdict whatever its state (a failed job is `invalid`).
    // Only a job run under a recipe has one (asking for the others would be a 404).
    let v = null;
    if (j.request && j.request.recipe) {
      try {
        v = await api(`/api/v1/jobs/${j.id}/verdict`);
      } catch {
        v = null;
      }
    }
    if (vp.verdictFor !== `${j.id}:${j.state}`) return;
    const mid = j.measurement_ids && j.measurement_ids[0];
    const openLink = mid ? h('a', { href: `#/measurement/${mid}`, id: vp.id('open-result') }, 'open the result') : null;
    if (v && v.verdict) {
      const d = v.detail || {};
      const recipe = h('p', { class: 'verdict-recipe', id: vp.id('verdict-recipe') }, `recipe ${v.recipe_name} version ${v.recipe_version} (${String(v.recipe_sha256 || '').slice(0, 12)})`);
      if (v.verdict === 'pass') {
        put(verdictEl, head('pass', 'PASS', recipe, openLink));
      } else if (v.verdict === 'fail') {
        put(verdictEl, head('fail', 'FAIL',
          h('ul', { class: 'failing', id: vp.id('failing') }, failingLines(d.failures)),
          recipe, openLink));
      } else if (v.verdict === 'invalid') {
        const [first, ...rest] = rankReasons(d.invalid_reasons);
        const t = first ? reasonText(first.code) : { title: 'The measurement cannot be trusted', action: 'Call the engineer.' };
        put(verdictEl, head('invalid', 'INVALID',
          h('div', { class: 'invalid-primary', id: vp.id('invalid-primary'), dataset: { code: first ? first.code : '' } },
            h('p', { class: 'invalid-title' }, t.title),
            first ? h('p', { class: 'invalid-detail' }, first.detail) : null,
            h('p', { class: 'invalid-action', id: vp.id('invalid-action') }, t.action)),
          rest.length
            ? h('details', { class: 'invalid-more', id: vp.id('invalid-more') },
              h('summary', {}, `${rest.length} consequence${rest.length === 1 ? '' : 's'} of this (not judged)`),
              h('ul', { id: vp.id('invalid-reasons') }, rest.map((r) => h('li', { dataset: { code: r.code } }, `${reasonText(r.code).title}: ${r.detail}`))))
            : null,
          recipe, openLink));
      } else {
        put(verdictEl, head('measured', 'NO LIMITS', h('p', { class: 'verdict-why' }, 'Measured under the recipe, which has no approved limits yet (golden units).'), recipe, openLink));
      }
      return;
    }
    if (j.state !== 'succeeded') {
      const why = pick(j, 'problem.detail', 'problem.title') || j.state;
      put(verdictEl, head('not-measured', 'NOT MEASURED', h('p', { class: 'verdict-why' }, `${j.state}: ${why}`, h('br'), 'The part was not judged: measure it again.')));
      return;
    }
    let m = null;
    try {
      m = mid ? await api(`/api/v1/measurements/${mid}`) : null;
    } catch {
      m = null;
    }
    if (vp.verdictFor !== `${j.id}:${j.state}`) return;
    const ls = (m && m.large_signal) || {};
    const figures = h('table', { class: 'kv' },
      h('tr', {}, h('th', {}, 'Keff at Xpeak'), h('td', {}, stated(q(ls.keff_n_per_m, 'N/mm', 1e-3), validityOf(m, 'large_signal.keff_n_per_m'), { unit: 'N/mm', scale: 1e-3, raw: ls.keff_n_per_m }))),
      h('tr', {}, h('th', {}, 'Xpeak'), h('td', {}, q(ls.xpeak_m, 'mm', 1e3))),
      h('tr', {}, h('th', {}, 'resonance'), h('td', {}, stated(q(ls.resonance_hz, 'Hz'), validityOf(m, 'large_signal.resonance_hz'), { unit: 'Hz', raw: ls.resonance_hz }))),
    );
    if (m && m.measurement && m.measurement.analysis_error) {
      put(verdictEl, head('not-measured', 'NO RESULT', h('p', { class: 'verdict-why' }, `analysis failed: ${m.measurement.analysis_error}`)));
      return;
    }
    put(verdictEl, head('measured', 'MEASURED', h('p', { class: 'verdict-why' }, 'No QC verdict: the job named no recipe.'), figures, openLink));
  }

  let refreshing = false;
  let again = false;
  // A job as read by a refresh. Its answer can be older than a progress
  // event the websocket delivered meanwhile: a running job's progress then
  // stays at the newer (larger) value instead of jumping back.
  function keepJob(j) {
    const seen = jobs.get(j.id);
    if (seen && seen.state === j.state && j.state === 'running' && (seen.progress || 0) > (j.progress || 0)) {
      j.progress = seen.progress;
      j.step = seen.step;
      j.eta_s = seen.eta_s;
    }
    jobs.set(j.id, j);
  }

  async function refresh() {
    if (refreshing) {
      again = true;
      return;
    }
    refreshing = true;
    try {
      const [bs, recent, queued] = await Promise.all([
        api('/api/v1/benches'),
        api('/api/v1/jobs?limit=12'),
        api('/api/v1/jobs?state=queued&limit=50'),
      ]);
      if (ctx.stale()) return;
      benches = bs.items || [];
      for (const j of [...recent.items, ...queued.items]) keepJob(j);
      const running = benches.filter((b) => b.job_id && !jobs.has(b.job_id));
      for (const b of running) {
        try {
          keepJob(await api(`/api/v1/jobs/${b.job_id}`));
        } catch {
          /* finished meanwhile: the next refresh shows it */
        }
      }
      drawBenches();
      put(queueEl, queued.items.length ? queued.items.slice().reverse().map((j) => jobRow(j, false)) : h('tr', {}, h('td', { colspan: '5', class: 'muted' }, 'empty')));
      // Newest finished first (two benches finish out of the order they started in).
      const fin = recent.items.filter((j) => FINISHED.includes(j.state))
        .sort((a, b) => String(b.finished_at || '').localeCompare(String(a.finished_at || '')));
      put(recentEl, fin.length ? fin.map((j) => jobRow(j, true)) : h('tr', {}, h('td', { colspan: '5', class: 'muted' }, 'none yet')));
      drawPanels();
      drawShift();
      // Each bench's panel shows the part on that bench: its running job, or
      // else its newest finished one (by the time it finished). Never back to
      // an older part: a list read before the shown part finished would
      // otherwise bring the previous verdict back for a moment.
      const finishedAt = (j) => String(j.finished_at || '');
      const startedAt = (j) => String(j.started_at || j.created_at || '');
      for (const b of benches) {
        const vp = panelOf(b.id);
        const mine = [...jobs.values()].filter((j) => j.bench_id === b.id);
        const last = mine.filter((j) => FINISHED.includes(j.state)).sort((a, c) => finishedAt(c).localeCompare(finishedAt(a)))[0];
        const cur = b.job_id && jobs.get(b.job_id);
        const onBench = cur && !FINISHED.includes(cur.state) ? cur : null;
        const runningIsNewer = onBench && (!last || startedAt(onBench) >= finishedAt(last));
        let show = runningIsNewer ? onBench : last;
        const shown = vp.el.dataset.job && jobs.get(vp.el.dataset.job);
        if (shown && show && shown.id !== show.id && String(shown.created_at) > String(show.created_at)) show = shown;
        drawVerdict(vp, show);
      }
    } catch (e) {
      // Unreachable: keep what is shown (the banner says it may be out of date).
      if (!ctx.stale() && !(e instanceof Unreachable)) put(benchesEl, h('p', { class: 'error' }, `Cannot read the benches: ${e.message}`));
    } finally {
      refreshing = false;
      if (again) {
        again = false;
        refresh();
      }
    }
  }

  // --- live signals ----------------------------------------------------------
  const live = { t: [], x: [], p: [], step: null, job: null, plot: null, pending: false };
  function resetLive() {
    live.t = [];
    live.x = [];
    live.p = [];
  }
  function onSamples(ev) {
    const d = ev.data || {};
    const xs = d.x_m || [];
    const ps = d.microphone_v || d.microphone_pa || [];
    const dt = d.dt_s || 0.001;
    const t0 = d.t0_s || 0;
    if (ev.job_id !== live.job || d.step !== live.step || (live.t.length && t0 < live.t[live.t.length - 1])) {
      resetLive();
      live.job = ev.job_id;
      live.step = d.step;
    }
    for (let i = 0; i < xs.length; i++) {
      live.t.push(t0 + i * dt);
      live.x.push(xs[i] * 1e3);
      live.p.push(ps[i] !== undefined ? ps[i] : null);
    }
    if (live.t.length > LIVE_POINTS) {
      const k = live.t.length - LIVE_POINTS;
      live.t.splice(0, k);
      live.x.splice(0, k);
      live.p.splice(0, k);
    }
    if (!live.pending) {
      live.pending = true;
      requestAnimationFrame(drawLive);
    }
  }
  function drawLive() {
    live.pending = false;
    if (ctx.stale()) return;
    const data = [live.t, live.x, live.p];
    if (!live.plot) {
      liveNote.textContent = '';
      live.plot = chart(liveEl, {
        title: 'Displacement and box pressure (microphone), decimated to 1 kHz',
        kind: 'live',
        x: { label: 'time in step', unit: 's' },
        y: { label: 'displacement x', unit: 'mm' },
        y2: { label: 'microphone', unit: 'V' },
        series: [
          { label: 'x', unit: 'mm' },
          { label: 'microphone', unit: 'V', y2: true },
        ],
        data,
        height: 220,
      });
    } else {
      live.plot.setData(data.map((a) => a.slice()));
    }
    liveEl.dataset.points = String(live.t.length);
    liveEl.dataset.step = live.step || '';
    liveNote.textContent = `job ${shortId(live.job)}, ${STEPS[live.step] || live.step}`;
  }

  // --- events ----------------------------------------------------------------
  let timer = null;
  const stream = events(
    (ev) => {
      if (ctx.stale()) return;
      if (ev.type === 'job.samples') onSamples(ev);
      else if (ev.type === 'job.progress') {
        updateProgress(ev.job_id, ev.data || {});
      } else if (ev.type === 'job.state' || ev.type === 'study.state') {
        // A study's step (its prompt) refreshes too; its `state` is the study's, not the job's.
        const j = jobs.get(ev.job_id);
        if (j && ev.type === 'job.state' && ev.data && ev.data.state) j.state = ev.data.state;
        if (timer) clearTimeout(timer);
        timer = setTimeout(refresh, 50);
      }
    },
    (open) => {
      wsState.textContent = open ? 'live' : 'reconnecting\u2026';
      wsState.className = open ? 'ok' : 'error';
      if (open) refresh();
    },
  );
  await refresh();
  // For the measured figure in docs/ui.md: navigation start to this point.
  if (!performance.getEntriesByName('springbench-first-view').length) performance.mark('springbench-first-view');
  // Fallback when events are lost: refresh every 5 s.
  const interval = setInterval(refresh, 5000);
  return () => {
    stream.close();
    clearInterval(interval);
    if (timer) clearTimeout(timer);
  };
}
