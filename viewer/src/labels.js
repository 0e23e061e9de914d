// Placing number labels on the canvas so that none covers another: greedy, in the order given,
// each at its anchor if free, else at the first free spot on rings around it.
const GAP = 2; // px kept between two labels
const RINGS = 4; // rings of candidate spots around the anchor, each a label height farther
const DIRECTIONS = 12;
const CELL = 32; // px: placed labels are kept in a grid of such cells, for quick look-ups

/** Top-left corners [x, y] (px) of labels {x, y, w, h} (anchor centre, size in px) inside a
 * width × height canvas, none overlapping another; null for a label with no free spot. */
export function placeLabels(labels, width, height) {
  const grid = new Map();
  return labels.map(({ x, y, w, h }) => {
    for (const [dx, dy] of spots(h)) {
      const r = [x - w / 2 + dx, y - h / 2 + dy, w, h];
      if (r[0] < 0 || r[1] < 0 || r[0] + w > width || r[1] + h > height) continue;
      if (cells(r).some((c) => grid.get(c)?.some((q) => overlaps(q, r)))) continue;
      for (const c of cells(r)) grid.set(c, [...(grid.get(c) ?? []), r]);
      return [r[0], r[1]];
    }
    return null;
  });
}

/** Grid cells a rectangle (grown by GAP) touches, as keys. */
function cells(r) {
  const out = [];
  for (let i = Math.floor((r[0] - GAP) / CELL); i <= Math.floor((r[0] + r[2] + GAP) / CELL); i++) {
    for (let j = Math.floor((r[1] - GAP) / CELL); j <= Math.floor((r[1] + r[3] + GAP) / CELL); j++) {
      out.push(i * 100003 + j);
    }
  }
  return out;
}

function overlaps(a, b) {
  return a[0] < b[0] + b[2] + GAP && b[0] < a[0] + a[2] + GAP
    && a[1] < b[1] + b[3] + GAP && b[1] < a[1] + a[3] + GAP;
}

const cache = new Map();
/** Offsets from the anchor, nearest first: the anchor, then RINGS rings of DIRECTIONS spots. */
function spots(h) {
  if (!cache.has(h)) {
    const out = [[0, 0]];
    for (let ring = 1; ring <= RINGS; ring++) {
      for (let i = 0; i < DIRECTIONS; i++) {
        const a = (2 * Math.PI * i) / DIRECTIONS - Math.PI / 2;
        out.push([Math.cos(a) * ring * (h + GAP) * 1.3, Math.sin(a) * ring * (h + GAP)]);
      }
    }
    cache.set(h, out);
  }
  return cache.get(h);
}
