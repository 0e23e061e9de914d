// Face colours: achieved resolution r* against the target r̄, and the face states of
// vpp_core/report/scene.py (met, unmet, uncovered, uncoverable, excluded). sRGB bytes.
// The same colours are vpp_core/report/plots.py's PALETTE (a test keeps the two equal).
//
// The scale is diverging around r̄ and logarithmic, fitted to the plan: met faces run from
// dark blue (the finest r*, 2nd percentile) to light green (just meets r̄), unmet ones from
// yellow (just misses) to dark red (98th percentile of the unmet r*, and beyond).
export const STATES = ['met', 'unmet', 'uncovered', 'uncoverable', 'excluded'];
const MET = [[8, 69, 148], [66, 146, 198], [116, 196, 118]]; // finest → just meets r̄
const UNMET = [[254, 224, 139], [253, 141, 60], [189, 0, 38]]; // just misses → worst
export const FIXED = {
  uncovered: [208, 28, 139], // seen by some candidate, by no selected viewpoint
  uncoverable: [85, 85, 85], // seen by no candidate
  excluded: [176, 160, 128], // degenerate or duplicate face, not counted
};
export const GHOST = [236, 238, 241]; // a met face under "problems only"
export const DESCRIPTIONS = {
  uncovered: 'uncovered: no selected viewpoint sees it (another candidate does)',
  uncoverable: 'uncoverable: no candidate sees it',
  excluded: 'not counted: degenerate or duplicate face',
};
const PERCENTILE = 0.02; // the scale's ends: this share of the faces lies beyond each
const MIN_SPAN = 1.25; // each half of the scale covers at least this ratio of r*
const MAX_SPAN = 100;

function ramp(stops, t) {
  const x = Math.min(Math.max(t, 0), 1) * (stops.length - 1);
  const i = Math.min(Math.floor(x), stops.length - 2);
  const f = x - i;
  return stops[i].map((a, k) => Math.round(a + (stops[i + 1][k] - a) * f));
}

function quantile(values, q) {
  const s = Float32Array.from(values).sort();
  return s[Math.min(s.length - 1, Math.floor(q * s.length))];
}

/** The plan's scale {target, lo, hi} (mm): r* from lo to r̄ for met faces, r̄ to hi for unmet. */
export function fitScale(state, resolution, target) {
  const met = [];
  const unmet = [];
  for (let i = 0; i < state.length; i++) {
    if (state[i] === 0) met.push(resolution[i]);
    else if (state[i] === 1 && Number.isFinite(resolution[i])) unmet.push(resolution[i]);
  }
  const clamp = (x) => Math.min(Math.max(x, MIN_SPAN), MAX_SPAN);
  const lo = met.length ? target / clamp(target / quantile(met, PERCENTILE)) : target / 2;
  const hi = unmet.length ? target * clamp(quantile(unmet, 1 - PERCENTILE) / target) : 2 * target;
  return { target, lo, hi };
}

/** Position of r (mm) on the scale's bar: 0 at lo, 0.5 at r̄, 1 at hi (log within halves). */
export function position(r, { target, lo, hi }) {
  if (r <= target) return 0.5 * (1 - Math.log(target / Math.max(r, 1e-12)) / Math.log(target / lo));
  return 0.5 * (1 + Math.log(r / target) / Math.log(hi / target));
}

/** sRGB [r, g, b] of a face with state index `state` and achieved resolution `r` (mm). */
export function faceColour(state, r, scale) {
  const name = STATES[state];
  if (name in FIXED) return FIXED[name];
  const t = Math.min(Math.max(position(r, scale), 0), 1);
  return name === 'met' ? ramp(MET, 2 * t) : ramp(UNMET, 2 * t - 1);
}

/** (M·3) Uint8Array of face colours for the scene's state and resolution arrays. */
export function faceColours(state, resolution, scale) {
  const out = new Uint8Array(state.length * 3);
  for (let i = 0; i < state.length; i++) out.set(faceColour(state[i], resolution[i], scale), 3 * i);
  return out;
}

/** CSS linear-gradient of one ramp: the met part (lo..r̄) or the unmet part (r̄..hi). */
export function gradient(which) {
  const stops = which === 'met' ? MET : UNMET;
  return `linear-gradient(to right, ${stops.map((c) => `rgb(${c.join(',')})`).join(', ')})`;
}
