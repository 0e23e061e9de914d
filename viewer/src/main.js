// The plan viewer page: /v1/plans/{id}/view. Loads the plan document, the mesh geometry and
// the plan's per-face results, draws them, and exposes `window.vppViewer` for tests and scripts.
import { AuthError, HttpError, followEvents, getBinary, getJson, postJson, setKey, base } from './api.js';
import { unpack } from './packed.js';
import { DESCRIPTIONS, FIXED, GHOST, faceColours, fitScale, gradient, position } from './palette.js';
import { PlanScene } from './scene3d.js';

const $ = (id) => document.getElementById(id);
const POLL_MS = 1000;
const PLAY_MS = 1200;
const state = { plan: null, doc: null, meshId: null, geometry: null, scene: null, playing: null };
const view = new PlanScene($('canvas'), $('labels'));
view.onPick = (k) => select(k);
view.onInteract = () => leaveCamera();
view.onLabels = (shown, total) => {
  $('labels-note').textContent = shown < total ? `${total - shown} of ${total} numbers hidden where they would cover others: zoom in to see them` : '';
};

function status(text, error = false) {
  $('status').textContent = text;
  $('status').classList.toggle('error', error);
}

const NB = '\u00a0'; // a number and its unit never part at a line end
/** Text made safe inside HTML: region names and labels come from requests and uploads. */
const esc = (t) => String(t).replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);
const fmt = (x, d = 3) => (x === null || x === undefined ? '—' : Number(x).toFixed(d));
const pct = (x) => `${(100 * x).toFixed(1)}${NB}%`;
const mm = (x, d = 3) => `${fmt(x, d)}${NB}mm`;
const sec = (x) => `${fmt(x, 2)}${NB}s`;
/** A tour's cycle time: "C s = T s travel + D s dwell" (TourOut or RobotTourOut, seconds). */
const cycle = (t) => `${sec(t.cycle_time_s)} = ${sec(t.travel_s)} travel + ${sec(t.dwell_s)} dwell`;
const TIPS = {
  'cycle time': 'The tour once: the dwell at every viewpoint plus the travel of every leg (from '
    + 'and back to home where one is set) at the objective\'s speed and acceleration.',
  'joint cycle': 'The same tour in the robot\'s joint space: each leg as long as its slowest '
    + 'joint at its speed limit, plus the dwell.',
  'mean C': 'The paper\'s eq. 4: per counted face, the share of the selected viewpoints that '
    + 'see it, averaged over the faces (1 = every viewpoint sees every face).',
  'resolution met': 'Share of the counted area (and faces) whose achieved resolution r* is at '
    + 'or below the target r̄, with every selected viewpoint counted.',
  coverage: 'Share of the counted area (and faces) that at least one selected viewpoint sees.',
  'seen at points': 'The plan judged a second time at points spread evenly by area over the '
    + 'counted surface: the share a selected viewpoint sees (in its image and depth of field, '
    + 'within the incidence limit, nothing in front), next to the share any candidate sees; '
    + 'views the patch rows did not need but these points did are counted as added.',
  uncoverable: 'Faces that no candidate sees: no plan can cover them.',
  note: 'What the plan\'s diagnostics say to change when something other than the part\'s '
    + 'geometry drives it: its units, area elements, tilted candidates, a partial cover.',
};

const TERMINAL = ['succeeded', 'failed', 'canceled'];
const STAGE_NOTES = { compiling: ' (compiling the ray tracer once after install: about half a minute)' };

function jobStatus(status, p) {
  const note = (p && STAGE_NOTES[p.stage]) || '';
  return `Plan ${status}${p ? `: ${p.stage} ${p.done}/${p.total}` : ''}${note}…`;
}

/** The plan document once the plan's job has succeeded; meanwhile its progress, pushed by the
 * API (Server-Sent Events), or polled every POLL_MS where the stream fails. */
