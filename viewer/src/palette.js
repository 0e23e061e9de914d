// Face colours: achieved resolution r* against the target r̄, and the face states of
// vpp_core/report/scene.py (met, unmet, uncovered, uncoverable, excluded). sRGB bytes.
export const STATES = ['met', 'unmet', 'uncovered', 'uncoverable', 'excluded'];
export const SPAN = 2; // the scale runs over r* in [0, SPAN·r̄]; beyond it, the last colour
const MET = [[8, 69, 148], [66, 146, 198], [116, 196, 118]]; // fine → just meets r̄
const UNMET = [[254, 224, 139], [253, 141, 60], [189, 0, 38]]; // just misses → ≥ SPAN·r̄
export const FIXED = {
  uncovered: [208, 28, 139], // seen by some candidate, by no selected viewpoint
  uncoverable: [85, 85, 85], // seen by no candidate
  excluded: [190, 190, 190], // degenerate or duplicate face, not counted
};
export const DESCRIPTIONS = {
  uncovered: 'uncovered: no selected viewpoint sees it (another candidate does)',
  uncoverable: 'uncoverable: no candidate sees it',
  excluded: 'not counted: degenerate or duplicate face',
};

function ramp(stops, t) {
  const x = Math.min(Math.max(t, 0), 1) * (stops.length - 1);
  const i = Math.min(Math.floor(x), stops.length - 2);
  const f = x - i;
  return stops[i].map((a, k) => Math.round(a + (stops[i + 1][k] - a) * f));
}

/** sRGB [r, g, b] of a face with state index `state` and achieved resolution `r` (mm). */
export function faceColour(state, r, target) {
  const name = STATES[state];
  if (name in FIXED) return FIXED[name];
  if (name === 'met') return ramp(MET, r / target);
  return ramp(UNMET, (r / target - 1) / (SPAN - 1));
}

/** (M·3) Uint8Array of face colours for the scene's state and resolution arrays. */
export function faceColours(state, resolution, target) {
  const out = new Uint8Array(state.length * 3);
  for (let i = 0; i < state.length; i++) out.set(faceColour(state[i], resolution[i], target), 3 * i);
  return out;
}

/** CSS linear-gradient of one ramp: the met part (0..r̄) or the unmet part (r̄..SPAN·r̄). */
export function gradient(which) {
  const stops = which === 'met' ? MET : UNMET;
  return `linear-gradient(to right, ${stops.map((c) => `rgb(${c.join(',')})`).join(', ')})`;
}
