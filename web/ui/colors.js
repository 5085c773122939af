// One colour per robot for its marker, trail, path, goal and card: the first free colour of the
// palette from a hash of the name, kept for the page's life (a robot never changes colour while
// watched; 10 robots get 10 different colours).

const PALETTE = [
  "#4fc3f7", "#ffb300", "#ab47bc", "#66bb6a", "#ff7043",
  "#26c6da", "#ec407a", "#d4e157", "#8d6e63", "#5c6bc0",
  "#26a69a", "#ffee58",
];

const assigned = new Map();

function hash(s) {
  let h = 2166136261;
  for (const c of s) h = Math.imul(h ^ c.charCodeAt(0), 16777619) >>> 0;
  return h;
}

/** The colour of robot `name`. */
export function robotColor(name) {
  let c = assigned.get(name);
  if (c) return c;
  const used = new Set(assigned.values());
  const start = hash(name) % PALETTE.length;
  for (let i = 0; i < PALETTE.length; i++) {
    const cand = PALETTE[(start + i) % PALETTE.length];
    if (!used.has(cand)) { c = cand; break; }
  }
  c = c || PALETTE[start];
  assigned.set(name, c);
  return c;
}