async function planDocument(plan) {
  let job = await getJson(`/v1/jobs/${plan}`); // asked first: no 404 while it runs
  api.polls = 1;
  status(jobStatus(job.status, job.progress));
  if (!TERMINAL.includes(job.status)) {
    try {
      let current = job.status;
      job = await followEvents(`/v1/jobs/${plan}/events`, (name, data) => {
        api.pushed += 1;
        if (name === 'status') current = data.status;
        if (name === 'progress') status(jobStatus(current, data));
      });
    } catch (e) {
      if (e instanceof AuthError || (e instanceof HttpError && e.status === 404)) throw e;
      console.info('job events unavailable, polling instead:', e.message || e);
      api.polling = true;
    }
  }
  while (!TERMINAL.includes(job.status)) {
    await new Promise((r) => setTimeout(r, POLL_MS));
    job = await getJson(`/v1/jobs/${plan}`);
    api.polls += 1;
    status(jobStatus(job.status, job.progress));
  }
  if (job.status === 'succeeded') return getJson(`/v1/plans/${plan}`);
  throw new Error(`the plan's job ${job.status}: ${job.error?.detail ?? ''}`);
}

/** Forget the plan shown while another loads: no selection, no camera view, no old figures,
 * cameras, colours or slider range (the part stays, grey). */
function forget() {
  if (!state.doc) return;
  select(null);
  state.doc = null;
  for (const id of ['metrics', 'legend', 'camera-info', 'links']) $(id).innerHTML = '';
  if (state.playing) $('play').click(); // stop the tour: there is none to step through
  $('summary').classList.add('pending');
  view.clearPlan();
  stepper(0);
  $('step-label').textContent = '– / 0';
}

async function load(plan) {
  const t0 = performance.now();
  status('Loading plan…');
  if (plan !== state.shown) forget();
  $('plan-id').textContent = plan.slice(0, 12);
  $('plan-id').title = plan;
  const doc = await planDocument(plan);
  status('Loading geometry and results…');
  const [geometry, scene] = await Promise.all([
    doc.mesh.id === state.meshId ? state.geometry : getBinary(`/v1/meshes/${doc.mesh.id}/geometry`)
      .then(unpack),
    getBinary(`/v1/plans/${plan}/scene`).then(unpack),
  ]);
  if (doc.mesh.id !== state.meshId) {
    view.setPart(geometry.arrays.vertices, geometry.arrays.faces);
    state.meshId = doc.mesh.id;
    state.geometry = geometry;
  }
  const a = scene.arrays;
  const r = judged(a, doc.target.resolution_mm);
  const scale = fitScale(a.state, r, doc.target.resolution_mm);
  const colours = faceColours(a.state, r, scale);
  const first = state.shown === undefined;
  Object.assign(state, { plan, doc, scene, shown: plan });
  Object.assign(view, { problems: $('problems').checked, states: a.state }); // painted once, next
  view.setPlan(colours, doc.viewpoints, doc.sensor, a.view_offsets, a.view_faces);
  view.setArm(a);
  view.setSetup(a);
  $('setup-toggle').hidden = !view.setup;
  if (first) view.fit(false);
  $('summary').classList.remove('pending');
  summary(doc);
  legend(doc, scene, scale);
  links(plan);
  stepper(doc.viewpoints.length);
  select(null);
  await formulations(plan);
  status('');
  api.loadSeconds = (performance.now() - t0) / 1000;
  api.ready = true;
}

// With regions each face has its own target r̄_f (scene array target_mm): its r* is shown scaled
// to the default target, r* · r̄ / r̄_f, so that one colour scale says "meets its own target".
function judged(a, target) {
  if (!a.target_mm) return a.resolution_mm;
  return a.resolution_mm.map((r, i) => (r * target) / a.target_mm[i]);
}

function summary(doc) {
  const m = doc.metrics;
  const s = doc.solver;
  const rows = [
    ['part', `${doc.mesh.faces.toLocaleString()}${NB}faces, ${fmt(doc.mesh.area_mm2, 1)}${NB}mm²`],
    ['target', `r̄ = ${mm(doc.target.resolution_mm, 2)}, ${doc.target.formulation}`],
    ['viewpoints', `${doc.viewpoints.length} of ${doc.candidates.length} candidates`],
    ['solver', `${s.name}: ${s.status}, objective ${fmt(s.objective, 2)}, bound ${fmt(s.bound, 2)}, gap ${fmt(s.gap, 4)}`],
    ['coverage', `${pct(m.coverage.area)} of area (max ${pct(m.coverage.max_area)}), ${pct(m.coverage.faces)} of faces`],
    ['resolution met', `${pct(m.resolution.met_area)} of area (max ${pct(m.resolution.max_met_area)}), ${pct(m.resolution.met_faces)} of faces`],
    ['median r*', mm(m.resolution.median_mm)],
    ['uncoverable', `${doc.uncoverable.faces}${NB}faces, ${fmt(doc.uncoverable.area_mm2, 2)}${NB}mm²`],
    ['tour', mm(doc.tour_length_mm, 0)],
    ...(doc.tour ? [['cycle time', cycle(doc.tour)]] : []),
    ...(doc.robot?.tour ? [['joint cycle', cycle(doc.robot.tour)]] : []),
    ['mean C', fmt(m.paper.C_mean, 4)],
  ];
  for (const g of m.regions || []) {
    const what = g.ignored
      ? `ignored: ${g.faces}${NB}faces, ${fmt(g.area_mm2, 1)}${NB}mm², not counted`
      : `r̄ = ${mm(g.resolution_mm, 2)}: met ${pct(g.met_area)} of ${fmt(g.area_mm2, 1)}${NB}mm² (max ${pct(g.max_met_area)})`;
    rows.push([`region ${esc(g.name)}`, what]);
  }
  if (doc.partial) rows.splice(5, 0, ['partial cover', `${pct(doc.partial.covered_fraction)} of coverable area (asked ${pct(doc.partial.min_coverage)})`]);
  const points = doc.partial?.points;
  if (points) rows.splice(6, 0, ['seen at points', seenAtPoints(points)]);
  const hint = doc.diagnostics?.hint;
  if (hint) rows.push(['note', esc(hint).replace(/(\d) (?=%|mm)/g, `$1${NB}`)]);
  const th = (k) => (TIPS[k] ? `<th title="${TIPS[k]}" class="tip">${k}</th>` : `<th>${k}</th>`);
  $('metrics').innerHTML = rows.map(([k, v]) => `<tr>${th(k)}<td>${v}</td></tr>`).join('');
  api.summary = Object.fromEntries(rows);
}

/** The plan judged at surface points (partial.points): seen, what the candidates reach, added. */
function seenAtPoints(p) {
  const added = p.added.length ? `; ${p.added.length} view${p.added.length > 1 ? 's' : ''} added for them` : '';
  return `${pct(p.seen_fraction)} of ${p.points.toLocaleString()}${NB}points (candidates ${pct(p.reach_fraction)})${added}`;
}

function legend(doc, scene, scale) {
  const t = doc.target.resolution_mm;
  const counts = [0, 0, 0, 0, 0];
  for (const s of scene.arrays.state) counts[s] += 1;
  const digits = (x) => Math.max(2, 1 - Math.floor(Math.log10(x)));
  const ticks = [scale.lo, Math.sqrt(scale.lo * t), t, Math.sqrt(t * scale.hi), scale.hi]
    .map((x) => `<span style="left:${100 * position(x, scale)}%">${fmt(x, digits(x))}</span>`);
  const swatch = (rgb) => `<span class="swatch" style="background:rgb(${rgb.join(',')})"></span>`;
  const own = scene.arrays.target_mm ? `<p>regions: each face against its own target; r* shown as r*·r̄/r̄<sub>face</sub></p>` : '';
  $('legend').innerHTML = `<h2>achieved resolution r* (mm, log scale)</h2>${own}
    <div class="bar" style="background:${gradient('met')} 0 0/50% 100% no-repeat, ${gradient('unmet')} 100% 0/50% 100% no-repeat">
      <div class="target" style="left:calc(50% - 1px)" title="target r̄ = ${t} mm"></div></div>
    <div class="ticks">${ticks.join('')}</div>
    <div class="halves"><span>meets r̄: ${counts[0]}${NB}faces</span><span>target r̄</span><span>misses r̄: ${counts[1]}${NB}faces</span></div>
    <ul class="legend-list">
      ${['uncovered', 'uncoverable', 'excluded'].map((k, i) => `<li class="state">${swatch(FIXED[k])}${DESCRIPTIONS[k]}: ${counts[i + 2]}${NB}faces</li>`).join('')}
      <li class="when-selected">${swatch([225, 232, 238])}faded: not seen by the selected viewpoint</li>
      <li class="when-problems">${swatch(GHOST)}pale: meets r̄ (problems only)</li>
      <li class="when-problems"><span class="dot"></span>a dot on each face that misses r̄, is uncovered or uncoverable, however small</li>
    </ul>`;
  api.stateCounts = counts;
  api.scale = scale;
}

function links(plan) {
  const p = `${base}/v1/plans/${plan}`;
  $('links').innerHTML = `<h2>documents</h2><a href="${p}">plan document (JSON)</a> ·
    <a href="${p}/plots/histogram.png">histogram</a> · <a href="${p}/plots/cameras.png">cameras</a>`;
}

async function formulations(plan) {
  const related = await getJson(`/v1/plans/${plan}/related`);
  api.related = related.plans;
  $('formulations').innerHTML = '';
  for (const r of related.plans) {
    const b = document.createElement('button');
    b.dataset.formulation = r.formulation;
    b.textContent = r.available || r.id === plan ? r.formulation : `${r.formulation} (compute)`;
    b.classList.toggle('active', r.id === plan);
    b.addEventListener('click', () => switchTo(r));
    $('formulations').append(b);
  }
}

async function switchTo(related) {
  if (related.id === state.plan) return;
  api.ready = false;
  for (const b of $('formulations').children) {
    b.classList.toggle('active', b.dataset.formulation === related.formulation);
    if (b.dataset.formulation === related.formulation && !related.available) {
      b.textContent = `${related.formulation} (computing…)`;
    }
  }
  try {
    if (!related.available) await postJson('/v1/plans', related.request);
  } catch (e) {
    status(`Could not submit the ${related.formulation} plan: ${e.message || e}`, true);
    await formulations(state.plan);
    api.ready = true; // the plan shown is still whole
    return;
  }
  history.replaceState(null, '', `${base}${related.view_url}`);
  await run(related.id);
}

function stepper(n) {
  $('step').max = String(Math.max(n, 1));
  $('step').disabled = n === 0;
}

/** Back from looking through a camera: the frame and caption gone, the other cameras back. */
function leaveCamera() {
  $('frame').hidden = true;
  $('through').hidden = true;
  if (view.frame) { view.frame = null; view.applyVisibility(); view.render(); }
}

function select(k) {
  view.select(k);
  $('look').disabled = k === null;
  $('side').classList.toggle('has-selection', k !== null);
  $('step').value = String(k === null ? 0 : k + 1);
  $('step-label').textContent = `${k === null ? '–' : k + 1} / ${state.doc?.viewpoints.length ?? 0}`;
  if (k === null) {
    $('camera-info').hidden = true;
    if (view.frame) { leaveCamera(); view.fit(false); }
    return;
  }
  const v = state.doc.viewpoints[k];
  const faces = view.facesOf(k);
  const met = faces.reduce((n, f) => n + (state.scene.arrays.state[f] === 0 ? 1 : 0), 0);
  const vec = (x) => `[${x.map((c) => c.toFixed(3)).join(', ')}]`;
  const c2w = v.camera_to_world.map((r) => r.map((c) => c.toFixed(4).padStart(10)).join(' ')).join('\n');
  $('camera-info').hidden = false;
  $('camera-info').innerHTML = `<h2>viewpoint ${k + 1} of ${state.doc.viewpoints.length} (candidate ${v.id})</h2>
    <table>
      <tr><th>position</th><td id="cam-position">${vec(v.position)}</td></tr>
      <tr><th>gaze</th><td id="cam-gaze">${vec(v.gaze)}</td></tr>
      <tr><th>up</th><td id="cam-up">${vec(v.up)}</td></tr>
      <tr><th>sees</th><td id="cam-faces">${faces.length}${NB}faces; <span class="tip" title="Of the faces this viewpoint sees, those whose achieved resolution r* meets the target r̄ once every selected viewpoint is counted.">${met} of them meet r̄ in the plan</span></td></tr>
    </table>
    <div>camera_to_world (OpenCV frame, mm)</div><pre id="cam-matrix">${c2w}</pre>`;
}

function step(delta) {
  const n = state.doc?.viewpoints.length ?? 0; // none while a plan loads
  if (!n) return;
  const k = view.selected === null ? (delta > 0 ? 0 : n - 1) : (view.selected + delta + n) % n;
  select(k);
  if (view.frame) look();
}

function look() {
  if (view.selected === null) return null;
  const out = view.lookThrough(view.selected);
  const [x, y, w, h] = out.frame;
  Object.assign($('frame').style, { left: `${x}px`, top: `${y}px`, width: `${w}px`, height: `${h}px` });
  $('frame').hidden = false;
  const v = state.doc.viewpoints[view.selected];
  $('through').textContent = `looking through viewpoint ${view.selected + 1} of ${state.doc.viewpoints.length}`
    + ` (candidate ${v.id}): its sensor frame · drag to leave`;
  $('through').hidden = false;
  return out;
}

function wire() {
  $('prev').onclick = () => step(-1);
  $('next').onclick = () => step(1);
  $('step').oninput = (e) => { select(Number(e.target.value) - 1 < 0 ? null : Number(e.target.value) - 1); if (view.frame) look(); };
  $('play').onclick = () => {
    if (state.playing) { clearInterval(state.playing); state.playing = null; $('play').textContent = 'play'; return; }
    $('play').textContent = 'stop';
    state.playing = setInterval(() => step(1), PLAY_MS);
  };
  $('look').onclick = look;
  $('fit').onclick = () => { leaveCamera(); view.fit(true); };
  $('fit-part').onclick = () => { leaveCamera(); view.fit(false); };
  $('problems').onchange = (e) => {
    $('side').classList.toggle('problems', e.target.checked);
    view.setProblemsOnly(e.target.checked, state.scene.arrays.state);
  };
  $('clear').onclick = () => select(null);
  for (const what of ['frusta', 'tour', 'labels', 'setup']) {
    $(`show-${what}`).onchange = (e) => view.show(what, e.target.checked);
  }
  $('shading').onchange = (e) => view.setShading(e.target.checked);
  addEventListener('keydown', (e) => {
    if (e.key === 'ArrowRight') step(1);
    if (e.key === 'ArrowLeft') step(-1);
  });
  $('key-form').onsubmit = (e) => {
    e.preventDefault();
    setKey($('key').value);
    $('key-form').hidden = true;
    run(state.plan);
  };
}

async function run(plan) {
  state.plan = plan;
  api.failed = null;
  try {
    await load(plan);
  } catch (e) {
    if (e instanceof AuthError) {
      status('An API key is needed (or the one given was refused).', true);
      $('key-form').hidden = false;
    } else {
      status(String(e.message || e), true);
      console.warn(e);
    }
    api.failed = String(e.message || e);
  }
}

// for tests and scripts: the page's state and a few actions
const api = {
  ready: false,
  /** GET /v1/jobs/{id} made while waiting for the plan, events pushed, whether it fell back. */
  polls: 0,
  pushed: 0,
  polling: false,
  get plan() { return state.plan; },
  get doc() { return state.doc; },
  cameraCount: () => view.labels?.length ?? 0,
  frustumSegments: () => (view.frusta?.geometry.getAttribute('position').count ?? 0) / 2,
  screenPosition: (k) => view.screenPosition(k),
  selected: () => view.selected,
  select,
  look: (k) => { select(k); return look(); },
  faceColours: () => Array.from(view.colours),
  shownColours: () => Array.from(view.shown),
  facing: () => view.facing(),
  fit: (all = true) => view.fit(all),
  labelBoxes: () => view.labelBoxes(),
  drawnCameras: () => ({ frusta: view.frusta.visible, tour: view.tour.visible }),
  partBox: () => view.partBox(),
  /** The arm drawn at the selected viewpoint: {visible, min, max} of its vertices (null: no arm). */
  arm: () => view.armState(),
  /** The setup drawn: {shown, floor, fixtures, keep_out}, each {visible, min, max} (world mm)
   * or null; null when the plan has no floor, fixtures or keep-out meshes. */
  setup: () => view.setupState(),
  problemsOnly: (on) => { $('problems').checked = on; $('problems').onchange({ target: $('problems') }); },
  setShading: (on) => { $('shading').checked = on; view.setShading(on); },
  show: (what, on) => view.show(what, on),
  drawn: () => view.drawn(),
  problemMarks: () => view.problemMarks(),
  /** Mean milliseconds per frame over a full turn of the eye in n drawn steps (benchmarks). */
  orbit: async (n = 60) => {
    const t0 = performance.now();
    for (let i = 0; i < n; i++) { view.rotate((2 * Math.PI) / n); await view.drawn(); }
    return (performance.now() - t0) / n;
  },
};
window.vppViewer = api;
wire();
run(location.pathname.slice(location.pathname.indexOf('/v1/plans/') + 10).split('/')[0]);
